"""Live input from a robot's own topics: JointState plus a Float64 command, aligned."""

from collections.abc import Mapping
import math
from typing import Any, cast

from rclpy.node import Node
from rclpy.subscription import Subscription
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64

from motor_id.data.align import StreamAligner
from motor_id.data.buffer import SampleBuffer
from motor_id.nodes import messages
from motor_id.nodes.common import TopicWatch

FLUSH_S = 0.05
"""How often aligned rows move into the buffer [s]."""


class TopicInput:
    """Feed ``buffer`` from ``joint_states`` (JointState) and ``input_topic`` (Float64).

    Each subscription is created once a publisher of the right type is found, with
    reliable delivery only if every publisher found is reliable (a reliable subscription
    never matches a best-effort, sensor-data publisher). Times: the JointState header
    stamp (its publication time when unset) and the command's publication time, both
    on the publishers' clock. Commands are zero-order held onto the samples by the
    ``align`` rule (:class:`motor_id.data.align.StreamAligner`). With
    ``effort_is: torque`` the effort is the plant input (a torque-controlled joint) and
    no command topic is needed.

    Parameters
    ----------
    node : rclpy.node.Node
    buffer : motor_id.data.buffer.SampleBuffer
    settings : dict
        ``joint_name``, ``input_topic``, ``speed_field``, ``current_field``,
        ``effort_is``, ``align``.
    """

    def __init__(self, node: Node, buffer: SampleBuffer, settings: Mapping[str, Any]) -> None:
        self.node = node
        self.buffer = buffer
        self.joint = settings['joint_name']
        self.speed_field = settings['speed_field']
        self.current_field = settings['current_field']
        self.torque = settings['effort_is'] == 'torque'
        self.aligner = StreamAligner(settings['align'])
        self.origin: float | None = None
        self.index: int | None = None
        self._warned: set[str] = set()
        self.subscriptions: dict[str, Subscription] = {}
        self.watches = [TopicWatch(node, messages.JOINT_STATES_TOPIC,
                                   messages.TYPE_NAMES[JointState],
                                   lambda eps: self._subscribe('joint', eps))]
        if not self.torque:
            self.watches.append(TopicWatch(node, settings['input_topic'],
                                           messages.TYPE_NAMES[Float64],
                                           lambda eps: self._subscribe('command', eps)))
            self.input_topic = settings['input_topic']
            node.create_timer(FLUSH_S, self._flush)

    def _subscribe(self, kind: str, endpoints: list[Any]) -> None:
        reliable = messages.all_reliable(endpoints)
        topic, msg_type, callback = (
            (messages.JOINT_STATES_TOPIC, JointState, self._on_joint) if kind == 'joint'
            else (self.input_topic, Float64, self._on_command))
        # rclpy passes the MessageInfo too to a two-argument callback (its annotation
        # names the one-argument form only)
        self.subscriptions[kind] = self.node.create_subscription(
            msg_type, topic, cast(Any, callback), messages.robot_qos(reliable))
        self.node.get_logger().info(
            f'subscribed {self.node.resolve_topic_name(topic)} '
            f'({"reliable" if reliable else "best effort"}, as its publishers)')

    def _warn_once(self, key: str, text: str) -> None:
        if key not in self._warned:
            self._warned.add(key)
            self.node.get_logger().warning(text)

    def _joint_index(self, msg: JointState) -> int | None:
        if self.index is not None and self.index < len(msg.name) and \
                msg.name[self.index] == self.joint:
            return self.index
        if not self.joint and len(msg.name) <= 1:
            self.index = 0
            return 0
        if self.joint in msg.name:
            self.index = list(msg.name).index(self.joint)
            return self.index
        self._warn_once('joint', f'joint_states has no joint {self.joint!r} (joints: '
                                 f'{", ".join(msg.name) or "none"}); set joint_name')
        return None

    def _time(self, t: float) -> float:
        if self.origin is None:
            self.origin = math.floor(t)
        return t - self.origin

    def _on_joint(self, msg: JointState, info: Any) -> None:
        k = self._joint_index(msg)
        if k is None:
            return
        t = messages.stamp_seconds(msg.header.stamp) or info['source_timestamp'] * 1e-9
        speed = messages.joint_value(msg, k, self.speed_field)
        other = (messages.joint_value(msg, k, self.current_field) if self.current_field
                 else math.nan)
        if math.isnan(speed):
            self._warn_once('speed', f'joint_states: {self.speed_field} is empty for joint '
                                     f'{msg.name[k] if k < len(msg.name) else k}')
            return
        if self.torque:
            row = [self.aligner.seq, self._time(t), other, speed, math.nan, 0.0]
            self.aligner.seq += 1
            self.buffer.extend([row])
        else:
            self.aligner.add_measurement(self._time(t), speed, other)

    def _on_command(self, msg: Float64, info: Any) -> None:
        self.aligner.add_command(self._time(info['source_timestamp'] * 1e-9), msg.data)

    def _flush(self) -> None:
        if self.origin is None:
            return
        now = self.node.get_clock().now().nanoseconds * 1e-9 - self.origin
        rows = self.aligner.ready_rows(now)
        if len(rows):
            self.buffer.extend(rows)

    def counts(self) -> dict[str, int | str]:
        """Counters for the diagnostics."""
        return {'dropped_no_command': self.aligner.dropped_no_command,
                'dropped_out_of_order': self.aligner.dropped_out_of_order,
                'subscribed': ','.join(sorted(self.subscriptions)) or 'none'}
