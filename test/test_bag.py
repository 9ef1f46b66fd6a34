"""Tests of motor_id.bag: round trips, a second reader, the file layout, read errors."""

import json
from pathlib import Path
import sys

from mcap.reader import make_reader
from mcap.records import Schema
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import pytest
from ruamel.yaml import YAML

from motor_id import bag
from motor_id.bag import (
    bag_info,
    BagWriter,
    message_definition,
    read_recording,
    read_samples,
    schemas,
    write_recording,
)
from motor_id.contracts import LATCHED_DEPTH, SAMPLES_DEPTH
from motor_id.errors import BagError, ConfigError
from motor_id.recording import Recording

ROOT = Path(__file__).resolve().parents[1]


def make_recording(n=600, seed=0, current=True, kind='voltage'):
    """Irregularly sampled random data: nothing about it is round by accident."""
    rng = np.random.default_rng(seed)
    time = np.cumsum(rng.uniform(0.005, 0.015, n)) + 1.2345
    cur = rng.normal(0.0, 2.0, n) if current else None
    return Recording(time, rng.normal(0.0, 10.0, n), rng.normal(0.0, 50.0, n), cur, kind,
                     {'provenance': 'test_bag', 'truth': {'J': 0.052}, 'seed': seed})


JAZZY_HASHES = {
    'std_msgs/msg/Float64MultiArray':
        'RIHS01_1025ddc6b9552d191f89ef1a8d2f60f3d373e28b283d8891ddcc974e8c55397f',
    'std_msgs/msg/Float64':
        'RIHS01_705ba9c3d1a09df43737eb67095534de36fd426c0587779bda2bc51fe790182a',
    'std_msgs/msg/String':
        'RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18',
    'diagnostic_msgs/msg/DiagnosticArray':
        'RIHS01_5a8a36efb05fb25070fa0fb3810290c0e6cd4862b54a8fb975a1ee8dc55a333e',
}
"""Type description hashes of ROS 2 Jazzy (``ros2 topic info -v``), written down once."""


def definition_sections(msgtype):
    """{type: section text} of a full ros2msg definition (the top type first)."""
    parts = message_definition(msgtype).split('=' * 80 + '\n')
    out = {msgtype: parts[0]}
    for part in parts[1:]:
        head, body = part.split('\n', 1)
        assert head.startswith('MSG: ')
        pkg, name = head[5:].split('/')
        assert f'{pkg}/msg/{name}' not in out, f'{head} appears twice'
        out[f'{pkg}/msg/{name}'] = body
    return out


def test_message_definitions_match_the_installed_msg_files():
    from rosbags.typesys import get_types_from_msg
    share = Path(sys.prefix) / 'share'
    for msgtype in JAZZY_HASHES:
        sections = definition_sections(msgtype)
        for name, text in sections.items():
            pkg, _, typ = name.split('/')
            installed = (share / pkg / 'msg' / f'{typ}.msg').read_text()
            assert get_types_from_msg(text, name) == get_types_from_msg(installed, name), name


def test_full_definition_holds_every_dependency_once():
    sections = definition_sections('diagnostic_msgs/msg/DiagnosticArray')
    assert list(sections)[0] == 'diagnostic_msgs/msg/DiagnosticArray'
    assert set(sections) == {'diagnostic_msgs/msg/DiagnosticArray',
                             'diagnostic_msgs/msg/DiagnosticStatus',
                             'diagnostic_msgs/msg/KeyValue', 'std_msgs/msg/Header',
                             'builtin_interfaces/msg/Time'}
    assert 'byte STALE=3' in sections['diagnostic_msgs/msg/DiagnosticStatus']
    assert set(definition_sections(bag.FLOAT64_MULTI_ARRAY)) == {
        bag.FLOAT64_MULTI_ARRAY, 'std_msgs/msg/MultiArrayLayout',
        'std_msgs/msg/MultiArrayDimension'}
    assert message_definition(bag.STRING) == 'string data\n'
    with pytest.raises(ConfigError, match='unknown message type'):
        message_definition('motor_id/msg/Nothing')


def test_channels_carry_the_jazzy_type_hashes(tmp_path):
    path = tmp_path / 'hashes.mcap'
    with BagWriter(path) as writer:
        writer.write_meta({'input_kind': 'voltage'})
        writer.write_samples(np.ones(6), 1)
        writer.write_estimate({'J': 1.0}, 2)
        writer.write_channel('speed', 3.0, 3)
    with open(path, 'rb') as fh:
        summary = make_reader(fh).get_summary()
    found = {summary.schemas[ch.schema_id].name: ch.metadata['topic_type_hash']
             for ch in summary.channels.values()}
    assert found == JAZZY_HASHES


