"""One static HTML page for a run folder: the pipeline, one results table, a chart per swept parameter,
the plots and renders, links to the other files.

No server and no script: the page is HTML and CSS only, every text from the run folder is
escaped (user text is never markup), and pictures are linked by relative URLs (or embedded as
``data:`` URLs with ``embed=True``, for a page that travels alone). The charts are drawn here with
matplotlib and always embedded. The page fits a 1280-pixel window: a table wider than the page
scrolls inside its own box.
"""

from __future__ import annotations

import base64
import csv
import html
import io
import json
import math
import os
from datetime import datetime, timezone
from pathlib import Path
from urllib.parse import quote

from .io import atomic_path

__all__ = ["write_report", "format_number", "sweep_parameters", "sweep_series"]

REPORT_NAME = "report.html"
MAX_TABLE_ROWS = 2000  # beyond this a table is cut, and the page says so
SIGNIFICANT = 4  # significant digits of a number shown in a table (the full value is its tooltip)
MAX_CHART_METRICS = 4  # panels per chart

# Keys a pipeline's runner writes into every results row; every other key that is not a metric
# (see _is_measurement) is a sweep variable.
_ROW_KEYS = {"input", "status", "outputs", "vertices", "faces", "seconds", "error", "traceback"}

_STYLE = """
body { font-family: sans-serif; margin: 1.5em auto; padding: 0 1.5em; max-width: 1200px; color: #222;
       line-height: 1.4; }
h1 { font-size: 1.5em; overflow-wrap: anywhere; }
h2 { margin-top: 1.6em; border-bottom: 1px solid #ddd; }
h3 { font-size: 1em; overflow-wrap: anywhere; }
.scroll { max-width: 100%; overflow-x: auto; margin: 0.5em 0 1.5em; }
table { border-collapse: collapse; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.6em; vertical-align: top; }
th { background: #f0f0f0; text-align: left; }
td { overflow-wrap: break-word; }
td.nw { white-space: nowrap; }
td.num { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
figure { display: inline-block; margin: 0 1em 1.5em 0; vertical-align: top; max-width: 100%; }
figure img { max-width: 100%; height: auto; border: 1px solid #ddd; }
figcaption, .note { font-size: 0.85em; color: #555; overflow-wrap: anywhere; }
pre { background: #f7f7f7; padding: 0.6em; overflow-x: auto; max-width: 100%; box-sizing: border-box; }
li { overflow-wrap: anywhere; }
"""


def write_report(run_dir: str | os.PathLike, *, embed: bool = False, out: str | os.PathLike | None = None,
                 pipeline: str | os.PathLike | None = None) -> Path:
    """Write ``report.html`` for a pipeline run or a reproduction folder; return its path.

    The page holds, in this order:

    - the pipeline: the file ``pipeline`` if given, and every ``*.yaml`` / ``*.yml`` of the folder, as text;
    - the results: one table per ``*.csv`` / ``*.json`` file, in file-name order (sub-folders included),
      and one only when ``name.csv`` and ``name.json`` hold the same rows (a pipeline's results);
      numbers are shown to 4 significant digits (the full value as the cell's tooltip), input paths by
      their shortest distinguishing tail, output files inside the folder as links. A list of objects
      gives one row per object, an object one row per (dotted) key, anything else indented JSON;
    - for a pipeline's results, a chart per swept numeric parameter: each metric against its value,
      one line per input and setting of the other swept parameters;
    - every ``*.png`` as a figure, linked relatively (or embedded with ``embed=True``);
    - links to all other files (meshes, logs), with their sizes.

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
        Its ``sweep:`` keys name the swept parameters; without it they are the row keys that are
        neither the runner's own (input, status, outputs, vertices, faces, seconds) nor metrics.

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
    files = sorted((p for p in run.rglob("*") if p.is_file() and not p.name.startswith(".")
                    and p.resolve() != target.resolve()), key=lambda p: _natural(p.relative_to(run).as_posix()))
    page_dir = target.parent
    parts = [f"<h1>meshdenoise report: {_e(run.resolve().name)}</h1>",
             f"<p class=\"note\">{_e(str(run.resolve()))}, written "
             f"{_e(datetime.now(timezone.utc).strftime('%Y-%m-%d %H:%M UTC'))}</p>"]
    configs = [p for p in files if p.suffix.lower() in (".yaml", ".yml")]
    images = [p for p in files if p.suffix.lower() == ".png"]
    data = [p for p in files if p.suffix.lower() in (".csv", ".json")]
    twins = {p for p in data if p.suffix.lower() == ".json" and p.with_suffix(".csv") in data
             and _same_rows(p.with_suffix(".csv"), p)}
    tables = [p for p in data if p not in twins]
    others = [p for p in files if p not in data and p not in configs and p not in images] + sorted(twins)

    sources = ([Path(pipeline)] if pipeline is not None else []) + configs
    sweep_keys = None
    if sources:
        parts.append("<h2>Pipeline</h2>")
        for p in sources:
            text = _read_text(p)
            name = str(p) if pipeline is not None and p == Path(pipeline) else _rel(p, run)
            parts.append(f"<h3>{_e(name)}</h3><div class=\"scroll\"><pre>{_e(text)}</pre></div>")
            sweep_keys = sweep_keys or _sweep_keys_of(text)
    if tables:
        parts.append("<h2>Results</h2>")
        for p in tables:
            parts.append(_table_section(p, run, page_dir, twins, sweep_keys))
    if images:
        parts.append("<h2>Plots and renders</h2>")
        parts += [_figure(p, run, page_dir, embed) for p in images]
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
        The pipeline's ``sweep:`` keys. Without them, a sweep variable is a key that is neither the
        runner's own (input, status, outputs, vertices, faces, seconds, error) nor a measurement.

    Returns
    -------
    params : list of str
        Swept keys taking at least two values (numbers, or names such as a ``method``), in row order.
    metrics : list of str
        Numeric measurements (metrics, ``auto.*`` choices), at most ``MAX_CHART_METRICS``.
    """
    keys = list(dict.fromkeys(k for r in rows for k in r))
    if sweep_keys is None:
        swept = [k for k in keys if k not in _ROW_KEYS and not _is_measurement(k)]
    else:
        swept = [k for k in keys if k in sweep_keys]
    ok = [r for r in rows if r.get("status", "ok") == "ok"]

    def numeric(k):
        vals = [_number(r.get(k)) for r in ok if k in r]
        return bool(vals) and all(v is not None and math.isfinite(v) for v in vals)

    params = [k for k in swept if len({_key(r[k]) for r in ok if k in r}) >= 2]
    metrics = [k for k in keys if k not in _ROW_KEYS and k not in swept and _is_measurement(k) and numeric(k)]
    return params, metrics[:MAX_CHART_METRICS]


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


