"""The identifier node's live drift: history_file, the fleet's rule after each fit, WARN."""

import json

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np

from motor_id.excitation import paper_steps
from motor_id.model import Plant
from motor_id.nodes import messages
from motor_id.simulate import simulate_recording
from motor_id.testing.procs import wait_until
from motor_id.testing.ros import publish_samples, stop_cleanly


def _paper_rows():
    t = np.arange(4000) * 0.01
    rec = simulate_recording(Plant(), t, paper_steps(t))
    return np.column_stack([np.arange(4000), rec.time, rec.input, rec.speed, rec.current,
                            np.zeros(4000)])


def _identifier(*params):
    args = ['-m', 'motor_id.nodes.identifier', '--ros-args']
    for p in params:
        args += ['-p', p]
    return args


def _latest(diags, name='motor_id: identifier'):
    for d in reversed(list(diags)):
        for st in d.status:
            if st.name == name:
                return st
    return None


def test_identifier_turns_diagnostics_to_warn_on_a_drift(client, launch, tmp_path):
    """Eight earlier estimates put K_T = K_b near 0.75; the paper's motor gives 0.65 now:
    two periodic fits later the status is WARN naming K_T and the change."""
    hist = tmp_path / 'left_wheel.jsonl'
    rng = np.random.default_rng(0)
    with open(hist, 'w') as fh:
        for d in range(8):
            v = 0.75 * (1 + rng.uniform(-0.003, 0.003))
            p = {'value': v, 'std': 1e-4, 'determined': True}
            fh.write(json.dumps({'time': f'2026-01-{d + 1:02d}T10:00:00Z', 'adequate': True,
                                 'parameters': {'K_T': p, 'K_b': p}}) + '\n')
    diags = client.collect(DiagnosticArray, '/diagnostics', messages.DIAGNOSTICS_QOS)
    proc = launch('identifier', _identifier('generations:=40', 'period_s:=1.0',
                                            f'history_file:={hist}'))
    proc.wait_for('identifier ready', timeout=60.0)
    publish_samples(client, _paper_rows())

    def warned():
        st = _latest(diags)
        return st is not None and st.level == messages.WARN and 'drift: K_T' in st.message
    assert wait_until(warned, 60.0), proc.output()
    st = _latest(diags)
    values = {kv.key: kv.value for kv in st.values}
    assert float(values['drift.K_T.change']) < -0.1
    assert values['drift.K_T.since'] >= '2026-01-09'
    assert 'drift: K_T -1' in st.message
    lines = [json.loads(x) for x in hist.read_text().splitlines()]
    assert len(lines) >= 10 and lines[-1]['parameters']['K_T']['value'] < 0.7
    assert 'drift: K_T' in proc.output()      # logged once when found
    stop_cleanly(proc)
