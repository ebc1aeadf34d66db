"""One static HTML page for a run folder: its results tables, plots and renders.

No server and no script: the page is HTML and CSS only, every text from the run folder is
escaped, and pictures are linked by relative URLs (or embedded as ``data:`` URLs with
``embed=True``, for a page that travels alone).
"""

from __future__ import annotations

import base64
import csv
import html
import json
import os
from datetime import datetime, timezone
from pathlib import Path
from urllib.parse import quote

from .io import atomic_path

__all__ = ["write_report"]

REPORT_NAME = "report.html"
MAX_TABLE_ROWS = 2000  # beyond this a table is cut, and the page says so

_STYLE = """
body { font-family: sans-serif; margin: 2em; color: #222; }
table { border-collapse: collapse; margin: 0.5em 0 1.5em; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.6em; }
th { background: #f0f0f0; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
figure { display: inline-block; margin: 0 1em 1.5em 0; vertical-align: top; }
figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption, .note { font-size: 0.85em; color: #555; }
pre { background: #f7f7f7; padding: 0.6em; overflow-x: auto; }
"""


def write_report(run_dir: str | os.PathLike, *, embed: bool = False, out: str | os.PathLike | None = None) -> Path:
    """Write ``report.html`` for a pipeline run or a reproduction folder; return its path.

    The page holds, in file-name order (sub-folders included):

    - a table per ``*.csv`` file (its header row as the table's header);
    - a table per ``*.json`` file: a list of objects gives one row per object, an object
      gives one row per (dotted) key, anything else is shown as indented JSON;
    - ``*.yaml`` / ``*.yml`` files (e.g. the pipeline's configuration) as text;
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

    Raises
    ------
    ValueError
        ``run_dir`` is not a folder, or ``out`` is outside it without ``embed``.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> run = pathlib.Path(tempfile.mkdtemp())
    >>> _ = (run / "results.csv").write_text("method,snr_db\\nsobolev,31.2\\n")
    >>> page = write_report(run)
    >>> "<td class=\\"num\\">31.2</td>" in page.read_text()
    True
    """
    run = Path(run_dir)
    if not run.is_dir():
        raise ValueError(f"report: {run} is not a folder (give the run folder of a pipeline or a reproduction)")
    target = Path(out) if out is not None else run / REPORT_NAME
    if not embed and not _inside(target.resolve().parent, run.resolve()):
        raise ValueError(f"report: {target} is outside {run}; relative image links would break (use embed=True)")
    files = sorted((p for p in run.rglob("*") if p.is_file() and not p.name.startswith(".")
                    and p.resolve() != target.resolve()), key=lambda p: p.relative_to(run).as_posix())
    parts = [f"<h1>meshdenoise report: {_e(run.resolve().name)}</h1>",
             f"<p class=\"note\">{_e(str(run.resolve()))}, written "
             f"{_e(datetime.now(timezone.utc).strftime('%Y-%m-%d %H:%M UTC'))}</p>"]
    tables = [p for p in files if p.suffix.lower() in (".csv", ".json")]
    configs = [p for p in files if p.suffix.lower() in (".yaml", ".yml")]
    images = [p for p in files if p.suffix.lower() == ".png"]
    others = [p for p in files if p not in tables and p not in configs and p not in images]
    if tables:
        parts.append("<h2>Results</h2>")
        parts += [_table_section(p, run) for p in tables]
    if images:
        parts.append("<h2>Plots and renders</h2>")
        parts += [_figure(p, run, target.parent, embed) for p in images]
    if configs:
        parts.append("<h2>Configuration</h2>")
        parts += [f"<h3>{_e(_rel(p, run))}</h3><pre>{_e(_read_text(p))}</pre>" for p in configs]
    if others:
        parts.append("<h2>Other files</h2><ul>")
        parts += [f"<li><a href=\"{_href(p, target.parent)}\">{_e(_rel(p, run))}</a> "
                  f"<span class=\"note\">({_size(p.stat().st_size)})</span></li>" for p in others]
        parts.append("</ul>")
    if not files:
        parts.append("<p>This folder holds no files yet.</p>")
    page = ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>meshdenoise report: {_e(run.resolve().name)}</title><style>{_STYLE}</style></head>\n<body>\n"
            + "\n".join(parts) + "\n</body></html>\n")
    with atomic_path(target) as tmp:
        tmp.write_text(page, encoding="utf-8")
    return target


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


def _is_number(text) -> bool:
    if isinstance(text, bool):
        return False
    if isinstance(text, (int, float)):
        return True
    try:
        float(str(text))
        return True
    except ValueError:
        return False


def _html_table(header: list, rows: list[list]) -> str:
    cut = len(rows) > MAX_TABLE_ROWS
    head = "".join(f"<th>{_e(h)}</th>" for h in header)
    body = "\n".join(
        "<tr>" + "".join(f"<td class=\"num\">{_e(c)}</td>" if _is_number(c) else f"<td>{_e(c)}</td>" for c in row)
        + "</tr>" for row in rows[:MAX_TABLE_ROWS])
    note = f"<p class=\"note\">first {MAX_TABLE_ROWS} of {len(rows)} rows shown</p>" if cut else ""
    return f"<table><thead><tr>{head}</tr></thead><tbody>\n{body}\n</tbody></table>{note}"


def _table_section(path: Path, run: Path) -> str:
    title = f"<h3>{_e(_rel(path, run))}</h3>"
    try:
        if path.suffix.lower() == ".csv":
            with path.open(newline="", encoding="utf-8", errors="replace") as fh:
                rows = list(csv.reader(fh))
            if not rows:
                return title + "<p class=\"note\">empty file</p>"
            width = max(len(r) for r in rows)
            return title + _html_table(rows[0] + [""] * (width - len(rows[0])), rows[1:])
        data = json.loads(_read_text(path))
    except (json.JSONDecodeError, csv.Error) as exc:
        return title + f"<p class=\"note\">cannot be read as a table ({_e(exc)}); shown as text:</p><pre>{_e(_read_text(path))}</pre>"
    return title + _json_table(data)


def _flatten(obj, prefix: str = "") -> dict:
    """Nested objects as dotted keys; lists of scalars as one comma-separated cell."""
    if isinstance(obj, dict):
        out = {}
        for k, v in obj.items():
            out.update(_flatten(v, f"{prefix}{k}."))
        return out
    if isinstance(obj, list) and all(not isinstance(v, (dict, list)) for v in obj):
        return {prefix[:-1]: ", ".join(str(v) for v in obj)}
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


def _figure(path: Path, run: Path, page_dir: Path, embed: bool) -> str:
    if embed:
        src = "data:image/png;base64," + base64.b64encode(path.read_bytes()).decode("ascii")
    else:
        src = _href(path, page_dir)
    name = _e(_rel(path, run))
    return f"<figure><img src=\"{src}\" alt=\"{name}\" loading=\"eager\"><figcaption>{name}</figcaption></figure>"
