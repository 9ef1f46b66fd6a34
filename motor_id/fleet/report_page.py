"""report.html: the fleet at a glance, per-motor histories with error bars and change points,
and the failed tasks, in one self-contained file (inline SVG and CSS; nothing fetched)."""

from __future__ import annotations

from collections.abc import Iterable
import datetime as dt
import html
import math
import os
from typing import Any

from motor_id.fleet.drift import DriftRule
from motor_id.fleet.history import histories, Row, UNITS
from motor_id.model import PARAM_NAMES

GLANCE = ('K_T', 'R_m', 'B')
"""The latest values the glance table shows per motor: what drifts as a motor wears."""

_CSS = """
body{font:14px/1.4 system-ui,sans-serif;margin:1.5em;color:#222;max-width:1200px}
h1{font-size:1.5em}h2{font-size:1.2em;margin-top:2em;border-bottom:1px solid #ccc}
table{border-collapse:collapse;margin:.5em 0}td,th{padding:3px 8px;border-bottom:1px solid
#eee;text-align:left;vertical-align:top}th{cursor:pointer;background:#f4f4f4}
.drift td{background:#fde8e8}.fail td{background:#fff6dc}.num{text-align:right;
font-variant-numeric:tabular-nums}.badge{font-weight:600}.bad{color:#b00020}.ok{color:#1b5e20}
.warn{color:#8a6d00}.plots{display:flex;flex-wrap:wrap;gap:8px}figure{margin:0}
figcaption{font-size:12px;color:#444}svg{background:#fff;border:1px solid #ddd}
.summary span{margin-right:1.5em}
"""

_JS = """
document.querySelectorAll('table.sortable th').forEach(function(th, col){
  th.addEventListener('click', function(){
    var body = th.closest('table').tBodies[0];
    var rows = Array.prototype.slice.call(body.rows);
    var asc = th.dataset.dir !== 'asc'; th.dataset.dir = asc ? 'asc' : 'desc';
    rows.sort(function(a, b){
      var x = a.cells[col].dataset.v || a.cells[col].textContent;
      var y = b.cells[col].dataset.v || b.cells[col].textContent;
      var nx = parseFloat(x), ny = parseFloat(y);
      var c = (!isNaN(nx) && !isNaN(ny)) ? nx - ny : x.localeCompare(y);
      return asc ? c : -c; });
    rows.forEach(function(r){ body.appendChild(r); }); }); });
document.body.dataset.ready = '1';
"""


def _e(x: object) -> str:
    return html.escape('' if x is None else str(x))


def _pct(x: float | None) -> str:
    return '-' if x is None else f'{x * 100:+.1f} %'


def _g(x: float | None, spec: str = '.4g') -> str:
    return '-' if x is None or (isinstance(x, float) and math.isnan(x)) else format(x, spec)


def _epoch(iso: object) -> float:
    return dt.datetime.fromisoformat(str(iso).replace('Z', '+00:00')).timestamp()


def motor_status(drift_rows: Iterable[Row], failures: Iterable[Row]
                 ) -> dict[tuple[str, str], dict[str, Any]]:
    """Per (robot, motor): the worst drift row (or None) and the failure count."""
    out: dict[tuple[str, str], dict[str, Any]] = {}
    for d in drift_rows:
        key = (d['robot'], d['motor'])
        cur = out.setdefault(key, {'worst': None, 'failed': 0, 'drifts': []})
        if d['detected']:
            cur['drifts'].append(d)
            if cur['worst'] is None or abs(d['z'] or 0) > abs(cur['worst']['z'] or 0):
                cur['worst'] = d
    for f in failures:
        out.setdefault((f['robot'], f['motor']),
                       {'worst': None, 'failed': 0, 'drifts': []})['failed'] += 1
    return out


