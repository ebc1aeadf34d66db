"""``two_stage``'s automatic rule on the corpus against the best of its sweeps, and the rule it replaced.

For every corpus case of a split (``benchmarks/corpus.py``): the mean face-normal error (degrees) of
``denoise(noisy, method="two_stage")`` (column ``rule``: the rule of the checkout the script runs in, so
run at a commit before the held-out rule, 6339954, it measures the search by SURE that rule replaced), of
the held-out choice over the default's candidate families (``meshdenoise.policy.choose``: what the rule
chooses since), and the least error along those families' runs (``oracle``, 60 outer iterations each).
Rows go to ``--out`` (JSON; a run resumes from it); ``--table`` writes the markdown of runs' rows.

Usage::

    python benchmarks/two_stage_rule.py --split tune --out tune.json
    python benchmarks/two_stage_rule.py --table tune.json check.json --out table.md
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(os.environ.get("ROOT", Path(__file__).resolve().parent.parent))  # the checkout measured
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT))


def measure(split: str, out: Path) -> None:
    warnings.filterwarnings("ignore")
    import corpus
    import meshdenoise as md
    from meshdenoise.metrics import normal_error_deg
    from meshdenoise.operators import get_operators
    from meshdenoise.policy.choose import choose
    from meshdenoise.policy.config import FAMILIES, DefaultConfig
    from meshdenoise.policy.paths import family_path

    rows = json.loads(out.read_text()) if out.exists() else []
    done = {r["case"] for r in rows}
    for name in [n for n in corpus.CASES if corpus.split(n) == split and n not in done]:
        c = corpus.load_case(name)
        V0, F, Vn = c["V0"], c["F"], c["Vn"]
        ops = get_operators(F, len(Vn))
        t0 = time.perf_counter()
        try:
            Y, p = md.denoise((Vn, F), method="two_stage", return_params=True, boundary_motion="free")
            e_rule = normal_error_deg((V0, F), Y[0])
        except Exception as exc:  # noqa: BLE001  (a failed rule is a row, not the end of the run)
            e_rule, p = float("nan"), str(exc)[:80]
        t_rule = time.perf_counter() - t0
        t0 = time.perf_counter()
        chosen = choose(Vn, F, ops, DefaultConfig())
        t_held = time.perf_counter() - t0
        errs = {f.label: [normal_error_deg((V0, F), X) for X in family_path(f, F, ops, 60)(Vn)] for f in FAMILIES}
        best = min(min(e) for e in errs.values())
        if chosen.method == "none":
            e_held = normal_error_deg((V0, F), Vn)
        else:
            family = next(f for f in FAMILIES if f.params(1) == {**chosen.params, "iterations": 1})
            e_held = errs[family.label][chosen.params["iterations"] - 1]
        rows.append(dict(case=name, split=split, n=len(Vn), rule=e_rule, t_rule=t_rule, rule_params=str(p),
                         held=e_held, t_held=t_held, held_params=str(chosen.params), oracle=best,
                         noisy=normal_error_deg((V0, F), Vn)))
        print(f"{name:36s} rule {e_rule / best:.3f} ({t_rule:.1f} s) held-out {e_held / best:.3f} ({t_held:.1f} s)",
              flush=True)
        out.write_text(json.dumps(rows, indent=1))


def table(paths: list[Path]) -> str:
    """Per split: geometric mean of each choice's error over the families' best, share within 10 %, worst, median time."""
    rows = [r for p in paths for r in json.loads(p.read_text())]
    out = ["| split | cases | rule | within 10 % | worst | median s | held-out | within 10 % | worst | median s |",
           "|---|---|---|---|---|---|---|---|---|---|"]
    for split in ("tune", "check"):
        sel = [r for r in rows if r["split"] == split]
        if not sel:
            continue
        cells = []
        for key in ("rule", "held"):
            x = np.array([r[key] / r["oracle"] for r in sel])
            t = float(np.median([r[f"t_{key}"] for r in sel]))
            cells.append(f"{np.exp(np.mean(np.log(x))):.3f} | {100 * np.mean(x <= 1.1):.0f} % | {x.max():.2f} | {t:.1f}")
        out.append(f"| {split} | {len(sel)} | " + " | ".join(cells) + " |")
    return "\n".join(out) + "\n"


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--split", default="tune", choices=("tune", "check"))
    ap.add_argument("--table", nargs="+", type=Path, metavar="JSON", help="write the markdown of these runs to --out")
    ap.add_argument("--out", type=Path, default=Path("two-stage-rule.json"))
    a = ap.parse_args()
    if a.table:
        a.out.write_text(table(a.table))
    else:
        measure(a.split, a.out)
