"""The experiment node: runs the test plan on one joint of a ros2_control robot, safely.

It reads the joint's state from ``sensor_msgs/JointState`` and commands the controller's
topic (``Float64MultiArray``, one value per controller joint, or ``Float64``); every
decision is the guard's (:mod:`motor_id.experiment.guard`). Nothing is sent before the
start (the ``~/start`` service, or ``autostart``). On every way out (the plan's end, a
safety stop, an exception, SIGINT, SIGTERM, SIGHUP) the last command sent is 0. Then, with
ROS shut down, the recording is finished and analysed (:func:`run`).

    python -m motor_id.nodes.experiment --ros-args --params-file config/experiment.yaml
    ros2 service call /experiment/start std_srvs/srv/Trigger
"""

from __future__ import annotations

from collections.abc import Callable
import math
import signal
import sys
import threading
import time
import traceback
from typing import Any, cast

from rcl_interfaces.srv import GetParameters
import rclpy
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Float64MultiArray
from std_srvs.srv import Trigger

from motor_id.contracts import INPUT_KINDS
from motor_id.effects import MECHANISMS
from motor_id.errors import ConfigError
from motor_id.experiment.guard import limit_command, StateSample
from motor_id.experiment.outcome import EXIT_CONFIG, finish
from motor_id.experiment.session import ExperimentSession
from motor_id.experiment.settings import COMMAND_TYPES, ExperimentSettings, PLANS, WATCHDOG
from motor_id.nodes import messages
from motor_id.nodes.common import (
    declare_parameters,
    init_ros,
    ParamSpec,
    SignalWatcher,
    TopicWatch,
)

PARAMETERS = (
    ParamSpec('joint', '', 'the joint to identify, by its JointState name'),
    ParamSpec('command_topic', '', "the controller's command topic, e.g. "
              '/forward_command_controller/commands'),
    ParamSpec('max_command', 0.0, 'no command exceeds this magnitude [V, or N m / N]',
              low=0.0, high=1e6),
    ParamSpec('out', 'experiment', 'output folder: recording.mcap, report.json, '
              'experiment.json'),
    ParamSpec('controller_joints', '', "the controller's joints in order, comma-separated "
              "('': read the controller node's joints parameter)"),
    ParamSpec('command_type', 'multi_array', 'std_msgs/Float64MultiArray (one value per '
              'controller joint) or std_msgs/Float64', choices=COMMAND_TYPES),
    ParamSpec('state_topic', '/joint_states', 'sensor_msgs/JointState topic'),
    ParamSpec('input_kind', 'voltage', 'what the command is', choices=INPUT_KINDS),
    ParamSpec('mechanism', 'simple', 'what the joint moves', choices=MECHANISMS),
    ParamSpec('travel', '', 'LO:HI, the window the joint stays in (required for arm and '
              'elevator)'),
    ParamSpec('max_speed', 0.0, 'a test ends above this speed (0: no limit)', low=0.0,
              high=1e9),
    ParamSpec('plan', 'sysid', 'the test plan', choices=PLANS),
    ParamSpec('resistance', 0.0, 'armature resistance [Ohm] as measured (0: not known)',
              low=0.0, high=1e6),
    ParamSpec('watchdog', WATCHDOG, 'state silent or late this long stops the experiment [s]',
              low=0.02, high=5.0),
    ParamSpec('time_scale', 1.0, "multiplies the plan's durations", low=0.05, high=10.0),
    ParamSpec('seed', 0, 'seed of the PRBS / multisine plans and the analysis', low=0,
              high=2 ** 31 - 1),
    ParamSpec('identify', True, 'analyse the recording at the end (false: record only)'),
    ParamSpec('autostart', False, 'start as soon as the state and the controller joints are '
              'known (else: call ~/start)'),
    ParamSpec('start_timeout', 30.0, 'give up if the state or the controller joints are '
              'not known this long after the start is asked for [s]', low=0.1, high=3600.0),
)

COMMAND_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)
"""Commands: reliable, as ros2_control's forward command controller subscribes."""
TICK = 0.02
"""The watchdog's period [s]."""
STATE_DEPTH = 10
"""The state subscription's queue: a late state is worse than a lost one (the guard acts
on it, the watchdog judges it), so a node that fell behind gets the newest states and
loses the older ones. With 1000 queued, a wheel at 250 Hz on a loaded machine (load
average 20-30) was received 0.6-0.85 s late for good and stopped as stale."""
ACK_WAIT = 5.0
"""How long the node waits for the controller to acknowledge the last 0 before it goes
[s]: a controller that stalled (its states stopped) gets the 0 when it resumes only while
the node is still there to resend it."""
JOINT_STATE = messages.TYPE_NAMES[JointState]


