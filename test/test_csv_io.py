"""CSV input: files as users have them (names, mappings, BOM), one line per bad file."""

import json

import numpy as np
import pytest

from motor_id.cli import main
from motor_id.data.csv_io import parse_columns, read_csv, write_csv
from motor_id.errors import ConfigError, DataError
from motor_id.recording import Recording
from motor_id.testing.recordings import paper_recording

HEADER = 'time,voltage,speed,current\n'


def write(tmp_path, text, name='d.csv', encoding='utf-8'):
    p = tmp_path / name
    p.write_text(text, encoding=encoding)
    return p


def rows(n=50, start=0):
    return ''.join(f'{0.01 * k},{1.0 + (k > 10)},{0.1 * k},{0.01 * k}\n'
                   for k in range(start, start + n))


def test_round_trip_is_exact(tmp_path):
    rec = paper_recording(speed_noise=0.01, current_noise=0.01, seed=1)
    write_csv(rec, tmp_path / 'r.csv', {'note': 'x'})
    back = read_csv(tmp_path / 'r.csv')
    for ch in ('time', 'input', 'speed', 'current'):
        np.testing.assert_array_equal(getattr(back, ch), getattr(rec, ch))
    assert back.meta['note'] == 'x' and back.input_kind == 'voltage'


def test_torque_recording_round_trips_with_a_torque_column(tmp_path):
    rec = paper_recording(seed=1)
    torque = Recording(rec.time, rec.input, rec.speed, None, 'torque')
    write_csv(torque, tmp_path / 't.csv')
    assert 'time,torque,speed' in (tmp_path / 't.csv').read_text()
    back = read_csv(tmp_path / 't.csv')
    assert back.input_kind == 'torque'
    np.testing.assert_array_equal(back.input, rec.input)


def test_optional_current_and_extra_columns(tmp_path):
    p = write(tmp_path, 'time,speed,voltage,temp\n' + ''.join(
        f'{0.01 * k},{0.1 * k},{1.0 + (k > 3)},20\n' for k in range(30)))
    rec = read_csv(p)
    assert not rec.has_current and rec.channels() == ('speed',)
    assert rec.input[5] == 2.0


@pytest.mark.parametrize('name, kind', [('voltage', 'voltage'), ('torque', 'torque'),
                                        ('force', 'torque'), ('Torque', 'torque')])
def test_the_input_column_name_sets_the_plant_kind(tmp_path, name, kind):
    rec = read_csv(write(tmp_path, f'time,{name},speed\n' + ''.join(
        f'{0.01 * k},{1.0 + (k > 3)},{0.1 * k}\n' for k in range(30))))
    assert rec.input_kind == kind and rec.input[5] == 2.0


def test_input_kind_comment_and_option(tmp_path):
    body = ''.join(f'{0.01 * k},{1.0 + (k > 3)},{0.1 * k}\n' for k in range(30))
    assert read_csv(write(tmp_path, '# input_kind: torque\ntime,voltage,speed\n'
                          + body)).input_kind == 'torque'
    p = write(tmp_path, 'time,voltage,speed\n' + body)
    assert read_csv(p, input_kind='torque').input_kind == 'torque'
    with pytest.raises(DataError, match="the input column 'force' is a force, not a voltage"):
        read_csv(write(tmp_path, 'time,force,speed\n' + body), input_kind='voltage')
    with pytest.raises(DataError, match='several input columns \\(voltage, torque\\); '
                                        "choose one with columns 'input=NAME'") as info:
        read_csv(write(tmp_path, 'time,voltage,torque,speed\n' + ''.join(
            f'{0.01 * k},1,{1.0 + (k > 3)},{0.1 * k}\n' for k in range(30))))
    assert info.value.params == ('columns',)


def test_columns_mapping_reads_any_names(tmp_path):
    p = write(tmp_path, 't,u_cmd,omega,i_a,extra\n' + ''.join(
        f'{0.01 * k},{1.0 + (k > 3)},{0.1 * k},{0.02 * k},x\n' for k in range(30)))
    cols = 'time=t,input=u_cmd,speed=omega,current=i_a'
    rec = read_csv(p, columns=cols)
    assert rec.input_kind == 'voltage' and rec.current[2] == pytest.approx(0.04)
    assert rec.meta['columns'] == {'time': 't', 'input': 'u_cmd', 'speed': 'omega',
                                   'current': 'i_a'}
    assert read_csv(p, columns=cols, input_kind='torque').input_kind == 'torque'
    with pytest.raises(DataError, match=r'missing column\(s\) volts in header .*\(columns '
                                        r'present: t, u_cmd, omega, i_a, extra\)'):
        read_csv(p, columns='time=t,input=volts,speed=omega')
    with pytest.raises(DataError, match=r'missing column\(s\) time, voltage \(or torque, '
                                        r"force\), speed .*columns 'time=T"):
        read_csv(p)
    with pytest.raises(ConfigError, match='ROLE one of time, input, speed, current'):
        parse_columns('time=t,volt=u')


