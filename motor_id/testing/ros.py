"""Helpers of the node tests: the nodes' environment, sample rows, diagnostics, stopping.

Node processes come from :mod:`motor_id.testing.procs`, the in-process client from
:mod:`motor_id.testing.client`; this module adds what only the tests need. ROS message
packages are imported where they are used, so a test that only needs :data:`REPO` or
:func:`ros_env` loads no rclpy.
"""

from collections.abc import Iterable, Sized
import os
import signal
import time
from typing import Any, TYPE_CHECKING
import weakref

import numpy as np
from numpy.typing import NDArray

from motor_id.contracts import SAMPLE_COLUMNS
from motor_id.testing import procs
from motor_id.testing.procs import domain_id, Process, wait_until

if TYPE_CHECKING:  # rclpy loads only where a client is used
    from motor_id.testing.client import RosClient

__all__ = ['domain_id', 'latest_status', 'Process', 'publish_samples', 'REPO', 'ros_env',
           'rows_of', 'samples_publisher', 'settle', 'stop_cleanly', 'wait_until']

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
"""The directory this ``motor_id`` is imported from: the repository in a source checkout."""


def ros_env(domain: int, **extra: object) -> dict[str, str]:
    """The environment of a node process started by a test: :func:`procs.ros_env` with
    :data:`REPO` first on PYTHONPATH, so the node runs the code under test."""
    return procs.ros_env(domain, pythonpath=REPO, **extra)


_SAMPLES_PUBLISHERS: 'weakref.WeakKeyDictionary[RosClient, Any]' = weakref.WeakKeyDictionary()
"""Each client's ``samples`` publisher, created on first use."""


def stop_cleanly(proc: Process, sig: int | None = None) -> None:
    """Stop ``proc`` with ``sig`` (SIGINT); assert exit code 0, no traceback and no use of
    a destroyed ROS entity ("cannot use Destroyable": a shutdown race)."""
    code = proc.stop(signal.SIGINT if sig is None else sig)
    err = proc.stderr()
    assert not proc.killed, f'{proc.name} ignored the signal:\n{proc.output()}'
    assert 'Traceback' not in err and 'Destroyable' not in err, err
    assert code == 0, f'{proc.name} exit {code}:\n{proc.output()}'


def settle(*boxes: Sized, quiet: float = 1.0, timeout: float = 60.0) -> bool:
    """Wait until no list in ``boxes`` (filled by subscriptions) grew for ``quiet`` [s]:
    the messages still on their way have arrived. Returns False after ``timeout`` [s]."""
    deadline = time.monotonic() + timeout
    sizes = [len(b) for b in boxes]
    still = time.monotonic()
    while time.monotonic() < deadline:
        time.sleep(0.05)
        now = [len(b) for b in boxes]
        if now != sizes:
            sizes, still = now, time.monotonic()
        elif time.monotonic() - still >= quiet:
            return True
    return False


def rows_of(msgs: Iterable[Any]) -> NDArray[np.float64]:
    """All rows of the collected samples messages."""
    from motor_id.nodes import messages
    msgs = list(msgs)
    if not msgs:
        return np.zeros((0, len(SAMPLE_COLUMNS)))
    return np.vstack([messages.msg_to_rows(m) for m in msgs])


def latest_status(diags: Iterable[Any], name: str) -> dict[str, str]:
    """Key/values of the latest /diagnostics status named ``name`` (or {})."""
    for d in reversed(list(diags)):
        for st_ in d.status:
            if st_.name == name:
                return {kv.key: kv.value for kv in st_.values}
    return {}


def samples_publisher(client: 'RosClient') -> Any:
    """The client's ``samples`` publisher, once another node subscribes to it."""
    from motor_id.nodes import messages
    pub = _SAMPLES_PUBLISHERS.get(client)
    if pub is None:
        pub = client.node.create_publisher(messages.Float64MultiArray, 'samples',
                                           messages.SAMPLES_QOS)
        _SAMPLES_PUBLISHERS[client] = pub
    own = sum(1 for info in client.node.get_subscriptions_info_by_topic('/samples')
              if info.node_name == client.node.get_name())
    assert wait_until(lambda: pub.get_subscription_count() > own, 20.0)
    return pub


def publish_samples(client: 'RosClient', rows: NDArray[np.float64], batch: int = 100) -> None:
    """Publish sample rows on ``samples`` in batches once another node subscribes."""
    from motor_id.nodes import messages
    pub = samples_publisher(client)
    for k in range(0, rows.shape[0], batch):
        pub.publish(messages.rows_to_msg(rows[k:k + batch]))
