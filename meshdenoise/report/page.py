"""The page: :func:`write_report` gathers the run folder's files into its sections and writes ``report.html``."""

from __future__ import annotations

import base64
import os
from datetime import datetime, timezone
from pathlib import Path

from ..io import atomic_path
from .outputs import _outputs_section
from .sweeps import _pipeline_facts
from .tables import _same_rows, _table_section
from .text import _e, _href, _inside, _natural, _read_text, _rel, _size

REPORT_NAME = "report.html"

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
      A table wider than the page is cut into several (see :func:`~meshdenoise.report.split_columns`);
    - for a pipeline's results with a sweep, a chart per swept parameter: each metric against its
      value, one line per input and setting of the other swept parameters (nothing without a sweep);
    - for a pipeline's results, each output mesh before / after / change: the input, the output and
      the displacement of each output vertex from the input (:func:`meshdenoise.render.render_comparison`
      with ``show_change``, drawn by the matplotlib rasteriser, seen along the input's mean normal so
      that a range scan faces the camera; a closed mesh from +z), at most
      :data:`~meshdenoise.report.outputs.MAX_RENDERS`;
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


def _figure(path: Path, run: Path, page_dir: Path, embed: bool) -> str:
    if embed:
        src = "data:image/png;base64," + base64.b64encode(path.read_bytes()).decode("ascii")
    else:
        src = _href(path, page_dir)
    name = _e(_rel(path, run))
    return f"<figure><img src=\"{src}\" alt=\"{name}\" loading=\"eager\"><figcaption>{name}</figcaption></figure>"
