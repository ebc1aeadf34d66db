"""benchmarks/quality.py: tasks stored as they complete, --resume and --redo keep what they should."""

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from meshdenoise.metrics import snr
from meshdenoise.noise import add_normal_noise
from meshdenoise.shapes import icosphere


def _quality_module():
    path = Path(__file__).resolve().parent.parent / "benchmarks" / "quality.py"
    spec = importlib.util.spec_from_file_location("quality_benchmark", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture
def quality(monkeypatch):
    """The benchmark on one small generated row (2 seeds) with one cheap library filter."""
    q = _quality_module()
    V, F = icosphere(2)
    noisy = [add_normal_noise((V, F), 0.02, seed=s)[0] for s in range(2)]
    row = {"row": "sphere rho=0.02", "V": V, "F": F, "noisy": noisy, "paper": None, "features": False}
    monkeypatch.setattr(q, "_cached_rows", lambda quick, seeds: [row])
    monkeypatch.setattr(q, "LIBRARY", {"Open3D simple": q.LIBRARY["Open3D simple"]})
    return q, row


def test_tasks_are_stored_and_resume_measures_only_what_is_asked(quality, tmp_path, monkeypatch):
    q, row = quality
    store = tmp_path / "tasks"
    first = q.run(False, 2, ["filtering", "sobolev"], store=store)
    files = sorted(p.name for p in store.iterdir())
    assert files == ["sphere_rho_0_02-seed0.json", "sphere_rho_0_02-seed1.json"]
    stored = json.loads((store / files[0]).read_text())["per"]
    # the stored SNR is the SNR of the noisy input computed independently
    assert stored["noisy"][0]["snr"] == pytest.approx(snr(row["V"], row["noisy"][0]))
    methods = first["rows"][0]["methods"]
    assert set(methods) == {"noisy", "filtering auto", "filtering oracle", "sobolev auto", "sobolev oracle", "Open3D simple oracle"}

    calls = []
    real_choose = q.auto.choose_parameters

    def counting(mesh, method, **kw):
        calls.append(method)
        return real_choose(mesh, method, **kw)

    monkeypatch.setattr(q.auto, "choose_parameters", counting)
    library_runs = []
    real_oracle = q.library_oracle
    monkeypatch.setattr(q, "library_oracle", lambda *a, **k: library_runs.append(1) or real_oracle(*a, **k))

    again = q.run(False, 2, ["filtering", "sobolev"], store=store, resume=True)
    assert calls == [] and library_runs == []  # everything came from the store
    assert again["rows"][0]["methods"] == methods

    redone = q.run(False, 2, ["filtering", "sobolev"], store=store, resume=True, redo=["sobolev"])
    assert sorted(calls) == ["sobolev"] * 4 and library_runs == []  # auto + oracle, 2 seeds
    assert redone["rows"][0]["methods"] == methods  # same code, same numbers

    calls.clear()
    added = q.run(False, 2, ["filtering", "sobolev", "taubin"], store=store, resume=True)
    assert sorted(calls) == ["taubin"] * 4
    assert {k: v for k, v in added["rows"][0]["methods"].items() if not k.startswith("taubin")} == methods


def test_redo_names_a_measured_method(quality, tmp_path):
    q, _ = quality
    with pytest.raises(SystemExit, match="--redo"):
        q.run(False, 2, ["filtering"], store=tmp_path, resume=True, redo=["sobolev"])
    with pytest.raises(SystemExit, match="only makes sense with --resume"):
        q.main(["--redo", "sobolev", "--out", str(tmp_path)])


def test_a_damaged_stored_task_is_named(quality, tmp_path):
    q, _ = quality
    (tmp_path / "sphere_rho_0_02-seed0.json").write_text("{not json")
    with pytest.raises(SystemExit, match="sphere_rho_0_02-seed0.json"):
        q.run(False, 2, ["filtering"], store=tmp_path, resume=True)


def test_rows_name_the_code_they_were_measured_on(quality, tmp_path):
    q, _ = quality
    res = q.run(False, 2, ["filtering"], store=tmp_path)
    commits = res["rows"][0]["commits"]
    assert len(commits) == 1 and commits[0] == q._commit()
    assert commits[0] in q._row_markdown(res["rows"][0])
    assert np.isfinite(res["peak_rss_mb"]) and res["peak_rss_mb"] > 0


@pytest.mark.parametrize("name", ["Open3D simple", "MeshLab Laplacian"])
def test_library_oracle_is_the_best_count_of_a_brute_force_run(name):
    """The library oracle (the tuning floor's walk along one run, one library call per step) against each
    count k computed from scratch with the library's own iteration count, and its stopping rule."""
    import open3d as o3d
    import pymeshlab

    q = _quality_module()
    V, F = icosphere(2)
    Vn = add_normal_noise((V, F), 0.03, seed=1)[0]

    def from_scratch(k: int) -> np.ndarray:
        if k == 0:
            return Vn
        if name == "Open3D simple":
            m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(Vn), o3d.utility.Vector3iVector(F.astype(np.int32)))
            return np.asarray(m.filter_smooth_simple(k).vertices)
        ms = pymeshlab.MeshSet()
        ms.add_mesh(pymeshlab.Mesh(vertex_matrix=Vn, face_matrix=F.astype(np.int32)))
        ms.apply_coord_laplacian_smoothing(stepsmoothnum=k, cotangentweight=False)
        return ms.current_mesh().vertex_matrix()

    found = q.library_oracle(q.LIBRARY[name], V, Vn, F, ("snr", "normal"))
    snrs = [snr(V, from_scratch(k)) for k in range(60)]
    k_snr = int(np.argmax(snrs))
    assert k_snr < 20  # so that the walk (twice the best count plus 20) stopped inside the 60 counts computed here
    assert found["snr"][0] == k_snr
    np.testing.assert_allclose(found["snr"][1], from_scratch(k_snr), atol=1e-12)
    from meshdenoise.metrics import normal_error_deg

    errors = [normal_error_deg((V, F), from_scratch(k)) for k in range(60)]
    assert found["normal"][0] == int(np.argmin(errors))
    with pytest.raises(ValueError, match="scores must be among"):
        q.library_oracle(q.LIBRARY[name], V, Vn, F, ("volume",))


def test_feature_benchmark_uses_the_quality_benchmarks_filters_and_oracle():
    """benchmarks/features.py has no search of its own: the library filters and their oracle are quality.py's."""
    path = Path(__file__).resolve().parent.parent / "benchmarks" / "features.py"
    spec = importlib.util.spec_from_file_location("features_benchmark", path)
    features = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(features)
    q = sys.modules["quality"]  # the module features.py imported
    assert features.library_oracle is q.library_oracle
    assert set(features.FILTERS) == set(q.LIBRARY)
    assert all(features.FILTERS[k] is q.LIBRARY[k] for k in q.LIBRARY if k != "MeshLab Laplacian")
