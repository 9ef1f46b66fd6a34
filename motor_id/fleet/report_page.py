"""report.html: the fleet at a glance, per-motor histories with error bars and change points,
and the failed tasks, in one self-contained file (inline SVG and CSS; nothing fetched)."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
import datetime as dt
import html
import math
import os

from motor_id.fleet.drift import DriftRule
from motor_id.fleet.history import (
    DriftRow,
    FleetFindings,
    histories,
    Point,
    SiblingRow,
    UNITS,
)
from motor_id.fleet.rows import EstimateRow, TaskFailure
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


@dataclass
class _Status:
    """One motor on the page: its drifting rows, its rows outside the siblings' spread,
    its failed tasks."""

    drifts: list[DriftRow] = field(default_factory=list)
    odd: list[SiblingRow] = field(default_factory=list)
    failed: int = 0

    @property
    def worst(self) -> DriftRow | None:
        return max(self.drifts, key=lambda d: abs(d.z or 0.0)) if self.drifts else None

    def rank(self) -> tuple[int, float]:
        w = self.worst
        if w is not None:
            return 0, -abs(w.z or 0.0)
        if self.odd:
            return 1, -max(abs(s.finding.score or 0.0) for s in self.odd)
        return (2 if self.failed else 3), 0.0


def motor_status(found: FleetFindings, failures: Iterable[TaskFailure]
                 ) -> dict[tuple[str, str], _Status]:
    """Per (robot, motor): drifting rows, rows against the siblings, failure count."""
    out: dict[tuple[str, str], _Status] = {}
    for d in found.drift:
        cur = out.setdefault((d.robot, d.motor), _Status())
        if d.detected:
            cur.drifts.append(d)
    for s in found.siblings:
        cur = out.setdefault((s.robot, s.motor), _Status())
        if s.outlier:
            cur.odd.append(s)
    for f in failures:
        out.setdefault((f.robot, f.motor), _Status()).failed += 1
    return out


def render(rows: list[EstimateRow], failures: list[TaskFailure], found: FleetFindings,
           rule: DriftRule | None = None, title: str = 'motor_id fleet report') -> str:
    """The report as one HTML text.

    Parameters
    ----------
    rows : list of EstimateRow
        Sorted by robot, motor, time.
    failures : list of TaskFailure
    found : FleetFindings
        :func:`motor_id.fleet.history.fleet_findings`.
    rule : DriftRule, optional
        Printed with the report.
    """
    status = motor_status(found, failures)
    hist = histories(rows)
    counts: dict[tuple[str, str], list[EstimateRow]] = {}
    for r in rows:
        counts.setdefault((r.robot, r.motor), []).append(r)
    for key in counts:
        status.setdefault(key, _Status())
    order = sorted(status, key=lambda k: (*status[k].rank(), k))
    n_rec = len({r.recording for r in rows} | {f.recording for f in failures})
    drifting = sum(1 for k in order if status[k].drifts)
    odd = sum(1 for k in order if status[k].odd)
    out = ['<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">',
           f'<title>{_e(title)}</title><style>{_CSS}</style></head><body>',
           f'<h1>{_e(title)}</h1>',
           '<p class="summary">'
           f'<span id="n-recordings">{n_rec} recordings</span>'
           f'<span id="n-motors">{len(order)} motors</span>'
           f'<span id="n-drifting" class="{"bad" if drifting else "ok"}">{drifting} drifting'
           '</span>'
           f'<span id="n-odd" class="{"bad" if odd else "ok"}">{odd} outside their '
           "siblings' spread</span>"
           f'<span id="n-failed" class="{"warn" if failures else "ok"}">{len(failures)} '
           'failed tasks</span></p>',
           '<h2 id="glance">The fleet at a glance (worst first)</h2>',
           _glance_table(order, status, counts),
           '<h2 id="siblings">Against their siblings</h2>',
           _siblings_table(found),
           '<h2 id="motors">Per motor: parameter histories</h2>',
           "<p>Each point is one recording's estimate with its +-2 std error bar (hollow: "
           'left out as a gross error); the grey line is the level before a change; a red '
           'line marks a step at its first recording after the change, a red band a ramp '
           'from its first changed recording to the first at the new level, and the red '
           "dashed line the level after it; the green band is the siblings' level +-2 "
           'spreads. Inadequate fits and undetermined parameters are left out.</p>']
    sib = {(s.robot, s.motor, s.parameter): s for s in found.siblings}
    for key in order:
        out.append(_motor_section(key, status[key], hist.get(key, {}), found.drift, sib))
    out.append(_failures_table(failures))
    if rule is not None:
        out.append('<h2 id="rule">Drift rule</h2><p>A change-point test over the whole '
                   'history at each recording: the largest weighted two-sample statistic '
                   'over every split, against the day-to-day scatter pooled over the '
                   'siblings, binary segmentation for more changes (docs/fleet.md): '
                   + ', '.join(f'{_e(k)} = {_e(v)}' for k, v in rule.to_dict().items())
                   + '</p>')
    out.append(f'<script>{_JS}</script></body></html>')
    return '\n'.join(out)


def _glance_table(order: list[tuple[str, str]], status: dict[tuple[str, str], _Status],
                  counts: dict[tuple[str, str], list[EstimateRow]]) -> str:
    head = ('robot', 'motor', 'status', 'parameter', 'change', 'since', 'z', 'siblings',
            *GLANCE, 'recordings', 'last recording', 'failed')
    out = ['<table id="glance-table" class="sortable"><thead><tr>'
           + ''.join(f'<th>{h}</th>' for h in head) + '</tr></thead><tbody>']
    for key in order:
        s = status[key]
        w = s.worst
        rows = counts.get(key, [])
        last = rows[-1] if rows else None
        cls = 'drift' if w or s.odd else 'fail' if s.failed else ''
        state = ('<span class="badge bad">DRIFT</span>' if w else
                 '<span class="badge bad">ODD</span>' if s.odd else
                 '<span class="badge warn">failures</span>' if s.failed else
                 '<span class="badge ok">ok</span>')
        params = ', '.join(d.parameter for d in s.drifts)
        odd = ', '.join(f'{o.parameter} {_pct(o.finding.deviation)}' for o in s.odd)
        latest = ''.join(
            f'<td class="num">{_g(last.parameter(p).value if last else None)}</td>'
            for p in GLANCE)
        out.append(
            f'<tr class="{cls}" data-robot="{_e(key[0])}" data-motor="{_e(key[1])}">'
            f'<td>{_e(key[0])}</td><td><a href="#{_anchor(key)}">{_e(key[1])}</a></td>'
            f'<td>{state}</td><td>{_e(params)}</td>'
            f'<td class="num" data-v="{w.change if w else 0}">'
            f'{_pct(w.change) if w else ""}</td><td>{_e(w.since) if w else ""}</td>'
            f'<td class="num">{_g(w.z, ".1f") if w else ""}</td><td>{_e(odd)}</td>{latest}'
            f'<td class="num">{len(rows)}</td>'
            f'<td>{_e(((last.start_time if last else None) or "")[:10])}</td>'
            f'<td class="num">{s.failed}</td></tr>')
    out.append('</tbody></table>')
    return ''.join(out)


def _siblings_table(found: FleetFindings) -> str:
    """The motors outside their siblings' spread, and how many could be compared."""
    compared = [s for s in found.siblings if s.finding.reason is None]
    groups = sorted({s.group for s in compared})
    out = [f"<p>Each motor's current level against the same motor on the other robots "
           f'(the same name or <code>type:</code>; the motor left out of its own '
           f'reference): {len(compared)} of {len(found.siblings)} motor parameters '
           f'compared in {len(groups)} group(s) of 4 or more.</p>']
    odd = found.odd()
    if not odd:
        out.append('<p id="siblings-none">None outside their siblings\' spread.</p>')
        return ''.join(out)
    out.append('<table id="siblings-table" class="sortable"><thead><tr><th>robot</th>'
               '<th>motor</th><th>parameter</th><th>level</th><th>siblings</th>'
               '<th>reference</th><th>spread</th><th>deviation</th><th>score</th>'
               '</tr></thead><tbody>')
    for s in odd:
        f = s.finding
        out.append(f'<tr class="drift" data-robot="{_e(s.robot)}" data-motor="{_e(s.motor)}">'
                   f'<td>{_e(s.robot)}</td><td><a href="#{_anchor((s.robot, s.motor))}">'
                   f'{_e(s.motor)}</a></td><td>{_e(s.parameter)}</td>'
                   f'<td class="num">{_g(f.level)} +- {_pct(f.level_std)[1:]}</td>'
                   f'<td class="num">{f.siblings}</td><td class="num">{_g(f.reference)} '
                   f'{_e(s.unit)}</td><td class="num">{_pct(f.spread)[1:]}</td>'
                   f'<td class="num">{_pct(f.deviation)}</td>'
                   f'<td class="num">{_g(f.score, ".1f")}</td></tr>')
    out.append('</tbody></table>')
    return ''.join(out)


