"""The validation corpus (benchmarks/corpus.py), its peers' oracle and its report: the cases, the split, a smoke run."""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

import numpy as np
import pytest

BENCH = Path(__file__).resolve().parent.parent / "benchmarks"
sys.path.insert(0, str(BENCH))

import corpus  # noqa: E402  (the bench extra: manifold3d, PyVista; `make test` installs it)
import corpus_peers  # noqa: E402
import corpus_report  # noqa: E402
import peers  # noqa: E402


def test_the_corpus_has_what_it_promises():
    cases = list(corpus.CASES.values())
    assert len(cases) >= 48
    assert {c.kind for c in cases} == {"normal", "random", "impulsive", "scan"}
    cad = {c.shape for c in cases if c.family == "cad"}
    assert len(cad) >= 12
    organic = {c.shape for c in cases if c.family == "organic"}
    assert len(organic) >= 8
    for shape in organic:  # every organic shape at two resolutions or more
        assert len({c.vertices for c in cases if c.shape == shape and c.kind != "scan"}) >= 2, shape
    assert min(c.level for c in cases) == 0.1 and max(c.level for c in cases) == 0.7
    for kind in ("normal", "random", "impulsive", "scan"):  # each kind meets low and high noise
        levels = {c.level for c in cases if c.kind == kind}
        assert min(levels) <= 0.2 and max(levels) >= 0.5, kind


def test_the_split_is_the_hash_of_the_name_and_about_half():
    for name, case in corpus.CASES.items():
        even = hashlib.sha256(name.encode()).digest()[0] % 2 == 0
        assert case.split == ("tune" if even else "check")
    tune = sum(c.split == "tune" for c in corpus.CASES.values())
    assert 0.35 <= tune / len(corpus.CASES) <= 0.65
    for kind in ("normal", "random", "impulsive", "scan"):  # both halves see every kind
        assert {c.split for c in corpus.CASES.values() if c.kind == kind} == {"tune", "check"}


SMALL = {"cad": "flange-random-0.2", "organic": "metaballs-3k-normal-0.2", "scan": "knob-scan-0.4-c0"}


@pytest.fixture(scope="module")
def small_cases():
    """Three cases built at about 800 vertices (the corpus builds them at 3,000 to 10,000)."""
    return {name: corpus.build_case(corpus.CASES[name], vertices=800) for name in SMALL.values()}


def test_cases_are_deterministic_and_noisy_at_their_level(small_cases):
    for name, m in small_cases.items():
        case = corpus.CASES[name]
        assert m["V0"].shape == m["Vn"].shape and m["F"].shape[1] == 3 and 300 < len(m["V0"]) < 2500, name
        if case.kind == "scan":  # the same arrays on every build (the others draw their noise the same way)
            again = corpus.build_case(case, vertices=800)
            assert np.array_equal(again["Vn"], m["Vn"]) and np.array_equal(again["F"], m["F"])
        d = np.linalg.norm(m["Vn"] - m["V0"], axis=1)
        rms = float(np.sqrt(np.mean(d**2))) / corpus.mean_edge(m["V0"], m["F"])
        assert rms == pytest.approx(case.level, rel=0.12), name  # the level, read back in mean edge lengths


def test_noise_kinds_move_vertices_as_described():
    from meshdenoise.geometry import vertex_normals

    case = corpus.CASES["flange-random-0.2"]
    V, F = corpus._clean(case, 800)
    rng = np.random.default_rng(0)
    N = vertex_normals(V, F)
    for kind in ("normal", "random", "impulsive"):
        k = corpus.Case("x", "cad", "flange", 800, kind, 0.3)
        D = corpus._noisy(k, V, F, rng) - V
        along = np.abs(np.einsum("ij,ij->i", D, N))
        moved = np.linalg.norm(D, axis=1) > 0
        if kind == "random":  # not along the normals
            assert np.median(along / np.maximum(np.linalg.norm(D, axis=1), 1e-300)) < 0.8
        else:
            assert np.allclose(along, np.linalg.norm(D, axis=1))
        if kind == "impulsive":
            assert moved.mean() == pytest.approx(corpus.IMPULSIVE_FRACTION, abs=0.01)


