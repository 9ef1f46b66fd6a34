"""Test helpers for ROS node tests, on the package's process and client helpers."""

import os

import numpy as np

from motor_id.nodes import procs
from motor_id.nodes.procs import Process, wait_until  # noqa: F401  (used by the tests)

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def domain_id(name):
    """A ROS_DOMAIN_ID in 1..101 for one test module, varied by process id."""
    return procs.domain_id(name)


def ros_env(domain, **extra):
    """The environment of a node process started from the tests (the repo on the path)."""
    return procs.ros_env(domain, pythonpath=REPO, **extra)


def Client(domain, name='test_client'):   # noqa: N802  (was a class; kept for the tests)
    """A threaded ROS client in this process (:class:`motor_id.nodes.client.RosClient`)."""
    from motor_id.nodes.client import RosClient
    return RosClient(domain, name)


def stop_cleanly(proc, sig=None):
    """Stop ``proc`` with ``sig`` (SIGINT); assert exit code 0 and no traceback."""
    import signal
    code = proc.stop(signal.SIGINT if sig is None else sig)
    err = proc.stderr()
    assert not proc.killed, f'{proc.name} ignored the signal:\n{proc.output()}'
    assert 'Traceback' not in err, err
    assert code == 0, f'{proc.name} exit {code}:\n{proc.output()}'


def rows_of(msgs):
    """All rows of the collected samples messages."""
    from motor_id.nodes import messages
    msgs = list(msgs)
    if not msgs:
        return np.zeros((0, 6))
    return np.vstack([messages.msg_to_rows(m) for m in msgs])


def latest_status(diags, name):
    """Key/values of the latest /diagnostics status named ``name`` (or {})."""
    for d in reversed(list(diags)):
        for st_ in d.status:
            if st_.name == name:
                return {kv.key: kv.value for kv in st_.values}
    return {}


def samples_publisher(client):
    """The client's ``samples`` publisher, once another node subscribes to it."""
    from motor_id.nodes import messages
    pub = getattr(client, '_samples_pub', None)
    if pub is None:
        pub = client.node.create_publisher(messages.Float64MultiArray, 'samples',
                                           messages.SAMPLES_QOS)
        client._samples_pub = pub
    own = sum(1 for info in client.node.get_subscriptions_info_by_topic('/samples')
              if info.node_name == client.node.get_name())
    assert wait_until(lambda: pub.get_subscription_count() > own, 20.0)
    return pub


def publish_samples(client, rows, batch=100):
    """Publish sample rows on ``samples`` in batches once another node subscribes."""
    from motor_id.nodes import messages
    pub = samples_publisher(client)
    for k in range(0, rows.shape[0], batch):
        pub.publish(messages.rows_to_msg(rows[k:k + batch]))
