"""One static HTML page for a run folder: the results table, a chart per swept parameter, each output
before / after / change, the plots and renders, the pipeline, links to the other files.

No server and no script: the page is HTML and CSS only, every text from the run folder is
escaped (user text is never markup), and pictures are linked by relative URLs (or embedded as
``data:`` URLs with ``embed=True``, for a page that travels alone). The before / after / change
pictures are drawn by :func:`meshdenoise.render.render_comparison` into a folder beside the page;
the charts are drawn here with matplotlib and always embedded. The page fits a 1280-pixel window
without scrolling sideways: text wraps, and a table with more columns than fit is cut into
several tables, each repeating the columns that name the row.
"""

from __future__ import annotations

import base64
import csv
import html
import io
import json
import math
import os
import re
import tempfile
import warnings
from datetime import datetime, timezone
from pathlib import Path
from urllib.parse import quote

from .io import SUPPORTED_EXTENSIONS, atomic_path

__all__ = ["write_report", "format_number", "sweep_parameters", "sweep_series", "split_columns"]

REPORT_NAME = "report.html"
MAX_TABLE_ROWS = 2000  # beyond this a table is cut, and the page says so
SIGNIFICANT = 4  # significant digits of a number shown in a table (the full value is its tooltip)
MAX_CHART_METRICS = 4  # panels per chart
RENDER_PANEL = (260, 260)  # pixels of one before / after / change panel: the picture is 906 x 300
MAX_RENDERS = 24  # outputs drawn before / after / change; the page says when there are more

# Keys a pipeline's runner writes into every results row; every other key that is not a metric
# (see _is_measurement) is a sweep variable.
_ROW_KEYS = {"input", "status", "outputs", "vertices", "faces", "seconds", "error", "traceback", "failure"}

# How wide a table may be, and how wide its columns are at the least, estimated from their text: a
# character of the table's font (0.9 em of 16 px; DejaVu Sans digits are 0.64 em, bold capitals
# wider) takes at most CHAR_PX, a cell's padding and border CELL_PX. The page's text is 1152 px wide
# in a 1280-pixel window.
TABLE_PX = 1120
CHAR_PX = 10.0
CELL_PX = 20

_STYLE = """
body { font-family: sans-serif; margin: 1.5em auto; padding: 0 1.5em; max-width: 1200px; color: #222;
       line-height: 1.4; }
h1 { font-size: 1.5em; overflow-wrap: anywhere; }
h2 { margin-top: 1.6em; border-bottom: 1px solid #ddd; }
h3 { font-size: 1em; overflow-wrap: anywhere; }
.scroll { max-width: 100%; overflow-x: auto; margin: 0.5em 0 1.5em; }
table { border-collapse: collapse; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.6em; vertical-align: top; overflow-wrap: break-word; }
th { background: #f0f0f0; text-align: left; }
td.any { overflow-wrap: anywhere; }
td.nw { white-space: nowrap; }
td.num { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
figure { display: inline-block; margin: 0 1em 1.5em 0; vertical-align: top; max-width: 100%; }
figure img { max-width: 100%; height: auto; border: 1px solid #ddd; }
figcaption, .note { font-size: 0.85em; color: #555; overflow-wrap: anywhere; }
pre { background: #f7f7f7; padding: 0.6em; max-width: 100%; box-sizing: border-box;
      white-space: pre-wrap; overflow-wrap: anywhere; }
li { overflow-wrap: anywhere; }
"""


