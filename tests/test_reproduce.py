"""The reproduction on Nefertiti (rho = 0.2, one seed) against dense matrices built here from the faces."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from click.testing import CliRunner

from meshdenoise.cli import cli
from meshdenoise.io import MeshFileError
from meshdenoise.metrics import snr
from meshdenoise.reproduce import GRIDS, STRATEGIES, GridSpec, available_methods, make_batch, run_reproduction, run_search
from meshdenoise.reproduce.chebyshev import heat_snr_chebyshev
from meshdenoise.reproduce.runner import load_batches
from meshdenoise.reproduce.sobolev_search import search_sobolev
from meshdenoise.reproduce.table import ROW_KEYS
from meshdenoise.reproduce.timing import time_best
from meshdenoise.shapes import icosphere
from tests.conftest import data_mesh_path


def dense_operators(F: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Dense D^-1 W and D - W from a loop over the faces (independent of meshdenoise.operators)."""
    W = np.zeros((n, n))
    for a, b, c in F:
        for i, j in ((a, b), (b, c), (c, a)):
            W[i, j] = W[j, i] = 1.0
    d = W.sum(axis=1)
    return W / d[:, None], np.diag(d) - W


@pytest.fixture(scope="module")
def nefertiti_batch():
    from meshdenoise.io import load_arrays

    V, F = load_arrays(data_mesh_path("nefertiti.off"))
    batch = make_batch("nefertiti", V, F, 0.2, (0,))
    P, L = dense_operators(F, V.shape[0])
    return batch, P, L


@pytest.fixture(scope="module")
def heat_result(nefertiti_batch):
    (r,) = run_search("heat", [nefertiti_batch[0]])
    return r


def test_noisy_batch_snr_is_metrics_snr(nefertiti_batch):
    batch, _, _ = nefertiti_batch
    two = make_batch("nefertiti", batch.V, batch.F, 0.2, (0, 7))
    assert two.noisy_snr() == pytest.approx([snr(batch.V, two.noisy(0)), snr(batch.V, two.noisy(1))], abs=1e-10)


def test_filtering_best_is_max_over_dense_powers(nefertiti_batch):
    batch, P, _ = nefertiti_batch
    (r,) = run_search("filtering", [batch])
    X, values = batch.noisy(0), []
    for _ in range(len(r.params)):
        values.append(snr(batch.V, X))
        X = P @ X
    assert r.snr[:, 0] == pytest.approx(values, abs=1e-9)
    assert r.best_snr == pytest.approx(max(values), abs=1e-9)
    assert r.best_params == {"iterations": int(np.argmax(values))}
    assert len(values) > 2 * np.argmax(values)  # the run went on past the peak