class ExperimentNode(Node):
    """The experiment on one joint (see the module notes).

    Parameters
    ----------
    parameter_overrides : list of rclpy.parameter.Parameter, optional
        The command line's settings (``motor-id experiment``).
    """

    def __init__(self, parameter_overrides: list[Parameter] | None = None) -> None:
        super().__init__('experiment', parameter_overrides=parameter_overrides or [])
        values = declare_parameters(self, PARAMETERS)
        self.settings = ExperimentSettings.from_parameters(values)
        self.start_timeout = float(values['start_timeout'])
        s = self.settings
        self._msg_type = Float64MultiArray if s.command_type == 'multi_array' else Float64
        self.session = ExperimentSession(self.settings)
        self.session.open({s.state_topic: JOINT_STATE,
                           s.command_topic: messages.TYPE_NAMES[self._msg_type]})
        self.on_finish: Callable[[], None] | None = None
        self.failure: str | None = None
        self.error: str | None = None
        """An error that stopped the experiment (the exit code says so)."""
        self.started = False
        self.sent = 0
        self.joints: tuple[str, ...] | None = (
            s.controller_joints if s.command_type == 'multi_array' else (s.joint,))
        self._start_asked: float | None = time.monotonic() if values['autostart'] else None
        self._index: int | None = None
        self._state: StateSample | None = None
        self._bad_state = ''
        self._warned: set[str] = set()
        self._logged = [0, 0, 0]   # tests started, tests ended, stop logged
        self._lock = threading.RLock()   # one decision and its command at a time
        self._alive = True
        self.publisher = self.create_publisher(self._msg_type, s.command_topic, COMMAND_QOS)
        self.watch = TopicWatch(self, s.state_topic, JOINT_STATE, self._subscribe, 0.2)
        self.create_service(Trigger, '~/start', self._on_start)
        self._client = None if self.joints is not None else self.create_client(
            GetParameters, f'{s.controller_node}/get_parameters')
        self._request: Any = None
        self.create_timer(TICK, self._on_tick)
        self.get_logger().info(
            f'joint {s.joint}: {s.plan} plan, commands on '
            f'{self.resolve_topic_name(s.command_topic)} within +-{s.max_command:g}, '
            f'{"autostart" if self._start_asked else "call ~/start to begin"}')

    # ------------------------------------------------------------------ inputs
    def _subscribe(self, endpoints: list[Any]) -> None:
        reliable = messages.all_reliable(endpoints)
        # two arguments: rclpy passes the message info (its source_timestamp) as well
        on_state: Callable[[Any], None] = cast(Any, self._on_state)
        self.create_subscription(JointState, self.settings.state_topic, on_state,
                                 messages.robot_qos(reliable, STATE_DEPTH))

    def _on_state(self, msg: JointState, info: Any) -> None:
        with self._lock:
            self._take_state(msg, info)

    def _take_state(self, msg: JointState, info: Any = None) -> None:
        now_ns = self.get_clock().now().nanoseconds
        self.session.record_message(self.settings.state_topic, JOINT_STATE,
                                    serialize_message(msg), now_ns)
        k = self._joint_index(msg)
        if k is None:
            return
        stamp = messages.stamp_seconds(msg.header.stamp)
        received = now_ns * 1e-9
        if not stamp:   # unset: when the robot sent it (DDS's source time), or now
            sent = int(info.get('source_timestamp') or 0) if info else 0
            stamp = sent * 1e-9 if 0 < sent <= now_ns else 0.0
        s = StateSample(stamp or received, time.monotonic(),
                        messages.joint_value(msg, k, 'position'),
                        messages.joint_value(msg, k, 'velocity'),
                        messages.joint_value(msg, k, 'effort'),
                        received - stamp if stamp else 0.0)
        if not math.isfinite(s.position):
            self._unusable(f'{self.settings.state_topic} gives no position of joint '
                           f'{self.settings.joint}')
            return
        self._state = s
        cmd = self.session.on_state(s)
        if cmd is not None:
            self.publish(cmd)
        self._check_writing()
        self._check_finished()

    def _joint_index(self, msg: JointState) -> int | None:
        joint = self.settings.joint
        if self._index is not None and self._index < len(msg.name) and \
                msg.name[self._index] == joint:
            return self._index
        if joint in msg.name:
            self._index = list(msg.name).index(joint)
            return self._index
        self._warn_once('joint', f'{self.settings.state_topic} has no joint {joint!r} '
                                 f'(joints: {", ".join(msg.name) or "none"})')
        return None

    def _unusable(self, reason: str) -> None:
        if self.started:
            self.stop(reason, safety=True)
        else:
            self._bad_state = reason
            self._warn_once('fields', reason)

    def _warn_once(self, key: str, text: str) -> None:
        if key not in self._warned:
            self._warned.add(key)
            self.get_logger().warning(text)

    # ------------------------------------------------------------------ start
    def _on_start(self, request: Trigger.Request, response: Trigger.Response
                  ) -> Trigger.Response:
        with self._lock:
            return self._start_request(response)

    def _start_request(self, response: Trigger.Response) -> Trigger.Response:
        if self.started:
            response.success, response.message = False, 'already started'
            return response
        if self._start_asked is None:
            self._start_asked = time.monotonic()
        missing = self._missing()
        if missing:
            response.success = False
            response.message = f'starting once {missing} (within {self.start_timeout:g} s)'
        else:
            self._start()
            response.success, response.message = True, 'started'
        return response

    def _missing(self) -> str:
        """What the start waits for ('' when nothing)."""
        if self.joints is None:
            return f'the controller {self.settings.controller_node} gives its joints'
        if self._state is None:
            return (f'the state of joint {self.settings.joint} arrives on '
                    f'{self.settings.state_topic}' +
                    (f' ({self._bad_state})' if self._bad_state else ''))
        if self.publisher.get_subscription_count() == 0:
            return f'the controller subscribes to {self.publisher.topic_name}'
        return ''

    def _start(self) -> None:
        self.started = True
        self.get_logger().info(f'started: joint {self.settings.joint} at '
                               f'{self._state.position if self._state else math.nan:.4g}')
        self.publish(self.session.start(time.monotonic()))

    def _ask_joints(self) -> None:
        client = self._client
        if client is None or self._request is not None or not client.service_is_ready():
            return
        self._request = client.call_async(GetParameters.Request(names=['joints']))
        self._request.add_done_callback(self._on_joints)

    def _on_joints(self, future: Any) -> None:
        with self._lock:
            self._take_joints(future)

    def _take_joints(self, future: Any) -> None:
        try:
            values = future.result().values
        except Exception as exc:   # noqa: BLE001 - the service's failure, reported once
            self.fail(f'the controller {self.settings.controller_node} did not give its '
                      f'joints: {exc}')
            return
        names = tuple(values[0].string_array_value) if values else ()
        if self.settings.joint not in names:
            self.fail(f'joint {self.settings.joint!r} is not among the controller '
                      f"{self.settings.controller_node}'s joints "
                      f'({", ".join(names) or "none"}); use a controller of that joint')
            return
        self.joints = names
        self.get_logger().info(f'controller joints: {", ".join(names)}')

    # ------------------------------------------------------------------ timer
    def _on_tick(self) -> None:
        with self._lock:
            self._tick()

    def _tick(self) -> None:
        now = time.monotonic()
        if self.joints is None:
            self._ask_joints()
        if not self.started and self._start_asked is not None and self.failure is None:
            missing = self._missing()
            if not missing:
                self._start()
            elif now - self._start_asked > self.start_timeout:
                hint = (' (does the node run? or give --controller-joints)'
                        if self.joints is None else '')
                self.fail(f'no start: waited {self.start_timeout:g} s until {missing}'
                          f'{hint}')
                return
        cmd = self.session.guard.tick(now)
        if cmd is not None:
            self.publish(cmd)
        self._check_writing()
        self._check_finished()

    def _check_writing(self) -> None:
        """A recording that cannot be written (a full disk) stops the experiment as an
        error."""
        if self.session.write_error is not None and self.error is None:
            self.error = self.session.write_error
            self.get_logger().error(self.error)
            self.stop(f'error: {self.error}')

    def _check_finished(self) -> None:
        self._log_progress()
        if self.session.guard.finished and self.on_finish is not None:
            self.on_finish()

    def _log_progress(self) -> None:
        """One line as each test starts and ends, and at the stop."""
        log = self.session.guard.log
        for k, test in enumerate(log.tests):
            if k >= self._logged[0]:
                self._logged[0] = k + 1
                self.get_logger().info(f'test {test.name} started')
            if test.end_reason is not None and k >= self._logged[1]:
                self._logged[1] = k + 1
                self.get_logger().info(f'test {test.name} ended: {test.end_reason}')
        if log.stop_reason is not None and not self._logged[2]:
            self._logged[2] = 1
            log_fn = self.get_logger().warning if log.safety_stop else self.get_logger().info
            log_fn(f'stopped: {log.stop_reason}')

    # ------------------------------------------------------------------ output
    def publish(self, value: float) -> None:
        """Send ``value`` to the joint (the one place a command leaves): within the limit,
        only after the start, 0 for the controller's other joints."""
        if not self.started or self.joints is None or not self._alive:
            return
        value = limit_command(value, self.settings.max_command)
        assert abs(value) <= self.settings.max_command
        if self._msg_type is Float64MultiArray:
            msg: Any = Float64MultiArray(
                data=[value if j == self.settings.joint else 0.0 for j in self.joints])
        else:
            msg = Float64(data=value)
        self.publisher.publish(msg)
        now_ns = self.get_clock().now().nanoseconds
        self.sent += 1
        self.session.note_sent(now_ns * 1e-9, value)
        self.session.record_message(self.settings.command_topic,
                                    messages.TYPE_NAMES[self._msg_type],
                                    serialize_message(msg), now_ns)

    def stop(self, reason: str, safety: bool = False) -> None:
        """Stop the experiment now: 0 is sent (if anything was)."""
        self.publish(self.session.guard.stop(reason, safety))
        self._check_finished()

    def fail(self, reason: str) -> None:
        """A start-up failure (no state, no controller): nothing was sent; end."""
        self.failure = reason
        self.get_logger().error(reason)
        self.session.guard.stop(reason)
        if self.on_finish is not None:
            self.on_finish()

    def emergency_stop(self, reason: str) -> None:
        """From any thread (a signal's): stop and send 0 at once."""
        with self._lock:
            if not self._alive:
                return
            if not self.session.guard.finished:
                self.session.guard.stop(reason)
            self.publish(0.0)

    def halt(self, reason: str) -> None:
        """The last word: stop if still running, send 0 and wait briefly for it to be
        acknowledged (call after spinning ends); after it nothing is sent."""
        with self._lock:
            if not self.session.guard.finished:
                self.session.guard.stop(reason)
            if self.started:
                self.publish(0.0)
                if not self.publisher.wait_for_all_acked(Duration(seconds=ACK_WAIT)):
                    self.get_logger().warning(
                        f'the last 0 was not acknowledged within {ACK_WAIT:g} s: check '
                        f'that {self.settings.command_topic} holds 0')
            self._alive = False


