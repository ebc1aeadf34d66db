"""The default's settings tried on the corpus: each variant of :class:`meshdenoise.policy.DefaultConfig` on every case.

A setting is kept when it improves the **tune** half's geometric mean ratio (our mean face-normal
error over the best oracle-tuned peer's, ``benchmarks/results/corpus-peers.json``); the **check**
half is reported beside it and never used to choose. Each variant changes one thing of the
shipped config (``base``): the hole radius, the masks, the steps read, the region's size, the fold
guard, a candidate family left out or one of ``OTHER_FAMILIES`` added.

Run: ``python benchmarks/policy_tune.py [--split tune|check|all] [--jobs 2]``
(writes ``benchmarks/results/policy-tune.md``; about 4 s per case and variant on 2 cores).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))

import corpus  # noqa: E402

RESULTS = HERE / "results" / "policy-tune.md"


def variants() -> dict:
    """Name -> DefaultConfig: the shipped one (``base``) and one change each."""
    from meshdenoise.policy import FAMILIES, OTHER_FAMILIES, DefaultConfig

    base = DefaultConfig()
    change = dataclasses.replace
    def held(**kw):
        return change(base, holdout=change(base.holdout, **kw))

    out = {"base": base, "radius 2": held(radius=2), "masks 2": held(masks=2), "masks 6": held(masks=6),
           "masks 4": held(masks=4), "steps 60": change(base, steps=60), "patience 8": held(patience=8),
           "centres 0": held(centres=0), "centres 600": held(centres=600), "region 6000": held(region_vertices=6_000),
           "no fold guard": change(base, unfold_rounds=0)}
    for i, family in enumerate(FAMILIES):
        out[f"without {family.label}"] = change(base, families=FAMILIES[:i] + FAMILIES[i + 1:])
    for family in OTHER_FAMILIES:
        out[f"with {family.label}"] = change(base, families=FAMILIES + (family,))
    return out


def best_peer(peers: dict, name: str) -> tuple[float, float, int]:
    """(normal error, SNR, flipped) of the best peer by normal error."""
    cells = [v["best_normal"] for v in peers["cases"][name]["peers"].values() if v.get("best_normal")]
    b = min(cells, key=lambda c: c["normal_error_deg"])
    return b["normal_error_deg"], b["snr_db"], b.get("flipped", 0)


def run_case(args: tuple) -> dict:
    variant, name = args
    import meshdenoise as md
    from peers import flipped_faces

    config = variants()[variant]
    m = corpus.load_case(name)
    V0, F, Vn = m["V0"], m["F"], m["Vn"]
    t0 = time.perf_counter()
    (X, _), choice = md.denoise((Vn.copy(), F), return_params=True, config=config)
    seconds = time.perf_counter() - t0
    return {"variant": variant, "case": name, "error": md.normal_error_deg((V0, F), X), "snr": md.snr(V0, X),
            "flipped": flipped_faces(V0, F, X), "seconds": seconds, "method": choice.method,
            "params": {k: v for k, v in choice.params.items()}}


def summary(rows: list, peers: dict) -> list:
    out = []
    for key in sorted({(r["variant"], corpus.split(r["case"])) for r in rows}, key=lambda k: (k[1], k[0] != "base", k[0])):
        sel = [r for r in rows if (r["variant"], corpus.split(r["case"])) == key]
        ratios = np.array([r["error"] / best_peer(peers, r["case"])[0] for r in sel])
        worst = sel[int(np.argmax(ratios))]["case"]
        flips_ok = np.mean([r["flipped"] <= best_peer(peers, r["case"])[2] for r in sel])
        out.append(f"| {key[1]} | {key[0]} | {len(sel)} | {100 * np.mean(ratios <= 1):.0f} % | "
                   f"{math.exp(np.mean(np.log(ratios))):.3f} | {ratios.max():.2f} ({worst}) | {100 * flips_ok:.0f} % | "
                   f"{np.median([r['seconds'] for r in sel]):.1f} s |")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--split", choices=("tune", "check", "all"), default="all")
    ap.add_argument("--variants", nargs="*", default=None, help="names of variants (default: all)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", type=Path, default=RESULTS)
    a = ap.parse_args(argv)
    peers = json.loads((HERE / "results" / "corpus-peers.json").read_text())
    names = [c for c in corpus.CASES if a.split in ("all", corpus.split(c))]
    chosen = a.variants or list(variants())
    for name in names:  # built once, before the workers read them
        corpus.load_case(name)
    work = [(v, n) for v in chosen for n in names]
    with ProcessPoolExecutor(a.jobs) as pool:
        rows = list(pool.map(run_case, work))
    lines = ["# The default's settings on the corpus", "",
             f"Command: `python benchmarks/policy_tune.py --split {a.split} --jobs {a.jobs}`; corpus version "
             f"{corpus.CORPUS_VERSION}; best peer from `benchmarks/results/corpus-peers.json`. Ratio: our mean face-normal "
             "error over the best oracle-tuned peer's. A variant changes one setting of the shipped `DefaultConfig` "
             "(`base`); settings are chosen on the tune half only. Time: the whole `denoise` call, run "
             f"{a.jobs} at a time (2 cores).", "",
             "| split | variant | cases | ours <= best peer | geometric mean ratio | worst ratio | flips <= best peer's "
             "| median time |", "|---|---|---|---|---|---|---|---|", *summary(rows, peers), "",
             "## Every case (base)", "", "| case | split | error (deg) | best peer (deg) | ratio | choice |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        if r["variant"] == "base":
            bp = best_peer(peers, r["case"])[0]
            p = ", ".join(f"{k}={v}" for k, v in r["params"].items())
            lines.append(f"| {r['case']} | {corpus.split(r['case'])} | {r['error']:.2f} | {bp:.2f} | {r['error'] / bp:.2f} "
                         f"| {r['method']} ({p}) |")
    a.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = a.out.with_name(a.out.name + ".tmp")
    tmp.write_text("\n".join(lines) + "\n")
    tmp.replace(a.out)
    print("\n".join(lines[:12 + len(chosen) * 2]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