def test_a_three_case_smoke_run_of_the_oracle_and_the_report(small_cases, tmp_path):
    """The peers' oracle (two peers, their quick grids) and the default on three small cases, then the report."""
    cases = {}
    ours = {}
    for name, m in small_cases.items():
        case = corpus.CASES[name]
        inp = {"n_vertices": len(m["V0"]), **peers._quality(m["V0"], m["F"], m["Vn"], distance=True)}
        found = {p: peers.tune_peer(peers.PEERS[p], m["V0"], m["F"], m["Vn"], quick=True)
                 for p in ("MeshLab HC", "Open3D simple")}
        cases[name] = {"split": case.split, "family": case.family, "kind": case.kind, "level": case.level,
                       "input": inp, "peers": found}
        ours[name] = peers.run_ours(None, m["V0"], m["F"], m["Vn"])
    doc = {"corpus_version": corpus.CORPUS_VERSION, "cases": cases}
    rs = corpus_report.rows(doc, ours)
    assert len(rs) == 3 and all("ratio" in r for r in rs)
    for r in rs:
        best = min(p["best_normal"]["normal_error_deg"] for p in cases[r["case"]]["peers"].values())
        assert r["ratio"] == pytest.approx(ours[r["case"]]["normal_error_deg"] / best)
        assert r["best_normal"][0] in ("MeshLab HC", "Open3D simple")
    meta = {"command": "test", "commit": "x", "machine": "m", "ours_wall_s": 1.0, "peers_json": "p.json",
            "peers_command": "pc", "peers_commit": "y"}
    text = corpus_report.markdown(rs, meta)
    assert "## Targets by split" in text and all(name in text for name in SMALL.values())
    agg = corpus_report.aggregate(rs)
    assert agg["measured"] == 3 and 0 < agg["gmean"] and agg["worst"][0] == max(r["ratio"] for r in rs)
    out = tmp_path / "corpus-peers.json"
    corpus_peers.write(doc, out)
    assert json.loads(out.read_text())["cases"].keys() == cases.keys()


def test_bowtie_vertices_are_split_with_their_noise():
    V0 = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]])
    F = np.array([[0, 1, 2], [0, 3, 4]])  # two triangles meeting at vertex 0 only
    Vn = V0 + 0.01 * np.arange(15.0).reshape(5, 3)
    V1, F1, Vn1 = corpus.split_nonmanifold_vertices(V0, F, Vn)
    assert len(V1) == 6 and np.array_equal(V1[:5], V0) and np.array_equal(V1[5], V0[0])
    assert np.array_equal(Vn1[:5], Vn) and np.array_equal(Vn1[5], Vn[0])
    assert sorted(np.bincount(F1.ravel(), minlength=6).tolist()) == [1, 1, 1, 1, 1, 1]  # one face at each copy
    same = corpus.split_nonmanifold_vertices(V0, F[:1], Vn)  # nothing to split: the same arrays back
    assert same[0] is V0 and same[2] is Vn


def test_best_peer_skips_failed_peers():
    per = {"peers": {"a": {"status": "failed"},
                     "b": {"best_normal": {"normal_error_deg": 3.0}, "best_snr": {"snr_db": 40.0}},
                     "c": {"best_normal": {"normal_error_deg": 2.0}, "best_snr": {"snr_db": 39.0}}}}
    assert corpus_peers.best_peer(per, "normal")[0] == "c"
    assert corpus_peers.best_peer(per, "snr")[0] == "b"
    assert corpus_peers.best_peer({"peers": {"a": {"status": "x"}}}) is None


def test_the_committed_peers_oracle_matches_the_corpus():
    doc = json.loads(corpus_peers.DEFAULT_OUT.read_text())
    assert doc["corpus_version"] == corpus.CORPUS_VERSION
    assert set(doc["cases"]) <= set(corpus.CASES)
    for name, per in doc["cases"].items():
        assert per["split"] == corpus.CASES[name].split and per["kind"] == corpus.CASES[name].kind
