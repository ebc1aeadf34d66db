"""Two commits' automatic choices timed in turn: per cell, fresh processes alternating between the codes.

A shared machine's speed drifts by 10 to 30 % within an hour (measured on the project's 2 cores: benchmarks/results/filter-time-ab.md): two
codes timed one after the other can differ by the drift alone. Here each code runs from a git worktree of its
commit, and each cell's calls alternate between them (base, new, base, new, ...), so both see the same machine.
A call is ``benchmarks/filter_time.py --rows ROW --filters F`` in a fresh process (``denoise(mesh, method=F)``, the
choice and the filter; ``default``: ``denoise(mesh)``). numba's cache is per source path, so each worktree first
runs every filter asked for on ``--warm-rows`` once, untimed (``--no-warm`` skips it). Per cell: each call's seconds
and parameters, the min and median per code, whether the two codes chose the same parameters, and each code's count
of cells within issue 22's limit.

    PYTHONPATH=. python benchmarks/filter_time_ab.py --base 063bc8e --new HEAD --repeats 4 \\
        --cells "elephant rho=0.2:sobolev_gls" "bunny scanner:sobolev_gls" --out benchmarks/results/filter-time-ab.md
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))

from filter_time import limit  # noqa: E402
from tables import write_table  # noqa: E402


def parse_cell(text: str) -> tuple[str, str]:
    """``"ROW:FILTER"`` -> ``(row, filter)`` (the row's name may hold spaces, not the filter's).

    >>> parse_cell("elephant rho=0.2:sobolev_gls")
    ('elephant rho=0.2', 'sobolev_gls')
    """
    row, sep, name = text.rpartition(":")
    if not sep or not row or not name:
        raise argparse.ArgumentTypeError(f"a cell is ROW:FILTER, got {text!r}")
    return row, name


def call(tree: Path, row: str, name: str, timeout: float) -> dict:
    """One fresh process of ``filter_time.py`` in worktree ``tree`` on one cell: its json record."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "cell.md"
        subprocess.run([sys.executable, "benchmarks/filter_time.py", "--timeout", str(timeout), "--rows", row,
                        "--filters", name, "--out", str(out)], cwd=tree, env={**os.environ, "PYTHONPATH": str(tree)},
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True)
        return json.loads(out.with_suffix(".json").read_text())[0]


def summary(records: list[dict], codes: tuple[str, str], cells: list[tuple[str, str]], command: str) -> str:
    """The markdown table: per cell, each code's min / median seconds (calls; **bold** over issue 22's limit,
    :func:`filter_time.limit`), and whether the parameters agree; then each code's count of cells within the limit
    by its fastest and by its median call."""
    lines = ["# Two codes' automatic choices, timed in turn\n", f"Command: `{command}`\n",
             "Cell: wall seconds of one fresh call `denoise(mesh, method=F)` (choice and filter), the codes' calls "
             "alternating; min / median over the calls (their count). **Bold**: over issue 22's limit (3 s up to "
             "50,000 vertices, proportionally more above).\n",
             f"| cell | {codes[0]} | {codes[1]} | same parameters |", "|---|---|---|---|"]
    within = {code: [0, 0] for code in codes}
    counted = 0
    for row, name in cells:
        got = {code: [r for r in records if r["code"] == code and r["row"] == row and r["filter"] == name]
               for code in codes}
        text = []
        for code in codes:
            times = [r["time_s"] for r in got[code] if "time_s" in r]
            if not times:
                text.append("error")
                continue
            cap = limit(got[code][0]["vertices"])
            best, median = min(times), statistics.median(times)
            within[code][0] += best <= cap
            within[code][1] += median <= cap
            bold = lambda t: f"**{t:.2f}**" if t > cap else f"{t:.2f}"  # noqa: E731
            text.append(f"{bold(best)} / {bold(median)} ({len(times)})")
        counted += 1
        params = [json.dumps(r.get("params"), sort_keys=True) for code in codes for r in got[code]]
        lines.append(f"| {row}: `{name}` | {text[0]} | {text[1]} | {'yes' if len(set(params)) == 1 else 'no'} |")
    lines.append("")
    for code in codes:
        lines.append(f"{code}: {within[code][0]} of {counted} cells within their limit by the fastest call, "
                     f"{within[code][1]} by the median.")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", required=True, help="the commit compared against")
    ap.add_argument("--new", default="HEAD")
    ap.add_argument("--cells", nargs="+", type=parse_cell, default=None,
                    help='"ROW:FILTER" (FILTER default: denoise(mesh)); default every row and filter of filter_time.py')
    ap.add_argument("--warm-rows", nargs="+", default=["Fandisk0.3", "face000 scanner"],
                    help="rows whose cells (every filter asked for) run once per worktree before timing: numba compiles")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--timeout", type=float, default=900.0)
    ap.add_argument("--no-warm", action="store_true")
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    if a.repeats < 1:
        ap.error(f"--repeats must be >= 1, got {a.repeats}")
    if a.cells is None:
        from peers import DEFAULT_MESHES, our_methods

        a.cells = [(row, name) for row in DEFAULT_MESHES for name in ["default", *our_methods()]]
    codes = tuple(subprocess.run(["git", "rev-parse", "--short", f"{rev}^{{commit}}"], cwd=ROOT, check=True,
                                 capture_output=True, text=True).stdout.strip() for rev in (a.base, a.new))
    records: list[dict] = []
    with tempfile.TemporaryDirectory(prefix="filter-time-ab-") as tmp:
        trees = {}
        try:
            for code, label in zip(codes, ("base", "new")):
                trees[code] = Path(tmp) / label
                subprocess.run(["git", "worktree", "add", "--detach", "-q", str(trees[code]), code], cwd=ROOT, check=True)
            if not a.no_warm:
                names = list(dict.fromkeys(name for _, name in a.cells))
                for code in codes:
                    subprocess.run([sys.executable, "benchmarks/filter_time.py", "--timeout", str(a.timeout), "--rows",
                                    *a.warm_rows, "--filters", *names, "--out", str(Path(tmp) / "warm.md")],
                                   cwd=trees[code], env={**os.environ, "PYTHONPATH": str(trees[code])},
                                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True)
            for repeat in range(a.repeats):
                for row, name in a.cells:
                    for code in codes:
                        record = {"code": code, "repeat": repeat, **call(trees[code], row, name, a.timeout)}
                        records.append(record)
                        print(json.dumps(record), flush=True)
        finally:
            for tree in trees.values():
                subprocess.run(["git", "worktree", "remove", "--force", str(tree)], cwd=ROOT, check=False)
    command = "PYTHONPATH=. python benchmarks/filter_time_ab.py " + " ".join(shlex.quote(x) for x in sys.argv[1:])
    out = Path(a.out)
    write_table(out, [summary(records, codes, a.cells, command)])
    write_table(out.with_suffix(".json"), [json.dumps(records, indent=1)])


if __name__ == "__main__":
    main()
