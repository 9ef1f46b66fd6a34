"""Controller-ready results from an identified DC motor: feedforward constants and PI gains.

design    the design rules: time constants, feedforward, PI gains, error bars
loops     the loop checks on the full model (margins, crossovers, closed-loop bandwidth)
result    what a design produced (ControllerDesign and its records), its JSON and table
export    a design from a fit (or its JSON), and as ROS parameters
"""

from motor_id.contracts import INPUT_KINDS
from motor_id.controller.design import (
    BANDWIDTH_RATIO,
    controller_constants,
    CONVENTION,
    design_controller,
    FD_RELATIVE_STEP,
    KS_SOURCES,
    SAMPLE_FRACTION,
    time_constants,
    TORQUE_NAMES,
    TORQUE_ZERO_RATIO,
    VOLTAGE_NAMES,
)
from motor_id.controller.export import from_fit, from_identification, to_ros_parameters
from motor_id.controller.loops import (
    DELAY_SAMPLES,
    loop_transfer_functions,
    LoopCheck,
    margins,
    pade_delay,
    PADE_ORDER,
)
from motor_id.controller.result import (
    ControllerDesign,
    Feedforward,
    LoopDesign,
    PiLoops,
    Quantity,
    TimeConstants,
)

__all__ = ['BANDWIDTH_RATIO', 'CONVENTION', 'controller_constants', 'ControllerDesign',
           'DELAY_SAMPLES', 'design_controller', 'FD_RELATIVE_STEP', 'Feedforward', 'from_fit',
           'from_identification', 'INPUT_KINDS', 'KS_SOURCES', 'LoopCheck', 'LoopDesign',
           'loop_transfer_functions', 'margins', 'pade_delay', 'PADE_ORDER', 'PiLoops',
           'Quantity', 'SAMPLE_FRACTION', 'time_constants', 'TimeConstants',
           'to_ros_parameters', 'TORQUE_NAMES', 'TORQUE_ZERO_RATIO', 'VOLTAGE_NAMES']
