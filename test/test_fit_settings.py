"""FitSettings: one validated settings object for every fit (issue 29 item 2)."""

import numpy as np
import pytest

from motor_id import FitSettings, Identifier
from motor_id.cli.flags import flag_hint
from motor_id.errors import ConfigError
from motor_id.identify import require_resistance
from motor_id.identify.estimator import staged
from motor_id.identify.settings import FitStages, SETTING_NAMES, STAGE_NAMES


@pytest.mark.parametrize('field, value, message', [
    ('method', 'magic', 'method must be one of'),
    ('R_m', -1.0, 'R_m must be a finite value > 0 Ohm'),
    ('R_m', float('nan'), 'R_m must be a finite value > 0 Ohm'),
    ('R_m_tolerance', 0.0, 'R_m_tolerance (the R_m tolerance) must be a finite fraction > 0'),
    ('tie', 'yes', 'tie takes True, False or None'),
    ('population', 1, 'population must be a whole number >= 2'),
    ('generations', 2.5, 'generations must be a whole number >= 1'),
    ('bootstrap', -1, 'bootstrap must be a whole number >= 0'),
    ('crossover', 1.5, 'crossover (a probability) must be in [0, 1]'),
    ('mutation', -0.1, 'mutation (a probability) must be in [0, 1]'),
    ('random_state', -3, 'random_state takes a seed >= 0'),
    ('fixed', {'Q': 1.0}, "fixed: unknown parameter 'Q'"),
    ('fixed', {'J': 0.0}, 'fixed: J must be a finite number > 0'),
    ('bounds', {'J': (1.0, 0.1)}, 'bounds: J needs finite LOW <= HIGH'),
    ('bounds', {'B': (0.0, 1.0)}, 'bounds: B is searched on a log scale: LOW must be > 0'),
    ('bounds', {'J': 3.0}, 'bounds: J takes (LOW, HIGH)'),
    ('channels', 'speed', 'channels takes a sequence of names'),
])
def test_a_bad_value_names_its_field(field, value, message):
    with pytest.raises(ConfigError) as exc:
        FitSettings(**{field: value})
    assert str(exc.value).startswith(message)
    assert exc.value.params == (field,)


def test_values_are_normalised_copies_and_replace_validates_again():
    fixed = {'J': np.float64(0.05)}
    s = FitSettings(R_m=2.3, fixed=fixed, bounds={'B': [1e-6, 0.1]}, channels=['speed'],
                    free_effects=['coulomb_friction.T_c'], random_state=np.int64(3))
    fixed['J'] = 1.0                       # the settings hold their own copy
    assert s.fixed == {'J': 0.05} and type(s.fixed['J']) is float
    assert s.bounds == {'B': (1e-6, 0.1)}
    assert s.channels == ('speed',) and s.free_effects == ('coulomb_friction.T_c',)
    assert s.replace(generations=40).generations == 40 and s.generations == 160
    with pytest.raises(ConfigError, match='generations must be'):
        s.replace(generations=0)
    with pytest.raises(ConfigError, match='unknown fit setting.*settle') as exc:
        s.replace(settle=False)
    assert exc.value.params == ('settle',)
    with pytest.raises(AttributeError):
        s.R_m = 1.0   # frozen


def test_the_stage_knobs_are_not_settings():
    assert not set(STAGE_NAMES) & set(SETTING_NAMES)
    for knob in STAGE_NAMES:
        with pytest.raises(ConfigError, match=f'unknown fit setting.*{knob}'):
            Identifier(R_m=2.3, **{knob: getattr(FitStages(), knob)})
    est = staged(FitSettings(R_m=2.3), settle=False, reweight=1)
    assert est.stages == FitStages(settle=False, reweight=1)


def test_the_constructor_takes_settings_or_their_fields():
    given = FitSettings(R_m=2.3, random_state=0)
    assert Identifier(given).settings == Identifier(R_m=2.3, random_state=0).settings
    assert Identifier(given, generations=40).settings == given.replace(generations=40)
    est = Identifier(given).warm_start({'J': 0.05})
    assert est.settings.start == {'J': 0.05} and est.stages.use_ga is False
    other = est.with_settings(R_m=3.0)
    assert other.settings.R_m == 3.0 and other.stages == est.stages
    assert est.settings.R_m == 2.3


@pytest.mark.parametrize('kind, current, fixed, needed', [
    ('voltage', True, None, True),          # the current sees R_m
    ('voltage', False, None, False),        # speed alone does not
    ('voltage', False, {'J': 0.05}, True),  # a known J ties the others to R_m
    ('voltage', False, {'R_m': 2.0}, False),
    ('torque', True, None, False),
])
def test_the_one_resistance_check(kind, current, fixed, needed):
    if not needed:
        require_resistance(None, kind, current, fixed)
        return
    with pytest.raises(ConfigError, match=r'R_m \(the armature resistance.*\) is required') \
            as exc:
        require_resistance(None, kind, current, fixed)
    assert exc.value.params == (('R_m', 'fixed') if fixed else ('R_m',))
    assert flag_hint(exc.value.params) == (
        ' (command line: -R/--resistance, --fix)' if fixed else
        ' (command line: -R/--resistance)')
    require_resistance(2.3, kind, current, fixed)   # given: no error
