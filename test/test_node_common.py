"""Node plumbing that needs no ROS graph: the stop future the nodes spin on."""

from motor_id.nodes.common import StopFuture


class FakeExecutor:
    def __init__(self):
        self.woken = 0

    def spin_once_until_future_complete(self, future):
        """What Jazzy's executor does on every spin: add a fresh wake callback."""
        future.add_done_callback(lambda x: self.wake())

    def wake(self):
        self.woken += 1


def test_stop_future_keeps_one_wake_callback_per_executor_and_every_other_callback():
    stop = StopFuture()
    a, b = FakeExecutor(), FakeExecutor()
    calls = []
    stop.add_done_callback(lambda f: calls.append(f.result()))
    for _ in range(10000):   # a long-lived node: one spin per executed callback
        a.spin_once_until_future_complete(stop)
        b.spin_once_until_future_complete(stop)
    assert len(stop._callbacks) == 3
    stop.set_result('signal')
    assert calls == ['signal'] and a.woken == 1 and b.woken == 1
    late = []
    stop.add_done_callback(lambda f: late.append(f.result()))   # done: runs at once
    assert late == ['signal']
