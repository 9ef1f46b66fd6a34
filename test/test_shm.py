"""Stale Fast DDS shared-memory files: what is removed and what is left alone."""

import fcntl
import os
import time

from motor_id.nodes.shm import clean_stale_shm


def touch(path, age_s=60.0):
    with open(path, 'wb') as fh:
        fh.write(b'x')
    t = time.time() - age_s
    os.utime(path, (t, t))


def test_removes_unlocked_segments_and_ports_and_keeps_held_and_young_ones(tmp_path):
    d = str(tmp_path)
    dead_seg, live_seg, young_seg = ('fastrtps_' + c * 16 for c in 'abc')
    for base in (dead_seg, live_seg):
        touch(os.path.join(d, base))
        touch(os.path.join(d, base + '_el'))
    touch(os.path.join(d, young_seg))
    touch(os.path.join(d, young_seg + '_el'), age_s=0.0)
    for name in ('fastrtps_port7411', 'fastrtps_port7411_sl', 'sem.fastrtps_port7411_mutex',
                 'unrelated_el', 'fastrtps_short_el'):
        touch(os.path.join(d, name))
    holder = open(os.path.join(d, live_seg + '_el'), 'rb')   # a live owner's lock
    fcntl.flock(holder, fcntl.LOCK_EX)
    try:
        removed = clean_stale_shm(d, min_age_s=5.0)
    finally:
        holder.close()
    assert sorted(os.path.basename(p) for p in removed) == sorted([
        dead_seg, dead_seg + '_el', 'fastrtps_port7411', 'fastrtps_port7411_sl',
        'sem.fastrtps_port7411_mutex'])
    assert sorted(os.listdir(d)) == sorted([
        live_seg, live_seg + '_el', young_seg, young_seg + '_el', 'unrelated_el',
        'fastrtps_short_el'])


def test_missing_directory_is_not_an_error(tmp_path):
    assert clean_stale_shm(str(tmp_path / 'absent')) == []
