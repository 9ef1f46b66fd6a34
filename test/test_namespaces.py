"""Two motors in two namespaces (the user guide's example), as separate processes."""

import json

import numpy as np
import pytest

from motor_id.contracts import FLAG_PROFILE_END, FLAGS
from motor_id.model import MotorParams
from motor_id.testing.procs import wait_until

MOTORS = {
    'left': MotorParams(J=0.052, K_T=0.66, K_b=0.66, B=0.002, L_m=0.0345, R_m=2.3),
    'right': MotorParams(J=0.02, K_T=0.45, K_b=0.45, B=0.001, L_m=0.02, R_m=1.5),
}
GLOBAL_TOPICS = {'/diagnostics', '/rosout', '/parameter_events'}
"""The only topics a motor's nodes may use outside their namespace."""


def ros_args(ns, module, *params):
    args = ['-m', f'motor_id.nodes.{module}', '--ros-args', '-r', f'__ns:=/{ns}']
    for p in params:
        args += ['-p', p]
    return args


def graph_names(node, name, ns):
    """Every topic and service of node ``ns/name`` in the graph (empty: not seen yet)."""
    names = set()
    if (name, ns) not in node.get_node_names_and_namespaces():
        return names
    for query in (node.get_publisher_names_and_types_by_node,
                  node.get_subscriber_names_and_types_by_node,
                  node.get_service_names_and_types_by_node):
        names |= {n for n, _ in query(name, ns)}
    return names


def test_two_motors_in_two_namespaces_each_fit_their_own(client, launch, tmp_path):
    from diagnostic_msgs.msg import DiagnosticArray
    from std_msgs.msg import Float64MultiArray, String

    from motor_id.nodes import messages
    diags = client.collect(DiagnosticArray, '/diagnostics', messages.DIAGNOSTICS_QOS)
    ends, reports, idents = {}, {}, {}
    for ns, motor in MOTORS.items():
        params = tmp_path / f'{ns}.json'
        params.write_text(json.dumps(motor.to_dict()))
        link = tmp_path / f'card_{ns}'
        launch(f'card_{ns}', ['-m', 'motor_id.cli', 'card-sim', '--link', str(link),
                              '--speedup', '10', '--params', str(params)])
        idents[ns] = launch(f'identifier_{ns}', ros_args(
            ns, 'identifier', f'R_m:={motor.R_m}', 'select:=profile', 'window_s:=120.0',
            'generations:=80'))
        launch(f'driver_{ns}', ros_args(ns, 'driver', f'device:={link}',
                                        'autostart:=false', 'publish_channels:=false'))
        ends[ns] = []
        client.subscribe(Float64MultiArray, f'/{ns}/samples', messages.SAMPLES_QOS,
                         lambda msg, box=ends[ns]: box.append(bool(np.any(
                             messages.msg_to_rows(msg)[:, FLAGS].astype(int)
                             & FLAG_PROFILE_END))))
        reports[ns] = client.collect(String, f'/{ns}/identifier/report',
                                     messages.LATCHED_QOS)
    for ns in MOTORS:
        assert wait_until(lambda ns=ns: client.node.count_publishers(f'/{ns}/samples') >= 1,
                          60.0)
        idents[ns].wait_for('identifier ready', 60.0)
    # nothing the nodes use leaves their namespace, except the global topics
    for ns in MOTORS:
        for name in ('driver', 'identifier', '_identifier_fit'):
            assert wait_until(lambda ns=ns, name=name: graph_names(client.node, name, f'/{ns}'),
                              20.0)
            outside = {n for n in graph_names(client.node, name, f'/{ns}')
                       if not n.startswith(f'/{ns}/')} - GLOBAL_TOPICS
            assert not outside, (ns, name, outside)
    assert wait_until(lambda: '/diagnostics' in graph_names(client.node, 'driver', '/left') and
                      '/left/samples' in graph_names(client.node, 'identifier', '/left'), 10.0)
    for ns in MOTORS:
        ok, text = client.trigger(f'/{ns}/driver/start', wait_service=30.0)
        assert ok, text
    for ns in MOTORS:
        assert wait_until(lambda ns=ns: any(ends[ns]), 120.0), ns
    for ns, motor in MOTORS.items():
        ok, text = client.identify(f'/{ns}/identifier/identify')
        assert ok, (text, idents[ns].output())
        assert wait_until(lambda ns=ns: reports[ns], 30.0)
        report = json.loads(reports[ns][-1].data)
        assert report['hardware_id'] == ns
        for name in ('J', 'K_T', 'B', 'L_m'):
            value = report['parameters'][name]['value']
            assert value == pytest.approx(getattr(motor, name), rel=0.02), (ns, name)
    hardware = {st.hardware_id for d in diags for st in d.status
                if st.name == 'motor_id: identifier'}
    assert {'left', 'right'} <= hardware
