"""Each filter's own automatic rule against held-out vertices sweeping its main parameter, both against the sweep's best.

For every corpus case of a split (``benchmarks/corpus.py``) and every filter named: the mean face-normal
error (degrees) of ``denoise(noisy, method=M)`` with the filter's rule by SURE and the estimated normal risk
(``AutoRule.held_out`` set aside: the rule the held-out choice replaced where it has one), of the value of least held-out
face-normal loss along a sweep of its main parameter (:func:`meshdenoise.tuning.holdout.path_losses`: 3 masks,
radius 1, patience 4; the other parameters at their defaults), and of the sweep's best value by the true
error (the 1-D oracle). Writes the rows as JSON (``--out``); the table is benchmarks/results/held-out-sweeps.md.

Usage::

    python benchmarks/held_out_sweeps.py --split tune --filters filtering,taubin,heat,sobolev --out OUT.json
"""
import json, sys, time, warnings
from pathlib import Path
import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))
warnings.filterwarnings("ignore")
import corpus
import meshdenoise as md
from meshdenoise.registry import get_filter
from meshdenoise.operators import get_operators
from meshdenoise.metrics import normal_error_deg
from meshdenoise.tuning.holdout import holdout, path_losses

GEO = 2 ** (1 / 3)


def grid(lo, hi, ratio=GEO, integer=False):
    v = lo * ratio ** np.arange(int(np.ceil(np.log(hi / lo) / np.log(ratio))) + 1)
    if integer:
        v = np.unique(np.round(v).astype(int))
    return [int(x) if integer else float(x) for x in v]


PATHS = {
    "sobolev_axes": ("mu", {}, grid(0.001, 1e5)),
    "filtering": ("iterations", {}, grid(1, 400, 1.15, True)),
    "taubin": ("iterations", {}, grid(1, 2000, 1.15, True)),
    "heat": ("time", {"tau": 0.1}, [round(0.1*k, 6) for k in grid(1, 5000, 1.15, True)]),
    "sobolev": ("mu", {}, grid(0.01, 1e4)),
    "sobolev_bilaplacian": ("mu", {}, grid(0.001, 1e5)),
    "sobolev_normal": ("mu", {}, grid(0.001, 1e5)),
    "sinkhorn": ("t", {}, grid(0.05, 200)),
    "sobolev_gls": ("mu", {}, grid(0.01, 1e6)),
}


def _without_held_out(name, call):
    """``call()`` with the filter's criterion-normals choice by SURE and the estimated normal risk (its rule without
    ``AutoRule.held_out``): the rule the held-out sweep replaced, measured in the same run."""
    import dataclasses

    from meshdenoise import registry

    spec = registry.REGISTRY[name]
    if spec.auto is None or spec.auto.held_out is None:
        return call()
    registry.REGISTRY[name] = dataclasses.replace(spec, auto=dataclasses.replace(spec.auto, held_out=None))
    try:
        return call()
    finally:
        registry.REGISTRY[name] = spec


def run(spec, V, F, ops, p):
    if spec.name == "sobolev_axes" and "mu" in p:
        mu = p.pop("mu"); p.update(mu1=mu, mu2=mu, mu3=mu)
    return spec.public((V, F), **p, operators=ops)[0]