def _sweep_keys_of(text: str) -> list[str] | None:
    import yaml

    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError:
        return None
    sweep = doc.get("sweep") if isinstance(doc, dict) else None
    return [str(k) for k in sweep] if isinstance(sweep, dict) else None


def _charts(rows: list[dict], sweep_keys: list[str] | None) -> str:
    params, metrics = sweep_parameters(rows, sweep_keys)
    if not params or not metrics:
        return ""
    keys = list(dict.fromkeys(k for r in rows for k in r))
    swept = [k for k in keys if (k in sweep_keys if sweep_keys is not None
                                 else k not in _ROW_KEYS and not _is_measurement(k))]
    out = []
    for param in params:
        png = _chart_png(rows, param, metrics, swept)
        alt = f"{', '.join(metrics)} against {param}"
        out.append(f"<figure><img src=\"data:image/png;base64,{base64.b64encode(png).decode('ascii')}\" "
                   f"alt=\"{_e(alt)}\" loading=\"eager\">"
                   f"<figcaption>{_e(alt)}</figcaption></figure>")
    return "<h3>Sweep</h3>" + "".join(out)


_CHART_W, _CHART_H, _DPI = 2.9, 2.4, 100  # inches per panel; a chart of 4 panels is 1160 px wide


def _chart_png(rows, param, metrics, swept) -> bytes:
    from matplotlib.figure import Figure  # no pyplot: no global backend or state, nothing left open
    from matplotlib.text import Text

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
                ax.plot(xs, ys, marker="o", markersize=3, color=f"C{i % 10}", label=label or None)
            else:  # one bar per value of the parameter (a method...), one colour per line
                bar = 0.8 / len(series)
                at = {name: j for j, name in enumerate(names)}
                ax.barh([at[x] + (i - (len(series) - 1) / 2) * bar for x, _ in pts], [y for _, y in pts],
                        height=bar, color=f"C{i % 10}", label=label or None)
        if numeric:
            xs_all = [x for pts in series.values() for x, _ in pts]
            if xs_all and min(xs_all) > 0 and max(xs_all) / min(xs_all) >= 20:
                ax.set_xscale("log")
            ax.set_xlabel(param)
        else:
            ax.set_yticks(range(len(names)), names, fontsize=7)
            ax.tick_params(axis="y", labelleft=ax is axes[0])
            if ax is axes[0]:
                ax.invert_yaxis()  # the first value on top (the y axis is shared: invert it once)
        ax.set_title(metric, fontsize=10)
        ax.grid(True, alpha=0.3)
    if 1 < len(series) <= 12:  # the same lines in every panel: one legend under them
        handles, labels = axes[0].get_legend_handles_labels()
        per_label = 4.5 * max(len(lb) for lb in labels) + 45  # pixels of a 7-point label and its handle
        ncols = max(1, min(len(labels), int(_CHART_W * n * _DPI // per_label)))
        fig.legend(handles, labels, loc="outside lower center", ncols=ncols, fontsize=7, frameon=False)
    for text in fig.findobj(match=Text):
        text.set_parse_math(False)  # names are user text: "$x$" stays "$x$"
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    return buf.getvalue()


# ----------------------------------------------------------------------------- tables


def _table_section(path: Path, run: Path, page_dir: Path, twins: set, sweep_keys) -> str:
    twin = path.with_suffix(".json") if path.with_suffix(".json") in twins else None
    title = f"<h3>{_e(_rel(path, run))}</h3>"
    try:
        if twin is not None:  # a pipeline's results: the JSON's typed rows in the CSV's column order
            with path.open(newline="", encoding="utf-8", errors="replace") as fh:
                header = next(csv.reader(fh), [])
            rows = json.loads(_read_text(twin))
            return (title + _rows_table(rows, header, run, page_dir)
                    + _charts(rows, sweep_keys))
        if path.suffix.lower() == ".csv":
            with path.open(newline="", encoding="utf-8", errors="replace") as fh:
                rows = list(csv.reader(fh))
            if not rows:
                return title + "<p class=\"note\">empty file</p>"
            width = max(len(r) for r in rows)
            return title + _html_table(rows[0] + [""] * (width - len(rows[0])), rows[1:])
        data = json.loads(_read_text(path))
    except (json.JSONDecodeError, csv.Error) as exc:
        return title + (f"<p class=\"note\">cannot be read as a table ({_e(exc)}); shown as text:</p>"
                        f"<div class=\"scroll\"><pre>{_e(_read_text(path))}</pre></div>")
    if _is_results_rows(data):
        return title + _rows_table(data, [], run, page_dir) + _charts(data, sweep_keys)
    return title + _json_table(data)


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


def _rows_table(rows: list[dict], header: list[str], run: Path, page_dir: Path) -> str:
    """A pipeline's results: input paths shortened, output files linked, numbers rounded."""
    keys = list(dict.fromkeys([*header, *(k for r in rows for k in r if k != "traceback")]))
    names = _short_names(sorted({str(r["input"]) for r in rows if "input" in r}))
    cells = []
    for r in rows:
        line = []
        for k in keys:
            v = r.get(k, "")
            if k == "input" and str(v) in names:
                name = names[str(v)]
                short = len(name) <= 2 * SHORT
                line.append(("html", f"<span title=\"{_e(v)}\">{_e(name) if short else _breakable(name)}</span>", short))
            elif k == "outputs":
                paths = v if isinstance(v, list) else [p for p in str(v).split(";") if p]
                line.append(("html", "<br>".join(_file_link(Path(p), run, page_dir) for p in paths), False))
            else:
                line.append(v)
        cells.append(line)
    return _html_table(keys, cells)


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


def _html_table(header: list, rows: list[list]) -> str:
    cut = len(rows) > MAX_TABLE_ROWS
    head = "".join(f"<th>{_breakable(h)}</th>" for h in header)
    body = "\n".join("<tr>" + "".join(_cell(c) for c in row) + "</tr>" for row in rows[:MAX_TABLE_ROWS])
    note = f"<p class=\"note\">first {MAX_TABLE_ROWS} of {len(rows)} rows shown</p>" if cut else ""
    return f"<div class=\"scroll\"><table><thead><tr>{head}</tr></thead><tbody>\n{body}\n</tbody></table></div>{note}"


SHORT = 16  # text cells up to this many characters never wrap


def _breakable(text) -> str:
    """Escaped text with break opportunities after ``_ / . , = -`` (long names wrap there, not mid-word)."""
    import re

    return re.sub(r"([_/.,=\-])", r"\1<wbr>", _e(text))


def _cell(value) -> str:
    if isinstance(value, tuple) and value[0] == "html":  # ("html", markup built here and escaped, no-wrap)
        return f"<td class=\"nw\">{value[1]}</td>" if value[2] else f"<td>{value[1]}</td>"
    if isinstance(value, list):
        value = ", ".join(str(v) for v in value)
    number = _number(value)
    if number is None:
        text = str(value)
        return f"<td class=\"nw\">{_e(text)}</td>" if len(text) <= SHORT else f"<td>{_breakable(text)}</td>"
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
    return f"<div class=\"scroll\"><pre>{_e(json.dumps(data, indent=2))}</pre></div>"


# ----------------------------------------------------------------------------- files


def _natural(text: str) -> list:
    """Sort key with runs of digits compared as numbers: ``a_2`` before ``a_10``."""
    import re

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
