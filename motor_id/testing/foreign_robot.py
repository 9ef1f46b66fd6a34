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
constants, the positions reached, the commands received, and how the states were
measured (how many, the instants skipped, the states dropped, the longest gap between
two).

Time is the robot's monotonic clock, as a real drive's: the states are measured at the
instants ``k / rate_hz`` after its start (its stamps are those instants), each command
acts from when DDS delivered it to the process (its receive time, not when Python got
to it), and the physics is integrated between those instants exactly. The joint states
come from a thread of their own that sleeps until the next instant, never from the
executor, which only takes the commands; one period costs about 0.1 ms of physics (4-5 %
of a core at 250 Hz, all of the process; it was 11-14 % with a timer on a
multi-threaded executor). A process that stalls measures, on waking, at the latest
instant passed, as a control loop that overran, and sends the newest state due only (as
ros2_control's realtime publisher drops a message while the one before is out): the
stream has a gap, never a burst (unset stamps take the send time) nor a state that is
not the one of its stamp.

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
from typing import Any

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Float64MultiArray

from motor_id.nodes.rclshim import RCLError

G = 9.81
STEP = 2e-4
"""The physics' Euler step [s] (the last one before a sample instant or a command is
shorter: the state is the one at that instant). 20 steps per 4 ms period cost 0.07-0.1
ms here; scipy's solve_ivp over the period, with the stop of the friction as an event,
cost 0.58 ms, odeint 0.14 ms."""

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
    """theta, omega of one joint under a held voltage (see the module notes), on the
    robot's monotonic clock: :meth:`run_until` integrates to a time, exactly."""

    def __init__(self, kind: str, start: float, t: float) -> None:
        self.p = KINDS[kind]
        self.kind = kind
        lo, hi = self.p.stops
        self.theta = min(max(start, lo), hi)
        self.omega = 0.0
        self.volts = 0.0
        self.t = t
        self.low = self.high = self.theta

    def gravity(self) -> float:
        if self.kind == 'arm':
            return self.p.Tg * math.cos(self.theta + self.p.offset)
        return float(self.p.Tg)

    def run_until(self, now: float) -> None:
        """Integrate to ``now`` (steps of :data:`STEP`, the last one shorter)."""
        while self.t < now:
            self.step(min(STEP, now - self.t))

    def step(self, h: float) -> None:
        p = self.p
        self.t += h
        drive = p.K * (self.volts - p.K * self.omega) / p.R - self.gravity()
        if self.omega == 0.0 and abs(drive) <= p.stick * p.Tc:
            acc = 0.0
        else:
            sgn = math.copysign(1.0, self.omega if self.omega else drive)
            acc = (drive - p.B * self.omega - p.Tc * sgn) / p.J
        new = self.omega + acc * h
        if self.omega != 0.0 and new * self.omega < 0.0:
            new = 0.0   # friction stops it; it sticks unless the drive beats it
        self.omega = new
        self.theta += self.omega * h
        lo, hi = p.stops
        if self.theta < lo or self.theta > hi:
            self.theta = min(max(self.theta, lo), hi)
            self.omega = 0.0
        self.low, self.high = min(self.low, self.theta), max(self.high, self.theta)

    def encoder(self) -> float:
        c = self.p.counts
        return math.floor(self.theta * c) / c


class ForeignRobot(Node):
    """The controller node that also broadcasts the joint states (from its own thread)."""

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
        self.period = 1.0 / rate
        self.latency = max(0, round(float(dp('latency', 0.02).value) * rate)) * self.period
        self.command_type = dp('command_type', 'multi_array').value
        self.truth_file = dp('truth_file', '').value
        self.rng = random.Random(int(dp('seed', 1).value))
        self.booted = time.monotonic()
        self.physics = Physics(self.kind, float(dp('start', 0.0).value), self.booted)
        self.me = KINDS[self.kind].joint
        self.received: list = []
        self.lock = threading.Lock()
        self.inbox: list[tuple[float, float]] = []   # (when it reached the robot, volts)
        self.outbox: deque[tuple[float, JointState]] = deque()   # (when it leaves, msg)
        self.samples = 0
        self.skipped = 0   # instants passed while the process stalled
        self.dropped = 0   # states measured, not sent: a newer one was due as well
        self.longest_gap = 0.0   # between two measured instants [s]
        # two arguments: rclpy passes the message info (its received_timestamp) as well
        on_command: Any = self.on_float if self.command_type == 'float64' else self.on_array
        self.create_subscription(Float64 if self.command_type == 'float64'
                                 else Float64MultiArray, '~/commands', on_command, 10)
        qos = qos_profile_sensor_data if self.rng.random() < 0.5 else \
            QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.pub = self.create_publisher(JointState, '/joint_states', qos)
        self.halt = threading.Event()
        self.thread = threading.Thread(target=self.run, name='joint_states')
        self.thread.start()
        self.get_logger().info(f'{READY_LINE}: {self.kind}, {rate:g} Hz')

    # ------------------------------------------------------------------ commands
    def on_array(self, msg: Float64MultiArray, info: Any) -> None:
        if len(msg.data) != len(self.joints):
            self.get_logger().warning(f'{len(msg.data)} values for {len(self.joints)} joints')
            return
        self.take(list(msg.data), msg.data[self.joints.index(self.me)], info)

    def on_float(self, msg: Float64, info: Any) -> None:
        self.take([msg.data], msg.data, info)

    def take(self, values: list, volts: float, info: Any) -> None:
        """A command acts from when it reached the robot (DDS's receive time, not when
        this callback ran), as a drive takes it when it comes in."""
        now, wall = time.monotonic(), time.time_ns()
        rx = int(info.get('received_timestamp') or 0) if info else 0
        t = now - (wall - rx) * 1e-9 if 0 < wall - rx < 10 ** 9 else now
        with self.lock:
            self.inbox.append((t, max(-12.0, min(12.0, volts))))
            self.received.append({'t': t, 'values': values})

    # ------------------------------------------------------------------ states
    def run(self) -> None:
        """The broadcaster's loop: measure at each sample instant (k periods after the
        boot, on the monotonic clock; after a stall the latest instant passed, as a
        control loop that overran), publish what is due, sleep until the next."""
        k = 0
        while True:
            due = self.booted + (k + 1) * self.period
            wake = min(due, self.outbox[0][0]) if self.outbox else due
            if self.halt.wait(max(0.0, wake - time.monotonic())):
                return
            now = time.monotonic()
            if now >= due:
                last, k = k, int((now - self.booted) / self.period)
                self.skipped += k - last - 1
                self.longest_gap = max(self.longest_gap, (k - last) * self.period)
                self.measure(self.booted + k * self.period, now)
            due_now = [m for t, m in self.outbox if t <= now]
            if due_now:   # the newest only: as ros2_control's realtime publisher drops a
                # message while the one before is out, a stall never leaves as a burst
                self.dropped += len(due_now) - 1
                while self.outbox and self.outbox[0][0] <= now:
                    self.outbox.popleft()
                try:
                    self.pub.publish(due_now[-1])
                except RCLError:   # ROS shut down (a signal) before the thread's end
                    if self.context.ok():
                        raise
                    return

    def measure(self, instant: float, now: float) -> None:
        """The state at ``instant`` (the physics integrated to it, the commands that came
        before it applied when they came), queued to leave ``latency`` later."""
        with self.lock:
            self.advance(instant)
            x, w = self.physics.encoder(), self.physics.omega
        self.samples += 1
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
            ns = self.get_clock().now().nanoseconds - round((now - instant) * 1e9)
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns, 10 ** 9)
        elif self.stamp_kind == 'boot':
            sec = instant - self.booted + 1.0
            msg.header.stamp.sec, msg.header.stamp.nanosec = int(sec), int(sec % 1 * 1e9)
        self.outbox.append((instant + self.latency, msg))

    def advance(self, until: float) -> None:
        """Integrate to ``until`` (call with the lock), each command from its time (or
        from where the physics is, if it came in later than that)."""
        inbox = sorted(self.inbox)
        while inbox and inbox[0][0] <= until:
            t, volts = inbox.pop(0)
            self.physics.run_until(t)
            self.physics.volts = volts
        self.inbox = inbox
        self.physics.run_until(until)

    def stop(self) -> None:
        """End the broadcaster's thread (before the node goes)."""
        self.halt.set()
        self.thread.join()

    def write_truth(self) -> None:
        if not self.truth_file:
            return
        with self.lock:
            self.advance(time.monotonic())
            truth = {'feedforward': true_feedforward(KINDS[self.kind]),
                     'position': {'min': self.physics.low, 'max': self.physics.high},
                     'commands': self.received,
                     'states': {'measured': self.samples, 'skipped': self.skipped,
                                'dropped': self.dropped,
                                'period': self.period, 'longest_gap': self.longest_gap}}
        with open(self.truth_file, 'w', encoding='utf-8') as fh:
            json.dump(truth, fh)


def main() -> int:
    rclpy.init(args=sys.argv)
    robot = ForeignRobot()
    executor = SingleThreadedExecutor()
    executor.add_node(robot)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        robot.stop()
        robot.write_truth()
        robot.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