def test_a_byte_order_mark_is_accepted(tmp_path):
    p = write(tmp_path, HEADER + rows(), encoding='utf-8-sig')
    assert p.read_bytes()[:3] == b'\xef\xbb\xbf'
    rec = read_csv(p)
    assert len(rec) == 50 and rec.time[0] == 0.0


def test_quoted_cells_are_read(tmp_path):
    p = write(tmp_path, '"time","voltage","speed"\n' + ''.join(
        f'"{0.01 * k}","{1.0 + (k > 3)}","{0.1 * k}"\n' for k in range(30)))
    assert read_csv(p).input[5] == 2.0


@pytest.mark.parametrize('text, message', [
    ('time,voltage\n' + '0,1\n' * 30, r'd\.csv:1: missing column\(s\) speed'),
    ('time:voltage:speed\n0:1:2\n', "delimited by something other than ',', ';'"),
    ('0,1,2,3\n' + rows(), 'the header is missing'),
    (HEADER + rows(5) + '0.05,abc,0.5,0.05\n' + rows(30, 6),
     r"d\.csv:7: column 'voltage' has non-numeric value 'abc'"),
    (HEADER + rows(5) + '0.05,1,nan,0.05\n' + rows(30, 6), r"d\.csv:7: column 'speed' is nan"),
    (HEADER + rows(5) + '0.05,1,0.5,\n' + rows(30, 6),
     r"d\.csv:7: column 'current' has non-numeric value ''"),
    (HEADER + rows(5) + rows(30, 4), r'd\.csv:7: duplicate time stamp'),
    (HEADER + rows(5) + '0.01,1,1,1\n' + rows(30, 6), r'd\.csv:7: time goes backwards'),
    (HEADER + rows(5), 'too few samples: 5'),
    (HEADER + ''.join(f'{0.01 * k},2.0,{0.1 * k},0\n' for k in range(40)), 'no excitation'),
    (HEADER + ''.join(f'{0.01 * k},{k % 3},0,0\n' for k in range(40)),
     'no response: the speed is constant'),
    (HEADER + rows(5) + '0.05,1,1e300,0.05\n' + rows(30, 6),
     r"d\.csv:7: column 'speed': 1e\+300 is above 1e\+200 in magnitude"),
    (HEADER + rows(5) + '0.05,1,0.5,2e15\n' + rows(30, 6),
     r"d\.csv:7: column 'current': 2e\+15 is .* times the typical magnitude"),
    ('', 'empty file'),
    (HEADER + '0,1,2\n', r'd\.csv:2: 3 cell\(s\), header has 4'),
    (HEADER + rows(5) + '0.05,1,2,3,4\n', r'd\.csv:7: 5 cell\(s\), header has 4'),
])
def test_bad_files_get_one_specific_line(tmp_path, text, message):
    with pytest.raises(DataError, match=message) as info:
        read_csv(write(tmp_path, text))
    assert '\n' not in str(info.value)


def test_errors_keep_their_line_numbers_in_long_files(tmp_path):
    n = 20000
    lines = [f'{0.001 * k!r},{float(k // 100 % 2)},{0.1 * k!r},0.5\n' for k in range(n)]
    good = ''.join(lines)
    assert len(read_csv(write(tmp_path, '# c\n' + HEADER + good))) == n
    bad = {15000: (f'{0.001 * 15000!r},abc,1,0.5\n', "column 'voltage' has non-numeric"),
           19999: ('inf,0,1,0.5\n', "column 'time' is inf"),
           7: ('1,2,3\n', r'3 cell\(s\), header has 4')}
    for k, (line, message) in bad.items():
        body = lines[:k] + [line] + lines[k + 1:]
        with pytest.raises(DataError, match=rf'd\.csv:{k + 3}: {message}'):
            read_csv(write(tmp_path, '# c\n' + HEADER + ''.join(body)))


def test_missing_file(tmp_path):
    with pytest.raises(DataError, match='cannot read'):
        read_csv(tmp_path / 'nope.csv')


def test_cli_exits_2_with_the_reason(tmp_path, capsys):
    p = write(tmp_path, HEADER + ''.join(f'{0.01 * k},{k % 3},0,0\n' for k in range(40)))
    assert main(['import', 'csv', str(p), str(tmp_path / 'o.mcap')]) == 2
    err = capsys.readouterr().err
    assert 'no response: the speed is constant' in err and 'Traceback' not in err
    q = write(tmp_path, 't,u,w\n' + ''.join(f'{0.01 * k},{1.0 + (k > 3)},{0.1 * k}\n'
                                           for k in range(30)), name='m.csv')
    assert main(['import', 'csv', str(q), str(tmp_path / 'm.mcap'), '--columns',
                 'time=t,input=u,speed=w', '--input-kind', 'torque']) == 0
    assert '(torque input)' in capsys.readouterr().out


