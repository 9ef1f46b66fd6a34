"""The one reach into rclpy internals: the exception type rcl errors are raised as."""

# ---------------------------------------------------------------------------- shim --
# Why: rclpy (Jazzy) raises ``RCLError`` from its C extension, e.g. for a malformed
# ``--ros-args`` command line in ``rclpy.init`` or a publish racing a context shutdown,
# but exports it under no public module. rclpy's own modules reach it through
# ``implementation_singleton``; this is the only place motor_id does the same. Remove
# when rclpy exports the type publicly.
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

RCLError = _rclpy.RCLError
# ------------------------------------------------------------------------ end shim --
