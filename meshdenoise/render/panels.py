"""The picture file: panels pasted pixel for pixel in a row or a grid, titles, the colour bar, the PNG's mode."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Sequence

import numpy as np

from ..io import atomic_path

__all__ = ["panel_grid", "new_file_mode"]

TITLE_BAND = 40  # pixels above each row of panels for titles
BAR_BAND = 110  # pixels right of the panels for the colour bar
GAP = 8  # pixels between panels in a row
MAX_PER_ROW = 4  # panels in a row before they go into a grid


def panel_grid(n_geometry: int, under: Sequence[int]) -> list[tuple[int, int]]:
    """(row, column) of each panel: the geometry panels, then one heat map per index in ``under``.

    Up to :data:`MAX_PER_ROW` panels in all stand in one row (before / after / error). More
    go into a grid of at most :data:`MAX_PER_ROW` columns: the meshes in the first rows, then
    each heat map under the mesh it colours (``under[j]`` is that mesh's geometry panel), so
    the first mesh of a change map has an empty place below it.

    Examples
    --------
    >>> panel_grid(2, [1])
    [(0, 0), (0, 1), (0, 2)]
    >>> panel_grid(4, [1, 2, 3])
    [(0, 0), (0, 1), (0, 2), (0, 3), (1, 1), (1, 2), (1, 3)]
    >>> panel_grid(5, [4])
    [(0, 0), (0, 1), (0, 2), (0, 3), (1, 0), (2, 0)]
    """
    if n_geometry + len(under) <= MAX_PER_ROW:
        return [(0, k) for k in range(n_geometry + len(under))]
    cols = min(MAX_PER_ROW, max(n_geometry, 1))
    places = [divmod(k, cols) for k in range(n_geometry)]
    first_heat_row = -(-n_geometry // cols)
    heat_rows = sorted({m // cols for m in under})  # only rows holding a heat map, packed
    return places + [(first_heat_row + heat_rows.index(m // cols), m % cols) for m in under]


def _compose(out_png: Path, panels, titles, errors, vmax, cmap, label, percentile,
             under: Sequence[int] | None = None) -> list[tuple[int, int, int, int]]:
    """Paste the panels pixel for pixel (``figimage``, no resampling) in :func:`panel_grid`'s places, with
    titles and a colour bar right of the heat maps."""
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.colorbar import ColorbarBase
    from matplotlib.colors import Normalize
    from matplotlib.figure import Figure
    from matplotlib.ticker import FuncFormatter

    h, w = panels[0].shape[:2]
    n_geometry = len(panels) - len(errors)
    if under is None:
        under = [n_geometry - len(errors) + j for j in range(len(errors))]
    places = panel_grid(n_geometry, list(under))
    n_rows = max(r for r, _ in places) + 1
    n_cols = max(c for _, c in places) + 1
    grid_w = n_cols * w + (n_cols - 1) * GAP
    width = grid_w + (BAR_BAND if errors else 0)
    height = n_rows * (h + TITLE_BAND)
    fig = Figure(figsize=(width / 100.0, height / 100.0), dpi=100, facecolor="white")
    FigureCanvasAgg(fig)
    boxes = []
    for k, (img, title, (r, c)) in enumerate(zip(panels, titles, places)):
        x0, top = c * (w + GAP), r * (h + TITLE_BAND)
        fig.figimage(img, xo=x0, yo=height - top - TITLE_BAND - h, origin="upper")
        boxes.append((top + TITLE_BAND, x0, h, w))
        lines = [title.replace("$", r"\$")]  # a file name is text, never mathtext
        if k >= n_geometry:
            e = errors[k - n_geometry]
            lines.append(f"max {e.max():.3g}, RMS {np.sqrt(np.mean(e**2)):.3g}")
        fig.text((x0 + w / 2) / width, 1 - (top + 4) / height, "\n".join(lines), ha="center", va="top",
                 fontsize=9, wrap=False, clip_on=True)
    if errors:
        rows = [r for r, _ in places[n_geometry:]]
        top = min(rows) * (h + TITLE_BAND) + TITLE_BAND  # the bar spans the rows of heat maps
        span = (max(rows) + 1) * (h + TITLE_BAND) - top
        cax = fig.add_axes([(grid_w + 4) / width, (height - top - 0.92 * span) / height,
                            14 / width, 0.84 * span / height])
        over = any(float(e.max()) > vmax for e in errors)
        bar = ColorbarBase(cax, cmap=matplotlib.colormaps[cmap], norm=Normalize(0.0, vmax),
                           extend="max" if over else "neither")
        bar.ax.tick_params(labelsize=8)
        bar.ax.yaxis.set_major_formatter(FuncFormatter(lambda x, _: f"{x:.3g}"))  # no offset text to clip
        top = "maximum" if percentile is None or percentile >= 100 else f"{_ordinal(percentile)} percentile"
        if percentile is None:
            top = "given vmax"
        bar.set_label(f"{label}\n(mesh units), top = {top}", fontsize=7)
    with atomic_path(out_png) as tmp:
        fig.savefig(tmp, dpi=100, format="png", facecolor="white")
    return boxes


def _ordinal(p: float) -> str:
    """'99th', '95th', '99.5th', '1st', '2nd', '3rd', '12th'."""
    text = f"{p:g}"
    if not float(p).is_integer():
        return text + "th"
    n = int(p)
    suffix = "th" if 10 <= n % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(n % 10, "th")
    return f"{n}{suffix}"


def new_file_mode(path: str | os.PathLike) -> int:
    """The permission bits an output written to ``path`` gets: the replaced file's, else 0666 minus the umask.

    As :class:`meshdenoise.io.atomic_path` gives every output (a temporary file from
    ``mkstemp`` is private, 0600, and would keep that mode through the rename).
    """
    from ..io import _UMASK

    path = Path(path)
    return path.stat().st_mode & 0o7777 if path.exists() else 0o666 & ~_UMASK