def render(rows: list[Row], failures: list[Row], drift_rows: list[Row],
           rule: DriftRule | None = None, title: str = 'motor_id fleet report') -> str:
    """The report as one HTML text.

    Parameters
    ----------
    rows : list of dict
        Result rows, sorted by robot, motor, time.
    failures : list of dict
    drift_rows : list of dict
        :func:`motor_id.fleet.history.drift_table`.
    rule : DriftRule, optional
        Printed with the report.
    """
    status = motor_status(drift_rows, failures)
    hist = histories(rows)
    counts: dict[tuple[str, str], list[Row]] = {}
    for r in rows:
        counts.setdefault((r['robot'], r['motor']), []).append(r)
    for key in counts:
        status.setdefault(key, {'worst': None, 'failed': 0, 'drifts': []})

    def rank(key: tuple[str, str]) -> tuple[int, float, tuple[str, str]]:
        s = status[key]
        w = s['worst']
        return (0 if w else 1 if s['failed'] else 2, -abs(w['z'] or 0) if w else 0, key)
    order = sorted(status, key=rank)
    n_rec = len({r['recording'] for r in rows} | {f['recording'] for f in failures})
    drifting = sum(1 for k in order if status[k]['worst'])
    out = ['<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">',
           f'<title>{_e(title)}</title><style>{_CSS}</style></head><body>',
           f'<h1>{_e(title)}</h1>',
           '<p class="summary">'
           f'<span id="n-recordings">{n_rec} recordings</span>'
           f'<span id="n-motors">{len(order)} motors</span>'
           f'<span id="n-drifting" class="{"bad" if drifting else "ok"}">{drifting} drifting'
           '</span>'
           f'<span id="n-failed" class="{"warn" if failures else "ok"}">{len(failures)} '
           'failed tasks</span></p>',
           '<h2 id="glance">The fleet at a glance (worst first)</h2>',
           _glance_table(order, status, counts),
           '<h2 id="motors">Per motor: parameter histories</h2>',
           "<p>Each point is one recording's estimate with its +-2 std error bar; the grey "
           'line is the baseline level, the red line a detected change point and the level '
           'after it. Inadequate fits and undetermined parameters are left out.</p>']
    for key in order:
        out.append(_motor_section(key, status[key], hist.get(key, {}), drift_rows))
    out.append(_failures_table(failures))
    if rule is not None:
        out.append('<h2 id="rule">Drift rule</h2><p>Self-starting two-sided CUSUM on '
                   'predictive normal scores (docs/fleet.md): '
                   + ', '.join(f'{_e(k)} = {_e(v)}' for k, v in rule.to_dict().items())
                   + '</p>')
    out.append(f'<script>{_JS}</script></body></html>')
    return '\n'.join(out)


def _glance_table(order: list[tuple[str, str]],
                  status: dict[tuple[str, str], dict[str, Any]],
                  counts: dict[tuple[str, str], list[Row]]) -> str:
    head = ('robot', 'motor', 'status', 'parameter', 'change', 'since', 'z', *GLANCE,
            'recordings', 'last recording', 'failed')
    out = ['<table id="glance-table" class="sortable"><thead><tr>'
           + ''.join(f'<th>{h}</th>' for h in head) + '</tr></thead><tbody>']
    for key in order:
        s = status[key]
        w = s['worst']
        rows = counts.get(key, [])
        last = rows[-1] if rows else {}
        cls = 'drift' if w else 'fail' if s['failed'] else ''
        state = ('<span class="badge bad">DRIFT</span>' if w else
                 '<span class="badge warn">failures</span>' if s['failed'] else
                 '<span class="badge ok">ok</span>')
        params = ', '.join(d['parameter'] for d in s['drifts'])
        latest = ''.join(
            f'<td class="num">{_g(last.get(p))}</td>' for p in GLANCE)
        anchor = _anchor(key)
        out.append(
            f'<tr class="{cls}" data-robot="{_e(key[0])}" data-motor="{_e(key[1])}">'
            f'<td>{_e(key[0])}</td><td><a href="#{anchor}">{_e(key[1])}</a></td>'
            f'<td>{state}</td><td>{_e(params)}</td>'
            f'<td class="num" data-v="{w["change"] if w else 0}">{_pct(w["change"]) if w else ""}'
            f'</td><td>{_e(w["since"]) if w else ""}</td>'
            f'<td class="num">{_g(w["z"], ".1f") if w else ""}</td>{latest}'
            f'<td class="num">{len(rows)}</td>'
            f'<td>{_e((last.get("start_time") or "")[:10])}</td>'
            f'<td class="num">{s["failed"]}</td></tr>')
    out.append('</tbody></table>')
    return ''.join(out)


def _anchor(key: tuple[str, str]) -> str:
    return 'm-' + ''.join(c if c.isalnum() else '-' for c in f'{key[0]}-{key[1]}')


def _motor_section(key: tuple[str, str], status: dict[str, Any],
                   per: dict[str, list[tuple[Any, ...]]], drift_rows: list[Row]) -> str:
    rows = {d['parameter']: d for d in drift_rows
            if (d['robot'], d['motor']) == key}
    title = f'{key[0]} / {key[1]}'
    open_attr = ' open' if status['worst'] else ''
    out = [f'<section id="{_anchor(key)}" class="motor"><details{open_attr}><summary>'
           f'<b>{_e(title)}</b> ']
    if status['drifts']:
        out.append('<span class="bad">' + _e('; '.join(
            f'{d["parameter"]} {_pct(d["change"])} since {d["since"]}'
            for d in status['drifts'])) + '</span>')
    else:
        out.append('<span class="ok">no drift</span>')
    out.append('</summary><div class="plots">')
    for p in PARAM_NAMES:
        h = per.get(p) or []
        if not h:
            continue
        d = rows.get(p)
        out.append(_plot(p, h, d))
    out.append('</div></details></section>')
    return ''.join(out)