def test_round_trip_is_exact(tmp_path):
    rec = make_recording(seed=1)
    path = tmp_path / 'rec.mcap'
    res = write_recording(rec, path, batch=37)
    assert res.samples == len(rec)
    back = read_recording(path)
    for name in ('time', 'input', 'speed', 'current'):
        np.testing.assert_array_equal(getattr(back, name), getattr(rec, name))
    assert back.input_kind == 'voltage'
    assert back.meta['truth'] == {'J': 0.052}
    assert back.meta['provenance'] == 'test_bag'
    assert back.meta['units']['voltage'] == 'V'
    assert back.meta['gaps'] == []
    samples = read_samples(path)
    np.testing.assert_array_equal(samples.seq, np.arange(len(rec)))
    assert np.all(samples.flags == 0)
    assert np.all(np.diff(samples.log_time_ns) >= 0)


def test_round_trip_torque_without_current(tmp_path):
    rec = make_recording(n=120, seed=2, current=False, kind='torque')
    path = tmp_path / 'torque.mcap'
    write_recording(rec, path, compression='lz4', channels=True)
    back = read_recording(path)
    assert back.current is None
    assert back.input_kind == 'torque'
    assert back.meta['units']['voltage'] == 'N m'
    np.testing.assert_array_equal(back.input, rec.input)
    counts = {t.topic: t.count for t in bag_info(path).topics}
    assert counts == {'/motor_id/meta': 1, '/samples': 3, '/voltage': 120, '/speed': 120}


def test_second_reader_rosbags_decodes_the_same_values(tmp_path):
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import get_typestore, Stores
    store = get_typestore(Stores.ROS2_JAZZY)
    rec = make_recording(n=250, seed=3)
    path = tmp_path / 'two.mcap'
    with BagWriter(path, chunk_size=2048) as writer:
        writer.write_meta({'input_kind': 'voltage', 'provenance': 'second reader'})
        rows = np.column_stack([np.arange(250), rec.time, rec.input, rec.speed,
                                rec.current, np.zeros(250)])
        for k in range(0, 250, 10):
            writer.write_samples(rows[k:k + 10], 1_000_000 * (k + 10))
        writer.write_estimate({'J': 0.0521, 'J_std': 1e-4, 'J_determined': True},
                              300_000_000, level=1, message='ok')
    got, estimate, meta, qos = [], None, None, {}
    with Reader(path) as reader:
        assert reader.message_count == 27
        for conn in reader.connections:
            qos[conn.topic] = conn.ext.offered_qos_profiles[0]
            assert conn.msgdef.data == message_definition(conn.msgtype)
        for conn, _stamp, raw in reader.messages():
            msg = store.deserialize_cdr(raw, conn.msgtype)
            if conn.topic == '/samples':
                assert msg.layout.dim[1].label == 'seq,t,voltage,speed,current,flags'
                assert msg.layout.dim[0].stride == 6 * msg.layout.dim[0].size
                got.append(np.asarray(msg.data).reshape(-1, 6))
            elif conn.topic == '/identifier/estimate':
                estimate = msg
            else:
                meta = json.loads(msg.data)
    np.testing.assert_array_equal(np.concatenate(got), rows)
    assert meta['provenance'] == 'second reader'
    values = {kv.key: kv.value for kv in estimate.status[0].values}
    assert values == {'J': '0.0521', 'J_std': '0.0001', 'J_determined': 'true'}
    assert estimate.status[0].level == 1
    assert (estimate.header.stamp.sec, estimate.header.stamp.nanosec) == (0, 300_000_000)
    assert qos['/samples'].depth == SAMPLES_DEPTH
    assert qos['/samples'].durability.name == 'VOLATILE'
    assert qos['/motor_id/meta'].durability.name == 'TRANSIENT_LOCAL'
    assert qos['/motor_id/meta'].depth == LATCHED_DEPTH
    assert qos['/identifier/estimate'].durability.name == 'TRANSIENT_LOCAL'