def run(args: list[str] | None = None, overrides: list[Parameter] | None = None,
        jobs: int | None = None) -> int:
    """Run the experiment node to its end, then finish the outputs and identify.

    Parameters
    ----------
    args : list of str, optional
        The ROS command line (default ``sys.argv``).
    overrides : list of Parameter, optional
        Parameter values (the CLI's flags).
    jobs : int, optional
        Processes for the analysis (default: every usable core).

    Returns
    -------
    int
        The exit code (:mod:`motor_id.experiment.outcome`): 0 identified, 2 a bad setting
        or no start, 3 a safety stop, 4 not identified, 5 an error, 128 + N signal N.
    """
    signals = SignalWatcher()   # SIGINT, SIGTERM, SIGHUP alike: 0 from its thread at once
    signals.install()
    if not init_ros('experiment', args):
        return EXIT_CONFIG
    node: ExperimentNode | None = None
    error: str | None = None
    try:
        try:
            node = ExperimentNode(overrides)
        except ConfigError as exc:
            rclpy.logging.get_logger('experiment').fatal(f'{exc}')
            return EXIT_CONFIG
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        signals.stop.attach(node)
        node.on_finish = signals.stop.set
        stopping = node.emergency_stop
        signals.on_stop = lambda sig: stopping(f'signal {signal.Signals(sig).name}')
        signals.last_resort = lambda: stopping('the stop took too long')
        try:
            signals.stop.spin(executor)
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        except Exception as exc:   # noqa: BLE001 - any error: 0 first, then report it
            error = f'error: {exc!r}'
            traceback.print_exc()
        finally:
            received = signals.received
            reason = error or (f'signal {signal.Signals(received).name}' if received
                               else 'interrupted')
            node.halt(reason)
            executor.shutdown(timeout_sec=1.0)
    finally:
        signals.on_stop = None
        signals.stop.detach()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return finish(node.session, node.failure, signals.received,
                  error is not None or node.error is not None, jobs)


def main(args: list[str] | None = None) -> int:
    """Console script ``experiment``."""
    return run(args)


if __name__ == '__main__':
    sys.exit(main())