def _plot(param: str, hist: list[tuple[Any, ...]], d: Row | None, width: int = 360,
          height: int = 150) -> str:
    """One parameter's history as inline SVG: points with +-2 std bars, baseline, change."""
    ml, mr, mt, mb = 62, 8, 8, 22
    t = [_epoch(x[0]) for x in hist]
    v: list[float] = [x[1] for x in hist]
    s: list[float] = [x[2] or 0.0 for x in hist]
    lo = min(a - 2 * b for a, b in zip(v, s, strict=True))
    hi = max(a + 2 * b for a, b in zip(v, s, strict=True))
    for extra in (d or {}).get('baseline'), (d or {}).get('latest'):
        if extra is not None:
            lo, hi = min(lo, extra), max(hi, extra)
    pad = (hi - lo) * 0.08 or abs(hi) * 0.01 or 1.0
    lo, hi = lo - pad, hi + pad
    t0, t1 = min(t), max(t)
    span = (t1 - t0) or 1.0

    def x_px(x: float) -> float:
        return ml + (x - t0) / span * (width - ml - mr)

    def y_px(y: float) -> float:
        return mt + (hi - y) / (hi - lo) * (height - mt - mb)
    parts = [f'<svg width="{width}" height="{height}" '
             f'viewBox="0 0 {width} {height}" role="img" data-parameter="{_e(param)}" '
             f'data-points="{len(v)}">']
    parts.append(f'<line x1="{ml}" y1="{height - mb}" x2="{width - mr}" y2="{height - mb}" '
                 'stroke="#999"/>')
    for y in (lo + pad, (lo + hi) / 2, hi - pad):
        parts.append(f'<text x="{ml - 4}" y="{y_px(y) + 4:.1f}" font-size="10" '
                     f'text-anchor="end">{_g(y, ".4g")}</text>')
    parts.append(f'<text x="{ml}" y="{height - 6}" font-size="10">'
                 f'{_e(str(hist[0][0])[:10])}</text>')
    parts.append(f'<text x="{width - mr}" y="{height - 6}" font-size="10" '
                 f'text-anchor="end">{_e(str(hist[-1][0])[:10])}</text>')
    cps = (d or {}).get('change_points') or []
    if d and d.get('baseline') is not None:
        x_end = x_px(_epoch(cps[-1]['since'])) if cps else width - mr
        parts.append(f'<line x1="{ml}" y1="{y_px(d["baseline"]):.1f}" x2="{x_end:.1f}" '
                     f'y2="{y_px(d["baseline"]):.1f}" stroke="#888" stroke-dasharray="4 3"/>')
    for cp in cps:
        xc = x_px(_epoch(cp['since']))
        parts.append(f'<line class="change-point" x1="{xc:.1f}" y1="{mt}" x2="{xc:.1f}" '
                     f'y2="{height - mb}" stroke="#c62828" stroke-width="1.5"/>')
        parts.append(f'<line x1="{xc:.1f}" y1="{y_px(cp["after"]):.1f}" x2="{width - mr}" '
                     f'y2="{y_px(cp["after"]):.1f}" stroke="#c62828" stroke-dasharray="4 3"/>')
    for a, b, x in zip(v, s, t, strict=True):
        xx = x_px(x)
        if b:
            parts.append(f'<line x1="{xx:.1f}" y1="{y_px(a - 2 * b):.1f}" x2="{xx:.1f}" '
                         f'y2="{y_px(a + 2 * b):.1f}" stroke="#1565c0"/>')
        parts.append(f'<circle cx="{xx:.1f}" cy="{y_px(a):.1f}" r="2.5" fill="#1565c0"/>')
    parts.append('</svg>')
    unit = UNITS.get(param, '')
    cap = f'{param} [{unit}]'
    if d and d['detected']:
        cap += (f': <span class="bad">{_pct(d["change"])} since {_e(d["since"])} '
                f'(z {_g(d["z"], ".1f")})</span>')
    elif d and d.get('reason'):
        cap += f': {_e(d["reason"])}'
    return f'<figure>{"".join(parts)}<figcaption>{cap}</figcaption></figure>'


def _failures_table(failures: list[Row]) -> str:
    out = [f'<h2 id="failed">Failed tasks ({len(failures)})</h2>']
    if not failures:
        out.append('<p>None.</p>')
        return ''.join(out)
    out.append('<table id="failed-table" class="sortable"><thead><tr><th>robot</th>'
               '<th>motor</th><th>recording</th><th>stage</th><th>reason</th></tr>'
               '</thead><tbody>')
    for f in sorted(failures, key=lambda f: (f['robot'], f['motor'], f['recording'])):
        out.append(f'<tr><td>{_e(f["robot"])}</td><td>{_e(f["motor"])}</td>'
                   f'<td>{_e(f["recording"])}</td><td>{_e(f.get("stage"))}</td>'
                   f'<td>{_e(f.get("reason"))}</td></tr>')
    out.append('</tbody></table>')
    return ''.join(out)


def write_report(path: str | os.PathLike[str], rows: list[Row], failures: list[Row],
                 drift_rows: list[Row], rule: DriftRule | None = None) -> None:
    """Write :func:`render`'s page to ``path``."""
    text = render(rows, failures, drift_rows, rule)
    tmp = f'{path}.tmp'
    with open(tmp, 'w', encoding='utf-8') as fh:
        fh.write(text)
    os.replace(tmp, path)
