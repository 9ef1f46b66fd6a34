"""A second simulated ros2_control robot, written apart from :mod:`sim_robot` on purpose.

The experiment's tests run against it to catch what :mod:`motor_id.testing.sim_robot`
would hide: its own physics (a DC motor without inductance, Coulomb friction that
sticks, gravity, inelastic hard stops, a quantised encoder; nothing of
:mod:`motor_id.testing.independent_physics` or :mod:`motor_id.testing.sim_joint`), and
the ways real robots differ:

- ``/joint_states`` lists the controller's joints and more (``extra_joints``), in an
  order shuffled on every message (``shuffle``);
- ``velocity:=false`` / ``effort:=false`` leave those arrays empty;
- ``stamp`` is ``ros`` (the ROS clock), ``zero`` (unset) or ``boot`` (the robot's own
  clock: seconds since it started, far from the ROS clock);
- ``rate_hz`` (50-1000 Hz), ``latency`` (messages leave whole sample periods late);
- ``command_type`` ``multi_array`` (one value per ``joints`` entry) or ``float64``;
- ``start`` puts the joint anywhere in its travel (an arm then falls to where friction or
  a stop holds it).

It is one rclpy node named after the controller (it owns ``~/commands`` and the
``joints`` parameter, as ros2_control's controller node does) that also publishes the
joint states. On SIGINT or SIGTERM it writes ``truth_file``: the true feedforward
constants, the positions reached, the commands received.

    python -m motor_id.testing.foreign_robot --ros-args -p kind:=arm -p velocity:=false
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
import json
import math
import random
import sys
import threading
import time

import rclpy
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Float64MultiArray

G = 9.81
STEP = 2e-4
"""The physics' Euler step [s]."""

@dataclass(frozen=True)
class Kind:
    """One mechanism seen at the joint, gearbox included: K [N m/A], R [Ohm], J, B, T_c,
    stiction / T_c, gravity torque T_g, offset [rad], hard stops, joint name and encoder
    counts per unit."""

    K: float
    R: float
    J: float
    B: float
    Tc: float
    stick: float
    Tg: float
    offset: float
    stops: tuple[float, float]
    joint: str
    counts: float


KINDS: dict[str, Kind] = {
    'wheel': Kind(K=0.03, R=0.08, J=2.25e-3, B=1.875e-3, Tc=0.09375, stick=1.1, Tg=0.0,
                  offset=0.0, stops=(-math.inf, math.inf), joint='shooter_wheel',
                  counts=4096 / (2 * math.pi)),
    'arm': Kind(K=0.8, R=0.1, J=0.4, B=0.8, Tc=1.6, stick=1.1, Tg=8.0, offset=-0.3,
                stops=(-2.2, 2.0), joint='shoulder', counts=8192 / (2 * math.pi)),
    'elevator': Kind(K=4.0, R=0.1, J=12.0, B=80.0, Tc=8.0, stick=1.1, Tg=40.0, offset=0.0,
                     stops=(0.0, 1.0), joint='lift', counts=20000.0),
}
"""The mechanisms (seen at the joint, gearbox included)."""

READY_LINE = 'foreign robot up'
"""Logged once the robot publishes."""


def true_feedforward(p: Kind) -> dict[str, float]:
    """V = kS sgn(w) + kV w + kA dw/dt [+ kG (cos(theta + offset))] of the physics."""
    r_k = p.R / p.K
    out = {'kS': r_k * p.Tc, 'kV': p.K + r_k * p.B, 'kA': r_k * p.J}
    if p.Tg:
        out['kG'] = r_k * p.Tg
    if p.Tg and p.offset:
        out['offset'] = p.offset
    return out


class Physics:
    """theta, omega of one joint under a held voltage (see the module notes)."""

    def __init__(self, kind: str, start: float) -> None:
        self.p = KINDS[kind]
        self.kind = kind
        lo, hi = self.p.stops
        self.theta = min(max(start, lo), hi)
        self.omega = 0.0
        self.volts = 0.0
        self.t = time.monotonic()
        self.low = self.high = self.theta

    def gravity(self) -> float:
        if self.kind == 'arm':
            return self.p.Tg * math.cos(self.theta + self.p.offset)
        return float(self.p.Tg)

    def run_until(self, now: float) -> None:
        p = self.p
        while self.t + STEP <= now:
            self.t += STEP
            drive = p.K * (self.volts - p.K * self.omega) / p.R - self.gravity()
            if self.omega == 0.0 and abs(drive) <= p.stick * p.Tc:
                acc = 0.0
            else:
                sgn = math.copysign(1.0, self.omega if self.omega else drive)
                acc = (drive - p.B * self.omega - p.Tc * sgn) / p.J
            new = self.omega + acc * STEP
            if self.omega != 0.0 and new * self.omega < 0.0:
                new = 0.0   # friction stops it; it sticks unless the drive beats it
            self.omega = new
            self.theta += self.omega * STEP
            lo, hi = p.stops
            if self.theta < lo or self.theta > hi:
                self.theta = min(max(self.theta, lo), hi)
                self.omega = 0.0
            self.low, self.high = min(self.low, self.theta), max(self.high, self.theta)

    def encoder(self) -> float:
        c = self.p.counts
        return math.floor(self.theta * c) / c


