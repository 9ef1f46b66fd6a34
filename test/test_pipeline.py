"""The one pipeline: a recording to the full fit report, for the CLI and the node alike."""

import json
import math

import numpy as np
import yaml

from motor_id import pipeline
from motor_id.cli import main
from motor_id.identify import Identifier
from motor_id.testing.recordings import paper_recording, SI_MOTOR


def test_the_report_holds_fit_data_and_controller_and_flattens_for_ros():
    rec = paper_recording(params=SI_MOTOR, speed_noise=0.01, current_noise=0.01, seed=3)
    fit = pipeline.fit_report(rec, Identifier(R_m=2.3, random_state=0),
                            extra={'hardware_id': 'bench'})
    d = fit.to_dict()
    assert d['adequate'] is True and d['data']['samples'] == len(rec)
    assert d['data']['runs'] == 1 and d['hardware_id'] == 'bench'
    assert set(d['controller']) == {'feedforward', 'time_constants', 'pi', 'notes'}
    flat = fit.to_ros_parameters()['/**']['ros__parameters']
    assert flat['estimate.J'] == d['parameters']['J']['value']
    assert flat['controller.kV'] == d['controller']['feedforward']['kV']['value']
    json.dumps(d, default=float)  # JSON-ready apart from numpy scalars


def test_unknown_values_are_left_out_of_a_file_and_nan_for_a_node():
    rec = paper_recording(params=SI_MOTOR, speed_noise=0.01, current_noise=0.01, seed=3)
    speed_only = rec.slice(0, len(rec))
    speed_only.current = None
    fit = pipeline.fit_report(speed_only, Identifier(R_m=2.3, random_state=0))
    undetermined = [n for n, p in fit.to_dict()['parameters'].items() if p['value'] is None]
    assert undetermined  # speed alone: three combinations of five parameters
    omit = fit.to_ros_parameters()['/**']['ros__parameters']
    nan = fit.to_ros_parameters('x', unknown='nan')['x']['ros__parameters']
    for n in undetermined:
        assert f'estimate.{n}' not in omit
        assert math.isnan(nan[f'estimate.{n}'])


def test_the_cli_writes_what_the_pipeline_builds(tmp_path):
    rec = paper_recording(params=SI_MOTOR, speed_noise=0.01, current_noise=0.01, seed=3)
    from motor_id.data.csv_io import write_csv
    path = tmp_path / 'r.csv'
    write_csv(rec, path)
    out, yml = tmp_path / 'r.json', tmp_path / 'r.yaml'
    assert main(['fit', str(path), '-R', '2.3', '-q', '--json', str(out),
                 '--yaml', str(yml)]) == 0
    d = json.loads(out.read_text())
    again = pipeline.fit_report(rec, Identifier(R_m=2.3, random_state=0)).to_dict()
    for n, p in again['parameters'].items():
        assert d['parameters'][n]['value'] == np.float64(p['value'])
    params = yaml.safe_load(yml.read_text())['/**']['ros__parameters']
    assert params['estimate.J'] == d['parameters']['J']['value']
    assert params['controller.kA'] == d['controller']['feedforward']['kA']['value']
