"""Shared node plumbing: table-driven parameters with ranges, and the spin/shutdown main."""

from dataclasses import dataclass
import re
import sys

from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                SetParametersResult)
import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

from motor_id.errors import ConfigError

RCLError = _rclpy.RCLError


@dataclass(frozen=True)
class ParamSpec:
    """One node parameter: name, default, meaning and what values are allowed.

    Attributes
    ----------
    name : str
    default : bool, int, float or str
        Also fixes the type (unless ``dynamic``).
    description : str
    low, high : float or int, optional
        Inclusive range for numbers (enforced by ROS through the descriptor).
    choices : tuple of str, optional
        Allowed values for strings (checked here; ROS descriptors have no enum).
    dynamic : bool
        Accept any type (e.g. ``auto`` or a bool); ``choices`` then lists every
        allowed value.
    read_only : bool
    """

    name: str
    default: object
    description: str
    low: float = None
    high: float = None
    choices: tuple = None
    dynamic: bool = False
    read_only: bool = False

    def allowed(self):
        """The allowed values, in words."""
        if self.choices is not None:
            return 'one of ' + ', '.join(str(c).lower() if isinstance(c, bool) else str(c)
                                         for c in self.choices)
        if self.low is not None:
            return f'{self.low} .. {self.high}'
        return f'a {type(self.default).__name__}'

    def descriptor(self):
        """The ROS parameter descriptor with the range."""
        d = ParameterDescriptor(description=f'{self.description} ({self.allowed()})',
                                read_only=self.read_only, dynamic_typing=self.dynamic)
        if self.low is not None and isinstance(self.default, float):
            d.floating_point_range = [FloatingPointRange(
                from_value=float(self.low), to_value=float(self.high), step=0.0)]
        elif self.low is not None and isinstance(self.default, int):
            d.integer_range = [IntegerRange(from_value=int(self.low), to_value=int(self.high),
                                            step=1)]
        return d

    def check(self, value):
        """Raise :class:`ConfigError` naming the parameter if ``value`` is not allowed."""
        if self.choices is not None and not any(
                value == c and type(value) is type(c) for c in self.choices):
            raise ConfigError(f'parameter {self.name}: got {value!r}; allowed: '
                              f'{self.allowed()}')


def declare_parameters(node, specs):
    """Declare ``specs`` on ``node`` and return ``{name: value}``.

    Raises
    ------
    ConfigError
        One line naming the first parameter that is out of range, of the wrong type or
        not among its choices, with the allowed values.
    """
    values = {}
    for spec in specs:
        try:
            param = node.declare_parameter(spec.name, spec.default, spec.descriptor())
        except ParameterException as exc:
            text = str(exc.args[0]) if exc.args else str(exc)
            m = re.search(r'value \((.*?)\) for parameter', text)
            m2 = re.search(r"to '(.*?)' of type '(\w+)'", text)
            if m:
                got = m.group(1)
            elif m2:
                got = (f'{m2.group(1)} of type {m2.group(2).lower()}, expected a '
                       f'{type(spec.default).__name__}')
            else:
                got = text
            raise ConfigError(f'parameter {spec.name}: got {got}; allowed: '
                              f'{spec.allowed()}') from None
        spec.check(param.value)
        values[spec.name] = param.value
    by_name = {s.name: s for s in specs}

    def on_set(params):
        for p in params:
            spec = by_name.get(p.name)
            if spec is None:
                continue
            try:
                spec.check(p.value)
            except ConfigError as exc:
                return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    node.add_on_set_parameters_callback(on_set)
    return values


def run_node(factory, name, num_threads=4, args=None):
    """Init rclpy, build the node, spin it, and shut down quietly.

    Ctrl-C and SIGTERM end with exit code 0 and no traceback; a :class:`ConfigError`
    from the constructor is logged as one line and gives exit code 2.

    Parameters
    ----------
    factory : callable
        Returns the node (called after ``rclpy.init``).
    name : str
        Logger name for start-up errors.
    num_threads : int
        MultiThreadedExecutor threads.
    args : list of str, optional
        Command line (default ``sys.argv``).

    Returns
    -------
    int
        Exit code.
    """
    try:
        rclpy.init(args=sys.argv if args is None else args)
    except RCLError as exc:
        print(f'{name}: bad command line: {exc}', file=sys.stderr)
        return 2
    node = None
    try:
        try:
            node = factory()
        except ConfigError as exc:
            rclpy.logging.get_logger(name).fatal(f'{exc}')
            return 2
        executor = MultiThreadedExecutor(num_threads=num_threads)
        executor.add_node(node)
        try:
            executor.spin()
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        except RCLError:
            if rclpy.ok():
                raise   # a real error, not a publish racing the shutdown
        finally:
            if hasattr(node, 'stop'):
                node.stop()
            executor.shutdown(timeout_sec=5.0)
    except KeyboardInterrupt:
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
