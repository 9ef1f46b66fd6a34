"""Shared fixtures: the paper's experiment, simulated, and the node tests' ROS plumbing.

Helpers live in :mod:`motor_id.testing` and are imported from there by name; this file
only turns them into fixtures.
"""

import os
import signal

import pytest

from motor_id.blas import limit_threads

limit_threads()  # before a test module loads numpy; xdist workers and node processes inherit it


def _ignore_by_handler() -> None:
    """A run started under ``nohup`` or in the background ignores SIGHUP or SIGINT, and an
    ignored signal stays ignored in every child: the children's stop tests could not pass.
    The run goes on ignoring them, by a handler that does nothing, and a handler (unlike an
    ignore) is reset to the default in a child."""
    for sig in (signal.SIGHUP, signal.SIGINT):
        if signal.getsignal(sig) == signal.SIG_IGN:
            signal.signal(sig, lambda *_: None)


_ignore_by_handler()


@pytest.fixture(scope='session', autouse=True)
def clean_dds_shm():
    """Start the run without Fast DDS shared-memory files left by killed processes."""
    from motor_id.nodes.shm import clean_stale_shm
    clean_stale_shm()


@pytest.fixture(scope='session', autouse=True)
def cpu_burners(request):
    """``MOTOR_ID_BURN=1``: one busy process per core beside the run, so that the node and
    process tests show whether they hold with every core busy (CONTRIBUTING.md). Under
    xdist only the first worker starts them."""
    from motor_id.testing.procs import start_burners
    worker = os.environ.get('PYTEST_XDIST_WORKER', 'gw0')
    burners = start_burners() if os.environ.get('MOTOR_ID_BURN', '0') not in ('', '0') \
        and worker == 'gw0' else []
    yield burners
    for proc in burners:
        proc.kill()
        proc.wait()


@pytest.fixture(scope='session', autouse=True)
def nothing_left_running(cpu_burners):
    """At the end of the run no process the tests started is still there (a leftover is
    killed, and the run fails naming it)."""
    yield
    from motor_id.testing.procs import leftovers
    left = leftovers()
    assert not left, f'processes left running (now killed): {left}'


@pytest.fixture(scope='session')
def clean_paper():
    """Noise-free speed and current of the paper's motor."""
    from motor_id.testing.recordings import paper_recording
    return paper_recording()


@pytest.fixture(scope='module')
def ros_domain(request):
    """The module's ROS_DOMAIN_ID (the same as ``domain_id(__name__)``)."""
    from motor_id.testing.procs import domain_id
    return domain_id(request.module.__name__)


@pytest.fixture(scope='module')
def client(request, ros_domain):
    """A threaded ROS client in the test process, one per module."""
    from motor_id.testing.client import RosClient
    c = RosClient(ros_domain, request.module.__name__.rsplit('.', 1)[-1] + '_client')
    yield c
    c.close()


@pytest.fixture
def launch(tmp_path, ros_domain):
    """Start node processes (``launch(name, args, **env)``); all are ended at the end."""
    from motor_id.testing.procs import Process
    from motor_id.testing.ros import ros_env
    procs = []

    def start(name, args, **env):
        p = Process(args, ros_env(ros_domain, **env), tmp_path, name)
        procs.append(p)
        return p
    yield start
    for p in procs:
        p.close()


ROS_MODULES = frozenset({'test_colcon', 'test_demo', 'test_driver_safety', 'test_faults',
                         'test_fleet_node', 'test_identifier_topics', 'test_namespaces',
                         'test_node_common', 'test_nodes', 'test_rosbag_input'})
"""Modules that start ROS nodes (or the demo, or a colcon build of them)."""


@pytest.hookimpl(wrapper=True)
def pytest_collection_modifyitems(config, items):
    """Put every test that starts ROS nodes in one xdist group: under ``-n 2 --dist
    loadgroup`` they run in one worker, one after another as in a single process (their
    domain ids never meet, and no two node tests load the machine at once), while the
    other worker runs the rest.

    The group is marked before every other hook (xdist's worker reads the mark in its
    own) and checked after them: a pytest whose node ids ignore xdist's group suffix
    (pytest 9.2 with pytest-xdist 3.8) would silently run node tests on both workers
    at once, so the run stops with the reason instead."""
    ros = []
    for item in items:
        module = item.module.__name__.rsplit('.', 1)[-1]
        if module in ROS_MODULES or {'client', 'launch', 'ros_domain'} & set(item.fixturenames):
            item.add_marker(pytest.mark.xdist_group('ros'))
            ros.append(item)
    result = yield
    if getattr(config.option, 'loadgroup', False):
        lost = [item.nodeid for item in ros if not item.nodeid.endswith('@ros')]
        if lost:
            raise pytest.UsageError(
                f'--dist loadgroup did not group {len(lost)} ROS node tests (e.g. {lost[0]}):'
                f' this pytest ({pytest.__version__}) and pytest-xdist do not work together;'
                ' install the versions setup.py pins')
    return result