def _anchor(key: tuple[str, str]) -> str:
    return 'm-' + ''.join(c if c.isalnum() else '-' for c in f'{key[0]}-{key[1]}')


def _motor_section(key: tuple[str, str], status: _Status, per: dict[str, list[Point]],
                   drift: Sequence[DriftRow], sib: dict[tuple[str, str, str], SiblingRow]
                   ) -> str:
    rows = {d.parameter: d for d in drift if (d.robot, d.motor) == key}
    title = f'{key[0]} / {key[1]}'
    open_attr = ' open' if status.drifts or status.odd else ''
    out = [f'<section id="{_anchor(key)}" class="motor"><details{open_attr}><summary>'
           f'<b>{_e(title)}</b> ']
    notes = [f'{d.parameter} {_pct(d.change)} since {d.since}' for d in status.drifts]
    notes += [f'{o.parameter} {_pct(o.finding.deviation)} from its siblings'
              for o in status.odd]
    if notes:
        out.append('<span class="bad">' + _e('; '.join(notes)) + '</span>')
    else:
        out.append('<span class="ok">no drift</span>')
    out.append('</summary><div class="plots">')
    for p in PARAM_NAMES:
        h = per.get(p) or []
        if not h:
            continue
        out.append(_plot(p, h, rows.get(p), sib.get((key[0], key[1], p))))
    out.append('</div></details></section>')
    return ''.join(out)


