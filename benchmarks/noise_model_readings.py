"""Record the noise model's readings (and the default's noise step) to JSON, or compare two such records field by field.

For a change meant to leave the estimates alone: record
before and after, then compare; every float is kept as its ``repr``, so "0 differences" means bit for bit.

Usage::

    python benchmarks/noise_model_readings.py record small OUT.json        # 28 small cases (about 2 minutes idle)
    python benchmarks/noise_model_readings.py record scale OUT.json        # the 400k and 1.6M scale meshes
    python benchmarks/noise_model_readings.py record small OUT.json --detail   # also separate_detail((V, F)) alone
    python benchmarks/noise_model_readings.py compare BEFORE.json AFTER.json

``small``: icosphere(5), the paper's elephant, pymeshlab's bunny, Fandisk0.3, Bunny0.2 and the smoothed face000
(``benchmarks/noise_model_grid.py``'s meshes) with scanner noise sigma 0.25 h at l = 0 and 2, 1 h at l = 0 and 0.5 h at
l = 3 (not for face and Bunny0.2), seed 1; and the peers benchmark's noisy meshes (``benchmarks/peers.py``). Each case:
``estimate_noise_model(details=True, spectrum=(DETAIL_BANDS, DETAIL_LENGTHS))`` and ``default_noise``. ``scale``:
``estimate_noise_model`` on ``~/.cache/meshdenoise/scale/elephant-o3dloop{2,3}.npz`` (``benchmarks/scale.py`` makes them).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT.parent))

SMALL_MESHES = ["icosphere", "elephant", "bunny", "Fandisk0.3", "Bunny0.2", "face"]
NOISE = [(0.25, 0.0), (0.25, 2.0), (1.0, 0.0), (0.5, 3.0)]
PEERS = ["bunny scanner", "face000 scanner", "Bunny0.2", "Fandisk0.3", "Block0.4", "Twelve0.5Impulsive"]


def plain(x):
    """JSON-ready, every float as its repr (exact)."""
    if isinstance(x, dict):
        return {k: plain(v) for k, v in x.items() if k != "smooth"}
    if isinstance(x, (list, tuple)):
        return [plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return plain(x.tolist()) if x.ndim else repr(float(x))
    if isinstance(x, (float, np.floating)):
        return repr(float(x))
    if isinstance(x, np.integer):
        return int(x)
    return x


def record_case(V: np.ndarray, F: np.ndarray, policy: bool, detail: bool) -> dict:
    import meshdenoise.default as default
    from meshdenoise.noise import mean_edge_length
    from meshdenoise.tuning.covariance import estimate_noise_model
    from meshdenoise.tuning.detail import separate_detail

    t = time.perf_counter()
    model, info = estimate_noise_model((V, F), details=True, spectrum=(default.DETAIL_BANDS, default.DETAIL_LENGTHS))
    out = {"rho": repr(model.rho), "ell": repr(model.correlation_length), "info": plain(info),
           "t_band": time.perf_counter() - t}
    if policy:
        t = time.perf_counter()
        m, reason, _, decided, allowed = default.default_noise(V, F, mean_edge_length(V, F))
        out.update(policy_rho=repr(m.rho), policy_ell=repr(m.correlation_length), decided=decided, reason=reason,
                   allowed=plain(allowed), t_policy=time.perf_counter() - t)
    if detail:
        t = time.perf_counter()
        v = separate_detail((V, F))
        out.update(detail=plain({k: x for k, x in v.as_dict().items()}), t_detail=time.perf_counter() - t)
    return out


def record(part: str, path: str, detail: bool) -> None:
    warnings.simplefilter("ignore")
    res = {}

    def run(name: str, V: np.ndarray, F: np.ndarray, policy: bool = True) -> None:
        res[name] = record_case(V, F, policy, detail and policy)
        r = res[name]
        print(f"{name}: rho {r['rho']} l {r['ell']} default {r.get('policy_rho')} l {r.get('policy_ell')} "
              f"{r.get('decided', '')} ({r['t_band']:.2f} s)", flush=True)

    if part == "small":
        import peers
        from noise_model_grid import load, noisy

        for mesh in SMALL_MESHES:
            V0, F = load(mesh)
            for sigma, ell in NOISE:
                if mesh in ("face", "Bunny0.2") and (sigma, ell) == (0.5, 3.0):
                    continue
                run(f"{mesh} {sigma:g} {ell:g}", noisy(V0, F, sigma, ell, 1), F)
        for name in PEERS:
            m = peers.MESHES[name]()
            run("peers " + name, m["Vn"], m["F"])
    elif part == "scale":
        for level in (2, 3):
            d = np.load(Path.home() / ".cache/meshdenoise/scale" / f"elephant-o3dloop{level}.npz")
            run(f"scale level {level}", d["Vn"], d["F"], policy=False)
    else:
        raise SystemExit(f"record: unknown part {part!r} (small or scale)")
    Path(path).write_text(json.dumps(res, indent=1))


def compare(before: str, after: str) -> int:
    a, b = json.loads(Path(before).read_text()), json.loads(Path(after).read_text())
    diffs = []

    def walk(x, y, where: str) -> None:
        if isinstance(x, dict):
            if not isinstance(y, dict):
                diffs.append((where, x, y))
                return
            for k in sorted(set(x) | set(y)):
                if not k.startswith("t_"):
                    walk(x.get(k), y.get(k), f"{where}/{k}")
        elif isinstance(x, list):
            if not isinstance(y, list) or len(x) != len(y):
                diffs.append((where, "length", None))
                return
            for i, (u, v) in enumerate(zip(x, y)):
                walk(u, v, f"{where}[{i}]")
        elif x != y:
            diffs.append((where, x, y))

    walk(a, b, "")
    for where, x, y in diffs:
        print(f"{where}: {x} -> {y}")
    print(f"{len(a)} cases, {len(diffs)} differences")
    return 1 if diffs else 0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="what", required=True)
    r = sub.add_parser("record")
    r.add_argument("part", choices=["small", "scale"])
    r.add_argument("out")
    r.add_argument("--detail", action="store_true", help="also the standalone detail fit (slow)")
    c = sub.add_parser("compare")
    c.add_argument("before")
    c.add_argument("after")
    a = ap.parse_args()
    if a.what == "record":
        record(a.part, a.out, a.detail)
    else:
        raise SystemExit(compare(a.before, a.after))


if __name__ == "__main__":
    main()
