"""Shared node plumbing: parameters with ranges, the stop signal, topic checks, the main."""

from collections.abc import Callable, Iterable
from dataclasses import dataclass
import functools
import re
import sys
import threading
from typing import Any

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import (
    Executor,
    ExternalShutdownException,
    MultiThreadedExecutor,
    SingleThreadedExecutor,
)
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from motor_id.errors import ConfigError
from motor_id.lifeline import SignalThread
from motor_id.nodes.rclshim import RCLError, wait_for_handed_out_callbacks


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
    syntax : str, optional
        The allowed values in words, for values that ``validator`` checks.
    validator : callable, optional
        ``validator(value, name)`` raises :class:`ConfigError` (its message starting
        with ``name``) when ``value`` is not allowed.
    """

    name: str
    default: object
    description: str
    low: float | None = None
    high: float | None = None
    choices: tuple[object, ...] | None = None
    dynamic: bool = False
    read_only: bool = False
    syntax: str | None = None
    validator: Callable[[Any, str], object] | None = None

    def allowed(self) -> str:
        """The allowed values, in words."""
        if self.syntax is not None:
            return self.syntax
        if self.choices is not None:
            return 'one of ' + ', '.join(str(c).lower() if isinstance(c, bool) else str(c)
                                         for c in self.choices)
        if self.low is not None:
            return f'{self.low} .. {self.high}'
        return f'a {type(self.default).__name__}'

    def descriptor(self) -> ParameterDescriptor:
        """The ROS parameter descriptor with the range."""
        d = ParameterDescriptor(description=f'{self.description} ({self.allowed()})',
                                read_only=self.read_only, dynamic_typing=self.dynamic)
        low, high = self.low, self.high
        if low is not None and high is not None and isinstance(self.default, float):
            d.floating_point_range = [FloatingPointRange(
                from_value=float(low), to_value=float(high), step=0.0)]
        elif low is not None and high is not None and isinstance(self.default, int):
            d.integer_range = [IntegerRange(from_value=int(low), to_value=int(high),
                                            step=1)]
        return d

    def check(self, value: Any) -> None:
        """Raise :class:`ConfigError` naming the parameter if ``value`` is not allowed."""
        if self.choices is not None and not any(
                value == c and type(value) is type(c) for c in self.choices):
            raise ConfigError(f'parameter {self.name}: got {value!r}; allowed: '
                              f'{self.allowed()}')
        if self.validator is not None:
            try:
                self.validator(value, self.name)
            except ConfigError as exc:
                raise ConfigError(f'parameter {exc}; allowed: {self.allowed()}') from None


def declare_parameters(node: Node, specs: Iterable[ParamSpec]) -> dict[str, Any]:
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

    def on_set(params: list[Any]) -> SetParametersResult:
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


class InFlight:
    """Count callbacks running in executor threads, so that shutdown can wait for them.

    rclpy's ``MultiThreadedExecutor.shutdown`` does not wait for callbacks already
    running in its thread pool; destroying the node under one of them is a race.
    Wrap every callback with :meth:`wrap` and call :meth:`wait_idle` before
    ``destroy_node``.
    """

    def __init__(self) -> None:
        self._count = 0
        self._cond = threading.Condition()

    def wrap(self, callback: Callable[..., Any]) -> Callable[..., Any]:
        """The callback, counted while it runs (same signature for rclpy's inspection)."""
        @functools.wraps(callback)
        def counted(*args: Any) -> Any:
            with self._cond:
                self._count += 1
            try:
                return callback(*args)
            finally:
                with self._cond:
                    self._count -= 1
                    self._cond.notify_all()
        return counted

    def wait_idle(self, timeout: float = 5.0) -> bool:
        """Wait until no wrapped callback runs; return False on timeout."""
        with self._cond:
            return self._cond.wait_for(lambda: self._count == 0, timeout)


class StopSignal:
    """A stop request that ends :meth:`spin` of an executor, from any thread.

    :meth:`spin` runs ``executor.spin_once()`` until :meth:`set` is called (or the
    context shuts down). :meth:`set` first sets an event, then triggers a guard condition
    on every attached node, so the executor wakes, runs the (empty) guard callback and
    returns from ``spin_once``; the loop then sees the event. Nothing is added per spin
    (``Executor.spin_until_future_complete`` adds a done-callback to its future on every
    spin, which grows without bound for a future that lives as long as the node), and a
    request made before spinning starts, even before the node exists, is not lost.
    """

    def __init__(self) -> None:
        self._event = threading.Event()
        self._lock = threading.Lock()
        self._guards: list[Any] = []

    def attach(self, node: Node) -> None:
        """Make :meth:`set` wake the executor that spins ``node``."""
        guard = node.create_guard_condition(_no_op)
        with self._lock:
            self._guards.append(guard)
            if self._event.is_set():
                guard.trigger()

    def detach(self) -> None:
        """Forget the guard conditions (call before destroying the attached nodes)."""
        with self._lock:
            self._guards = []

    def set(self) -> None:
        """Request the stop (idempotent; thread-safe)."""
        with self._lock:
            if self._event.is_set():
                return
            self._event.set()
            for guard in self._guards:
                guard.trigger()

    def is_set(self) -> bool:
        """Whether the stop was requested."""
        return self._event.is_set()

    def wait(self, timeout: float | None = None) -> bool:
        """Block until the stop is requested; return whether it was."""
        return self._event.wait(timeout)

    def spin(self, executor: Executor) -> None:
        """Spin ``executor`` until the stop is requested or its context shuts down."""
        while not self._event.is_set() and executor.context.ok():
            executor.spin_once()


def _no_op() -> None:
    """Guard-condition callback: waking the executor is all it is for."""


class TopicWatch:
    """Watch what a topic carries until a publisher of the expected type is found.

    A subscription to a topic of another type (``samples`` remapped to a JointState
    topic, say) matches nothing and says nothing; :meth:`check`, called from a timer,
    asks the graph (``get_topic_names_and_types``, then the publishers' types, since
    the graph also lists this node's own subscription) and warns once naming the type
    the publishers have. When a publisher of the right type appears, ``on_found(endpoints)`` is
    called once with its ``TopicEndpointInfo`` list and the timer is cancelled.

    Parameters
    ----------
    node : rclpy.node.Node
    topic : str
        Name as subscribed (relative names resolve in the node's namespace).
    type_name : str
        E.g. ``'std_msgs/msg/Float64MultiArray'``.
    on_found : callable, optional
    period_s : float
        How often to look [s].
    """

    def __init__(self, node: Node, topic: str, type_name: str,
                 on_found: Callable[[list[Any]], None] | None = None,
                 period_s: float = 1.0) -> None:
        self.node = node
        self.name = node.resolve_topic_name(topic)
        self.type_name = type_name
        self.on_found = on_found
        self.found = False
        self.wrong_type: list[str] | None = None
        self._timer = node.create_timer(period_s, self.check)

    def check(self) -> bool:
        """Look once; return whether a publisher of the right type was found."""
        if self.found:
            return True
        if self.name not in dict(self.node.get_topic_names_and_types()):
            return False
        publishers = self.node.get_publishers_info_by_topic(self.name)
        endpoints = [e for e in publishers if e.topic_type == self.type_name]
        types = sorted({e.topic_type for e in publishers})
        if not endpoints and types and self.wrong_type != types:
            self.wrong_type = types
            self.node.get_logger().warning(
                f'topic {self.name} has type {", ".join(types)}, not {self.type_name}: '
                f'nothing from it is received; remap to a topic of type {self.type_name}')
        if not endpoints:
            return False
        self.found = True
        self._timer.cancel()
        if self.on_found is not None:
            self.on_found(endpoints)
        return True


class SignalWatcher(SignalThread):
    """Turn SIGINT, SIGTERM and SIGHUP into a clean end of spinning, the context valid.

    rclpy's own handlers shut the context down inside the signal handler, so the node
    is then destroyed on a dead context, and ``Executor.shutdown`` from another thread
    destroys the guard condition that a running ``spin`` waits on (Jazzy). Instead a
    :class:`~motor_id.lifeline.SignalThread` hears the signals and sets :attr:`stop`,
    the :class:`StopSignal` the main thread spins on (after ``on_stop(signum)``: a node
    sends 0 there at once). The spin then returns, the node stops and is destroyed, and
    only then the context. A second SIGINT (Ctrl-C twice) ends the process at once; a
    repeated SIGTERM or SIGHUP does not (the parent-death signal of
    :mod:`motor_id.lifeline` arrives once per thread of a dying parent). A node still
    running :data:`~motor_id.lifeline.STOP_DEADLINE` seconds after the signal is ended
    (``last_resort()`` first).
    """

    def __init__(self) -> None:
        self.stop = StopSignal()
        """The stop request the main thread spins on (also :attr:`stopped`)."""
        super().__init__(stopped=self.stop)


def drain(executor: Executor, node: Node, timeout: float = 10.0) -> bool:
    """After spinning: wait for the callbacks ``executor`` still has queued or running
    (then shut it down and destroy its nodes); log what they raised and a timeout."""
    done, errors = wait_for_handed_out_callbacks(executor, timeout)
    log = node.get_logger()
    if not done:
        log.warning(f'callbacks still running {timeout:g} s after the stop')
    for exc in errors:
        log.error(f'a callback failed while stopping: {type(exc).__name__}: {exc}')
    return done


def init_ros(name: str, args: list[str] | None = None) -> bool:
    """``rclpy.init`` with rclpy's own signal handlers off (a :class:`SignalWatcher` has them).

    Parameters
    ----------
    name : str
        The program, named in the one line a bad command line gets on stderr.
    args : list of str, optional
        Command line (default ``sys.argv``).

    Returns
    -------
    bool
        False when rclpy refused the command line (the caller exits with code 2).
    """
    try:
        rclpy.init(args=sys.argv if args is None else args,
                   signal_handler_options=SignalHandlerOptions.NO)
    except RCLError as exc:
        print(f'{name}: bad command line: {exc}', file=sys.stderr)
        return False
    return True


def run_node(factory: Callable[[], Node], name: str, num_threads: int = 4,
             args: list[str] | None = None) -> int:
    """Init rclpy, build the node, spin it, and shut down quietly.

    Ctrl-C, SIGTERM and SIGHUP end with exit code 0 and no traceback (see
    :class:`SignalWatcher`); a :class:`ConfigError` from the constructor is logged as one
    line and gives exit code 2.

    Parameters
    ----------
    factory : callable
        Returns the node (called after ``rclpy.init``).
    name : str
        Logger name for start-up errors.
    num_threads : int
        Executor threads; 1 gives a SingleThreadedExecutor (the fastest for many small
        callbacks: rclpy's MultiThreadedExecutor hands each one to a worker thread).
    args : list of str, optional
        Command line (default ``sys.argv``).

    Returns
    -------
    int
        Exit code.
    """
    signals = SignalWatcher()
    signals.install()
    if not init_ros(name, args):
        return 2
    node = None
    try:
        try:
            node = factory()
        except ConfigError as exc:
            rclpy.logging.get_logger(name).fatal(f'{exc}')
            return 2
        executor = (SingleThreadedExecutor() if num_threads == 1 else
                    MultiThreadedExecutor(num_threads=num_threads))
        executor.add_node(node)
        signals.stop.attach(node)
        signals.last_resort = getattr(node, 'last_resort', None)
        try:
            signals.stop.spin(executor)
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        except RCLError:
            if rclpy.ok():
                raise   # a real error, not a publish racing a shutdown
        finally:
            if hasattr(node, 'stop'):
                node.stop()   # stops the node's own threads, waits for running callbacks
            drain(executor, node)
            executor.shutdown(timeout_sec=5.0)
    except KeyboardInterrupt:
        pass
    finally:
        signals.stop.detach()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
