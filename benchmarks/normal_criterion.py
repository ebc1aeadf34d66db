"""Each linear filter's automatic choice under the "normals" criterion against its own normal-error oracle.

For every row of the peers table and every filter of :func:`meshdenoise.tuning.choose.normal_filters`,
``denoise(mesh, method=M)`` (no clean mesh; its criterion is ``"normals"``) is run in a
process of its own and its mean face-normal error compared with the filter's oracle measured by
``benchmarks/filter_oracle.py`` (the least error over the rule's parameters, read from ``--oracles``,
by default benchmarks/results/filter-oracle.json; where the new choice beats that oracle, the choice is the oracle: ratio 1).
The position-SURE choice of the same table is shown beside it.

    PYTHONPATH=. python benchmarks/normal_criterion.py --out benchmarks/results/normal-criterion.md
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from tables import grid_lines  # noqa: E402

TARGET = 1.10  # issue 22: within 10 % of the filter's oracle
ORACLES = HERE / "results" / "filter-oracle.json"


def run_cell(row: str, name: str, timeout: float) -> dict:
    """``peers.run_ours(name)`` on ``row`` in a fresh process: its quality, parameters and time."""
    code = ("import json, sys; sys.path.insert(0, %r); from peers import MESHES, run_ours; m = MESHES[%r](); "
            "print(json.dumps(run_ours(%r, m['V0'], m['F'], m['Vn'])))" % (str(HERE), row, name))
    env = {**os.environ, "PYTHONPATH": str(HERE.parent) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    try:
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout, env=env)
    except subprocess.TimeoutExpired:
        return {"error": f"timeout after {timeout:.0f} s"}
    if out.returncode != 0:
        return {"error": (out.stderr.strip().splitlines() or ["exit %d" % out.returncode])[-1]}
    return json.loads(out.stdout.strip().splitlines()[-1])


def ratio(ne: float, oracle: float) -> float:
    """``ne`` over the oracle, 1 where the choice beats the stored oracle (it is then the best known)."""
    return max(ne / oracle, 1.0)


def table(cells: list[dict], command: str, note: str = "") -> str:
    rows = list(dict.fromkeys(c["row"] for c in cells))
    filters = list(dict.fromkeys(c["filter"] for c in cells))
    by = {(c["row"], c["filter"]): c for c in cells}
    lines = [f"# Linear filters' automatic choice, criterion \"normals\", against each filter's oracle\n",
             f"Command: `{command}`\n" + (f"\n{note}\n" if note else ""),
             "Cell: normal error of `denoise(mesh, method=M)` (deg) / its oracle's (`benchmarks/filter_oracle.py`: "
             "`benchmarks/results/filter-oracle.json`, or the files the command's `--oracles` names) = ratio; in "
             "brackets the position-SURE choice's ratio (from the same file). "
             "**Bold**: outside 10 %.\n",
             "| filter | " + " | ".join(rows) + " |", "|---|" + "---|" * len(rows)]
    def ratio_cell(c: dict) -> str:
        cell = f"{c['ne']:.2f} / {c['oracle_ne']:.2f} = {c['ratio']:.3f} ({c['sure_ratio']:.3f})"
        return f"**{cell}**" if c["ratio"] > TARGET else cell

    lines += grid_lines(by, rows, filters, ratio_cell)
    done = [c for c in cells if "error" not in c]
    inside = sum(c["ratio"] <= TARGET for c in done)
    lines.append(f"\n{inside} of {len(done)} cells within 10 % (position SURE: "
                 f"{sum(c['sure_ratio'] <= TARGET for c in done)} of the same cells).\n")
    lines.append("SNR (dB) and time (s, one call, choice and filter) of the normals choice, SNR of the SURE choice:\n")
    lines.append("| filter | " + " | ".join(rows) + " |")
    lines.append("|---|" + "---|" * len(rows))
    for f in filters:
        out = []
        for r in rows:
            c = by.get((r, f))
            out.append("" if c is None or "error" in c else f"{c['snr']:.2f} ({c['sure_snr']:.2f}), {c['time']:.1f} s")
        lines.append(f"| {f} | " + " | ".join(out) + " |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    from meshdenoise.tuning.choose import normal_filters

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", nargs="*", default=None)
    ap.add_argument("--filters", nargs="*", default=None)
    ap.add_argument("--oracles", nargs="+", default=[str(ORACLES)],
                    help="benchmarks/filter_oracle.py JSON files; a later file's cell replaces an earlier one's")
    ap.add_argument("--timeout", type=float, default=900.0)
    ap.add_argument("--out", required=True)
    ap.add_argument("--keep", action="store_true",
                    help="keep the cells of OUT's JSON that this run does not measure (--rows x --filters)")
    ap.add_argument("--note", default="", help="a line under the command (what else made the table)")
    a = ap.parse_args(argv)
    stored = {(c["row"], c["filter"]): c for path in a.oracles for c in json.loads(Path(path).read_text())
              if "oracle" in c}
    filters = a.filters or normal_filters()
    rows = a.rows or list(dict.fromkeys(r for r, _ in stored))
    out = Path(a.out)
    kept = {}
    if a.keep and out.with_suffix(".json").exists():
        kept = {(c["row"], c["filter"]): c for c in json.loads(out.with_suffix(".json").read_text())}
    measured = {}
    for r in rows:
        for f in filters:
            old = stored.get((r, f))
            if old is None:
                continue
            got = run_cell(r, f, a.timeout)
            cell = {"row": r, "filter": f}
            if "error" in got:
                cell["error"] = got["error"]
            else:
                oracle = old["oracle"]["ne"]
                cell.update(ne=got["normal_error_deg"], snr=got["snr_db"], time=got["time_s"], params=got["params"],
                            oracle_ne=oracle, ratio=ratio(got["normal_error_deg"], oracle), sure_ne=old["auto"]["ne"],
                            sure_snr=old["auto"]["snr"], sure_ratio=old["ratio"])
            measured[(r, f)] = cell
            print(json.dumps(cell), flush=True)
    cells = list({**kept, **measured}.values())  # a kept cell keeps its place; new ones follow
    command = "PYTHONPATH=. python benchmarks/normal_criterion.py " + " ".join(shlex.quote(x) for x in (argv or sys.argv[1:]))
    for path, text in ((out.with_suffix(".json"), json.dumps(cells, indent=1)), (out, table(cells, command, a.note))):
        tmp = path.with_name(path.name + ".tmp")  # never a half-written table
        tmp.write_text(text)
        tmp.replace(path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
