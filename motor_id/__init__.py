"""motor_id: identify a DC motor's physical parameters from voltage, speed and current."""

__version__ = '0.1.0'