def _plot(param: str, hist: list[Point], d: DriftRow | None, sib: SiblingRow | None,
          width: int = 360, height: int = 150) -> str:
    """One parameter's history as inline SVG: points with +-2 std bars, the levels, each
    change where it is, the siblings' band."""
    ml, mr, mt, mb = 62, 8, 8, 22
    t = [_epoch(x[0]) for x in hist]
    v: list[float] = [x[1] for x in hist]
    s: list[float] = [x[2] or 0.0 for x in hist]
    f = d.finding if d is not None else None
    lo = min(a - 2 * b for a, b in zip(v, s, strict=True))
    hi = max(a + 2 * b for a, b in zip(v, s, strict=True))
    band = None
    g = sib.finding if sib is not None else None
    if g is not None and g.reference is not None and g.spread is not None:
        band = (g.reference * math.exp(-2 * g.spread), g.reference * math.exp(2 * g.spread))
    shown = band if band is not None and sib is not None and sib.outlier else None
    for extra in ((f.baseline, f.latest) if f else ()) + (shown or ()):
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

    def x_at(i: int) -> float:
        """Midway between recording i and the one before: where a change at i is."""
        return x_px((t[i] + t[max(i - 1, 0)]) / 2)
    parts = [f'<svg width="{width}" height="{height}" viewBox="0 0 {width} {height}" '
             f'role="img" data-parameter="{_e(param)}" data-points="{len(v)}">',
             f'<line x1="{ml}" y1="{height - mb}" x2="{width - mr}" y2="{height - mb}" '
             'stroke="#999"/>']
    if band is not None:       # drawn within the plot (the range set by the motor's own)
        top = min(max(y_px(band[1]), mt), height - mb)
        bottom = min(max(y_px(band[0]), mt), height - mb)
        if bottom > top:
            parts.append(f'<rect class="siblings" x="{ml}" y="{top:.1f}" '
                         f'width="{width - ml - mr}" height="{bottom - top:.1f}" '
                         'fill="#2e7d32" fill-opacity="0.10"/>')
    for y in (lo + pad, (lo + hi) / 2, hi - pad):
        parts.append(f'<text x="{ml - 4}" y="{y_px(y) + 4:.1f}" font-size="10" '
                     f'text-anchor="end">{_g(y, ".4g")}</text>')
    parts.append(f'<text x="{ml}" y="{height - 6}" font-size="10">'
                 f'{_e(str(hist[0][0])[:10])}</text>')
    parts.append(f'<text x="{width - mr}" y="{height - 6}" font-size="10" '
                 f'text-anchor="end">{_e(str(hist[-1][0])[:10])}</text>')
    cps = f.change_points if f is not None else ()
    if f is not None and f.baseline is not None:
        x_end = x_at(cps[-1].index) if cps else width - mr
        parts.append(f'<line x1="{ml}" y1="{y_px(f.baseline):.1f}" x2="{x_end:.1f}" '
                     f'y2="{y_px(f.baseline):.1f}" stroke="#888" stroke-dasharray="4 3"/>')
    for j, cp in enumerate(cps):
        x0, x1 = x_at(cp.index), x_at(cp.until_index)
        x_next = x_at(cps[j + 1].index) if j + 1 < len(cps) else width - mr
        if cp.kind == 'ramp':
            parts.append(f'<rect class="change-point ramp" x="{x0:.1f}" y="{mt}" '
                         f'width="{max(x1 - x0, 1.5):.1f}" height="{height - mt - mb}" '
                         'fill="#c62828" fill-opacity="0.15"/>')
        parts.append(f'<line class="change-point" x1="{x0:.1f}" y1="{mt}" x2="{x0:.1f}" '
                     f'y2="{height - mb}" stroke="#c62828" stroke-width="1.5"/>')
        parts.append(f'<text x="{x0 + 2:.1f}" y="{mt + 9}" font-size="9" fill="#c62828">'
                     f'{_e((cp.since or "")[5:10])}</text>')
        parts.append(f'<line x1="{x1:.1f}" y1="{y_px(cp.after):.1f}" x2="{x_next:.1f}" '
                     f'y2="{y_px(cp.after):.1f}" stroke="#c62828" stroke-dasharray="4 3"/>')
    left_out = set(d.outliers) if d is not None else set()
    for a, b, x, point in zip(v, s, t, hist, strict=True):
        xx = x_px(x)
        if b:
            parts.append(f'<line x1="{xx:.1f}" y1="{y_px(a - 2 * b):.1f}" x2="{xx:.1f}" '
                         f'y2="{y_px(a + 2 * b):.1f}" stroke="#1565c0"/>')
        fill = 'fill="#fff" stroke="#1565c0" class="outlier"' if point[0] in left_out \
            else 'fill="#1565c0"'
        parts.append(f'<circle cx="{xx:.1f}" cy="{y_px(a):.1f}" r="2.5" {fill}/>')
    parts.append('</svg>')
    return f'<figure>{"".join(parts)}<figcaption>{_caption(param, d, sib)}</figcaption></figure>'


