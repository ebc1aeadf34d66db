"""benchmarks/peers.py: vertex-order check, peer adapters against independent computations, the table's shape."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))

import peers  # noqa: E402

from meshdenoise.metrics import snr  # noqa: E402
from meshdenoise.metrics import normal_error_deg  # noqa: E402


@pytest.fixture(scope="module")
def tiny():
    return peers.MESHES["tiny"]()


def _adjacency(F, n):
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    W = sp.coo_matrix((np.ones(len(E)), (E[:, 0], E[:, 1])), shape=(n, n)).tocsr()
    return ((W + W.T) > 0).astype(float)


# ----------------------------------------------------------------------------- vertex order
class _Identity(peers.Session):
    """A fake library that keeps our order; its filter is one uniform Laplacian step."""

    def __init__(self, V, F):
        self.V, self.F = V.copy(), F.copy()

    def vertices(self):
        return self.V.copy()

    def faces(self):
        return self.F.copy()

    def apply(self, params, iterations=1):
        W = _adjacency(self._faces_ours(), len(self.V))
        P = sp.diags(1 / np.asarray(W.sum(1)).ravel()) @ W
        perm = self._perm()
        X = self.V[perm]  # in our order
        for _ in range(iterations):
            X = 0.5 * X + 0.5 * (P @ X)
        self.V = np.empty_like(X)
        self.V[perm] = X

    def _perm(self):  # library index of our vertex i
        return np.arange(len(self.V))

    def _faces_ours(self):
        return self.F


class _Reordered(_Identity):
    """Reorders the vertices on loading (as PyGEL does) and says so through its faces."""

    def __init__(self, V, F):
        n = len(V)
        self.p = np.random.default_rng(1).permutation(n)  # our vertex i is the library's p[i]
        self.V = np.empty_like(V)
        self.V[self.p] = V
        self.F = self.p[F][:, [1, 2, 0]]  # same triangles, rotated
        self.F_ours = F.copy()

    def _perm(self):
        return self.p

    def _faces_ours(self):
        return self.F_ours


class _PermutesOnFilter(_Identity):
    """Reorders its vertices during the filter (faces follow): our order is lost."""

    def apply(self, params, iterations=1):
        super().apply(params, iterations)
        p = np.random.default_rng(2).permutation(len(self.V))
        Vp = np.empty_like(self.V)
        Vp[p] = self.V
        self.V, self.F = Vp, p[self.F]


class _Compacts(_Identity):
    """Drops the last vertex during the filter."""

    def apply(self, params, iterations=1):
        super().apply(params, iterations)
        self.V = self.V[:-1]


def _fake_peer(cls):
    return peers.Peer("numpy", "fake", cls, [{}], [{}], path=True, quick_iters=3)


def test_reordering_on_load_is_mapped_back(tiny):
    V0, F, Vn = tiny["V0"], tiny["F"], tiny["Vn"]
    a = peers.tune_peer(_fake_peer(_Identity), V0, F, Vn, quick=True)
    b = peers.tune_peer(_fake_peer(_Reordered), V0, F, Vn, quick=True)
    assert b["best_normal"]["iterations"] == a["best_normal"]["iterations"]
    for key in ("normal_error_deg", "snr_db", "mean_distance"):
        assert b["best_normal"][key] == pytest.approx(a["best_normal"][key], rel=1e-12)
    # independent: k lazy uniform Laplacian steps in our order
    W = _adjacency(F, len(V0))
    P = sp.diags(1 / np.asarray(W.sum(1)).ravel()) @ W
    X = Vn.copy()
    for _ in range(a["best_snr"]["iterations"]):
        X = 0.5 * X + 0.5 * (P @ X)
    assert a["best_snr"]["snr_db"] == pytest.approx(snr(V0, X), rel=1e-12)
    assert a["best_snr"]["normal_error_deg"] == pytest.approx(normal_error_deg((V0, F), X), rel=1e-12)


@pytest.mark.parametrize("cls", [_PermutesOnFilter, _Compacts])
def test_a_permuted_or_compacted_result_is_caught(tiny, cls):
    with pytest.raises(peers.TopologyChanged):
        peers.tune_peer(_fake_peer(cls), tiny["V0"], tiny["F"], tiny["Vn"], quick=True)


def test_vertex_map_refuses_a_non_bijection_and_other_faces(tiny):
    V, F = tiny["Vn"], tiny["F"]
    V2 = V.copy()
    V2[5] = V[6]  # the library merged two vertices' positions: 5 and 6 both map to one
    with pytest.raises(peers.TopologyChanged, match="moved|bijection"):
        peers.vertex_map(V, F, V2[::-1].copy(), F)
    F2 = F.copy()
    F2[0] = F2[0, ::-1]  # one face flipped
    with pytest.raises(peers.TopologyChanged, match="faces"):
        peers.vertex_map(V, F, V, F2)
    assert np.array_equal(peers.vertex_map(V, F, V, F[:, [2, 0, 1]]), np.arange(len(V)))


# ----------------------------------------------------------------------------- real peers
def test_every_peer_is_installed():
    """The bench extra is part of `make test`: a peer missing here is a broken install, not a skip."""
    missing = sorted({p.library for p in peers.PEERS.values() if not peers.installed(p.library)})
    assert not missing, f"install the bench extra: pip install -e '.[bench]' (missing {missing})"


@pytest.mark.parametrize("name", list(peers.PEERS))
def test_each_peer_runs_on_the_quick_grid(tiny, name):
    out = peers.tune_peer(peers.PEERS[name], tiny["V0"], tiny["F"], tiny["Vn"], quick=True)
    bn, bs = out["best_normal"], out["best_snr"]
    assert out["evaluated"] >= 1
    for rec in (bn, bs):
        assert np.isfinite([rec["normal_error_deg"], rec["snr_db"], rec["mean_distance"], rec["time_s"]]).all()
    assert bn["normal_error_deg"] <= bs["normal_error_deg"] + 1e-9  # each best is best at its own criterion
    assert bs["snr_db"] >= bn["snr_db"] - 1e-9


def test_pygel_taubin_mapped_back_matches_an_independent_taubin(tiny):
    """PyGEL reorders vertices; its Taubin (uniform Laplacian, +0.5 then -0.52) computed here in our order."""
    V0, F, Vn = tiny["V0"], tiny["F"], tiny["Vn"]
    X, _ = peers._run_once(peers.PyGELTaubin, Vn, F, {}, 3)
    W = _adjacency(F, len(Vn))
    L = sp.diags(1 / np.asarray(W.sum(1)).ravel()) @ W - sp.eye(len(Vn))
    Y = Vn.copy()
    for it in range(6):
        Y = Y + (0.5 if it % 2 == 0 else -0.52) * (L @ Y)
    np.testing.assert_allclose(X, Y, atol=1e-9)


def test_meshlab_taubin_matches_a_direct_pymeshlab_call(tiny):
    import pymeshlab

    V0, F, Vn = tiny["V0"], tiny["F"], tiny["Vn"]
    X, _ = peers._run_once(peers.MeshLabTaubin, Vn, F, {"lambda_": 0.5, "mu": -0.53}, 4)
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=Vn, face_matrix=F.astype(np.int32)))
    ms.apply_coord_taubin_smoothing(lambda_=0.5, mu=-0.53, stepsmoothnum=4)
    np.testing.assert_array_equal(X, ms.current_mesh().vertex_matrix())


# ----------------------------------------------------------------------------- noise stand-in
def test_correlated_noise_stand_in_statistics(tiny):
    from meshdenoise.geometry import vertex_normals
    from meshdenoise.shapes import icosphere

    V, F = icosphere(4)
    rho = 0.01
    Vn = peers.correlated_normal_noise(V, F, rho, seed=3)
    N = vertex_normals(V, F)
    d = Vn - V
    e = np.einsum("ij,ij->i", d, N)
    np.testing.assert_allclose(d, e[:, None] * N, atol=1e-15)  # along the normals
    assert np.sqrt(np.mean(e**2)) == pytest.approx(rho, rel=1e-12)
    E = np.unique(np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1), axis=0)
    corr = np.corrcoef(e[E[:, 0]], e[E[:, 1]])[0, 1]
    assert corr > 0.8  # neighbours move together (white noise: about 0)
    white = peers.correlated_normal_noise(V, F, rho, steps=0, seed=3)
    ew = np.einsum("ij,ij->i", white - V, N)
    assert abs(np.corrcoef(ew[E[:, 0]], ew[E[:, 1]])[0, 1]) < 0.05


# ----------------------------------------------------------------------------- the script
def test_quick_run_writes_the_table(tmp_path):
    """Three cells (input, one peer, our default), each in its own process."""
    out = tmp_path / "p"
    cmd = [sys.executable, str(ROOT / "benchmarks" / "peers.py"), "--meshes", "tiny", "--quick", "--jobs", "2",
           "--peers", "PyGEL anisotropic", "--ours", "default", "--out", str(out)]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    data = json.loads((out / "peers.json").read_text())
    per = data["results"]["tiny"]
    assert set(per["peers"]) == {"PyGEL anisotropic"}
    assert set(per["ours"]) == {"default"}
    assert per["input"]["n_vertices"] == 162
    md_lines = (out / "peers.md").read_text().splitlines()
    summary = [ln for ln in md_lines if ln.startswith("| tiny |")]
    assert len(summary) == 2 and all(ln.count("|") == 7 for ln in summary)  # the summary and the targets tables
    table_start = next(i for i, ln in enumerate(md_lines) if ln.startswith("| method | normal err (deg) |"))
    rows = []
    for ln in md_lines[table_start + 2:]:
        if not ln.startswith("|"):
            break
        rows.append(ln)
    assert len(rows) == 1 + 1 + 2  # noisy, our default, two rows (best normal, best SNR) for the peer
    assert all(r.count("|") == 7 for r in rows)


def test_bad_arguments_exit_2(tmp_path):
    r = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "peers.py"), "--meshes", "nosuch", "--out", str(tmp_path)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "unknown mesh 'nosuch'" in r.stderr and "Traceback" not in r.stderr


def test_a_cell_over_the_timeout_is_killed_and_recorded(tmp_path):
    cell = peers.Cell("tiny", "ours", "sobolev")
    peers.run_cells([cell], tmp_path, timeout=0.2, jobs=1, quick=True, resume=False, log=lambda s: None)
    assert cell.result["status"] == "> 0.2 s"
    assert cell.result["wall_s"] < 30


def test_resume_measures_again_the_cells_of_another_mesh(tmp_path, monkeypatch):
    """--resume reuses a stored cell only for the mesh it was measured on: a cell with another fingerprint, or an
    older cell (no fingerprint) whose mesh's stored input cell names another noise, is measured again; a matching
    one, or an older one with the same noise line, is reused."""
    m = peers.MESHES["tiny"]()
    now = peers.mesh_fingerprint(m)
    other = {**m, "Vn": m["Vn"] + 1e-9}
    assert peers.mesh_fingerprint(other) != now and peers.mesh_fingerprint(peers.MESHES["tiny"]()) == now

    def store(name, record):
        (tmp_path / (peers._slug("tiny", *name) + ".json")).write_text(json.dumps(record))

    store(("input", "input"), {"noise": m["noise"], "normal_error_deg": 1.0})  # older: no fingerprint, same noise
    store(("ours", "default"), {"normal_error_deg": 2.0, "mesh_fingerprint": now})
    store(("ours", "sobolev"), {"normal_error_deg": 3.0, "mesh_fingerprint": peers.mesh_fingerprint(other)})
    store(("ours", "taubin"), {"normal_error_deg": 4.0})  # older, same noise as now: reused
    measured, lines = [], []
    monkeypatch.setattr(peers, "_drive", lambda todo, *a, **k: measured.extend(c.name for c, _ in todo))
    cells = [peers.Cell("tiny", "input", "input")] + [peers.Cell("tiny", "ours", n) for n in ("default", "sobolev", "taubin")]
    peers.run_cells(cells, tmp_path, timeout=10, jobs=1, quick=True, resume=True, log=lines.append)
    assert measured == ["sobolev"]
    assert [c.result.get("normal_error_deg") for c in cells] == [1.0, 2.0, None, 4.0]
    assert any("sobolev" in ln and "another mesh" in ln for ln in lines)
    # the stored input cell names another noise (a run on the stand-in): its older cells are all measured again
    store(("input", "input"), {"noise": "stand-in correlated noise", "normal_error_deg": 1.0})
    measured.clear()
    cells = [peers.Cell("tiny", "input", "input")] + [peers.Cell("tiny", "ours", n) for n in ("default", "taubin")]
    peers.run_cells(cells, tmp_path, timeout=10, jobs=1, quick=True, resume=True, log=lines.append)
    assert measured == ["input", "taubin"]
    assert peers.stale({"status": "> 120 s"}, {"fingerprint": now, "noise": m["noise"]}, tmp_path / "none.json") == ""


def test_a_measured_cell_names_its_meshs_fingerprint():
    out = peers.measure_cell("tiny", "input", "input", quick=True)
    assert out["mesh_fingerprint"] == peers.mesh_fingerprint(peers.MESHES["tiny"]()) and out["n_vertices"] == 162


def test_grid_edges_marks_a_best_at_the_end_of_its_axis():
    p = peers.Peer("numpy", "fake", peers.Session, peers._product(a=[1.0, 2.0, 3.0], b=[0.1, 0.2]), [{}], path=True)
    assert peers.grid_edges(p, {"params": {"a": 2.0, "b": 0.2}, "iterations": 5}) == ["b"]
    assert peers.grid_edges(p, {"params": {"a": 1.0, "b": 0.2}, "iterations": peers.MAX_ITERS}) == ["a", "b", "iterations"]


def test_sample_meshes_drop_unreferenced_vertices_and_keep_the_triangles(tmp_path, monkeypatch):
    # pymeshlab's face000.ply ships 667 unreferenced vertices; PyGEL drops them, so the benchmark does it first
    import meshdenoise.data
    from meshdenoise.io import save_mesh
    from meshdenoise.shapes import icosphere

    V, F = icosphere(2)
    extra = np.array([[5.0, 5.0, 5.0], [6.0, 6.0, 6.0]])
    V2 = np.vstack([extra[:1], V, extra[1:]])  # unreferenced vertices first and last
    F2 = F + 1
    path = tmp_path / "with_loose.ply"
    save_mesh(path, V2, F2)
    monkeypatch.setattr(meshdenoise.data, "sample_mesh", lambda name: path)
    mesh = peers._sample("whatever.ply")()
    assert mesh["V0"].shape == V.shape and "2 unreferenced vertices of the file dropped" in mesh["noise"]
    np.testing.assert_allclose(mesh["V0"][mesh["F"]], V2[F2], atol=1e-6)  # the same triangles, renumbered
    assert mesh["Vn"].shape == V.shape


def test_vertex_map_tells_coincident_vertices_apart_by_their_faces():
    """A bowtie split into one vertex per fan (two vertices at one position), in a library's shuffled order."""
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0], [0.0, 0, 0]])
    F = np.array([[0, 1, 2], [5, 3, 4]])
    perm = np.array([5, 2, 4, 0, 3, 1])  # library vertex k is our vertex perm[k]
    inv = np.argsort(perm)
    idx = peers.vertex_map(V, F, V[perm], inv[F])
    assert np.array_equal(perm[idx], np.arange(6))  # our vertex i is the library's idx[i]
    with pytest.raises(peers.TopologyChanged):  # fans of other corners: another mesh at the same positions
        peers.vertex_map(V, F, V[perm], inv[np.array([[0, 1, 3], [5, 2, 4]])])