def write_report(run_dir: str | os.PathLike, *, embed: bool = False, out: str | os.PathLike | None = None,
                 pipeline: str | os.PathLike | None = None, renders: bool = True) -> Path:
    """Write ``report.html`` for a pipeline run or a reproduction folder; return its path.

    The page holds, in this order:

    - the pipeline's ``description:`` under the title;
    - the results: one table per ``*.csv`` / ``*.json`` file, in file-name order (sub-folders included),
      and one only when ``name.csv`` and ``name.json`` hold the same rows (a pipeline's results);
      numbers are shown to 4 significant digits (the full value as the cell's tooltip), input paths by
      their shortest distinguishing tail, output files inside the folder as links. A list of objects
      gives one row per object, an object one row per (dotted) key, anything else indented JSON.
      A table wider than the page is cut into several (see :func:`split_columns`);
    - for a pipeline's results with a sweep, a chart per swept parameter: each metric against its
      value, one line per input and setting of the other swept parameters (nothing without a sweep);
    - for a pipeline's results, each output mesh before / after / change: the input, the output and
      the displacement of each output vertex from the input (:func:`meshdenoise.render.render_comparison`
      with ``show_change``, drawn by the matplotlib rasteriser, seen along the input's mean normal so
      that a range scan faces the camera; a closed mesh from +z), at most :data:`MAX_RENDERS`;
    - every other ``*.png`` as a figure, linked relatively (or embedded with ``embed=True``);
    - the pipeline: the file ``pipeline`` if given, and every ``*.yaml`` / ``*.yml`` of the folder, as text;
    - links to all other files (meshes, logs), with their sizes.

    The before / after / change pictures are written into the folder ``<report name>-renders``
    beside the page (``report-renders/``; a picture newer than both its meshes is kept, pictures no
    longer shown are removed) and linked relatively; with ``embed=True`` they are drawn in a
    temporary folder and put inside the page.

    Parameters
    ----------
    run_dir : path
        The run folder.
    embed : bool
        Put the PNGs inside the page as ``data:`` URLs, so it can be moved alone.
    out : path, optional
        Where to write; default ``run_dir/report.html``. Must be inside ``run_dir`` unless
        ``embed`` (relative links are computed from it).
    pipeline : path, optional
        The pipeline file of the run (``meshdenoise run`` does not copy it into the output folder).
        Its ``sweep:`` keys name the swept parameters (none when it has no ``sweep:``); without it
        they are the row keys that are plain names (no dot) and neither the runner's own (input,
        status, outputs, vertices, faces, seconds) nor metrics.
    renders : bool
        Draw each output before / after / change (the only slow part of a report: about a second
        per output of a million vertices).

    Raises
    ------
    ValueError
        ``run_dir`` is not a folder, ``out`` is outside it without ``embed``, or ``pipeline`` is not a file.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> run = pathlib.Path(tempfile.mkdtemp())
    >>> _ = (run / "results.csv").write_text("method,snr_db\\nsobolev,31.2549\\n")
    >>> page = write_report(run)
    >>> '<td class="num" title="31.2549">31.25</td>' in page.read_text()
    True
    """
    run = Path(run_dir)
    if not run.is_dir():
        raise ValueError(f"report: {run} is not a folder (give the run folder of a pipeline or a reproduction)")
    target = Path(out) if out is not None else run / REPORT_NAME
    if not embed and not _inside(target.resolve().parent, run.resolve()):
        raise ValueError(f"report: {target} is outside {run}; relative image links would break (use embed=True)")
    if pipeline is not None and not Path(pipeline).is_file():
        raise ValueError(f"report: pipeline {pipeline} is not a file")
    render_dir = target.with_name(target.stem + "-renders")
    files = sorted((p for p in run.rglob("*") if p.is_file() and not p.name.startswith(".")
                    and p.resolve() != target.resolve() and not _inside(p.resolve().parent, render_dir.resolve())),
                   key=lambda p: _natural(p.relative_to(run).as_posix()))
    page_dir = target.parent
    configs = [p for p in files if p.suffix.lower() in (".yaml", ".yml")]
    images = [p for p in files if p.suffix.lower() == ".png"]
    data = [p for p in files if p.suffix.lower() in (".csv", ".json")]
    twins = {p for p in data if p.suffix.lower() == ".json" and p.with_suffix(".csv") in data
             and _same_rows(p.with_suffix(".csv"), p)}
    tables = [p for p in data if p not in twins]
    others = [p for p in files if p not in data and p not in configs and p not in images] + sorted(twins)

    sources = ([Path(pipeline)] if pipeline is not None else []) + configs
    texts = {p: _read_text(p) for p in sources}
    sweep_keys, description = None, None
    for text in texts.values():
        keys, about = _pipeline_facts(text)
        sweep_keys = keys if sweep_keys is None else sweep_keys
        description = about if description is None else description

    parts = [f"<h1>meshdenoise report: {_e(run.resolve().name)}</h1>"]
    if description:
        parts.append(f"<p>{_e(description)}</p>")
    parts.append(f"<p class=\"note\">{_e(str(run.resolve()))}, written "
                 f"{_e(datetime.now(timezone.utc).strftime('%Y-%m-%d %H:%M UTC'))}</p>")
    results: list[dict] = []  # a pipeline's rows, for the before / after / change pictures
    if tables:
        parts.append("<h2>Results</h2>")
        for p in tables:
            section, rows = _table_section(p, run, page_dir, twins, sweep_keys)
            parts.append(section)
            results += rows
    if results and renders:
        parts.append(_outputs_section(results, run, page_dir, render_dir, embed, sweep_keys))
    if images:
        parts.append("<h2>Plots and renders</h2>")
        parts += [_figure(p, run, page_dir, embed) for p in images]
    if sources:
        parts.append("<h2>Pipeline</h2>")
        for p, text in texts.items():
            name = str(p) if pipeline is not None and p == Path(pipeline) else _rel(p, run)
            parts.append(f"<h3>{_e(name)}</h3><pre>{_e(text)}</pre>")
    if others:
        parts.append("<h2>Other files</h2><ul>")
        for p in others:
            note = f"the same rows as {p.with_suffix('.csv').name}, " if p in twins else ""
            parts.append(f"<li><a href=\"{_href(p, page_dir)}\">{_e(_rel(p, run))}</a> "
                         f"<span class=\"note\">({note}{_size(p.stat().st_size)})</span></li>")
        parts.append("</ul>")
    if not files:
        parts.append("<p>This folder holds no files yet.</p>")
    page = ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
            f"<title>meshdenoise report: {_e(run.resolve().name)}</title><style>{_STYLE}</style></head>\n<body>\n"
            + "\n".join(parts) + "\n</body></html>\n")
    with atomic_path(target) as tmp:
        tmp.write_text(page, encoding="utf-8")
    return target


