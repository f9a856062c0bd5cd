"""Self-contained HTML reports: clouds in a WebGL viewer (drag turns, wheel zooms) beside the run's numbers.

The page needs no network: the viewer (``viewer.js``, written for this package) and the points are inside it.
Each cloud is drawn from at most ``max_points`` rows (finite rows only, a seeded choice, so the same run gives
the same file), quantised to 16 bits per coordinate over the box of all clouds (65,536 steps per axis: finer
than any screen), base64 in the page: 8 bytes a point, ~0.5 MB for three clouds of 20,000 points. Each view
opens framed on the bounding sphere of what it draws. ``alerts`` (:mod:`~rpmnet_jax.report.alerts`) are a
banner across the top of the page; numbers are written by :mod:`~rpmnet_jax.report.formats`, as the CLIs print
them.
"""

from __future__ import annotations

import base64
import html
import json
import pathlib
import re

import numpy as np

from rpmnet_jax.report import formats

_HERE = pathlib.Path(__file__).parent
PAIR_COLOURS = {"source": "#d62728", "reference": "#1f77b4", "aligned source": "#2ca02c"}  # as cli/plots
SCAN_COLOURS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f",
                "#bcbd22", "#17becf", "#aec7e8", "#ffbb78", "#98df8a", "#ff9896", "#c5b0d5", "#c49c94",
                "#f7b6d2", "#c7c7c7", "#dbdb8d", "#9edae5")  # matplotlib's tab10, then tab20's light tones
WRAP = 16  # a table cell with more characters than this may wrap (a name at its _ - /); a shorter one never does


def check_path(path: str) -> None:
    """Raises ``ValueError`` (one line) unless ``path`` names a ``.html`` file: call it before any work."""
    if not str(path).lower().endswith((".html", ".htm")):
        raise ValueError(f"--html must name a .html file, got {path}")


def pair_report(path: str, src, ref, aligned, numbers: dict, title: str = "rpmnet-register",
                max_points: int = 20000, alerts=()) -> None:
    """Writes the page of one registration: views *before* (source and reference as given) and *after* (aligned
    source on the reference, shown first), or both side by side (before left), beside ``numbers``.

    ``src``, ``aligned``: ``(N, 3)``, row for row (the same rows are drawn in both); ``ref``: ``(M, 3)``;
    ``numbers``: see :func:`numbers_html`; ``alerts``: lines of the banner (:func:`rpmnet_jax.report.alerts.pair`).
    """
    src, aligned, ref = (np.asarray(x, np.float64).reshape(-1, 3) for x in (src, aligned, ref))
    keep = _rows(np.all(np.isfinite(src), 1) & np.all(np.isfinite(aligned), 1), max_points)
    clouds = [("source", src, keep), ("reference", ref, _rows(np.all(np.isfinite(ref), 1), max_points)),
              ("aligned source", aligned, keep)]
    layers = [(name, PAIR_COLOURS[name], x, rows) for name, x, rows in clouds]
    views = [("before", [0, 1]), ("after", [2, 1])]
    _write(path, title, layers, views, numbers, alerts, first=1)


