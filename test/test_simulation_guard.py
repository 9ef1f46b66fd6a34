"""The simulation-error stage's guard (issue 26): a model that diverges in simulation, or
whose values are not physical, is never the stage's model, and the analysis' model
competes with the model without its extra effects.

``data/arm_experiment_diverged.mcap`` is ``motor-id demo --robot arm``'s recording of a
run on a busy machine (16 states late, up to 0.13 s): its equation-error verdict was
Coulomb friction and a 1.1 Hz overdamped resonance, whose simulation explained nothing
(held-out cost 1.09), so every feedforward constant was reported not determined. The
linear model under it had kept the slow electrical pole (the last test here). Part of
that was the simulator's: a two-mass model's simulated position started from 0 (fixed
in 0745bc2); the resonance is now sound there, and no better than the model without it.
"""

from pathlib import Path
from types import SimpleNamespace

import pytest

from motor_id.analysis.analyzer import _stage_warnings
from motor_id.analysis.simulation_fit import simulation_stage
from motor_id.analysis.simulation_guard import DIVERGED, reduced_model, unsound
from motor_id.data.load import load_recording
from motor_id.identify.validation import SavedModel
from motor_id.testing.independent_physics import feedforward
from motor_id.testing.sim_joint import MECHANISMS, SimConfig

RECORDING = Path(__file__).parent / 'data' / 'arm_experiment_diverged.mcap'

ANALYSIS_MODEL = SavedModel(
    'voltage', {'J': 0.000589797, 'K_T': 0.00814764, 'K_b': 0.00235157, 'B': 0.0100319,
                'L_m': 0.0104284, 'R_m': 1.0},
    {'arm_gravity': {'T_g': 0.00958442, 'offset': 0.35064},
     'coulomb_friction': {'T_c': 0.00136274},
     'resonance': {'r': 0.440352, 'f_r': 1.11288, 'zeta': 4.72317}},
    'the equation-error model of the analysis on that recording')
"""What ``motor-id analyze --mechanism arm`` chose on the recording (seed 0)."""


def test_reduced_model_keeps_gravity_friction_and_measurement_effects():
    model = SavedModel('voltage', dict(ANALYSIS_MODEL.parameters),
                       {**ANALYSIS_MODEL.effects, 'input_delay': {'d': 2.0},
                        'speed_quantization': {'q': 0.01}})
    reduced = reduced_model(model)
    assert reduced is not None
    assert sorted(reduced.effects) == ['arm_gravity', 'coulomb_friction',
                                       'speed_quantization']
    assert reduced.parameters == model.parameters
    assert reduced_model(reduced) is None      # nothing left to drop


def test_unsound_names_divergence_and_an_aliased_resonance():
    scales = {'per_sample': 100.0}               # Nyquist 50 Hz
    assert unsound(0.5 * DIVERGED, {'resonance': {'f_r': 10.0}}, scales) == ''
    assert unsound(DIVERGED, {}, scales).startswith('diverged')
    assert unsound(float('inf'), {}, scales).startswith('diverged')
    why = unsound(0.01, {'resonance': {'r': 1.0, 'f_r': 998.0, 'zeta': 5.0}}, scales)
    assert why.startswith('implausible') and 'alias' in why


def test_a_stage_without_a_sound_model_makes_the_report_inadequate():
    report = SimpleNamespace(adequate=True, warnings=['the steady states show ...'])
    _stage_warnings(report, SimpleNamespace(failed='no sound model', fallback=''))
    assert not report.adequate
    assert report.warnings[0] == 'the simulation-error stage found no model: no sound model'
    report = SimpleNamespace(adequate=True, warnings=[])
    _stage_warnings(report, SimpleNamespace(failed='', fallback='fell back', heldout_fit={}))
    assert report.adequate and report.warnings == ['simulation error: fell back']