# ----------------------------------------------------------------------------- before / after / change


def _outputs_section(rows: list[dict], run: Path, page_dir: Path, render_dir: Path, embed: bool,
                     sweep_keys) -> str:
    """Each output mesh of the rows that succeeded beside its input, and the change between them."""
    pairs = []
    for r in rows:
        if r.get("status", "ok") != "ok" or not r.get("input"):
            continue
        outputs = r.get("outputs", [])
        outputs = outputs if isinstance(outputs, list) else [x for x in str(outputs).split(";") if x]
        for o in outputs:
            if Path(str(o)).suffix.lower() in SUPPORTED_EXTENSIONS:
                pairs.append((r, Path(str(r["input"])), Path(str(o))))
    if not pairs:
        return ""
    names = _short_names(sorted({str(i) for _, i, _ in pairs}))
    swept = [k for k in dict.fromkeys(k for r in rows for k in r) if _is_swept(k, sweep_keys)]
    out = ["<h2>Outputs: before / after / change</h2>",
           "<p class=\"note\">Each output (after) beside its input (before), one camera for both, and how far each "
           "output vertex moved from the input (its own vertex when the faces are the same, else the nearest point "
           "of the input's surface), on a colour bar topped at the 99th percentile.</p>"]
    if len(pairs) > MAX_RENDERS:
        out.append(f"<p class=\"note\">the first {MAX_RENDERS} of {len(pairs)} outputs are drawn</p>")
    used = set()
    with tempfile.TemporaryDirectory(prefix="meshdenoise-report-") as tmp:
        folder = Path(tmp) if embed else render_dir
        for row, before, after in pairs[:MAX_RENDERS]:
            try:
                rel = after.resolve().relative_to(run.resolve()).as_posix()
            except ValueError:
                rel = after.name
            png = folder / (re.sub(r"[/\\:]", "--", rel) + ".png")
            used.add(png.name)
            setting = ", ".join(f"{k}={row[k]}" for k in swept if k in row)
            caption = f"{_e(names[str(before)])} → {_breakable(rel)}"
            if setting:
                caption += f" <span class=\"note\">({_e(setting)})</span>"
            try:
                _draw_change(before, after, png)
            except Exception as exc:  # noqa: BLE001 - any mesh that cannot be drawn: say why, draw the rest
                out.append(f"<p class=\"note\">{caption}: not drawn ({_e(' '.join(str(exc).split()))})</p>")
                continue
            src = ("data:image/png;base64," + base64.b64encode(png.read_bytes()).decode("ascii")) if embed \
                else _href(png, page_dir)
            w, h = _png_size(png)
            out.append(f"<figure><img src=\"{src}\" width=\"{w}\" height=\"{h}\" loading=\"eager\" "
                       f"alt=\"before, after and change of {_e(rel)}\"><figcaption>{caption}</figcaption></figure>")
    if not embed and render_dir.is_dir():  # pictures of outputs no longer in the results
        for old in render_dir.glob("*.png"):
            if old.name not in used:
                old.unlink()
    return "\n".join(out)


