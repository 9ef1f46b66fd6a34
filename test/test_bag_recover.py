"""Damaged bags: one-line errors, the tolerant scan, recovery (also after a killed writer)."""

import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import textwrap

from mcap.reader import make_reader
import numpy as np
import pytest
from ruamel.yaml import YAML

from motor_id.bag import bag_info, BagWriter, read_recording, recover, type_hash
from motor_id.cli import main
from motor_id.contracts import SAMPLES_DEPTH
from motor_id.errors import BagError

ROOT = Path(__file__).resolve().parents[1]


def chunk_layout(path):
    """(end offset, message end time) of every chunk, from the mcap library's summary."""
    with open(path, 'rb') as fh:
        summary = make_reader(fh).get_summary()
    return [(c.chunk_start_offset + c.chunk_length, c.message_end_time)
            for c in summary.chunk_indexes], summary


def write_chunked(path, batches=60, seed=6):
    """A bag of many small chunks with distinct log times; returns all rows."""
    rng = np.random.default_rng(seed)
    rows = np.column_stack([np.arange(batches * 8), np.arange(batches * 8) * 0.01,
                            rng.normal(size=(batches * 8, 4))])
    with BagWriter(path, chunk_size=1500, flush_interval=None) as writer:
        writer.write_meta({'input_kind': 'voltage'}, 0)
        for k in range(batches):
            writer.write_samples(rows[8 * k:8 * k + 8], 1000 * (k + 1))
    return rows


