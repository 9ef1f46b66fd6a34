"""A first-order lag of the speed sensor."""

from motor_id.effects.spec import Confusion, EffectParam, EffectSpec, KernelArg

SPEC = EffectSpec(
    'sensor_lag', 'tau_s dy/dt = w - y (speed sensor first-order filter)',
    (EffectParam('tau_s', 's', 0.05, 0.0, 10.0, 'sample', (0.5, (0.1, 'record'), 16),
                 (0.0, (0.2, 'record'))),),
    description='first-order lag of the speed measurement',
    min_fraction=(('tau_s', (1.0, 'lag_floor')),),
    kernel_args=(KernelArg('tau_s', 'tau_s'),),
    confused_with=(
        Confusion('input_delay', 'fast steps or a PRBS with the current measured: a delay '
                  'shifts the whole response, a sensor lag smooths only the speed reading'),
        Confusion('resonance', 'a multisine through the suspected resonance: a lag only '
                  'attenuates, a compliant shaft rings')),
    stage_rule='position_and_speed')
