"""The corpus report: our default on every case of the validation corpus, against the peers' oracle, by split.

Usage::

    python benchmarks/corpus_report.py [--cases NAME ...] [--jobs 2] [--resume] [--methods]
                                       [--peers-json benchmarks/results/corpus-peers.json]
                                       [--out benchmarks/results/corpus.md]

Runs ``meshdenoise.denoise(noisy)`` (the default: no method, no clean mesh) on every case of
``benchmarks/corpus.py``, each in a fresh process, ``--jobs`` at a time (``peers.run_ours``: the
time is the whole call, choice and filter), and compares it with the best peer of the committed
peers' oracle (``benchmarks/corpus_peers.py``; a peer tuned against the clean mesh). Writes
``OUT`` (markdown) and ``OUT`` with ``.json`` (every cell). Tables: the targets of the default per
split (tune, check, all); per split and noise kind; one row per case.

- normal error: the mean angle between corresponding face normals of the result and the clean mesh
  (degrees); ratio = ours / the best peer's (at or below 1: ours at least as good);
- SNR in dB (``meshdenoise.snr``), against the input's and the best peer's by SNR;
- flipped: faces whose normal turned more than 90 degrees from the clean mesh's;
- time: the whole ``denoise`` call, and per 100k vertices; the budget is 1 s + 3 s per 100k vertices.

``--methods`` also runs ``benchmarks/filter_oracle.py`` on the corpus (each filter's automatic
choice against that filter's own oracle; hours) and adds its summary.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shlex
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import corpus  # noqa: E402
import corpus_peers  # noqa: E402
import peers  # noqa: E402

DEFAULT_OUT = ROOT / "benchmarks" / "results" / "corpus.md"
CELLS = ROOT / "out" / "corpus-report" / "cells"
BUDGET_S = 1.0  # the default's time budget: 1 s + 3 s per 100k vertices (issue "a default that generalizes")
BUDGET_S_PER_100K = 3.0
RATIO_TARGET = 1.0


def budget(n: int) -> float:
    return BUDGET_S + BUDGET_S_PER_100K * n / 1e5


def rows(doc_peers: dict, ours: dict) -> list[dict]:
    """One record per case with ours, the input and the best peers (cases missing either are left out)."""
    out = []
    for name, case in corpus.CASES.items():
        per = doc_peers.get("cases", {}).get(name)
        mine = ours.get(name)
        if per is None or mine is None:
            continue
        inp = per.get("input", {})
        bn, bs = corpus_peers.best_peer(per, "normal"), corpus_peers.best_peer(per, "snr")
        r = {"case": name, "split": case.split, "kind": case.kind, "family": case.family, "level": case.level,
             "n": inp.get("n_vertices"), "input": inp, "ours": mine, "best_normal": bn, "best_snr": bs}
        if "status" not in mine and bn is not None and "status" not in inp:
            r["ratio"] = mine["normal_error_deg"] / bn[1]["normal_error_deg"]
            r["snr_gain"] = mine["snr_db"] - inp["snr_db"]
            r["snr_vs_peer"] = mine["snr_db"] - bs[1]["snr_db"]
            r["flips_ok"] = mine.get("flipped", 0) <= bn[1].get("flipped", 0)
            r["time_per_100k"] = mine["time_s"] / (r["n"] / 1e5)
            r["in_budget"] = mine["time_s"] <= budget(r["n"])
        out.append(r)
    return out


def aggregate(rs: list[dict]) -> dict:
    ok = [r for r in rs if "ratio" in r]
    if not ok:
        return {"cases": len(rs), "measured": 0}
    ratios = [r["ratio"] for r in ok]
    worst = max(ok, key=lambda r: r["ratio"])
    slow = max(ok, key=lambda r: r["time_per_100k"])
    return {
        "cases": len(rs), "measured": len(ok),
        "beats": sum(x <= RATIO_TARGET for x in ratios) / len(ok),
        "gmean": math.exp(statistics.fmean(math.log(x) for x in ratios)),
        "worst": (worst["ratio"], worst["case"]),
        "snr_gain_3db": sum(r["snr_gain"] >= 3.0 for r in ok) / len(ok),
        "snr_vs_peer": sum(r["snr_vs_peer"] >= -0.5 for r in ok) / len(ok),
        "flips_ok": sum(r["flips_ok"] for r in ok) / len(ok),
        "flipped": sum(r["ours"].get("flipped", 0) for r in ok),
        "time_median": statistics.median(r["time_per_100k"] for r in ok),
        "time_worst": (slow["time_per_100k"], slow["case"]),
        "in_budget": sum(r["in_budget"] for r in ok) / len(ok),
    }


def _pct(x: float) -> str:
    return f"{100 * x:.0f} %"


def _params(p: dict) -> str:
    method = p.get("method", "?")
    rest = ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in p.items() if k != "method")
    return f"{method} ({rest})" if rest else method


def markdown(rs: list[dict], meta: dict) -> str:
    L = ["# The default on the validation corpus", "",
         f"Command: `{meta['command']}` (ours: {meta['ours_wall_s']:.0f} s of wall time on {meta['machine']}); "
         f"commit {meta['commit']}; corpus version {corpus.CORPUS_VERSION}; the peers' oracle from "
         f"`{meta['peers_json']}` (`{meta['peers_command']}`, commit {meta['peers_commit']}).", "",
         "Ours: `meshdenoise.denoise(noisy)` with no clean mesh, the whole call timed in a fresh process. The best "
         "peer: every peer of `benchmarks/peers.py` tuned against the clean mesh on its own grid (its best case). "
         "Ratio: our mean face-normal error over the best peer's (at or below 1: ours is as good). Flipped: faces "
         "turned more than 90 degrees from the clean mesh's. Time budget: 1 s + 3 s per 100k vertices. How the "
         "corpus is made and split: [docs/corpus.md](../../docs/corpus.md).", "",
         "## Targets by split", "",
         "| split | cases | ours <= best peer | geometric mean ratio | worst ratio | SNR >= input + 3 dB | "
         "SNR >= best peer's - 0.5 dB | flips <= best peer's | flipped faces (all cases) | time per 100k vertices "
         "(median / worst) | within the time budget |",
         "|---|---|---|---|---|---|---|---|---|---|---|"]
    for split in ("check", "tune", "all"):
        a = aggregate([r for r in rs if split == "all" or r["split"] == split])
        if not a.get("measured"):
            L.append(f"| {split} | {a['cases']} | not measured | | | | | | | | |")
            continue
        L.append(f"| **{split}** | {a['measured']} of {a['cases']} | {_pct(a['beats'])} | {a['gmean']:.3f} | "
                 f"{a['worst'][0]:.2f} ({a['worst'][1]}) | {_pct(a['snr_gain_3db'])} | {_pct(a['snr_vs_peer'])} | "
                 f"{_pct(a['flips_ok'])} | {a['flipped']} | {a['time_median']:.1f} s / {a['time_worst'][0]:.1f} s "
                 f"({a['time_worst'][1]}) | {_pct(a['in_budget'])} |")
    L += ["", "## By split and noise kind", "",
          "| split | kind | cases | ours <= best peer | geometric mean ratio | worst ratio | within the time budget |",
          "|---|---|---|---|---|---|---|"]
    for split in ("check", "tune"):
        for kind in ("normal", "random", "impulsive", "scan"):
            a = aggregate([r for r in rs if r["split"] == split and r["kind"] == kind])
            if a.get("measured"):
                L.append(f"| {split} | {kind} | {a['measured']} | {_pct(a['beats'])} | {a['gmean']:.3f} | "
                         f"{a['worst'][0]:.2f} ({a['worst'][1]}) | {_pct(a['in_budget'])} |")
    L += ["", "## Every case", "",
          "| case | split | vertices | noisy (deg) | ours (deg) | best peer (deg) | ratio | SNR ours / input / best "
          "peer (dB) | flipped ours / best peer | time (s) | our choice |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in sorted(rs, key=lambda r: (r["split"], r["case"])):
        mine, inp = r["ours"], r["input"]
        if "ratio" not in r:
            why = mine.get("status") or inp.get("status") or ("no peer measured" if r["best_normal"] is None else "")
            L.append(f"| {r['case']} | {r['split']} | {r['n'] or ''} | | {why} | | | | | | |")
            continue
        bn, bs = r["best_normal"], r["best_snr"]
        L.append(f"| {r['case']} | {r['split']} | {r['n']} | {inp['normal_error_deg']:.2f} | "
                 f"{mine['normal_error_deg']:.2f} | {bn[0]} {bn[1]['normal_error_deg']:.2f} | {r['ratio']:.2f} | "
                 f"{mine['snr_db']:.1f} / {inp['snr_db']:.1f} / {bs[1]['snr_db']:.1f} | "
                 f"{mine.get('flipped', 0)} / {bn[1].get('flipped', 0)} | {mine['time_s']:.2f} | "
                 f"{_params(mine.get('params', {}))} |")
    if meta.get("methods"):
        L += ["", "## Each filter's automatic choice against its own oracle (`--methods`)", "",
              "| filter | split | cells | within 10 % of the oracle | median ratio | worst |", "|---|---|---|---|---|---|"]
        for line in meta["methods"]:
            L.append(line)
    return "\n".join(L) + "\n"


def methods_summary(cells: list[dict]) -> list[str]:
    out = []
    for f in sorted({c["filter"] for c in cells}):
        for split in ("check", "tune"):
            cs = [c for c in cells if c["filter"] == f and "ratio" in c
                  and corpus.split(c["row"][len(peers.CORPUS_PREFIX):]) == split]
            if cs:
                rs = sorted(c["ratio"] for c in cs)
                worst = max(cs, key=lambda c: c["ratio"])
                out.append(f"| {f} | {split} | {len(cs)} | {_pct(sum(x <= 1.1 for x in rs) / len(rs))} | "
                           f"{statistics.median(rs):.3f} | {worst['ratio']:.2f} ({worst['row'][len(peers.CORPUS_PREFIX):]}) |")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="+", default=None, help="corpus case names (default: all)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--timeout", type=float, default=300.0, help="seconds per case of ours (default 300)")
    ap.add_argument("--resume", action="store_true", help="keep the cells of ours already in out/corpus-report")
    ap.add_argument("--methods", action="store_true", help="also each filter's automatic choice against its oracle")
    ap.add_argument("--peers-json", type=Path, default=corpus_peers.DEFAULT_OUT)
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    ap.add_argument("--cells", type=Path, default=CELLS, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    names = a.cases or list(corpus.CASES)
    bad = [n for n in names if n not in corpus.CASES]
    if bad:
        print(f"corpus_report.py: unknown case {bad[0]!r}", file=sys.stderr)
        return 2
    if not a.peers_json.is_file():
        print(f"corpus_report.py: {a.peers_json}: no peers' oracle (run benchmarks/corpus_peers.py)", file=sys.stderr)
        return 2
    doc_peers = json.loads(a.peers_json.read_text())
    if doc_peers.get("corpus_version") != corpus.CORPUS_VERSION:
        print(f"corpus_report.py: {a.peers_json} was measured on corpus version {doc_peers.get('corpus_version')}, "
              f"the corpus is version {corpus.CORPUS_VERSION}: run benchmarks/corpus_peers.py again", file=sys.stderr)
        return 2
    cells = [peers.Cell(peers.CORPUS_PREFIX + n, "ours", "default") for n in names]
    t0 = time.time()
    peers.run_cells(cells, a.cells, timeout=a.timeout, jobs=a.jobs, quick=False, resume=a.resume)
    wall = time.time() - t0
    ours = {c.mesh[len(peers.CORPUS_PREFIX):]: c.result for c in cells}
    for name, rec in ours.items():  # a peers' record of another mesh would compare two meshes
        fp = doc_peers["cases"].get(name, {}).get("input", {}).get("mesh_fingerprint")
        if "status" not in rec and fp is not None and rec.get("mesh_fingerprint") != fp:
            rec.clear()
            rec["status"] = "measured on another mesh than the peers' oracle"
    pm = doc_peers.get("meta", {})
    meta = {"command": "python benchmarks/corpus_report.py " + shlex.join(argv if argv is not None else sys.argv[1:]),
            "commit": peers._commit(), "machine": f"{os.cpu_count()} cores", "ours_wall_s": wall,
            "peers_json": os.path.relpath(a.peers_json, ROOT), "peers_command": pm.get("command", "?"),
            "peers_commit": pm.get("commit", "?")}
    if a.methods:
        import filter_oracle

        js = a.out.with_name(a.out.stem + "-methods.md")
        filter_oracle.main(["--rows", *[peers.CORPUS_PREFIX + n for n in names], "--jobs", str(a.jobs), "--resume",
                            "--out", str(js)])
        meta["methods"] = methods_summary(json.loads(js.with_suffix(".json").read_text()))
    rs = rows(doc_peers, ours)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(markdown(rs, meta))
    a.out.with_suffix(".json").write_text(json.dumps({"corpus_version": corpus.CORPUS_VERSION, "meta": meta,
                                                      "ours": ours}, indent=1, default=float) + "\n")
    for split in ("check", "tune"):
        s = aggregate([r for r in rs if r["split"] == split])
        if s.get("measured"):
            print(f"{split}: {s['measured']} cases, ours <= best peer on {_pct(s['beats'])}, geometric mean ratio "
                  f"{s['gmean']:.3f}, worst {s['worst'][0]:.2f} ({s['worst'][1]}), within the time budget "
                  f"{_pct(s['in_budget'])}")
    print(f"wrote {a.out} ({wall:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