def test_truncated_file_gives_a_one_line_error_with_the_recoverable_count(tmp_path):
    full = tmp_path / 'full.mcap'
    write_chunked(full)
    layout, _ = chunk_layout(full)
    cut = tmp_path / 'cut.mcap'
    end, end_time = layout[len(layout) // 2]
    cut.write_bytes(full.read_bytes()[:end + 40])
    expected = end_time // 1000
    with pytest.raises(BagError) as err:
        read_recording(cut)
    text = str(err.value)
    assert '\n' not in text
    assert 'truncated or corrupt MCAP' in text
    assert f'{expected + 1} message(s) ({expected} on /samples) can be recovered' in text
    assert f'motor-id bag recover {cut} OUT.mcap' in text
    info = bag_info(cut)
    assert not info.complete
    assert info.messages == expected + 1


@pytest.mark.parametrize('seed', [11, 12, 13])
def test_recover_salvages_every_complete_chunk(tmp_path, seed):
    full = tmp_path / 'full.mcap'
    rows = write_chunked(full, seed=seed)
    layout, _ = chunk_layout(full)
    data = full.read_bytes()
    rng = np.random.default_rng(seed)
    cut_at = int(rng.integers(layout[0][0] + 1, layout[-1][0]))
    complete = [t for end, t in layout if end <= cut_at]
    expected = complete[-1] // 1000
    cut = tmp_path / 'cut.mcap'
    cut.write_bytes(data[:cut_at])
    out = tmp_path / 'fixed.mcap'
    res = recover(cut, out)
    assert res.messages == expected + 1
    assert res.topics == {'/motor_id/meta': 1, '/samples': expected}
    assert not res.was_complete
    assert bag_info(out).complete
    rec = read_recording(out)
    np.testing.assert_array_equal(rec.time, rows[:8 * expected, 1])
    np.testing.assert_array_equal(rec.speed, rows[:8 * expected, 3])


def test_recover_skips_a_corrupt_chunk_and_keeps_the_rest(tmp_path):
    full = tmp_path / 'full.mcap'
    write_chunked(full, batches=30)
    layout, summary = chunk_layout(full)
    data = bytearray(full.read_bytes())
    bad = summary.chunk_indexes[2]
    data[bad.chunk_start_offset + bad.chunk_length - 5] ^= 0xFF
    broken = tmp_path / 'broken.mcap'
    broken.write_bytes(bytes(data))
    with pytest.raises(BagError, match='1 corrupt chunk'):
        read_recording(broken)
    res = recover(broken, tmp_path / 'fixed.mcap')
    lost = (bad.message_end_time - bad.message_start_time) // 1000 + 1
    assert res.chunks_lost == 1
    assert res.topics['/samples'] == 30 - lost


def test_recover_resumes_after_a_chunk_with_a_damaged_header(tmp_path):
    full = tmp_path / 'full.mcap'
    write_chunked(full, batches=30)
    _, summary = chunk_layout(full)
    data = bytearray(full.read_bytes())
    bad = summary.chunk_indexes[3]
    data[bad.chunk_start_offset + 9 + 28 + 3] ^= 0x7F   # length of the compression name
    broken = tmp_path / 'broken.mcap'
    broken.write_bytes(bytes(data))
    lost = (bad.message_end_time - bad.message_start_time) // 1000 + 1
    with pytest.raises(BagError, match=rf'1 unreadable record\(s\), first at byte '
                                       rf'{bad.chunk_start_offset} .*\); '
                                       rf'{31 - lost} message\(s\)'):
        read_recording(broken)
    res = recover(broken, tmp_path / 'fixed.mcap')
    assert res.topics == {'/motor_id/meta': 1, '/samples': 30 - lost}
    assert res.chunks == len(summary.chunk_indexes) - 1


KILLED_WRITER = textwrap.dedent("""
    import sys, time
    import numpy as np
    from motor_id.bag import BagWriter
    writer = BagWriter(sys.argv[1], chunk_size=1 << 20, flush_interval=None)
    writer.write_meta({'input_kind': 'voltage', 'provenance': 'killed'})
    row = 0
    for batch in range(40):
        rows = np.column_stack([np.arange(row, row + 5), np.arange(row, row + 5) * 0.01,
                                np.ones((5, 4))])
        writer.write_samples(rows, 1000 * (batch + 1))
        row += 5
        if batch % 10 == 9:
            writer.flush()
    for batch in range(40, 47):
        rows = np.column_stack([np.arange(row, row + 5), np.arange(row, row + 5) * 0.01,
                                np.ones((5, 4))])
        writer.write_samples(rows, 1000 * (batch + 1))
        row += 5
    print('ready', flush=True)
    time.sleep(60)
""")


def test_recover_after_the_writer_is_killed(tmp_path):
    script = tmp_path / 'writer.py'
    script.write_text(KILLED_WRITER)
    path = tmp_path / 'killed.mcap'
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen([sys.executable, str(script), str(path)], stdout=subprocess.PIPE,
                            env=env, text=True)
    try:
        assert proc.stdout.readline().strip() == 'ready'
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
        proc.stdout.close()
    assert proc.returncode == -signal.SIGKILL
    with pytest.raises(BagError, match=r'41 message\(s\) \(40 on /samples\) can be recovered'):
        read_recording(path)
    out = tmp_path / 'recovered.mcap'
    res = recover(path, out)
    assert res.topics == {'/motor_id/meta': 1, '/samples': 40}
    rec = read_recording(out)
    np.testing.assert_array_equal(rec.time, np.arange(200) * 0.01)
    assert rec.meta['provenance'] == 'killed'
    assert rec.meta['gaps'] == []
    with open(out, 'rb') as fh:
        records = {m.name: m.metadata for m in make_reader(fh).iter_metadata()}
    info = YAML(typ='safe').load(records['rosbag2']['serialized_metadata'])
    topics = {t['topic_metadata']['name']: t for t in info['topics_with_message_count']}
    samples = topics['/samples']
    assert samples['message_count'] == 40
    assert samples['topic_metadata']['offered_qos_profiles'][0]['depth'] == SAMPLES_DEPTH
    # the published Jazzy hash (test_bag.py holds type_hash to the published values)
    assert samples['topic_metadata']['type_description_hash'] == type_hash(
        'std_msgs/msg/Float64MultiArray')


def test_cli_bag_info_and_recover(tmp_path, capsys):
    full = tmp_path / 'full.mcap'
    write_chunked(full, batches=20)
    layout, _ = chunk_layout(full)
    cut = tmp_path / 'cut.mcap'
    cut.write_bytes(full.read_bytes()[:layout[-2][0] + 3])
    assert main(['bag', 'info', str(full)]) == 0
    text = capsys.readouterr().out
    assert 'integrity:   complete' in text
    assert '/samples' in text and 'std_msgs/msg/Float64MultiArray' in text
    assert main(['bag', 'info', str(cut), '--json']) == 0
    info = json.loads(capsys.readouterr().out)
    assert info['complete'] is False
    out = tmp_path / 'out.mcap'
    assert main(['bag', 'recover', str(cut), str(out)]) == 0
    assert 'recovered' in capsys.readouterr().out
    assert main(['bag', 'recover', str(cut), str(out)]) == 2
    assert 'exists; pass --force' in capsys.readouterr().err
    assert main(['bag', 'info', str(tmp_path / 'missing.mcap')]) == 2
    assert 'no such file' in capsys.readouterr().err


def test_committed_bags_are_complete():
    for path in sorted((ROOT / 'bags').glob('*.mcap')):
        info = bag_info(path)
        assert info.complete, path
        assert info.profile == 'ros2'
        assert path.stat().st_size < 2_000_000, path


def test_a_cut_summary_loses_no_data_and_directories_resolve(tmp_path):
    full = tmp_path / 'run' / 'run_0.mcap'
    full.parent.mkdir()
    rows = write_chunked(full, batches=10)
    data = full.read_bytes()
    cut = tmp_path / 'nosummary.mcap'
    cut.write_bytes(data[:-30])
    rec = read_recording(cut)
    np.testing.assert_array_equal(rec.time, rows[:, 1])
    assert 'summary/footer is missing' in rec.meta['bag_note']
    assert not bag_info(cut).complete
    np.testing.assert_array_equal(read_recording(full.parent).speed, rows[:, 3])
    (tmp_path / 'empty_dir').mkdir()
    with pytest.raises(BagError, match='directory with 0 .mcap'):
        read_recording(tmp_path / 'empty_dir')