def main(cases, filters, out, patience=4, rule=True):
    rows = []
    for name in cases:
        c = corpus.load_case(name)
        V0, F, Vn = c["V0"], c["F"], c["Vn"]
        ops = get_operators(F, len(Vn))
        held = holdout(Vn, ops, 1, 3, centres=300)
        e_noisy = normal_error_deg((V0, F), Vn)
        for f in filters:
            spec = get_filter(f)
            pname, fixed, values = PATHS[f]
            # today's rule
            t0 = time.perf_counter()
            try:
                if not rule:
                    raise RuntimeError("not measured (--no-rule)")
                Y, chosen = _without_held_out(f, lambda: md.denoise((Vn, F), method=f, return_params=True,
                                                                     boundary_motion="free"))
                e_auto = normal_error_deg((V0, F), Y[0])
            except Exception as exc:  # noqa
                e_auto, chosen = float("nan"), str(exc)[:80]
            t_auto = time.perf_counter() - t0
            # held-out scan
            t0 = time.perf_counter()

            def path(Y):
                for v in values:
                    yield run(spec, Y, F, ops, {**fixed, pname: v})
            losses = path_losses(path, Vn, F, held, len(values), patience)
            k = int(np.argmin(losses))
            Yh = run(spec, Vn, F, ops, {**fixed, pname: values[k]})
            t_hold = time.perf_counter() - t0
            e_hold = normal_error_deg((V0, F), Yh)
            # 1-D oracle on the same grid (all values until 6 past the minimum)
            errs = []
            for v in values:
                errs.append(normal_error_deg((V0, F), run(spec, Vn, F, ops, {**fixed, pname: v})))
                if len(errs) > 6 and np.argmin(errs) < len(errs) - 6:
                    break
            j = int(np.argmin(errs))
            row = dict(case=name, split=corpus.split(name), filter=f, noisy=e_noisy, auto=e_auto, t_auto=t_auto,
                       chosen=str(chosen), hold=e_hold, t_hold=t_hold, hold_at=values[k], oracle=errs[j],
                       oracle_at=values[j])
            rows.append(row)
            print(f"{name:34s} {f:20s} auto {e_auto/errs[j]:.3f} ({t_auto:.1f}s) hold {e_hold/errs[j]:.3f} "
                  f"({t_hold:.1f}s) at {values[k]:.3g} oracle {errs[j]:.3f} at {values[j]:.3g}", flush=True)
            Path(out).write_text(json.dumps(rows, indent=1))


def table(paths: list) -> str:
    """Markdown: per filter and split, the geometric mean of each choice's error over its sweep's best and the share
    within 10 % (a row's rule column over the cases where it was measured)."""
    rows = [r for p in paths for r in json.loads(Path(p).read_text())]
    out = ["| filter | split | cases | its rule | within 10 % | held-out sweep | within 10 % | worst |",
           "|---|---|---|---|---|---|---|---|"]
    keys = sorted({(r["filter"], r["split"]) for r in rows}, key=lambda k: (k[1] != "tune", k[0]))
    for f, split in keys:
        sel = [r for r in rows if (r["filter"], r["split"]) == (f, split)]
        hold = np.array([r["hold"] / r["oracle"] for r in sel])
        rule = np.array([r["auto"] / r["oracle"] for r in sel if np.isfinite(r["auto"])])
        ruled = (f"{np.exp(np.mean(np.log(rule))):.3f} ({rule.size}) | {100 * np.mean(rule <= 1.1):.0f} %"
                 if rule.size else "- | -")
        out.append(f"| {f} | {split} | {len(sel)} | {ruled} | {np.exp(np.mean(np.log(hold))):.3f} | "
                   f"{100 * np.mean(hold <= 1.1):.0f} % | {hold.max():.2f} |")
    return "\n".join(out) + "\n"


if __name__ == "__main__":
    import argparse
    ap = argparse.ArgumentParser()
    ap.add_argument("--split", default="tune")
    ap.add_argument("--filters", default="filtering,taubin,heat,sobolev,sobolev_bilaplacian")
    ap.add_argument("--limit", type=int, default=100)
    ap.add_argument("--patience", type=int, default=4, help="steps of the sweep read past its least held-out loss")
    ap.add_argument("--no-rule", action="store_true", help="do not run the filter's own rule")
    ap.add_argument("--table", nargs="+", metavar="JSON", help="write the markdown table of these runs' rows to --out")
    ap.add_argument("--out", default="held-out-sweeps.json")
    a = ap.parse_args()
    if a.table:
        Path(a.out).write_text(table(a.table))
        raise SystemExit(0)
    names = [n for n in corpus.CASES if corpus.split(n) == a.split][: a.limit]
    main(names, a.filters.split(","), a.out, a.patience, not a.no_rule)