def _draw_change(before: Path, after: Path, png: Path) -> None:
    """Draw before / after / change into ``png``, unless a picture newer than both meshes is there."""
    for mesh in (before, after):
        if not mesh.is_file():
            raise ValueError(f"{mesh} is missing")
    newest = max(before.stat().st_mtime, after.stat().st_mtime)
    if png.is_file() and png.stat().st_mtime >= newest:
        return
    from .render import render_comparison

    png.parent.mkdir(parents=True, exist_ok=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        render_comparison([before, after], png, titles=["before", "after"], size=RENDER_PANEL, view="facing",
                          show_change=True, backend="matplotlib")


def _png_size(path: Path) -> tuple[int, int]:
    import struct

    head = path.read_bytes()[:24]
    return struct.unpack(">II", head[16:24])


# ----------------------------------------------------------------------------- numbers


def format_number(value, digits: int = SIGNIFICANT) -> str:
    """A number as a person reads it: integers whole, other numbers to ``digits`` significant digits.

    Parameters
    ----------
    value : int, float or str
        A number, or text holding one (a CSV cell); other text is returned unchanged.
    digits : int
        Significant digits of a non-integer.

    Returns
    -------
    str

    Examples
    --------
    >>> [format_number(v) for v in (44.07087922224201, "0.10840", 28088, "1e-07", 123456.789, "inf", "mu=1")]
    ['44.07', '0.1084', '28088', '1e-07', '123457', 'inf', 'mu=1']
    """
    number = _number(value)
    if number is None:
        return str(value)
    if isinstance(number, int):
        return str(number)
    if not math.isfinite(number):
        return str(number)
    if number != 0 and 10 ** digits <= abs(number) < 1e15:
        return f"{number:.0f}"
    return f"{number:.{digits}g}"


def _number(value):
    """``value`` as an int or a float, or None when it is not a number (bool is not a number here)."""
    if isinstance(value, bool) or value is None:
        return None
    if isinstance(value, int):
        return value
    if isinstance(value, float):
        return value
    text = str(value).strip()
    if not text:
        return None
    try:
        return int(text)
    except ValueError:
        pass
    try:
        return float(text)
    except ValueError:
        return None


# ----------------------------------------------------------------------------- sweeps


def _is_measurement(key: str) -> bool:
    """A key a pipeline step writes: a metric (``snr``, ``clean.snr``), a chosen parameter (``auto.*``), a render."""
    from .metrics import METRICS

    last = key.rsplit(".", 1)[-1]
    return last in METRICS or key.startswith("auto.") or ".auto." in key or "render." in key or key.startswith("render")


def sweep_parameters(rows: list[dict], sweep_keys: list[str] | None = None) -> tuple[list[str], list[str]]:
    """The swept parameters of a pipeline's results rows, and the metrics to chart against them.

    Parameters
    ----------
    rows : list of dict
        The results rows (``results.json``).
    sweep_keys : list of str, optional
        The pipeline's ``sweep:`` keys (``[]``: it has no sweep). Without them, a sweep variable is
        a key that is a plain name (a pipeline variable: no dot, as the columns steps add have) and
        neither the runner's own (input, status, outputs, vertices, faces, seconds, error) nor a
        measurement.

    Returns
    -------
    params : list of str
        Swept keys taking at least two values (numbers, or names such as a ``method``), in row order.
    metrics : list of str
        Numeric measurements (metrics, ``auto.*`` choices), at most ``MAX_CHART_METRICS``.
    """
    keys = list(dict.fromkeys(k for r in rows for k in r))
    swept = [k for k in keys if _is_swept(k, sweep_keys)]
    ok = [r for r in rows if r.get("status", "ok") == "ok"]

    def numeric(k):
        vals = [_number(r.get(k)) for r in ok if k in r]
        return bool(vals) and all(v is not None and math.isfinite(v) for v in vals)

    params = [k for k in swept if len({_key(r[k]) for r in ok if k in r}) >= 2]
    metrics = [k for k in keys if k not in _ROW_KEYS and k not in swept and _is_measurement(k) and numeric(k)]
    return params, metrics[:MAX_CHART_METRICS]


def _is_swept(key: str, sweep_keys: list[str] | None) -> bool:
    """Whether a results column is a swept variable: one of ``sweep_keys``, or without them a plain variable name."""
    if sweep_keys is not None:
        return key in sweep_keys
    return (key not in _ROW_KEYS and not _is_measurement(key) and "." not in key
            and re.fullmatch(r"[A-Za-z][A-Za-z0-9_]*", key) is not None)


def _key(value) -> str:
    return json.dumps(value, sort_keys=True) if isinstance(value, (list, dict)) else str(value)


def _is_numeric_param(rows: list[dict], param: str) -> bool:
    vals = [_number(r[param]) for r in rows if param in r]
    return bool(vals) and all(v is not None and math.isfinite(v) for v in vals)


def sweep_series(rows: list[dict], param: str, metric: str, swept: list[str]) -> dict[str, list[tuple]]:
    """One line of ``metric`` against ``param`` per input and setting of the other swept keys.

    Parameters
    ----------
    rows : list of dict
        Results rows; rows whose status is not ``ok`` or that lack either key are left out.
    param, metric : str
        The x and y keys.
    swept : list of str
        Every swept key (numeric or not): those other than ``param`` name the lines.

    Returns
    -------
    dict
        Line label -> points ``(x, y)``: sorted by x for a numeric parameter, in row order with x the
        value's text for any other (a ``method``). The label is the input's file name (when there are
        several inputs) and ``key=value`` of the other swept keys; ``""`` for a single line.
    """
    ok = [r for r in rows if r.get("status", "ok") == "ok" and param in r and _number(r.get(metric)) is not None]
    numeric = _is_numeric_param(ok, param)
    inputs = {str(r.get("input", "")) for r in ok}
    names = _short_names(sorted(inputs))
    lines: dict[str, list[tuple[float, float]]] = {}
    for r in ok:
        label = []
        if len(inputs) > 1:
            label.append(names[str(r.get("input", ""))])
        label += [f"{k}={r[k]}" for k in swept if k != param and k in r]
        x = float(_number(r[param])) if numeric else _key(r[param])
        lines.setdefault(", ".join(label), []).append((x, float(_number(r[metric]))))
    return {k: sorted(v) for k, v in lines.items()} if numeric else lines


def _pipeline_facts(text: str) -> tuple[list[str] | None, str | None]:
    """A pipeline file's swept keys (``[]`` for a pipeline without ``sweep:``) and its description.

    (None, None) for text that is not a pipeline (no ``steps:``).
    """
    import yaml

    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError:
        return None, None
    if not isinstance(doc, dict) or "steps" not in doc:
        return None, None
    sweep = doc.get("sweep")
    about = doc.get("description")
    return ([str(k) for k in sweep] if isinstance(sweep, dict) else []), (str(about) if about else None)


def _charts(rows: list[dict], sweep_keys: list[str] | None) -> str:
    """The sweep's charts: one per swept parameter, a panel per metric with points; nothing without a sweep."""
    params, metrics = sweep_parameters(rows, sweep_keys)
    keys = list(dict.fromkeys(k for r in rows for k in r))
    swept = [k for k in keys if _is_swept(k, sweep_keys)]
    out = []
    for param in params:
        shown = [m for m in metrics if any(sweep_series(rows, param, m, swept).values())]
        if not shown:
            continue
        png = _chart_png(rows, param, shown, swept)
        alt = f"{', '.join(shown)} against {param}"
        out.append(f"<figure><img src=\"data:image/png;base64,{base64.b64encode(png).decode('ascii')}\" "
                   f"alt=\"{_e(alt)}\" loading=\"eager\">"
                   f"<figcaption>{_e(alt)}</figcaption></figure>")
    return "<h3>Sweep</h3>" + "".join(out) if out else ""


_CHART_W, _CHART_H, _DPI = 2.9, 2.4, 100  # inches per panel; a chart of 4 panels is 1160 px wide


def _chart_png(rows, param, metrics, swept) -> bytes:
    buf = io.BytesIO()
    _chart_figure(rows, param, metrics, swept).savefig(buf, format="png")
    return buf.getvalue()


def _plain(text) -> str:
    """User text for a matplotlib label: a ``$`` is shown as itself, never starts mathtext."""
    return str(text).replace("$", r"\$")


def _chart_figure(rows, param, metrics, swept):
    """The chart of ``metrics`` against ``param`` as a matplotlib Figure (no pyplot: no global state).

    Names from the rows (parameter, metric, input and method names) are escaped for mathtext
    (:func:`_plain`); tick labels keep matplotlib's own mathtext (a log axis labels ``10^-2`` as
    a power), so no ``$\\mathdefault{...}$`` source is ever drawn as text.
    """
    from matplotlib.figure import Figure

    n = len(metrics)
    ok = [r for r in rows if r.get("status", "ok") == "ok"]
    numeric = _is_numeric_param(ok, param)
    names = list(dict.fromkeys(_key(r[param]) for r in ok if param in r))
    height = _CHART_H if numeric else max(_CHART_H, 0.9 + 0.2 * len(names))
    fig = Figure(figsize=(_CHART_W * n, height), dpi=_DPI, layout="constrained")
    axes = fig.subplots(1, n, squeeze=False, sharey=not numeric)[0]
    series = {}
    for ax, metric in zip(axes, metrics):
        series = sweep_series(rows, param, metric, swept)
        for i, (label, pts) in enumerate(series.items()):
            if numeric:
                xs, ys = zip(*pts)
                ax.plot(xs, ys, marker="o", markersize=3, color=f"C{i % 10}", label=_plain(label) if label else None)
            else:  # one bar per value of the parameter (a method...), one colour per line
                bar = 0.8 / len(series)
                at = {name: j for j, name in enumerate(names)}
                ax.barh([at[x] + (i - (len(series) - 1) / 2) * bar for x, _ in pts], [y for _, y in pts],
                        height=bar, color=f"C{i % 10}", label=_plain(label) if label else None)
        if numeric:
            xs_all = [x for pts in series.values() for x, _ in pts]
            if xs_all and min(xs_all) > 0 and max(xs_all) / min(xs_all) >= 20:
                ax.set_xscale("log")
            ax.set_xlabel(_plain(param))
        else:
            ax.set_yticks(range(len(names)), [_plain(n) for n in names], fontsize=7)
            ax.tick_params(axis="y", labelleft=ax is axes[0])
            if ax is axes[0]:
                ax.invert_yaxis()  # the first value on top (the y axis is shared: invert it once)
        ax.set_title(_plain(metric), fontsize=10)
        ax.grid(True, alpha=0.3)
    if 1 < len(series) <= 12:  # the same lines in every panel: one legend under them
        handles, labels = axes[0].get_legend_handles_labels()
        per_label = 4.5 * max(len(lb) for lb in labels) + 45  # pixels of a 7-point label and its handle
        ncols = max(1, min(len(labels), int(_CHART_W * n * _DPI // per_label)))
        fig.legend(handles, labels, loc="outside lower center", ncols=ncols, fontsize=7, frameon=False)
    return fig


# ----------------------------------------------------------------------------- tables


def _table_section(path: Path, run: Path, page_dir: Path, twins: set, sweep_keys) -> tuple[str, list[dict]]:
    """The table of one file (and a pipeline's sweep charts); the pipeline's results rows it holds, if any."""
    twin = path.with_suffix(".json") if path.with_suffix(".json") in twins else None
    title = f"<h3>{_e(_rel(path, run))}</h3>"
    try:
        if twin is not None:  # a pipeline's results: the JSON's typed rows in the CSV's column order
            with path.open(newline="", encoding="utf-8", errors="replace") as fh:
                header = next(csv.reader(fh), [])
            rows = json.loads(_read_text(twin))
            return title + _rows_table(rows, header, run, page_dir, sweep_keys) + _charts(rows, sweep_keys), rows
        if path.suffix.lower() == ".csv":
            with path.open(newline="", encoding="utf-8", errors="replace") as fh:
                rows = list(csv.reader(fh))
            if not rows:
                return title + "<p class=\"note\">empty file</p>", []
            width = max(len(r) for r in rows)
            return title + _html_table(rows[0] + [""] * (width - len(rows[0])), rows[1:]), []
        data = json.loads(_read_text(path))
    except (json.JSONDecodeError, csv.Error) as exc:
        return title + (f"<p class=\"note\">cannot be read as a table ({_e(exc)}); shown as text:</p>"
                        f"<pre>{_e(_read_text(path))}</pre>"), []
    if _is_results_rows(data):
        return title + _rows_table(data, [], run, page_dir, sweep_keys) + _charts(data, sweep_keys), data
    return title + _json_table(data), []


def _is_results_rows(data) -> bool:
    return (isinstance(data, list) and bool(data) and all(isinstance(r, dict) for r in data)
            and all("input" in r and "status" in r for r in data))


def _same_rows(csv_path: Path, json_path: Path) -> bool:
    """True when ``json_path`` holds the rows of ``csv_path`` (as a pipeline writes them: same count and keys)."""
    try:
        with csv_path.open(newline="", encoding="utf-8", errors="replace") as fh:
            table = list(csv.reader(fh))
        data = json.loads(_read_text(json_path))
    except (json.JSONDecodeError, csv.Error, UnicodeDecodeError, RecursionError):
        return False
    if not table or not isinstance(data, list) or not all(isinstance(r, dict) for r in data):
        return False
    header, body = table[0], table[1:]
    return len(body) == len(data) and all(set(r) - {"traceback"} <= set(header) for r in data)


def _rows_table(rows: list[dict], header: list[str], run: Path, page_dir: Path, sweep_keys=None) -> str:
    """A pipeline's results: input paths shortened, output files linked, numbers rounded.

    The input and the swept variables name a row: they come first, and every part of a table
    cut to fit the page repeats them.
    """
    keys = list(dict.fromkeys([*header, *(k for r in rows for k in r if k != "traceback")]))
    first = [k for k in keys if k == "input"] + [k for k in keys if _is_swept(k, sweep_keys)]
    keys = first + [k for k in keys if k not in first]
    names = _short_names(sorted({str(r["input"]) for r in rows if "input" in r}))
    cells = []
    for r in rows:
        line = []
        for k in keys:
            v = r.get(k, "")
            if k == "input" and str(v) in names:
                name = names[str(v)]
                short = len(name) <= 2 * SHORT
                line.append(("html", f"<span title=\"{_e(v)}\">{_e(name) if short else _breakable(name)}</span>",
                             short, name))
            elif k == "outputs":
                paths = v if isinstance(v, list) else [p for p in str(v).split(";") if p]
                line.append(("html", "<br>".join(_file_link(Path(p), run, page_dir) for p in paths), False,
                             " ".join(Path(p).name for p in paths)))
            else:
                line.append(v)
        cells.append(line)
    return _html_table(keys, cells, keep=max(len(first), 1))


def _file_link(path: Path, run: Path, page_dir: Path) -> str:
    if _inside(path.resolve().parent, run.resolve()) and path.exists():
        return f"<a href=\"{_href(path, page_dir)}\">{_breakable(path.resolve().relative_to(run.resolve()).as_posix())}</a>"
    return f"<span title=\"{_e(path)}\">{_breakable(path.name)}</span>"


def _short_names(paths: list[str]) -> dict[str, str]:
    """Each path by its shortest tail of components that no other path in ``paths`` ends with."""
    parts = {p: Path(p).parts for p in paths}
    out = {}
    for p, comps in parts.items():
        for n in range(1, len(comps) + 1):
            tail = comps[-n:]
            if not any(q != p and other[-n:] == tail for q, other in parts.items()):
                break
        out[p] = "/".join(tail) if comps else p
    return out


def _html_table(header: list, rows: list[list], keep: int = 1) -> str:
    """One table, or several when its columns do not fit the page: each part repeats the first ``keep`` columns."""
    cut = len(rows) > MAX_TABLE_ROWS
    rows = rows[:MAX_TABLE_ROWS]
    widths = [_column_px(h, [row[i] if i < len(row) else "" for row in rows]) for i, h in enumerate(header)]
    parts = split_columns(widths, keep)
    out = []
    for n, cols in enumerate(parts, 1):
        if len(parts) > 1:
            rest = cols[keep:] if n > 1 and len(cols) > keep else cols
            named = ", ".join(str(header[i]) for i in range(min(keep, len(header))))
            out.append(f"<p class=\"note\">part {n} of {len(parts)}: columns {rest[0] + 1}-{rest[-1] + 1} of "
                       f"{len(header)}" + (f", after {_e(named)}" if n > 1 and named else "")
                       + (" (the table is cut to fit the page)" if n == 1 else "") + "</p>")
        head = "".join(f"<th>{_breakable(header[i])}</th>" for i in cols)
        body = "\n".join("<tr>" + "".join(_cell(row[i] if i < len(row) else "") for i in cols) + "</tr>"
                         for row in rows)
        out.append(f"<div class=\"scroll\"><table><thead><tr>{head}</tr></thead>"
                   f"<tbody>\n{body}\n</tbody></table></div>")
    if cut:
        out.append(f"<p class=\"note\">first {MAX_TABLE_ROWS} rows shown</p>")
    return "".join(out)


def split_columns(widths: list[float], keep: int = 1, budget: float = TABLE_PX) -> list[list[int]]:
    """The columns of each table a table too wide for the page is cut into.

    Every part starts with the first ``keep`` columns (those naming a row: the input, the swept
    variables) and holds as many of the next columns, in order, as fit in ``budget`` pixels
    with them (always at least one), the parts as even as their number allows.

    Parameters
    ----------
    widths : list of float
        Each column's least width in pixels (see ``_column_px``).
    keep : int
        Leading columns repeated in every part.
    budget : float
        Pixels a table may take.

    Returns
    -------
    list of list of int
        Column indices of each part; one part when everything fits.

    Examples
    --------
    >>> split_columns([100, 300, 300, 300], keep=1, budget=800)
    [[0, 1, 2], [0, 3]]
    >>> split_columns([100, 200, 200, 200, 200, 200], keep=1, budget=1000)
    [[0, 1, 2, 3], [0, 4, 5]]
    >>> split_columns([100, 300], keep=1, budget=800)
    [[0, 1]]
    >>> split_columns([900, 300, 300], keep=1, budget=800)
    [[0, 1], [0, 2]]
    """
    keep = min(keep, len(widths))

    def greedy(limit):
        parts, current, used = [], [], sum(widths[:keep])
        for i in range(keep, len(widths)):
            if current and used + widths[i] > limit:
                parts.append(list(range(keep)) + current)
                current, used = [], sum(widths[:keep])
            current.append(i)
            used += widths[i]
        if current or not parts:
            parts.append(list(range(keep)) + current)
        return parts

    parts = greedy(budget)
    low, high = 0.0, float(budget)  # the same number of parts, as even as can be: the least budget giving it
    for _ in range(30):
        mid = (low + high) / 2
        low, high = (low, mid) if len(greedy(mid)) <= len(parts) else (mid, high)
    return greedy(high)


SHORT = 16  # text cells up to this many characters never wrap
_BREAKS = re.compile(r"(?<=[_/.,=\- ])")


def _longest_piece(text: str) -> int:
    """Characters of the longest run between break opportunities (after ``_ / . , = -`` and spaces)."""
    return max((len(piece) for piece in _BREAKS.split(text)), default=0)


def _cell_chars(value) -> int:
    """Characters a cell needs on one line at the least: numbers and short text whole, longer text its longest
    piece (at most SHORT: beyond that it may break anywhere)."""
    if isinstance(value, tuple) and value[0] == "html":
        return len(value[3]) if value[2] else min(_longest_piece(value[3]), SHORT)
    if isinstance(value, list):
        value = ", ".join(str(v) for v in value)
    number = _number(value)
    if number is not None:
        return len(format_number(number))
    text = str(value)
    return len(text) if len(text) <= SHORT else min(_longest_piece(text), SHORT)


def _column_px(header, cells: list) -> float:
    """An upper bound of a column's least width in pixels: its widest unbreakable cell or header piece."""
    chars = max([_longest_piece(str(header)), *(_cell_chars(c) for c in cells)])  # a header breaks at those only
    return chars * CHAR_PX + CELL_PX


def _breakable(text) -> str:
    """Escaped text with break opportunities after ``_ / . , = -`` (long names wrap there, not mid-word)."""
    return re.sub(r"([_/.,=\-])", r"\1<wbr>", _e(text))


def _cell(value) -> str:
    """A ``<td>``: numbers and text up to SHORT characters on one line; longer text wraps after ``_ / . , = -`` and
    spaces, and anywhere when a piece between those is longer than SHORT (a table never outgrows the page)."""
    if isinstance(value, tuple) and value[0] == "html":  # ("html", markup built here and escaped, no-wrap, text)
        if value[2]:
            return f"<td class=\"nw\">{value[1]}</td>"
        return f"<td class=\"any\">{value[1]}</td>" if _longest_piece(value[3]) > SHORT else f"<td>{value[1]}</td>"
    if isinstance(value, list):
        value = ", ".join(str(v) for v in value)
    number = _number(value)
    if number is None:
        text = str(value)
        if len(text) <= SHORT:
            return f"<td class=\"nw\">{_e(text)}</td>"
        wrap = " class=\"any\"" if _longest_piece(text) > SHORT else ""
        return f"<td{wrap}>{_breakable(text)}</td>"
    shown = format_number(number)
    full = str(value).strip()
    title = f" title=\"{_e(full)}\"" if shown != full else ""
    return f"<td class=\"num\"{title}>{_e(shown)}</td>"


def _flatten(obj, prefix: str = "") -> dict:
    """Nested objects as dotted keys; lists of scalars as one comma-separated cell."""
    if isinstance(obj, dict):
        out = {}
        for k, v in obj.items():
            out.update(_flatten(v, f"{prefix}{k}."))
        return out
    if isinstance(obj, list) and all(not isinstance(v, (dict, list)) for v in obj):
        return {prefix[:-1]: ", ".join(format_number(v) for v in obj)}
    if isinstance(obj, list):
        return {prefix[:-1]: json.dumps(obj)}
    return {prefix[:-1]: obj}


def _json_table(data) -> str:
    if isinstance(data, list) and data and all(isinstance(r, dict) for r in data):
        flat = [_flatten(r) for r in data]
        header = list(dict.fromkeys(k for r in flat for k in r))
        return _html_table(header, [[r.get(k, "") for k in header] for r in flat])
    if isinstance(data, dict):
        # a reproduction's results: {"rows": [...], ...} gives the rows as a table, the rest as keys
        lists = {k: v for k, v in data.items() if isinstance(v, list) and v and all(isinstance(r, dict) for r in v)}
        rest = {k: v for k, v in data.items() if k not in lists}
        parts = []
        if rest:
            parts.append(_html_table(["key", "value"], [[k, v] for k, v in _flatten(rest).items()]))
        for k, v in lists.items():
            parts.append(f"<h4>{_e(k)}</h4>" + _json_table(v))
        return "\n".join(parts) or "<p class=\"note\">empty object</p>"
    return f"<pre>{_e(json.dumps(data, indent=2))}</pre>"


# ----------------------------------------------------------------------------- files


def _natural(text: str) -> list:
    """Sort key with runs of digits compared as numbers: ``a_2`` before ``a_10``."""
    return [(0, int(t), "") if t.isdigit() else (1, 0, t) for t in re.split(r"(\d+)", text)]


def _e(text) -> str:
    return html.escape(str(text), quote=True)


def _inside(path: Path, folder: Path) -> bool:
    return path == folder or folder in path.parents


def _rel(path: Path, run: Path) -> str:
    return path.relative_to(run).as_posix()


def _href(path: Path, page_dir: Path) -> str:
    """A relative URL: each path segment percent-encoded (spaces, '#', '?', non-ASCII)."""
    rel = os.path.relpath(path.resolve(), page_dir.resolve())
    return _e("/".join(quote(part) for part in Path(rel).parts))


def _size(n: int) -> str:
    for unit in ("B", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n} B"


def _read_text(path: Path) -> str:
    return path.read_text(encoding="utf-8", errors="replace")


def _figure(path: Path, run: Path, page_dir: Path, embed: bool) -> str:
    if embed:
        src = "data:image/png;base64," + base64.b64encode(path.read_bytes()).decode("ascii")
    else:
        src = _href(path, page_dir)
    name = _e(_rel(path, run))
    return f"<figure><img src=\"{src}\" alt=\"{name}\" loading=\"eager\"><figcaption>{name}</figcaption></figure>"