def test_heat_curves_match_dense_euler_steps_on_both_paths(nefertiti_batch, heat_result):
    batch, P, _ = nefertiti_batch
    r = heat_result
    curves = r.figure_data["curves"]
    assert "Chebyshev" in r.how and "direct" in r.how  # both evaluation paths are exercised
    n = batch.V.shape[0]
    for tau in (min(curves), sorted(curves)[len(curves) // 2], max(curves)):
        times, values = curves[tau]
        M = np.eye(n) - tau * (np.eye(n) - P)
        for i in (1, len(times) // 3, len(times) - 1):
            k = int(round(times[i] / tau))
            expected = snr(batch.V, np.linalg.matrix_power(M, k) @ batch.noisy(0))
            assert values[i, 0] == pytest.approx(expected, abs=1e-7), (tau, k)
    all_best = max(float(v[:, 0].max()) for _, v in curves.values())
    assert r.best_snr == pytest.approx(all_best)


def test_heat_skips_and_reports_unstable_steps(nefertiti_batch, heat_result):
    batch, P, _ = nefertiti_batch
    r = heat_result
    bound = 2.0 / np.linalg.eigvals(np.eye(P.shape[0]) - P).real.max()
    skipped = r.figure_data["unstable"]
    assert set(np.round(skipped, 4)) == {1.4211, 1.9953} and all(t > bound for t in skipped)
    assert all(t <= bound for t in r.figure_data["curves"])
    assert any("1.42" in note and "diverges" in note for note in r.notes)


def test_chebyshev_is_exact_for_polynomials_and_close_for_long_runs():
    V, F = icosphere(2)
    batch = make_batch("sphere", V, F, 0.05, (0, 1))
    P, _ = dense_operators(F, V.shape[0])
    taus = np.array([0.9, 0.01, 0.01, 0.3])
    ks = np.array([3, 2000, 17, 0])
    values, degree = heat_snr_chebyshev(batch, taus, ks)
    I = np.eye(V.shape[0])
    for i, (tau, k) in enumerate(zip(taus, ks)):
        Mk = np.linalg.matrix_power(I - tau * (I - P), int(k))
        for s in range(2):
            assert values[i, s] == pytest.approx(snr(V, Mk @ batch.noisy(s)), abs=1e-8)
    assert degree < 2000  # the long run is not a polynomial of its own degree


def test_sobolev_best_is_max_over_dense_solves(nefertiti_batch):
    batch, _, L = nefertiti_batch
    (r,) = run_search("sobolev", [batch])
    I = np.eye(L.shape[0])
    values = [snr(batch.V, batch.noisy(0) if p["mu"] == 0 else np.linalg.solve(I + p["mu"] * L, batch.noisy(0))) for p in r.params]
    assert r.snr[:, 0] == pytest.approx(values, abs=1e-9)
    assert r.best_snr == pytest.approx(max(values))
    assert r.params[0] == {"mu": 0.0} and r.best_snr >= snr(batch.V, batch.noisy(0))  # mu -> 0 returns the input
    assert "eigendecomposition" in r.how


def test_sobolev_factor_paths_equal_spectral_path(nefertiti_batch):
    batch, _, _ = nefertiti_batch
    mus = np.array([0.0, 0.01, 0.3, 5.0])
    (spectral,) = search_sobolev([batch], mus)
    (cholespy,) = search_sobolev([batch], mus, dense_limit=0, cholmod=False)
    assert "cholespy" in cholespy.how
    assert cholespy.snr == pytest.approx(spectral.snr, abs=1e-9)
    # the default sparse path reuses CHOLMOD's symbolic analysis across mu (scikit-sparse, a dev extra)
    (cholmod,) = search_sobolev([batch], mus, dense_limit=0)
    assert "one symbolic analysis" in cholmod.how
    assert cholmod.snr == pytest.approx(spectral.snr, abs=1e-9)


def test_generic_grid_search_for_any_registered_filter(nefertiti_batch, monkeypatch):
    batch, _, L = nefertiti_batch
    monkeypatch.delitem(STRATEGIES, "sobolev")
    monkeypatch.setitem(GRIDS, "sobolev", GridSpec("mu", (0.1, 1.0, 3.0)))
    (r,) = run_search("sobolev", [batch])
    I = np.eye(L.shape[0])
    assert r.snr[:, 0] == pytest.approx([snr(batch.V, np.linalg.solve(I + mu * L, batch.noisy(0))) for mu in (0.1, 1.0, 3.0)])
    monkeypatch.setitem(GRIDS, "no_such_filter", GridSpec("x", (1,)))
    assert "no_such_filter" not in available_methods()
    with pytest.raises(ValueError, match="no_such_filter.*not registered"):
        run_search("no_such_filter", [batch])
    with pytest.raises(ValueError, match="no search for method 'nope'"):
        run_search("nope", [batch])
    monkeypatch.setitem(GRIDS, "heat", GridSpec("steps", (1,)))
    monkeypatch.delitem(STRATEGIES, "heat")
    with pytest.raises(ValueError, match="'steps' is not declared; its parameters are tau, time"):
        run_search("heat", [batch])


def test_sinkhorn_is_searched_only_when_registered():
    from meshdenoise.registry import REGISTRY

    assert ("sinkhorn" in available_methods()) == ("sinkhorn" in REGISTRY)
    assert GRIDS["sinkhorn"].param == "t"


def test_timing_cross_check_catches_a_wrong_search(nefertiti_batch):
    batch, _, _ = nefertiti_batch
    (r,) = run_search("filtering", [batch])
    timing = time_best(r, batch, budget=0.01)
    assert timing["seconds"] > 0 and timing["repeats"] >= 3 and timing["seconds_cold"] is None
    r.snr[r.best_index, 0] += 0.01
    with pytest.raises(RuntimeError, match="scores .* when run, but the search computed"):
        time_best(r, batch, budget=0.01)


@pytest.mark.data
def test_full_run_on_nefertiti_writes_every_file(tmp_path):
    data = data_mesh_path("nefertiti.off").parent
    rows = run_reproduction(data, tmp_path, seeds=1, meshes=["nefertiti"], quick=True)
    saved = json.loads((tmp_path / "results.json").read_text())
    assert saved == rows and len(rows) == 3 * len(available_methods())
    for row in rows:
        assert set(ROW_KEYS) <= set(row) and math.isfinite(row["best_snr"]) and row["seconds"] > 0
    sob = next(r for r in rows if r["rho"] == 0.015 and r["method"] == "sobolev")
    assert sob["best_snr"] >= sob["noisy_snr"] > sob["paper_snr"] == 21.77
    table = (tmp_path / "table.md").read_text()
    assert "paper not self-consistent" in table and "21.77" in table and "diverges" in table
    for name in ("filtering_snr_vs_iterations", "heat_snr_vs_time", "heat_best_snr_vs_tau", "sobolev_snr_vs_mu"):
        assert (tmp_path / f"{name}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not list(tmp_path.glob(".*"))  # no temporary files left


def test_missing_mesh_names_the_file(tmp_path):
    with pytest.raises(MeshFileError, match=r"nefertiti\.off: not found; --data"):
        load_batches(tmp_path, "nefertiti", (0,))
    with pytest.raises(ValueError, match="unknown mesh 'bunny'"):
        load_batches(tmp_path, "bunny", (0,))


def test_cli_rejects_an_unknown_method_and_a_missing_mesh(tmp_path):
    runner = CliRunner()
    res = runner.invoke(cli, ["reproduce", "--data", str(tmp_path), "--out", str(tmp_path / "o"), "--methods", "nope"])
    assert res.exit_code == 2 and "nope cannot be searched" in res.output
    res = runner.invoke(cli, ["reproduce", "--data", str(tmp_path), "--out", str(tmp_path / "o"), "--quick"])
    assert res.exit_code == 2 and "elephant-50kv.off: not found; --data must be" in res.output
