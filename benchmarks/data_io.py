"""Data loading: a 1,000,000-row CSV and 100,000-message robot bags to a Recording."""

import os
import sys
import tempfile
import time

from common import render_table, target
import numpy as np

from motor_id.data.csv_io import read_csv
from motor_id.data.mapping import TopicMapping
from motor_id.data.rosbag import read_bag
from motor_id.errors import DataError

TITLE = 'Data loading: CSV rows and rosbag2 messages to a Recording'
CSV_TARGET_S = 3.0
BAG_TARGET_S = 5.0
EPOCH_NS = 1_700_000_000_000_000_000


def _signals(n, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 1e-3
    u = np.where((np.arange(n) // 150) % 2, 9.0, -9.0)
    w = np.cumsum(u) * 1e-3 + rng.normal(0, 0.01, n)
    i = 0.1 * u + rng.normal(0, 0.01, n)
    return t, u, w, i


def write_big_csv(path, n, bad_line=None):
    """``time,voltage,speed,current`` with ``n`` rows; optionally text at one line."""
    t, u, w, i = _signals(n)
    with open(path, 'w') as fh:
        fh.write('# benchmark\ntime,voltage,speed,current\n')
        body = np.column_stack([t, u, w, i])
        lines = [f'{a!r},{b!r},{c!r},{d!r}\n' for a, b, c, d in body.tolist()]
        if bad_line is not None:
            lines[bad_line - 3] = lines[bad_line - 3].replace(',', ',x', 1)
        fh.writelines(lines)


def write_robot_bag(path, n, storage):
    """JointState (2 joints, header stamps) and a Float64 command, ``n`` of each."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import get_typestore, Stores
    ts = get_typestore(Stores.ROS2_JAZZY)
    JS = ts.types['sensor_msgs/msg/JointState']
    Header = ts.types['std_msgs/msg/Header']
    Time = ts.types['builtin_interfaces/msg/Time']
    F64 = ts.types['std_msgs/msg/Float64']
    t, u, w, i = _signals(n)
    plugin = StoragePlugin.MCAP if storage == 'mcap' else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as wr:
        js = wr.add_connection('/joint_states', JS.__msgtype__, typestore=ts)
        cmd = wr.add_connection('/motor_voltage_cmd', F64.__msgtype__, typestore=ts)
        for k in range(n):
            ns = EPOCH_NS + k * 1_000_000
            msg = JS(header=Header(stamp=Time(sec=ns // 10**9, nanosec=ns % 10**9),
                                   frame_id=''), name=['wheel_right', 'wheel_left'],
                     position=np.array([0.0, 0.0]), velocity=np.array([0.0, w[k]]),
                     effort=np.array([0.0, i[k]]))
            wr.write(js, ns + 100_000, ts.serialize_cdr(msg, JS.__msgtype__))
            wr.write(cmd, ns, ts.serialize_cdr(F64(data=float(u[k])), F64.__msgtype__))


def _best(fn, repeats):
    """Best wall and CPU seconds of ``repeats`` calls (CPU: less sensitive to load)."""
    best, cpu = np.inf, np.inf
    for _ in range(repeats):
        start, start_cpu = time.perf_counter(), time.process_time()
        fn()
        best = min(best, time.perf_counter() - start)
        cpu = min(cpu, time.process_time() - start_cpu)
    return best, cpu


def run(quick=False):
    """Run the section; returns the section record."""
    n_csv = 20_000 if quick else 1_000_000
    n_bag = 2_000 if quick else 100_000
    repeats = 1 if quick else 3
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        good = os.path.join(tmp, 'big.csv')
        write_big_csv(good, n_csv)
        size = os.path.getsize(good)
        s, cpu = _best(lambda: read_csv(good), repeats)
        rows.append({'case': f'CSV {n_csv} rows, 4 columns ({size / 1e6:.0f} MB)',
                     'items': n_csv, 'seconds': s, 'cpu_seconds': cpu,
                     'us_per_item': 1e6 * s / n_csv})
        bad = os.path.join(tmp, 'bad.csv')
        write_big_csv(bad, n_csv, bad_line=n_csv + 2)
        message = []

        def read_bad():
            try:
                read_csv(bad)
            except DataError as exc:
                message[:] = [str(exc)]
        s_bad, cpu_bad = _best(read_bad, repeats)
        rows.append({'case': 'CSV, text in the last row (error: ' + message[0].split(': ', 1)[
            0].rsplit('/', 1)[-1] + ')', 'items': n_csv, 'seconds': s_bad,
            'cpu_seconds': cpu_bad, 'us_per_item': 1e6 * s_bad / n_csv})
        mapping = TopicMapping(input='/motor_voltage_cmd', speed='/joint_states:velocity',
                          current='/joint_states:effort', joint='wheel_left',
                          effort_is='current')
        bag_s = {}
        for storage in ('mcap', 'sqlite3'):
            path = os.path.join(tmp, f'robot_{storage}')
            write_robot_bag(path, n_bag, storage)
            s, cpu = _best(lambda path=path: read_bag(path, mapping), repeats)
            bag_s[storage] = s
            rows.append({'case': f'rosbag2 {storage} folder, {n_bag} JointState + {n_bag} '
                                 'Float64', 'items': n_bag, 'seconds': s,
                         'cpu_seconds': cpu, 'us_per_item': 1e6 * s / n_bag})
    targets = [] if quick else [
        target(f'CSV {n_csv} rows to a recording', rows[0]['seconds'],
               f'< {CSV_TARGET_S:g} s', rows[0]['seconds'] < CSV_TARGET_S, 's'),
        target(f'bag {n_bag} JointState + {n_bag} Float64 to a recording (slower storage)',
               max(bag_s.values()), f'< {BAG_TARGET_S:g} s',
               max(bag_s.values()) < BAG_TARGET_S, 's'),
    ]
    return {
        'title': TITLE,
        'status': 'ok',
        'settings': {'timing': f'best of {repeats}', 'csv_rows': n_csv, 'bag_messages': n_bag},
        'tables': [{'title': 'load times (read + parse + align + validate)',
                    'columns': [('case', 'case', 's'), ('items', 'rows/msgs', 'd'),
                                ('seconds', 'seconds', '.3f'), ('cpu_seconds', 'CPU s', '.3f'),
                                ('us_per_item', 'us/item', '.2f')],
                    'rows': rows}],
        'targets': targets,
    }


def main():
    """Print the table (``--quick`` for a small smoke run)."""
    rec = run(quick='--quick' in sys.argv[1:])
    for table in rec['tables']:
        print(table['title'])
        print(render_table(table['columns'], table['rows']))
    for t in rec['targets']:
        print(f'{t["name"]}: {t["value"]:.3f} {t["unit"]} -> {"PASS" if t["pass"] else "FAIL"}')
    print(f'load average: {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs')


if __name__ == '__main__':
    main()
