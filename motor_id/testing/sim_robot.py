"""A simulated ros2_control robot: a forward command controller and a joint state broadcaster.

One process, three rclpy nodes spun by one executor (their callbacks never overlap):

- ``/<controller>`` (the ``controller`` parameter, default ``forward_command_controller``)
  with the string-array parameter ``joints``, subscribing ``/<controller>/commands``:
  ``std_msgs/Float64MultiArray``, one value per joint in ``joints`` order, or with
  ``command_type:=float64`` a ``std_msgs/Float64`` for a single joint. Like
  forward_command_controller it holds the last command, with no watchdog of its own; a
  message of the wrong length (or not finite) is ignored with a warning.
- ``/joint_state_broadcaster`` publishing ``/joint_states`` (``sensor_msgs/JointState``,
  the controller's joints in reverse order; the simulated joint's position, velocity and
  effort = current [A] for a voltage drive, torque for a torque drive; the others at 0) at
  ``rate_hz`` with period ``jitter``: stamps are the measurement instants and each message
  leaves ``latency`` (0.5 to 1.5 x) later; ``stamp:=false`` leaves the stamps zero.
- ``/sim_robot``: the parameters below and the physics,
  :mod:`motor_id.testing.independent_physics` through
  :class:`~motor_id.testing.sim_joint.JointSim`, integrated over the elapsed wall time by
  a thread that wakes at each sample instant and message time (and at least every
  ``tick_period``): a late wake-up integrates longer, the samples keep their instants.

On exit (SIGINT, SIGTERM, SIGHUP: exit 0) it writes ``truth_file``: the true feedforward
constants, the positions reached and every command received with its receive time.

    python -m motor_id.testing.sim_robot --ros-args -p mechanism:=arm \\
        -p truth_file:=/tmp/truth.json        # or: sim-robot --ros-args ...
"""

from collections import deque
import math
import sys
import threading
import time
from typing import Any

from rcl_interfaces.msg import ParameterDescriptor
import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Float64MultiArray

from motor_id.errors import ConfigError
from motor_id.nodes.common import declare_parameters, init_ros, ParamSpec, SignalWatcher
from motor_id.nodes.rclshim import RCLError
from motor_id.testing.sim_joint import (
    ARM_OFFSET,
    compile_physics,
    JointSim,
    MECHANISMS,
    Sample,
    SimConfig,
    write_json,
)

PARAMS = (
    ParamSpec('mechanism', 'wheel', 'the simulated joint', choices=tuple(MECHANISMS)),
    ParamSpec('controller', 'forward_command_controller',
              'the controller: its node name and /<controller>/commands'),
    ParamSpec('joint', '', "the simulated joint's name ('' = the mechanism's)"),
    ParamSpec('command_type', 'multi_array', 'commands as Float64MultiArray or Float64',
              choices=('multi_array', 'float64')),
    ParamSpec('input_kind', 'voltage', 'the command is a voltage [V] or a torque [N m, N]',
              choices=('voltage', 'torque')),
    ParamSpec('rate_hz', 100.0, 'joint_states rate [Hz]', low=1.0, high=1000.0),
    ParamSpec('jitter', 0.05, 'std of the sample period, a fraction of it', low=0.0,
              high=0.5),
    ParamSpec('latency', 0.003, 'mean delay from a measurement to its message [s]',
              low=0.0, high=0.5),
    ParamSpec('stamp', True, 'stamp the measurement instants (false: stamps zero)'),
    ParamSpec('noise', 1.0, "sensor noise, times the mechanism's nominal", low=0.0,
              high=100.0),
    ParamSpec('seed', 0, 'seed of the noise and the jitter', low=0, high=2 ** 31 - 1),
    ParamSpec('offset', ARM_OFFSET, "the arm's encoder zero below horizontal [rad]",
              low=-math.pi, high=math.pi),
    ParamSpec('stop_low', math.nan, "low hard stop [rad or m] (nan: the mechanism's)"),
    ParamSpec('stop_high', math.nan, "high hard stop [rad or m] (nan: the mechanism's)"),
    ParamSpec('tick_period', 0.01, 'longest physics step between wake-ups [s]',
              low=0.0005, high=0.1),
    ParamSpec('truth_file', '', "JSON of the truth, written on exit ('' = none)"),
)
"""The parameters of ``/sim_robot``."""

QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                 reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
"""As ros2_control's controllers and broadcasters (the system default: reliable, depth 10)."""


