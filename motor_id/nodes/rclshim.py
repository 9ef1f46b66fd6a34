"""The reaches into rclpy internals: the rcl error type, an executor's handed-out callbacks."""

import time
from typing import Any

# ---------------------------------------------------------------------------- shim --
# Why: rclpy (Jazzy) raises ``RCLError`` from its C extension, e.g. for a malformed
# ``--ros-args`` command line in ``rclpy.init`` or a publish racing a context shutdown,
# but exports it under no public module. rclpy's own modules reach it through
# ``implementation_singleton``; this is the only place motor_id does the same. Remove
# when rclpy exports the type publicly.
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

RCLError = _rclpy.RCLError
# ------------------------------------------------------------------------ end shim --


# ---------------------------------------------------------------------------- shim --
# Why: ``Executor.shutdown`` is documented to wait for the callbacks still running, but
# in Jazzy it does not (its wait is skipped by the flag it has just set), and it destroys
# the executor's guard condition. A callback a MultiThreadedExecutor handed to its thread
# pool just before spinning stopped (the wake-up of a stop request, a timer) may still be
# queued; when it runs it triggers that destroyed guard, and its task holds
# "cannot use Destroyable because destruction was requested", printed at exit as "The
# following exception was never retrieved". The executor keeps those tasks in
# ``_futures``; this waits for them. Remove when ``shutdown`` waits.
def wait_for_handed_out_callbacks(executor: Any, timeout: float = 10.0,
                                  ) -> tuple[bool, list[BaseException]]:
    """Wait until every callback ``executor`` handed to its threads has finished.

    Call after spinning has stopped (nothing new is handed out) and before
    ``executor.shutdown()``. A SingleThreadedExecutor runs callbacks in the spinning
    thread and has none pending then.

    Parameters
    ----------
    executor : rclpy.executors.Executor
    timeout : float
        [s]

    Returns
    -------
    (bool, list of BaseException)
        Whether all finished in time, and the exceptions they raised (retrieved, so
        not printed at exit; the caller logs them).
    """
    tasks = list(getattr(executor, '_futures', ()))
    deadline = time.monotonic() + timeout
    while not all(t.done() for t in tasks):
        if time.monotonic() > deadline:
            return False, []
        time.sleep(0.005)
    return True, [e for e in (t.exception() for t in tasks) if e is not None]
# ------------------------------------------------------------------------ end shim --
