"""Republish a bag's sample stream into the ROS graph at a chosen rate."""

import time

import numpy as np
from numpy.typing import NDArray
import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from motor_id.contracts import T
from motor_id.nodes import messages
from motor_id.nodes.common import SignalWatcher, StopSignal


class Replayer(Node):
    """Publishes ``samples`` batches from recorded rows, paced by their card time.

    Parameters
    ----------
    rows : ndarray, shape (n, 6)
        Sample rows (seq, t, voltage, speed, current, flags) in recorded order.
    rate : float
        Playback speed relative to the recorded time (2.0 = twice as fast).
    batch : int
        Rows per message.
    subscribers : int, optional
        Wait up to 30 s for this many matched subscribers before the first rows
        (default: up to 5 s for one).
    """

    def __init__(self, rows: NDArray[np.float64], rate: float = 1.0, batch: int = 10,
                 subscribers: int | None = None) -> None:
        super().__init__('replayer')
        self.rows = rows
        self.rate = rate
        self.batch = batch
        self.pub = self.create_publisher(messages.Float64MultiArray, messages.SAMPLES_TOPIC,
                                         messages.SAMPLES_QOS)
        self.next = 0
        self.t0_wall: float | None = None
        self.done = StopSignal()
        self.done.attach(self)
        self.subscribers = subscribers or 1
        self._wait_until = time.monotonic() + (5.0 if subscribers is None else 30.0)
        self.timer = self.create_timer(0.005, self._tick)

    def _tick(self) -> None:
        if self.done.is_set():
            return
        t0 = self.t0_wall
        if t0 is None:
            if self.pub.get_subscription_count() < self.subscribers and \
                    time.monotonic() < self._wait_until:
                return  # give subscribers time to match before the first rows
            t0 = self.t0_wall = time.monotonic()
        t_card = self.rows[:, T]
        elapsed = (time.monotonic() - t0) * self.rate
        due = int(((t_card - t_card[0]) <= elapsed).sum())
        while self.next < due:
            end = min(self.next + self.batch, due)
            self.pub.publish(messages.rows_to_msg(self.rows[self.next:end]))
            self.next = end
        if self.next >= len(self.rows):
            self.get_logger().info(f'replayed {len(self.rows)} samples')
            self.stop()

    def stop(self) -> None:
        """End the replay (at the end of the rows, or early on a signal)."""
        self.done.set()


def replay(rows: NDArray[np.float64], rate: float, batch: int = 10,
           subscribers: int | None = None) -> int:
    """Publish every row, paced, then return the number published.

    Ctrl-C or SIGTERM stops early and cleanly (see :class:`SignalWatcher`); call from
    the main thread.
    """
    signals = SignalWatcher()
    signals.install()
    rclpy.init(args=[], signal_handler_options=SignalHandlerOptions.NO)
    node = Replayer(rows, rate, batch, subscribers)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    signals.stop.attach(node)
    try:
        while not (node.done.is_set() or signals.stop.is_set()) and executor.context.ok():
            executor.spin_once()
        if signals.received is None:
            time.sleep(0.5)  # let reliable transport deliver the last batches
            executor.spin_once(timeout_sec=0.1)
    except ExternalShutdownException:
        pass
    finally:
        sent = node.next
        signals.stop.detach()
        node.done.detach()
        executor.shutdown(timeout_sec=1.0)
        node.destroy_node()
        rclpy.try_shutdown()
    return sent
