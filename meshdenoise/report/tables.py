"""The results as HTML tables: one per CSV or JSON file, cut into several when wider than the page."""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path

from .charts import _charts
from .sweeps import _is_swept
from .text import _breakable, _e, _href, _inside, _number, _read_text, _rel, _short_names, format_number

MAX_TABLE_ROWS = 2000  # beyond this a table is cut, and the page says so

# How wide a table may be, and how wide its columns are at the least, estimated from their text: a
# character of the table's font (0.9 em of 16 px; DejaVu Sans digits are 0.64 em, bold capitals
# wider) takes at most CHAR_PX, a cell's padding and border CELL_PX. The page's text is 1152 px wide
# in a 1280-pixel window.
TABLE_PX = 1120
CHAR_PX = 10.0
CELL_PX = 20

SHORT = 16  # text cells up to this many characters never wrap
_BREAKS = re.compile(r"(?<=[_/.,=\- ])")


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