class ForeignRobot(Node):
    """The controller node that also broadcasts the joint states."""

    def __init__(self) -> None:
        super().__init__('forward_command_controller')
        dp = self.declare_parameter
        self.kind = dp('kind', 'wheel').value
        default_joints = [KINDS[self.kind].joint, 'elbow', 'wrist']
        self.joints = list(dp('joints', default_joints).value)
        self.extra = list(dp('extra_joints', ['caster_left', 'caster_right']).value)
        self.shuffle = dp('shuffle', True).value
        self.with_velocity = dp('velocity', False).value
        self.with_effort = dp('effort', False).value
        self.stamp_kind = dp('stamp', 'zero').value
        rate = float(dp('rate_hz', 250.0).value)
        self.delay = max(0, round(float(dp('latency', 0.02).value) * rate))
        self.command_type = dp('command_type', 'multi_array').value
        self.truth_file = dp('truth_file', '').value
        self.rng = random.Random(int(dp('seed', 1).value))
        self.physics = Physics(self.kind, float(dp('start', 0.0).value))
        self.me = KINDS[self.kind].joint
        self.booted = time.monotonic()
        self.received: list = []
        self.lock = threading.Lock()
        self.outbox: deque = deque()
        if self.command_type == 'float64':
            self.create_subscription(Float64, '~/commands', self.on_float, 10)
        else:
            self.create_subscription(Float64MultiArray, '~/commands', self.on_array, 10)
        qos = qos_profile_sensor_data if self.rng.random() < 0.5 else \
            QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.pub = self.create_publisher(JointState, '/joint_states', qos)
        self.create_timer(1.0 / rate, self.sample)
        self.get_logger().info(f'{READY_LINE}: {self.kind}, {rate:g} Hz')

    def on_array(self, msg: Float64MultiArray) -> None:
        if len(msg.data) != len(self.joints):
            self.get_logger().warning(f'{len(msg.data)} values for {len(self.joints)} joints')
            return
        self.take(list(msg.data), msg.data[self.joints.index(self.me)])

    def on_float(self, msg: Float64) -> None:
        self.take([msg.data], msg.data)

    def take(self, values: list, volts: float) -> None:
        now = time.monotonic()
        with self.lock:
            self.physics.run_until(now)
            self.physics.volts = max(-12.0, min(12.0, volts))
            self.received.append({'t': now, 'values': values})

    def sample(self) -> None:
        now = time.monotonic()
        with self.lock:
            self.physics.run_until(now)
            x, w = self.physics.encoder(), self.physics.omega
        names = self.joints + self.extra
        if self.shuffle:
            names = self.rng.sample(names, len(names))
        msg = JointState()
        msg.name = names
        msg.position = [x if n == self.me else 0.0 for n in names]
        if self.with_velocity:
            msg.velocity = [w if n == self.me else 0.0 for n in names]
        if self.with_effort:
            msg.effort = [0.0 for _ in names]
        if self.stamp_kind == 'ros':
            msg.header.stamp = self.get_clock().now().to_msg()
        elif self.stamp_kind == 'boot':
            sec = now - self.booted + 1.0
            msg.header.stamp.sec, msg.header.stamp.nanosec = int(sec), int(sec % 1 * 1e9)
        self.outbox.append(msg)
        while len(self.outbox) > self.delay:
            self.pub.publish(self.outbox.popleft())

    def write_truth(self) -> None:
        if not self.truth_file:
            return
        with self.lock:
            self.physics.run_until(time.monotonic())
            truth = {'feedforward': true_feedforward(KINDS[self.kind]),
                     'position': {'min': self.physics.low, 'max': self.physics.high},
                     'commands': self.received}
        with open(self.truth_file, 'w', encoding='utf-8') as fh:
            json.dump(truth, fh)


def main() -> int:
    rclpy.init(args=sys.argv)
    robot = ForeignRobot()
    executor = MultiThreadedExecutor(num_threads=2)
    executor.add_node(robot)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        robot.write_truth()
        robot.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
