"""The peers' oracle on the validation corpus: every peer of benchmarks/peers.py tuned against the clean mesh.

Usage::

    python benchmarks/corpus_peers.py [--cases NAME ...] [--peers NAME ...] [--jobs 2] [--resume [--retry]]
                                      [--out benchmarks/results/corpus-peers.json]

For every case of ``benchmarks/corpus.py`` and every peer of ``benchmarks/peers.py`` (MeshLib,
PyGEL, PyVista, pymeshlab, Open3D), the peer's grid is searched against the clean mesh (its best
case: ``peers.tune_peer``), each cell in a fresh process, ``--jobs`` at a time; the input's
metrics are stored beside. The result is one JSON, committed, with the corpus version it was
measured on: ``{"corpus_version", "meta", "cases": {name: {"split", "family", "kind", "level",
"input": {...}, "peers": {peer: {"best_normal", "best_snr"} or {"status"}}}}}``.

It takes about an hour on 2 cores. ``--resume`` keeps what the JSON at ``--out`` already holds (a cell
records its mesh's fingerprint: a cell of another mesh is measured again), and what
``out/corpus-peers/cells`` holds, and measures the rest (``--retry``: and the cells that failed); the
JSON is rewritten after every cell, so an interrupted run loses at most the cells in flight.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import corpus  # noqa: E402
import peers  # noqa: E402

DEFAULT_OUT = ROOT / "benchmarks" / "results" / "corpus-peers.json"
CELLS = ROOT / "out" / "corpus-peers" / "cells"


def _cell_file(store: Path, case: str, kind: str, name: str) -> Path:
    return store / (peers._slug(peers.CORPUS_PREFIX + case, kind, name) + ".json")


def seed_cells(doc: dict, store: Path) -> int:
    """Write the cells a committed JSON holds into ``store`` (for ``run_cells(resume=True)``); how many.

    Of any corpus version: every cell names its mesh's fingerprint, and ``run_cells`` measures again a cell
    whose mesh is not the case's mesh now, so a new version reuses the cells of the cases that did not change.
    """
    store.mkdir(parents=True, exist_ok=True)
    count = 0
    for case, per in doc.get("cases", {}).items():
        cells = [("input", "input", per.get("input"))] + [("peer", p, r) for p, r in per.get("peers", {}).items()]
        for kind, name, rec in cells:
            if rec and "mesh_fingerprint" in rec and not _cell_file(store, case, kind, name).is_file():
                _cell_file(store, case, kind, name).write_text(json.dumps(rec))
                count += 1
    return count


def assemble(cells: list, meta: dict) -> dict:
    cases: dict = {}
    for c in cells:
        name = c.mesh[len(peers.CORPUS_PREFIX):]
        case = corpus.CASES[name]
        per = cases.setdefault(name, {"split": case.split, "family": case.family, "kind": case.kind,
                                      "level": case.level, "input": {}, "peers": {}})
        if c.kind == "input":
            per["input"] = c.result
        else:
            per["peers"][c.name] = c.result
    return {"corpus_version": corpus.CORPUS_VERSION, "meta": meta, "cases": cases}


def best_peer(per: dict, key: str = "normal") -> tuple[str, dict] | None:
    """The best peer of a case by normal error (``key="normal"``) or SNR (``"snr"``): (name, its record)."""
    ok = {p: r[f"best_{key}"] for p, r in per.get("peers", {}).items() if "status" not in r}
    if not ok:
        return None
    if key == "normal":
        name = min(ok, key=lambda p: ok[p]["normal_error_deg"])
    else:
        name = max(ok, key=lambda p: ok[p]["snr_db"])
    return name, ok[name]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="+", default=None, help="corpus case names (default: all)")
    ap.add_argument("--peers", nargs="+", default=None, help=f"of {', '.join(peers.PEERS)} (default: all)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--peer-timeout", type=float, default=900.0, help="seconds per peer cell (default 900)")
    ap.add_argument("--resume", action="store_true", help="keep the cells already measured (the JSON, out/)")
    ap.add_argument("--retry", action="store_true", help="with --resume: measure again the cells that failed")
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    ap.add_argument("--cells", type=Path, default=CELLS, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    names = a.cases or list(corpus.CASES)
    chosen = a.peers or list(peers.PEERS)
    bad = [n for n in names if n not in corpus.CASES] or [p for p in chosen if p not in peers.PEERS]
    if bad:
        print(f"corpus_peers.py: unknown case or peer {bad[0]!r}", file=sys.stderr)
        return 2
    if a.jobs < 1 or a.peer_timeout <= 0:
        print("corpus_peers.py: --jobs must be >= 1 and --peer-timeout > 0", file=sys.stderr)
        return 2
    kept: dict = {}  # the stored JSON's cases that this run does not measure, kept as they are
    if a.resume and a.out.is_file():
        old = json.loads(a.out.read_text())
        print(f"{seed_cells(old, a.cells)} cells taken from {a.out}")
        if old.get("corpus_version") == corpus.CORPUS_VERSION:
            kept = {k: v for k, v in old["cases"].items() if k not in names and k in corpus.CASES}
    cells = []
    for n in names:
        cells.append(peers.Cell(peers.CORPUS_PREFIX + n, "input", "input"))
        cells += [peers.Cell(peers.CORPUS_PREFIX + n, "peer", p) for p in chosen]
    if a.retry:
        for c in cells:
            f = _cell_file(a.cells, c.mesh[len(peers.CORPUS_PREFIX):], c.kind, c.name)
            if f.is_file() and "status" in json.loads(f.read_text()):
                f.unlink()
    t0 = time.time()
    meta = {"date": time.strftime("%Y-%m-%d", time.gmtime()), "commit": peers._commit(),
            "command": "python benchmarks/corpus_peers.py " + shlex.join(argv if argv is not None else sys.argv[1:]),
            "machine": f"{os.cpu_count()} cores",
            "grids": {n: {"call": p.call, "grid": p.grid, "path": p.path} for n, p in peers.PEERS.items()},
            "max_iters": peers.MAX_ITERS, "patience": peers.PATIENCE}

    def log(line: str) -> None:  # rewrite the JSON after every cell: an interruption loses only the cells in flight
        print(line, flush=True)
        finished = [c for c in cells if c.result]
        if finished:
            doc = assemble(finished, {**meta, "wall_s": time.time() - t0})
            write({**doc, "cases": {**kept, **doc["cases"]}}, a.out)

    import signal

    signal.signal(signal.SIGTERM, peers._terminate)
    peers.run_cells(cells, a.cells, timeout=a.peer_timeout, jobs=a.jobs, quick=False, resume=a.resume,
                    log=log, peer_timeout=a.peer_timeout)
    doc = assemble(cells, {**meta, "wall_s": time.time() - t0})
    doc["cases"] = {**kept, **doc["cases"]}
    write(doc, a.out)
    print(f"wrote {a.out} ({len(doc['cases'])} cases, {time.time() - t0:.0f} s)")
    return 0


def write(doc: dict, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(doc, indent=1, sort_keys=False, default=float) + "\n")
    tmp.replace(path)


if __name__ == "__main__":
    sys.exit(main())
