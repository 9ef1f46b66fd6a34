"""Shared fixtures: the paper's experiment, simulated."""

import numpy as np
import pytest

from motor_id.excitation import paper_steps
from motor_id.model import MotorParams, PAPER_MOTOR, Plant
from motor_id.simulate import simulate_recording

PAPER_T = np.arange(4000) * 0.01
SI_MOTOR = MotorParams(J=0.052, K_T=0.66, K_b=0.66, B=0.002, L_m=0.0345, R_m=2.3)
"""The paper's motor with K_T = K_b, as SI units require."""


def paper_recording(params=PAPER_MOTOR, speed_noise=0.0, current_noise=0.0, seed=0,
                    with_current=True, effects=None, method='zoh'):
    """The paper's Eq. 14 experiment: 4000 samples at 10 ms."""
    return simulate_recording(Plant(params, 'voltage', effects or {}), PAPER_T,
                              paper_steps(PAPER_T), speed_noise, current_noise,
                              with_current, method, seed)


@pytest.fixture(scope='session', autouse=True)
def clean_dds_shm():
    """Start the run without Fast DDS shared-memory files left by killed processes."""
    from motor_id.nodes.shm import clean_stale_shm
    clean_stale_shm()


@pytest.fixture(scope='session')
def clean_paper():
    """Noise-free speed and current of the paper's motor."""
    return paper_recording()


@pytest.fixture(scope='module')
def ros_domain(request):
    """The module's ROS_DOMAIN_ID (the same as ``rosutil.domain_id(__name__)``)."""
    from rosutil import domain_id
    return domain_id(request.module.__name__)


@pytest.fixture(scope='module')
def client(request, ros_domain):
    """A threaded ROS client in the test process, one per module."""
    from rosutil import Client
    c = Client(ros_domain, request.module.__name__.rsplit('.', 1)[-1] + '_client')
    yield c
    c.close()


@pytest.fixture
def launch(tmp_path, ros_domain):
    """Start node processes (``launch(name, args, **env)``); all are ended at the end."""
    from rosutil import Process, ros_env
    procs = []

    def start(name, args, **env):
        p = Process(args, ros_env(ros_domain, **env), tmp_path, name)
        procs.append(p)
        return p
    yield start
    for p in procs:
        p.close()