def scans_report(path: str, clouds_in_world: list, names, numbers: dict, title: str = "rpmnet-register-scans",
                 max_points: int = 20000, max_total: int = 150000, alerts=()) -> None:
    """Writes the page of a scan set: every placed scan in the common frame, one colour each, beside
    ``numbers``.

    ``clouds_in_world``: ``(N_i, 3)`` per scan, ``None`` for one left out (named in the legend, not drawn);
    each is drawn from at most ``min(max_points, max_total // S)`` rows; ``alerts``: lines of the banner
    (:func:`rpmnet_jax.report.alerts.scans`).
    """
    per_scan = max(1, min(max_points, max_total // max(1, len(names))))
    layers = []
    for i, (name, x) in enumerate(zip(names, clouds_in_world)):
        x = np.zeros((0, 3)) if x is None else np.asarray(x, np.float64).reshape(-1, 3)
        rows = _rows(np.all(np.isfinite(x), 1), per_scan)
        layers.append((str(name), SCAN_COLOURS[i % len(SCAN_COLOURS)], x, rows))
    _write(path, title, layers, [("registered scans", list(range(len(layers))))], numbers, alerts)


def _rows(finite, max_points: int) -> np.ndarray:
    """Indices of at most ``max_points`` of the rows where ``finite`` ``(N,)`` is set: a seeded choice, in row
    order."""
    rows = np.flatnonzero(finite)
    if len(rows) > max_points:
        rows = np.sort(np.random.default_rng(0).choice(rows, max_points, replace=False))
    return rows


def _write(path, title: str, layers, views, numbers: dict, alerts=(), first: int = 0) -> None:
    """``layers``: ``(name, colour, points (N, 3), rows)``; ``views``: ``(title, layer indices)``, ``first`` the
    one shown when the page opens."""
    drawn = [x[rows] for _, _, x, rows in layers]
    every = np.concatenate(drawn + [np.zeros((0, 3))])
    lo, hi = (every.min(0), every.max(0)) if len(every) else (np.zeros(3), np.ones(3))
    extent = np.maximum(hi - lo, 1e-12 * max(1.0, float(np.abs(lo).max())))  # a flat cloud keeps its axis
    clouds = []
    for (name, colour, x, _), pts in zip(layers, drawn):
        q = np.rint((pts - lo) / extent * 65535).clip(0, 65535).astype("<u2")
        clouds.append({"name": name, "colour": colour, "rows": int(np.all(np.isfinite(x), 1).sum()),
                       "drawn": len(pts), "points": base64.b64encode(q.tobytes()).decode("ascii")})
    spheres = [_sphere(drawn, c, lo + extent / 2) for _, c in views]
    data = {"clouds": clouds, "views": [{"title": t, "clouds": c, "centre": centre, "radius": radius}
                                        for (t, c), (centre, radius) in zip(views, spheres)],
            "extent": extent.tolist(), "first": first, "up": _up(hi - lo)}
    parts = {"TITLE": html.escape(("⚠ " if alerts else "") + title), "HEADING": html.escape(title),
             "ALERTS": _banner(alerts), "NUMBERS": numbers_html(numbers),
             "DATA": json.dumps(data).replace("<", "\\u003c"),  # no "</script>" inside the script
             "VIEWER": (_HERE / "viewer.js").read_text(encoding="utf-8")}
    page = re.sub("@@(TITLE|HEADING|ALERTS|NUMBERS|DATA|VIEWER)@@", lambda m: parts[m.group(1)],
                  (_HERE / "page.html").read_text(encoding="utf-8"))  # one pass: the parts' own text is never rescanned
    with open(path, "w", encoding="utf-8") as f:
        f.write(page)


def _sphere(drawn, shown, middle) -> tuple:
    """``(centre, radius)``: the centre of the box of the clouds ``shown`` (indices into ``drawn``) from
    ``middle`` ``(3,)``, the centre of the box of all, and the radius of the sphere about it that holds them: each
    view turns about its own clouds and opens framed on that sphere."""
    pts = np.concatenate([drawn[i] for i in shown] + [np.zeros((0, 3))])
    if not len(pts):
        return [0.0, 0.0, 0.0], 0.0
    centre = (pts.min(0) + pts.max(0)) / 2
    return (centre - middle).tolist(), float(np.sqrt(((pts - centre) ** 2).sum(1).max()))


def _up(size) -> str:
    """The axis drawn upwards when the page opens, from the size ``(3,)`` of the box of all: ``"z"`` for a cloud
    much flatter in z than across (a street or a room scanned from the ground, z up by the sensors' convention),
    else ``"y"`` (scans of objects and the clouds of graphics files)."""
    return "z" if size[2] < 0.5 * min(size[0], size[1]) else "y"


def _banner(alerts) -> str:
    """HTML of the banner across the top of the page: one item per line of ``alerts``; empty without any."""
    if not alerts:
        return ""
    items = "".join(f"<li>{html.escape(str(a))}</li>" for a in alerts)
    return f"<div id='alerts' role='alert'><strong>Check this result</strong><ul>{items}</ul></div>"


def numbers_html(numbers: dict) -> str:
    """HTML of ``numbers`` in order: a number, string or flag is one row ``name value``; a 2-D array (a 4×4
    transform) a matrix; a list of dicts a table under the name as heading (columns from the first dict's keys);
    a dict a sub-section."""
    rows, blocks = [], []
    for name, value in numbers.items():
        if isinstance(value, dict):
            blocks.append(f"<h3>{html.escape(str(name))}</h3>{numbers_html(value)}")
        elif isinstance(value, (list, tuple)) and value and all(isinstance(r, dict) for r in value):
            head = "".join(_th(k) for k in value[0])
            body = "".join("<tr>" + "".join(_td(r.get(k)) for k in value[0]) + "</tr>"
                           for r in value)
            blocks.append(f"<h3>{html.escape(str(name))}</h3><table class='rows'><tr>{head}</tr>{body}</table>")
        elif np.ndim(value) == 2:
            matrix = html.escape(formats.matrix(value))
            rows.append(f"<tr>{_th(name, colspan=2)}</tr>"
                        f"<tr><td colspan='2' class='w'><pre>{matrix}</pre></td></tr>")
        else:
            rows.append(f"<tr>{_th(name)}{_td(value)}</tr>")
    table = f"<table class='pairs'>{''.join(rows)}</table>" if rows else ""
    return table + "".join(blocks)


def _td(value) -> str:
    """A table cell of ``value``: kept on one line (a number, a flag, a short word) unless its text is longer than
    ``WRAP`` characters (a file name, a sentence): that one may wrap (:func:`_breakable`)."""
    text = _cell(value)
    if len(html.unescape(text)) > WRAP:
        return f"<td class='w'>{_breakable(text)}</td>"
    return f"<td>{text}</td>"


def _th(name, colspan: int = 1) -> str:
    """A heading cell: it wraps between words, and inside a word longer than ``WRAP`` characters (a file name)."""
    text = str(name)
    attributes = (" class='w'" if max(map(len, text.split()), default=0) > WRAP else "") + (
        f" colspan='{colspan}'" if colspan > 1 else "")
    return f"<th{attributes}>{_breakable(html.escape(text))}</th>"


def _breakable(text: str) -> str:
    """Escaped ``text`` with a line-break opportunity after each ``_ - /`` of a word longer than ``WRAP``
    characters: a file name wraps where it reads best (a word with none breaks anywhere, see ``page.html``)."""
    words = re.split(r"(\s+|&[a-z]+;|&#\d+;)", text)  # entities stay whole
    return "".join(re.sub(r"(?<=[_\-/])(?=.)", "<wbr>", w) if len(w) > WRAP and not w.startswith("&") else w
                   for w in words)


def _cell(value) -> str:
    if isinstance(value, (bool, np.bool_)):
        return "yes" if value else "no"
    if isinstance(value, (float, np.floating)):
        return formats.number(value)
    if value is None:
        return ""
    if np.ndim(value) == 1:
        return " ".join(_cell(v) for v in value)  # each escaped
    return html.escape(str(value))