def any_reader_rows(path):
    """{topic: decoded messages} read by rosbags' AnyReader from the bag's own schemas."""
    from rosbags.highlevel import AnyReader
    out = {}
    with AnyReader([Path(path)]) as reader:
        for conn, _, raw in reader.messages():
            out.setdefault(conn.topic, []).append(reader.deserialize(raw, conn.msgtype))
    return out


def test_any_reader_decodes_with_the_definitions_in_the_bag(tmp_path):
    rec = make_recording(n=90, seed=7)
    path = tmp_path / 'any.mcap'
    write_recording(rec, path, batch=20, channels=True)
    with BagWriter(tmp_path / 'est.mcap') as writer:
        writer.write_estimate({'K_T': 0.66}, 5, level=2)
    got = any_reader_rows(path)
    rows = np.concatenate([np.asarray(m.data).reshape(-1, 6) for m in got['/samples']])
    np.testing.assert_array_equal(rows[:, 1], rec.time)
    np.testing.assert_array_equal(rows[:, 4], rec.current)
    np.testing.assert_array_equal([m.data for m in got['/speed']], rec.speed)
    assert json.loads(got['/motor_id/meta'][0].data)['input_kind'] == 'voltage'
    status = any_reader_rows(tmp_path / 'est.mcap')['/identifier/estimate'][0].status[0]
    assert (status.level, status.values[0].key, status.values[0].value) == (2, 'K_T', '0.66')


COMMITTED_ROWS = {'emps.mcap': 24841, 'dunker_ident_m1.mcap': 2291,
                  'dunker_valid_m2.mcap': 1238, 'sim_card_paper.mcap': 8782}
"""Sample counts of committed bags (bags/README.md); they were written before this reader."""


@pytest.mark.parametrize('name', sorted(COMMITTED_ROWS))
def test_committed_bags_read_the_same_with_both_readers(name):
    path = ROOT / 'bags' / name
    rec = read_recording(path)
    assert len(rec) == COMMITTED_ROWS[name]
    assert rec.meta['gaps'] == []
    assert 'bag_note' not in rec.meta
    got = any_reader_rows(path)
    rows = np.concatenate([np.asarray(m.data).reshape(-1, 6) for m in got['/samples']])
    np.testing.assert_array_equal(rows[np.argsort(rows[:, 0]), 1], rec.time)
    np.testing.assert_array_equal(rows[np.argsort(rows[:, 0]), 3], rec.speed)


def test_meta_is_strict_json_with_numpy_values_converted(tmp_path):
    path = tmp_path / 'meta.mcap'
    with BagWriter(path) as writer:
        writer.write_meta({'input_kind': 'voltage', 'J': np.float64(0.25), 'n': np.int64(3),
                           'missing': np.nan, 'grid': np.arange(3), 'pair': (1, 2)})
        with pytest.raises(ConfigError, match='not JSON-serialisable'):
            writer.write_meta({'bad': object()})
    raw = any_reader_rows(path)['/motor_id/meta'][0].data

    def reject(name):
        raise AssertionError(f'non-standard JSON constant {name}')
    assert json.loads(raw, parse_constant=reject) == bag.read_meta(path)
    assert bag.read_meta(path) == {'input_kind': 'voltage', 'J': 0.25, 'n': 3, 'missing': None,
                                   'grid': [0, 1, 2], 'pair': [1, 2]}


def test_write_builds_messages_from_dicts_with_ros_defaults(tmp_path):
    path = tmp_path / 'dicts.mcap'
    with BagWriter(path) as writer:
        writer.write('/status', bag.DIAGNOSTIC_ARRAY, {'status': [{'name': 'x'}]}, 4)
        with pytest.raises(ConfigError, match=r"has no field\(s\) \['nmae'\]"):
            writer.write('/status', bag.DIAGNOSTIC_ARRAY, {'status': [{'nmae': 'x'}]}, 5)
        with pytest.raises(BagError, match='/status: cannot serialise'):
            writer.write('/status', bag.DIAGNOSTIC_ARRAY, {'status': [{'level': 300}]}, 6)
    status = any_reader_rows(path)['/status']
    assert len(status) == 1
    assert (status[0].status[0].name, status[0].status[0].level) == ('x', 0)
    assert status[0].header.frame_id == ''


