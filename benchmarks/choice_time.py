"""Time of the default's choice (``choose_default``) on the peers benchmark's meshes (issue 22: under 3 s per 50k).

Each mesh (``benchmarks/peers.py``'s ``MESHES``, noisy as there) is chosen for once to warm
the caches and compiled kernels, then timed ``--reps`` times (the minimum is reported, wall
and CPU seconds of this process) with the choice printed; ``--prof`` adds a cProfile.

Usage::

    python benchmarks/choice_time.py "Bunny0.2" "bunny scanner" "face000 scanner" "Fandisk0.3"
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT.parent))

import peers  # noqa: E402

from meshdenoise.policy import choose_default  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("meshes", nargs="+", choices=sorted(peers.MESHES), metavar="MESH")
    ap.add_argument("--reps", type=int, default=1)
    ap.add_argument("--prof", action="store_true")
    a = ap.parse_args()
    print(f"load average at the start: {os.getloadavg()[0]:.2f}")
    print("| mesh | vertices | choice wall s | CPU s | method and parameters |\n|---|---|---|---|---|")
    for name in a.meshes:
        m = peers.MESHES[name]()
        mesh = (m["Vn"], m["F"])
        choose_default(mesh)  # warm: caches and compiled kernels
        best = None
        for _ in range(max(a.reps, 1)):
            w, c = time.perf_counter(), time.process_time()
            choice = choose_default(mesh)
            t = (time.perf_counter() - w, time.process_time() - c)
            best = t if best is None or t[0] < best[0] else best
        said = ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in choice.params.items())
        print(f"| {name} | {len(m['Vn']):,} | {best[0]:.2f} | {best[1]:.2f} | {choice.method} ({said}) |", flush=True)
        if a.prof:
            pr = cProfile.Profile()
            pr.enable()
            choose_default(mesh)
            pr.disable()
            pstats.Stats(pr).sort_stats("cumulative").print_stats(25)
    print(f"load average at the end: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
