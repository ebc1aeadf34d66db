"""Text as the page shows it: numbers rounded, text escaped for HTML, paths named short, relative URLs."""

from __future__ import annotations

import html
import math
import os
import re
from pathlib import Path
from urllib.parse import quote

SIGNIFICANT = 4  # significant digits of a number shown in a table (the full value is its tooltip)


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


def _e(text) -> str:
    return html.escape(str(text), quote=True)


def _breakable(text) -> str:
    """Escaped text with break opportunities after ``_ / . , = -`` (long names wrap there, not mid-word)."""
    return re.sub(r"([_/.,=\-])", r"\1<wbr>", _e(text))


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


def _natural(text: str) -> list:
    """Sort key with runs of digits compared as numbers: ``a_2`` before ``a_10``."""
    return [(0, int(t), "") if t.isdigit() else (1, 0, t) for t in re.split(r"(\d+)", text)]


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
