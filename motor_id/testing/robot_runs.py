"""The simulated robot's experiment without ROS: the same joint, sensor timing and plan as
``motor-id demo --robot``, run offline in simulated time, for many seeds.

The joint is :class:`motor_id.testing.sim_joint.JointSim` (the independent physics, the
sampling jitter, the message latency and the sensor noise of ``sim_robot``); the plan and
its guard are the experiment's own (:class:`motor_id.experiment.session.ExperimentSession`).
Each sample reaches the guard when its message would arrive (its ``due`` time); a command
decided on it takes effect a random ``command_latency`` later (a loaded host's delivery
and scheduling). What the recording lacks against a
live run is the scheduling noise of a loaded machine.
"""

from __future__ import annotations

from dataclasses import dataclass
import heapq

import numpy as np

from motor_id.experiment.guard import StateSample
from motor_id.experiment.session import ExperimentSession
from motor_id.experiment.settings import ExperimentSettings
from motor_id.recording import Recording
from motor_id.testing.sim_joint import JointSim, JointTruth, Sample, SimConfig


@dataclass(frozen=True)
class RobotRun:
    """One offline experiment: its recording (None: too short to fit), the truth, and why
    the plan ended."""

    recording: Recording | None
    truth: JointTruth
    stop_reason: str | None


def robot_run(config: SimConfig, settings: ExperimentSettings,
              command_latency: tuple[float, float] = (1e-3, 8e-3),
              t_max: float = 600.0) -> RobotRun:
    """Run the experiment of ``settings`` on the simulated joint of ``config``.

    Parameters
    ----------
    config : SimConfig
        The robot (mechanism, rate, jitter, latency, noise, seed).
    settings : ExperimentSettings
        The experiment (plan, limits, time scale); nothing is written to its ``out``.
    command_latency : (float, float)
        From a sample's arrival to its command acting on the joint [s]: uniform in this
        range, seeded by ``config.seed``.
    t_max : float
        Simulated time after which the run is cut [s].

    Returns
    -------
    RobotRun
    """
    rng = np.random.default_rng([config.seed, 1])
    sim = JointSim(config, 0.0)
    sess = ExperimentSession(settings)
    first = sess.start(0.0)
    sess.note_sent(0.0, first)
    sim.command(0.0, first)
    inbox: list[tuple[float, int, Sample]] = []
    count = 0
    now = 0.0
    while not sess.guard.finished and now < t_max:
        if not inbox or sim.next_sample <= inbox[0][0]:
            now = sim.next_sample
            for s in sim.advance(now):
                heapq.heappush(inbox, (s.due, count, s))
                count += 1
            continue
        due, _, s = heapq.heappop(inbox)
        now = due
        cmd = sess.on_state(StateSample(s.t, due, s.position, s.velocity, s.effort,
                                        lag=due - s.t))
        if cmd is not None:
            sess.note_sent(due, cmd)
            sim.command(due + float(rng.uniform(*command_latency)), cmd)
    return RobotRun(sess.recording(), sim.truth(), sess.guard.log.stop_reason)