def test_the_report_is_as_adequate_as_the_stage_model_it_presents():
    # the stage's model explains 40 % of the held-out speed: inadequate, whatever the
    # equation-error stage said; 93.8 % (the Miami drivetrain's two masses) makes an
    # equation-error inadequacy a warning, its parameters still not determined
    stage = SimpleNamespace(failed='', fallback='', chosen='coulomb_friction+resonance',
                            heldout_fit={'position': 99.0, 'speed': 40.0})
    report = SimpleNamespace(adequate=True, warnings=['the speed kept one sign'])
    _stage_warnings(report, stage)
    assert not report.adequate and len(report.warnings) == 2
    assert report.warnings[0].startswith('the simulation-error model (coulomb_friction+'
                                         'resonance) explains 40.0 % of the speed')
    stage.heldout_fit['speed'] = 93.8
    lost = ('the chosen model explains (held out) 25.5 % of the speed (an adequate model '
            'explains at least 50 %): its parameters are not presented as determined; no '
            'named effect explains this record (a load that changes along it, a second '
            'input?)')
    report = SimpleNamespace(adequate=False, warnings=[lost])
    _stage_warnings(report, stage)
    assert report.adequate and report.warnings == [
        'the equation-error model explains (held out) 25.5 % of the speed (an adequate '
        'model explains at least 50 %): its parameters are not presented as determined; '
        'the simulation-error model (coulomb_friction+resonance) explains 93.8 % of the '
        'speed on the held-out blocks, simulated from the start of each, and is the model '
        'reported']
    # an inadequacy for another reason stands
    report = SimpleNamespace(adequate=False, warnings=['the model explains 10 % of x'])
    _stage_warnings(report, stage)
    assert not report.adequate


def test_stage_leaves_the_analysis_model_for_a_simpler_one_as_good():
    """The busy-machine arm recording: the analysis' model (with a resonance) does no
    better than without it, the stage searches from gravity and Coulomb friction, and
    the feedforward constants meet the issue's targets (kG, kV within 10 %, kA within
    30 %, kS within 0.1 V, offset within 0.1 rad; on this recording they are within 6 %,
    0.01 V and 0.01 rad)."""
    rec = load_recording(RECORDING)
    sim = simulation_stage(rec, ANALYSIS_MODEL, init_samples=20, halves=False)
    assert sim.model is not None and 'resonance' not in sim.model.effects
    assert {'arm_gravity', 'coulomb_friction'} <= set(sim.model.effects)
    first = sim.candidates[0]
    assert first.name == 'arm_gravity+coulomb_friction+resonance'
    # the resonance does not help. It had diverged (held-out cost 0.97 of the channels'
    # spread) while a two-mass model's simulated position started from 0, which was the
    # simulator's fault (fixed 0745bc2); now it is sound and no better than the rival
    # without it (held-out 7.6e-5 against 6.9e-5), and the stage falls back to the rival
    rival = next(c for c in sim.candidates if c.name == 'arm_gravity+coulomb_friction')
    assert rival.heldout_cost < 0.002
    assert first.failed or first.heldout_cost >= rival.heldout_cost, (first, rival)
    assert 'arm_gravity+coulomb_friction+resonance' in sim.fallback
    assert sim.estimates is not None and sim.estimates.combinations is not None
    found = {c.name: c for c in sim.estimates.combinations}
    arm = MECHANISMS['arm']
    true = feedforward(arm.motor, SimConfig(mechanism='arm').effects(), 'voltage')
    assert all(found[k].determined for k in ('kS', 'kV', 'kA', 'kG', 'offset'))
    assert found['kG'].value == pytest.approx(true['kG'], rel=0.10)
    assert found['offset'].value == pytest.approx(true['offset'], abs=0.1)
    assert found['kV'].value == pytest.approx(true['kV'], rel=0.10)
    assert found['kS'].value == pytest.approx(true['kS'], abs=0.1)
    assert found['kA'].value == pytest.approx(true['kA'], rel=0.30)


@pytest.mark.slow   # two GAs of the linear model (20 s alone)
def test_the_linear_arm_model_keeps_the_electrical_pole_the_faster():
    """Speed alone cannot tell the electrical pole from the mechanical one. On this
    recording the fit with the gravity ended in both assignments within 1.5 % of each
    other's training cost: the one with the slow electrical pole (L_m 0.058 H, J 6.8e-5)
    had been kept, held-out error 0.0759, and Coulomb friction then explained only 22 %
    of it; with the electrical pole the faster, 0.0412."""
    from motor_id.analysis.candidates import CandidateFitter
    from motor_id.analysis.heldout import HeldOutSplit
    from motor_id.identify.mechanism import electrical_first
    rec = load_recording(RECORDING)
    fitter = CandidateFitter(rec, HeldOutSplit(rec, 10, {}), None, 0, 2, 40, 0.1, 'arm')
    base = fitter.fit_linear(100)
    assert electrical_first(fitter.linear_estimator)
    assert base.heldout_error < 0.05
