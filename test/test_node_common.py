"""Node plumbing in one process: the stop signal the nodes spin on, the topic-type watch."""

import threading
import time
import tracemalloc

import pytest
import rclpy
from rclpy.executors import MultiThreadedExecutor, SingleThreadedExecutor
from std_msgs.msg import Float64

from motor_id.nodes.common import drain, StopSignal, TopicWatch
from motor_id.testing.procs import domain_id


@pytest.fixture
def context(monkeypatch):
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain_id(__name__))
    yield ctx
    rclpy.try_shutdown(context=ctx)


@pytest.mark.parametrize('executor_type', [SingleThreadedExecutor, MultiThreadedExecutor])
def test_stop_signal_from_another_thread_ends_a_spin_at_once(context, executor_type):
    node = rclpy.create_node('stop_test', context=context)
    executor = executor_type(context=context)
    executor.add_node(node)
    stop = StopSignal()
    stop.attach(node)
    ticks = []
    node.create_timer(0.01, lambda: ticks.append(1))
    threading.Timer(0.3, stop.set).start()
    t0 = time.monotonic()
    stop.spin(executor)
    elapsed = time.monotonic() - t0
    stop.detach()
    assert drain(executor, node)     # the timer's last callbacks, queued in the pool
    executor.shutdown(1.0)
    node.destroy_node()
    assert stop.is_set() and 0.25 <= elapsed < 5.0, elapsed   # 5 s: a failure bound
    assert len(ticks) >= 5


def test_stop_requested_before_spinning_is_not_lost(context):
    stop = StopSignal()
    stop.set()   # e.g. SIGINT while the node is being built
    node = rclpy.create_node('early_stop', context=context)
    stop.attach(node)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    t0 = time.monotonic()
    stop.spin(executor)
    assert time.monotonic() - t0 < 1.0
    stop.detach()
    executor.shutdown(1.0)
    node.destroy_node()


def test_spinning_on_the_stop_signal_does_not_grow_memory(context):
    """The old stop future gained a done-callback per spin (1.5 MiB/min at 100 msg/s)."""
    node = rclpy.create_node('no_growth', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    stop = StopSignal()
    stop.attach(node)
    count = [0]
    marks = {}

    def tick():
        count[0] += 1
        if count[0] == 1000:
            marks['a'] = tracemalloc.get_traced_memory()[0]
        elif count[0] == 6000:
            marks['b'] = tracemalloc.get_traced_memory()[0]
            stop.set()
    node.create_timer(0.0, tick)   # a callback on every spin
    tracemalloc.start()
    try:
        stop.spin(executor)
    finally:
        tracemalloc.stop()
        stop.detach()
        executor.shutdown(1.0)
        node.destroy_node()
    # 5000 spins; one lambda per spin (the old leak, ~260 B each) would be > 1 MB
    assert marks['b'] - marks['a'] < 100_000, marks


def test_topic_watch_names_the_wrong_type(context):
    pub_node = rclpy.create_node('wrong_type_pub', context=context)
    pub_node.create_publisher(Float64, 'watched', 10)
    node = rclpy.create_node('watcher', context=context)
    found = []
    watch = TopicWatch(node, 'watched', 'std_msgs/msg/Float64MultiArray', found.append,
                       period_s=0.05)
    warnings = []
    node.get_logger().warning = warnings.append
    deadline = time.monotonic() + 10.0
    while not warnings and time.monotonic() < deadline:
        watch.check()
        time.sleep(0.05)
    assert warnings and 'std_msgs/msg/Float64' in warnings[0], warnings
    assert not found and not watch.found
    right = rclpy.create_node('right_type_pub', context=context)
    right.create_publisher(Float64, 'watched_ok', 10)
    ok = TopicWatch(node, 'watched_ok', 'std_msgs/msg/Float64', found.append)
    deadline = time.monotonic() + 10.0
    while not ok.check() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert ok.found and len(found) == 1 and found[0][0].node_name == 'right_type_pub'
    for n in (pub_node, node, right):
        n.destroy_node()