def test_fit_reads_a_time_torque_speed_csv(tmp_path, capsys):
    rec = paper_recording(seed=3)
    p = tmp_path / 'torque.csv'
    p.write_text('time,torque,speed\n' + ''.join(
        f'{t!r},{u!r},{w!r}\n' for t, u, w in zip(rec.time.tolist(),
                                                   (0.66 * rec.current).tolist(),
                                                   rec.speed.tolist(), strict=True)))
    assert main(['fit', str(p), '--generations', '2', '-q']) == 0, capsys.readouterr().err


def test_comments_between_rows_keep_line_numbers(tmp_path):
    for every in (1, 20):                       # 100 and 5 comment lines among the rows
        lines = [HEADER]
        for k in range(100):
            lines.append(f'{0.01 * k},{1.0 + (k > 10)},{0.1 * k},{0.01 * k}\n')
            if k % every == 0:
                lines.append('# note: x\n' if k % 2 else '\n')
        assert len(read_csv(write(tmp_path, ''.join(lines)))) == 100
        bad = max(i for i, line in enumerate(lines[:-3]) if ',' in line)
        lines[bad] = lines[bad].replace(',', ',?', 1)
        with pytest.raises(DataError, match=rf"d\.csv:{bad + 1}: column 'voltage' has "
                                            r"non-numeric value '\?"):
            read_csv(write(tmp_path, ''.join(lines)))


def spreadsheet(text, delimiter=';'):
    """A comma-separated text as a spreadsheet with decimal commas exports it."""
    return text.translate(str.maketrans({',': delimiter, '.': ','}))


@pytest.mark.parametrize('delimiter', [';', '\t'])
def test_a_spreadsheet_csv_reads_as_its_plain_twin(tmp_path, delimiter):
    rec = paper_recording(speed_noise=0.01, current_noise=0.01, seed=4)
    write_csv(rec, tmp_path / 'plain.csv')
    plain = read_csv(tmp_path / 'plain.csv')
    text = (tmp_path / 'plain.csv').read_text()
    sheet = write(tmp_path, spreadsheet(text, delimiter), name='sheet.csv')
    assert '0,0' in sheet.read_text() and ',' not in sheet.read_text().splitlines()[0]
    back = read_csv(sheet)
    for ch in ('time', 'input', 'speed', 'current'):
        np.testing.assert_array_equal(getattr(back, ch), getattr(plain, ch))
    assert back.meta['csv_dialect'] == {'delimiter': delimiter, 'decimal': ','}
    assert 'csv_dialect' not in plain.meta
    # given instead of found; a spreadsheet's "sep=;" line names the delimiter too
    np.testing.assert_array_equal(read_csv(sheet, delimiter=delimiter, decimal=',').speed,
                                  plain.speed)
    hinted = write(tmp_path, f'sep={delimiter}\n' + spreadsheet(text, delimiter), name='h.csv')
    np.testing.assert_array_equal(read_csv(hinted).speed, plain.speed)


def test_a_semicolon_csv_with_decimal_points_and_bad_dialects(tmp_path):
    text = HEADER + rows()
    plain = read_csv(write(tmp_path, text))
    semi = read_csv(write(tmp_path, text.replace(',', ';'), name='s.csv'))
    np.testing.assert_array_equal(semi.speed, plain.speed)
    assert semi.meta['csv_dialect'] == {'delimiter': ';', 'decimal': '.'}
    mixed = write(tmp_path, HEADER.replace(',', ';') + '0,5;1.000,5;2;3\n' * 30, name='x.csv')
    with pytest.raises(DataError, match='both "." and ","'):
        read_csv(mixed)
    with pytest.raises(ConfigError, match='cannot both be'):
        read_csv(write(tmp_path, text), decimal=',')
    with pytest.raises(ConfigError, match='delimiter must be one of'):
        read_csv(write(tmp_path, text), delimiter=':')


def test_fit_of_a_spreadsheet_csv_equals_the_fit_of_its_twin(tmp_path, capsys):
    rec = paper_recording(speed_noise=0.01, current_noise=0.01, seed=5)
    write_csv(rec, tmp_path / 'plain.csv')
    sheet = write(tmp_path, spreadsheet((tmp_path / 'plain.csv').read_text()),
                  name='sheet.csv')
    reports = []
    for path in (tmp_path / 'plain.csv', sheet):
        out = tmp_path / f'{path.stem}.json'
        assert main(['fit', str(path), '-R', '2.3', '--generations', '20', '-q', '--json',
                     str(out)]) == 0
        reports.append(json.loads(out.read_text()))
    assert sum(p['value'] is not None for p in reports[0]['parameters'].values()) >= 3
    assert reports[0]['parameters'] == reports[1]['parameters']
    assert main(['fit', str(sheet), '-R', '1', '--generations', '2', '-q', '--delimiter', ';',
                 '--decimal', ',']) == 0
    capsys.readouterr()