class SimRobot(Node):
    """The physics node; it creates the controller and broadcaster nodes beside it.

    Raises
    ------
    ConfigError
        A parameter out of range, a bad controller name, a joint not among ``joints``.
    """

    def __init__(self) -> None:
        super().__init__('sim_robot', start_parameter_services=False)
        p = declare_parameters(self, PARAMS)
        mech = MECHANISMS[p['mechanism']]
        self.config = SimConfig(
            mechanism=p['mechanism'], input_kind=p['input_kind'], rate_hz=p['rate_hz'],
            jitter=p['jitter'], latency=p['latency'], noise=p['noise'], seed=p['seed'],
            offset=p['offset'], stop_low=None if math.isnan(p['stop_low']) else p['stop_low'],
            stop_high=None if math.isnan(p['stop_high']) else p['stop_high'])
        self.config.check()
        self.truth_file = p['truth_file']
        self.stamp = p['stamp']
        self.joint = p['joint'] or mech.joint
        self.controller = self._controller_node(p['controller'], p['command_type'], mech)
        self.broadcaster = rclpy.create_node('joint_state_broadcaster', context=self.context,
                                             start_parameter_services=False)
        self.pub = self.broadcaster.create_publisher(JointState, '/joint_states', QOS)
        self.names = list(reversed(self.joints))
        self._index = self.names.index(self.joint)
        self._outbox: deque[tuple[Sample, int]] = deque()   # with its stamp [ns]
        compile_physics(self.config)
        self.sim = JointSim(self.config, time.monotonic())
        self._lock = threading.Lock()
        self._halt = threading.Event()
        self._tick_max = p['tick_period']
        self._thread = threading.Thread(target=self._physics, name='physics')
        self._thread.start()
        self.get_logger().info(
            f'sim_robot: {mech.name} ready: joint {self.joint} of {self.joints} on '
            f'/{p["controller"]}/commands ({p["command_type"]}, {p["input_kind"]}), '
            f'/joint_states at {p["rate_hz"]:g} Hz')

    def _controller_node(self, name: str, command_type: str, mech: Any) -> Node:
        try:
            node = rclpy.create_node(name, context=self.context)
        except (ValueError, RCLError) as exc:   # rclpy's InvalidNodeNameException is one
            raise ConfigError(f'parameter controller: {name!r} is no node name: {exc}'
                              ) from None
        default = [self.joint] if command_type == 'float64' else [
            self.joint if j == mech.joint else j for j in mech.joints]
        joints = node.declare_parameter(
            'joints', default, ParameterDescriptor(
                description="the controller's joints, in command order",
                read_only=True)).value
        self.joints = [str(j) for j in joints or []]
        if self.joint not in self.joints:
            raise ConfigError(f'parameter joints: {self.joints} lacks the joint {self.joint}')
        if command_type == 'float64' and len(self.joints) != 1:
            raise ConfigError(f'parameter joints: command_type float64 takes one joint, '
                              f'not {self.joints}')
        topic = f'/{name}/commands'
        if command_type == 'float64':
            node.create_subscription(Float64, topic, self._on_float64, QOS)
        else:
            node.create_subscription(Float64MultiArray, topic, self._on_multi_array, QOS)
        return node

    def nodes(self) -> list[Node]:
        """The three nodes, for the executor."""
        return [self, self.controller, self.broadcaster]

    def _on_multi_array(self, msg: Float64MultiArray) -> None:
        self._command(list(msg.data))

    def _on_float64(self, msg: Float64) -> None:
        self._command([msg.data])

    def _command(self, values: list[float]) -> None:
        now, wall = time.monotonic(), time.time()
        if len(values) != len(self.joints) or not all(math.isfinite(v) for v in values):
            self.sim.record_command(now, wall, values, None)
            self.get_logger().warning(
                f'command {values} ignored: {len(self.joints)} finite values expected, one '
                f'per joint of {self.joints}', throttle_duration_sec=1.0)
            return
        with self._lock:
            applied = self.sim.command(now, values[self.joints.index(self.joint)])
            self.sim.record_command(now, wall, values, applied)

    def _physics(self) -> None:
        """The physics thread: integrate the elapsed wall time up to the next sample or
        message (at most ``tick_period`` at a time), publish what is due, sleep again."""
        wake = time.monotonic()
        while not self._halt.wait(max(0.0, wake - time.monotonic())):
            now = time.monotonic()
            wall = self.get_clock().now().nanoseconds   # the ROS clock now, as `now`
            with self._lock:
                self._outbox.extend((s, wall - round((now - s.t) * 1e9))
                                    for s in self.sim.advance(now))
                wake = min(now + self._tick_max, self.sim.next_sample)
            while self._outbox and self._outbox[0][0].due <= now:
                self.pub.publish(self._message(*self._outbox.popleft()))
            if self._outbox:
                wake = min(wake, self._outbox[0][0].due)

    def stop(self) -> None:
        """End the physics thread (before the nodes are destroyed)."""
        self._halt.set()
        self._thread.join()

    def _message(self, s: Sample, stamp_ns: int) -> JointState:
        msg = JointState()
        if self.stamp:   # the ROS clock at the measurement (it follows clock steps)
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 10 ** 9)
        n = len(self.names)
        msg.name = self.names
        msg.position, msg.velocity, msg.effort = [0.0] * n, [0.0] * n, [0.0] * n
        msg.position[self._index] = s.position
        msg.velocity[self._index] = s.velocity
        msg.effort[self._index] = s.effort
        return msg

    def write_truth(self) -> None:
        """Write the truth file (if one is asked for)."""
        if self.truth_file:
            with self._lock:
                self.sim.advance(time.monotonic())
                write_json(self.truth_file, self.sim.truth().to_dict())

    def destroy_node(self) -> None:
        """Destroy the controller and broadcaster nodes, then this one."""
        self.controller.destroy_node()
        self.broadcaster.destroy_node()
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    """Run the simulated robot until SIGINT, SIGTERM or SIGHUP; write the truth file.

    Returns
    -------
    int
        0, or 2 for a bad parameter (one line on stderr).
    """
    signals = SignalWatcher()
    signals.install()
    if not init_ros('sim_robot', args):
        return 2
    robot = None
    try:
        robot = SimRobot()
        executor = SingleThreadedExecutor()
        for node in robot.nodes():
            executor.add_node(node)
        signals.stop.attach(robot)
        try:
            signals.stop.spin(executor)
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        finally:
            robot.stop()
            executor.shutdown(timeout_sec=5.0)
            robot.write_truth()
    except ConfigError as exc:
        rclpy.logging.get_logger('sim_robot').fatal(f'{exc}')
        return 2
    except KeyboardInterrupt:
        pass
    finally:
        signals.stop.detach()
        if robot is not None:
            robot.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