def test_reads_samples_recorded_by_another_rosbag2_writer(tmp_path):
    """/samples as `ros2 bag record` stores them (rosbags' rosbag2 writer, MCAP plugin)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    store = schemas.typestore()
    rec = make_recording(n=200, seed=8)
    rows = np.column_stack([np.arange(200), rec.time, rec.input, rec.speed, rec.current,
                            np.zeros(200)])
    path = tmp_path / 'recorded'
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        samples = writer.add_connection('/samples', bag.FLOAT64_MULTI_ARRAY, typestore=store)
        meta = writer.add_connection('/motor_id/meta', bag.STRING, typestore=store)
        writer.write(meta, 1_700_000_000_000_000_000, schemas.serialize(
            bag.STRING, {'data': json.dumps({'input_kind': 'voltage', 'robot': 'r1'})}))
        for k in range(0, 200, 25):
            msg = {'layout': {'dim': [{'label': 'samples', 'size': 25, 'stride': 150},
                                      {'label': 'seq,t,voltage,speed,current,flags',
                                       'size': 6, 'stride': 6}]},
                   'data': rows[k:k + 25].ravel()}
            writer.write(samples, 1_700_000_000_000_000_000 + k * 10_000_000,
                         schemas.serialize(bag.FLOAT64_MULTI_ARRAY, msg))
    back = read_recording(path)
    np.testing.assert_array_equal(back.time, rec.time)
    np.testing.assert_array_equal(back.current, rec.current)
    assert back.meta['robot'] == 'r1'
    assert bag_info(path).complete


def test_file_has_ros2_profile_statistics_and_rosbag2_metadata(tmp_path):
    path = tmp_path / 'meta.mcap'
    write_recording(make_recording(n=300, seed=4), path, batch=25)
    with open(path, 'rb') as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == 'ros2'
        assert reader.get_header().library.startswith('motor_id ')
        summary = reader.get_summary()
        assert summary.statistics.message_count == 13
        assert summary.statistics.chunk_count >= 1
        assert {s.encoding for s in summary.schemas.values()} == {'ros2msg'}
        for ch in summary.channels.values():
            assert ch.message_encoding == 'cdr'
            assert ch.metadata['topic_type_hash'].startswith('RIHS01_')
            profile = YAML(typ='safe').load(ch.metadata['offered_qos_profiles'])[0]
            assert profile['reliability'] == 'reliable'
        decoded = [m for _, _, _, m in reader.iter_decoded_messages(topics=['/samples'])]
        assert sum(m.layout.dim[0].size for m in decoded) == 300
        records = {m.name: m.metadata for m in reader.iter_metadata()}
    info = YAML(typ='safe').load(records['rosbag2']['serialized_metadata'])
    assert info['version'] == 9
    assert info['ros_distro'] == 'jazzy'
    assert info['message_count'] == 13
    counts = {t['topic_metadata']['name']: t['message_count']
              for t in info['topics_with_message_count']}
    assert counts == {'/motor_id/meta': 1, '/samples': 12}
    qos = info['topics_with_message_count'][1]['topic_metadata']['offered_qos_profiles']
    assert qos[0]['durability'] == 'volatile'


def test_chunks_are_bounded_by_chunk_size(tmp_path):
    path = tmp_path / 'chunks.mcap'
    rows = np.random.default_rng(5).normal(size=(10, 6))
    with BagWriter(path, chunk_size=4096, flush_interval=None) as writer:
        for k in range(100):
            writer.write_samples(rows + k, 1000 * k)
    with open(path, 'rb') as fh:
        summary = make_reader(fh).get_summary()
    sizes = [c.uncompressed_size for c in summary.chunk_indexes]
    message_bytes = 6 * 10 * 8 + 200
    assert len(sizes) >= 10
    assert max(sizes) <= 4096 + message_bytes


def test_flush_interval_closes_chunks_on_time(tmp_path):
    ticks = iter(np.arange(0.0, 100.0, 0.25))
    path = tmp_path / 'timed.mcap'
    with BagWriter(path, chunk_size=10**9, flush_interval=1.0,
                   clock=lambda: float(next(ticks))) as writer:
        for k in range(20):
            writer.write_samples(np.ones(6) * k, 10 * k)
    with open(path, 'rb') as fh:
        summary = make_reader(fh).get_summary()
    assert len(summary.chunk_indexes) == 5


def test_writer_rejects_bad_arguments(tmp_path):
    with pytest.raises(ConfigError, match='compression'):
        BagWriter(tmp_path / 'a.mcap', compression='gzip')
    with BagWriter(tmp_path / 'b.mcap') as writer:
        with pytest.raises(ConfigError, match='6 columns'):
            writer.write_samples(np.ones((2, 5)), 0)
        with pytest.raises(ConfigError, match='>= 0'):
            writer.write_samples(np.ones(6), -1)
        with pytest.raises(ConfigError, match='declared as'):
            writer.write('/samples', bag.STRING, {'data': 'x'}, 0)
        writer.write_samples(np.ones(6), 0)
    with pytest.raises(BagError, match='closed'):
        writer.write_samples(np.ones(6), 1)


def test_gaps_are_kept_not_filled_and_reported(tmp_path):
    path = tmp_path / 'gaps.mcap'
    seq = np.r_[0:10, 15:20].astype(float)
    rows = np.column_stack([seq, seq * 0.01, seq, -seq, np.full(15, np.nan), np.zeros(15)])
    with BagWriter(path) as writer:
        writer.write_meta({'input_kind': 'torque'})
        writer.write_samples(rows[10:], 200)
        writer.write_samples(rows[:10], 100)
        writer.write_samples(rows[3:5], 300)
    rec = read_recording(path)
    assert len(rec) == 15
    np.testing.assert_array_equal(rec.time, seq * 0.01)
    np.testing.assert_array_equal(rec.input, seq)
    assert rec.current is None
    assert rec.input_kind == 'torque'
    assert rec.meta['gaps'] == [{'after_seq': 9, 'missing': 5, 't_before': 0.09,
                                 't_after': 0.15}]
    assert rec.meta['duplicate_rows'] == 2


def test_missing_file_and_not_an_mcap(tmp_path):
    with pytest.raises(BagError, match='no such file'):
        read_recording(tmp_path / 'nope.mcap')
    fake = tmp_path / 'fake.mcap'
    fake.write_text('time,voltage,speed\n0,1,2\n')
    with pytest.raises(BagError, match='not an MCAP file') as err:
        read_recording(fake)
    assert '\n' not in str(err.value)
    empty = tmp_path / 'empty.mcap'
    empty.write_bytes(b'')
    with pytest.raises(BagError, match='empty file'):
        bag_info(empty)


def test_missing_samples_topic_lists_the_topics_present(tmp_path):
    path = tmp_path / 'nosamples.mcap'
    with BagWriter(path) as writer:
        writer.write_meta({'input_kind': 'voltage'})
        writer.write_estimate({'J': 1.0}, 5)
    with pytest.raises(BagError, match='no /samples topic') as err:
        read_recording(path)
    text = str(err.value)
    assert '/motor_id/meta (std_msgs/msg/String, 1 msgs)' in text
    assert '/identifier/estimate' in text


def test_wrong_or_undecodable_samples_type(tmp_path):
    path = tmp_path / 'wrongtype.mcap'
    with BagWriter(path) as writer:
        writer.write('/samples', bag.STRING, {'data': 'hello'}, 0)
    with pytest.raises(BagError, match="has type 'std_msgs/msg/String'"):
        read_recording(path)
    path = tmp_path / 'json.mcap'
    schema = Schema(id=1, name='Samples', encoding='jsonschema', data=b'{}')
    with BagWriter(path) as writer:
        writer.write_raw('/samples', schema, 'json', b'{"t": 1}', 0)
    with pytest.raises(BagError, match="cannot decode /samples: schema encoding 'jsonschema'"):
        read_recording(path)
    path = tmp_path / 'layout.mcap'
    with BagWriter(path) as writer:
        writer.write('/samples', bag.FLOAT64_MULTI_ARRAY,
                     {'layout': {'dim': [{'label': 'x', 'size': 2, 'stride': 10},
                                         {'label': 'a,b,c,d,e', 'size': 5, 'stride': 5}]},
                      'data': [0.0] * 10}, 0)
    with pytest.raises(BagError, match=r'is not \(n, 6\) rows of seq,t,voltage'):
        read_recording(path)


def test_writer_is_safe_to_share_between_threads(tmp_path):
    import threading
    path = tmp_path / 'threads.mcap'
    with BagWriter(path, chunk_size=2048) as writer:
        def worker(offset):
            for k in range(100):
                seq = offset + k
                writer.write_samples([seq, seq * 0.01, 1.0, 2.0, np.nan, 0.0], 1000 * seq)
        threads = [threading.Thread(target=worker, args=(i * 100,)) for i in range(4)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    rec = read_recording(path)
    np.testing.assert_array_equal(rec.time, np.arange(400) * 0.01)
