"""Each filter's automatic choice, timed: ``denoise(mesh, method=M)`` in a fresh process per cell.

Issue 22's target: automatic choices in time comparable to one peer call, under 3 s per mesh of 50,000
vertices on 2 cores. Per (row, filter) cell one process runs :func:`peers.run_ours` (the choice and the
filter, one call, cold: compiled kernels loaded from numba's cache, nothing memoised) and the table gives the
call's wall seconds and its limit, 3 s for a mesh of up to 50,000 vertices and proportionally more above
(:func:`limit`); **bold** over it. Run a cell of each filter once before timing from a new checkout: numba's cache
is per source path, and the first process compiles. The default
(``denoise(mesh)``) is the ``default`` column's filter. Rows: :data:`peers.MESHES`; filters: every filter with an
automatic rule.

    PYTHONPATH=. python benchmarks/filter_time.py --out benchmarks/results/filter-time.md
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from tables import grid_lines, write_table  # noqa: E402

TARGET = 3.0  # seconds for a mesh of 50,000 vertices ...
PER = 50_000


def limit(vertices: int) -> float:
    """Issue 22's time for a mesh of ``vertices``: ``TARGET`` up to ``PER`` vertices, proportionally more above.

    >>> limit(299), limit(50_000), limit(85_182)
    (3.0, 3.0, 5.11092)
    """
    return TARGET * max(1.0, vertices / PER)


def table(cells: list[dict], command: str, note: str = "") -> str:
    """The markdown table of ``cells`` (dicts with row, filter, vertices, time_s or error)."""
    rows = list(dict.fromkeys(c["row"] for c in cells))
    filters = list(dict.fromkeys(c["filter"] for c in cells))
    by = {(c["row"], c["filter"]): c for c in cells}
    sizes = {c["row"]: c["vertices"] for c in cells if "vertices" in c}
    lines = ["# Each filter's automatic choice, timed (one cold call: choice and filter)\n",
             f"Command: `{command}`\n" + (f"\n{note}\n" if note else ""),
             "Cell: wall seconds of `denoise(mesh, method=M)` in a fresh process (`default`: `denoise(mesh)`), one "
             f"call, choice and filter. Limit (issue 22): {TARGET:g} s for a mesh of up to {PER:,} vertices, "
             "proportionally more above (in the header). **Bold**: over it.\n",
             "| filter | " + " | ".join(f"{r} ({sizes.get(r, 0):,}; {limit(sizes.get(r, 0)):.1f} s)" for r in rows) + " |",
             "|---|" + "---|" * len(rows)]
    lines += grid_lines(by, rows, filters, lambda c: f"{c['time_s']:.2f}" if c["time_s"] <= limit(c["vertices"])
                        else f"**{c['time_s']:.2f}**")
    done = [c for c in cells if "error" not in c]
    met, total = sum(c["time_s"] <= limit(c["vertices"]) for c in done), len(done)
    lines.append(f"\n{met} of {total} cells within their limit.\n")
    return "\n".join(lines)


def main() -> None:
    from normal_criterion import run_cell
    from peers import DEFAULT_MESHES, MESHES, our_methods

    _main(run_cell, DEFAULT_MESHES, MESHES, our_methods)


def _main(run_cell, default_meshes, meshes, our_methods) -> None:

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", nargs="*", default=None)
    ap.add_argument("--filters", nargs="*", default=None, help="filters; 'default' for denoise(mesh)")
    ap.add_argument("--timeout", type=float, default=600.0)
    ap.add_argument("--note", default="")
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    rows = a.rows or default_meshes
    filters = a.filters or ["default", *our_methods()]
    load = os.getloadavg()
    cells = []
    for row in rows:
        n = len(meshes[row]()["Vn"])
        for f in filters:
            got = run_cell(row, None if f == "default" else f, a.timeout)
            cell = {"row": row, "filter": f, "vertices": n, **({"error": got["error"]} if "error" in got else
                                                                {"time_s": got["time_s"], "params": got["params"]})}
            cells.append(cell)
            print(json.dumps(cell), flush=True)
    command = "PYTHONPATH=. python benchmarks/filter_time.py " + " ".join(shlex.quote(x) for x in sys.argv[1:])
    note = (a.note + " " if a.note else "") + f"Load average at the start {load[0]:.2f}, at the end {os.getloadavg()[0]:.2f}."
    out = Path(a.out)
    write_table(out, [table(cells, command, note)])
    write_table(out.with_suffix(".json"), [json.dumps(cells, indent=1)])


if __name__ == "__main__":
    main()