def _caption(param: str, d: DriftRow | None, sib: SiblingRow | None) -> str:
    cap = f'{param} [{UNITS.get(param, "")}]'
    if d is not None and d.detected:
        cps = d.finding.change_points
        cap += ': <span class="bad">' + _e('; '.join(
            f'{c.kind} {_pct(c.change)} since {(c.since or "")[:10]}'
            + (f' to {(c.until or "")[:10]}' if c.kind == 'ramp' else '')
            + f' (flagged {(c.flagged_at or "")[:10]})' for c in cps)) + '</span>'
    elif d is not None and d.finding.reason:
        cap += f': {_e(d.finding.reason)}'
    if sib is not None and sib.outlier:
        cap += (f' <span class="bad">{_pct(sib.finding.deviation)} from its '
                f'{sib.finding.siblings} siblings</span>')
    return cap


def _failures_table(failures: list[TaskFailure]) -> str:
    out = [f'<h2 id="failed">Failed tasks ({len(failures)})</h2>']
    if not failures:
        out.append('<p>None.</p>')
        return ''.join(out)
    out.append('<table id="failed-table" class="sortable"><thead><tr><th>robot</th>'
               '<th>motor</th><th>recording</th><th>stage</th><th>reason</th></tr>'
               '</thead><tbody>')
    for f in sorted(failures, key=lambda f: (f.robot, f.motor, f.recording)):
        out.append(f'<tr><td>{_e(f.robot)}</td><td>{_e(f.motor)}</td>'
                   f'<td>{_e(f.recording)}</td><td>{_e(f.stage)}</td>'
                   f'<td>{_e(f.reason)}</td></tr>')
    out.append('</tbody></table>')
    return ''.join(out)


def write_report(path: str | os.PathLike[str], rows: list[EstimateRow],
                 failures: list[TaskFailure],
                 found: FleetFindings, rule: DriftRule | None = None) -> None:
    """Write :func:`render`'s page to ``path``."""
    text = render(rows, failures, found, rule)
    tmp = f'{path}.tmp'
    with open(tmp, 'w', encoding='utf-8') as fh:
        fh.write(text)
    os.replace(tmp, path)
