"""Each output mesh before / after / change: drawn by :func:`meshdenoise.render.render_comparison`, kept while newer
than its meshes."""

from __future__ import annotations

import base64
import re
import tempfile
import warnings
from pathlib import Path

from ..io import SUPPORTED_EXTENSIONS
from .sweeps import _is_swept
from .text import _breakable, _e, _href, _short_names

RENDER_PANEL = (260, 260)  # pixels of one before / after / change panel: the picture is 906 x 300
MAX_RENDERS = 24  # outputs drawn before / after / change; the page says when there are more


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
    from ..render import render_comparison

    png.parent.mkdir(parents=True, exist_ok=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        render_comparison([before, after], png, titles=["before", "after"], size=RENDER_PANEL, view="facing",
                          show_change=True, backend="matplotlib")


def _png_size(path: Path) -> tuple[int, int]:
    import struct

    head = path.read_bytes()[:24]
    return struct.unpack(">II", head[16:24])
