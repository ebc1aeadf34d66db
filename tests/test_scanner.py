"""The virtual range scanner (meshdenoise.scanner) and ``meshdenoise simulate-scan``."""

from __future__ import annotations

import math

import numpy as np
import pytest
from click.testing import CliRunner

from meshdenoise.cli import cli
from meshdenoise.geometry import face_normals
from meshdenoise.io import load_arrays, save_arrays
from meshdenoise.scanner import ScannerSettings, _grid_faces, simulate_scan, view_direction
from meshdenoise.shapes import grid, icosphere, torus

from .conftest import MESH_KINDS, make_mesh

FLAT = ScannerSettings(depth_power=0.0)  # stationary noise: its level and correlation are the same everywhere


def _along(scan) -> np.ndarray:
    return np.einsum("ij,ij->i", scan.V - scan.V_clean, scan.rays)


def _image(scan, values: np.ndarray) -> np.ndarray:
    w, h = scan.resolution
    img = np.full((h, w), np.nan)
    img[scan.pixels[:, 0], scan.pixels[:, 1]] = values
    return img


def _lag_correlation(img: np.ndarray, lag: int) -> float:
    """Correlation of the image with itself shifted ``lag`` pixels along rows and columns (both averaged)."""
    pairs = []
    for a, b in ((img[:, :-lag], img[:, lag:]), (img[:-lag, :], img[lag:, :])):
        ok = np.isfinite(a) & np.isfinite(b)
        pairs.append((a[ok], b[ok]))
    x = np.concatenate([p[0] for p in pairs])
    y = np.concatenate([p[1] for p in pairs])
    return float(np.mean(x * y) / np.sqrt(np.mean(x * x) * np.mean(y * y)))


def _one_over_e(img: np.ndarray) -> float:
    """The lag (pixels, interpolated) at which the correlation falls to 1/e."""
    lags = np.arange(1, 40)
    c = np.array([_lag_correlation(img, int(k)) for k in lags])
    k = int(np.argmax(c < 1 / math.e))
    c0, c1 = (1.0, c[0]) if k == 0 else (c[k - 1], c[k])
    l0 = 0 if k == 0 else lags[k - 1]
    return float(l0 + (c0 - 1 / math.e) / (c0 - c1))


@pytest.fixture(scope="module")
def wall():
    """A large plane facing the camera at view 0,0 (it fills the image)."""
    V, F = grid(120, 120, size=2.0)
    return V - [1.0, 1.0, 0.0], F


def test_noise_is_along_the_rays_and_at_its_level(wall):
    scan = simulate_scan(wall, resolution=(96, 96), fov=60, noise=0.3, correlation=2, seed=3)
    d = _along(scan)
    assert np.allclose(scan.V - scan.V_clean, d[:, None] * scan.rays, atol=1e-12)
    assert np.allclose(np.linalg.norm(scan.rays, axis=1), 1.0)
    rms = float(np.sqrt(np.mean(d**2)))
    assert rms / scan.mean_edge == pytest.approx(0.3, rel=1e-9)  # the level, read back from the two meshes
    h = np.mean([np.linalg.norm(scan.V_clean[a] - scan.V_clean[b], axis=1).mean()
                 for a, b in ((scan.F[:, 0], scan.F[:, 1]),)])
    assert rms / h == pytest.approx(0.3, rel=0.1)  # against an edge mean computed here


def test_noise_in_mesh_units(wall):
    scan = simulate_scan(wall, resolution=(64, 64), noise=0.002, noise_in_edges=False, seed=0)
    assert float(np.sqrt(np.mean(_along(scan) ** 2))) == pytest.approx(0.002, rel=1e-9)
    assert scan.rho == pytest.approx(0.002)


def test_clean_scan_lies_on_the_clean_surface():
    V, F = icosphere(5)
    scan = simulate_scan((V, F), resolution=(80, 60), noise=0.4, seed=0)
    r = np.linalg.norm(scan.V_clean, axis=1)
    edge = np.linalg.norm(V[F[:, 0]] - V[F[:, 1]], axis=1).max()
    assert np.all(r <= 1 + 1e-12) and np.all(r >= math.cos(edge))  # on the inscribed triangles, not off them
    assert np.abs(np.linalg.norm(scan.V, axis=1) - 1).max() > 10 * (1 - math.cos(edge))  # the noisy one is off


@pytest.mark.parametrize("ell", [2.0, 5.0])
def test_correlation_reads_back_within_10_percent(wall, ell):
    scan = simulate_scan(wall, resolution=(256, 256), fov=70, noise=0.3, correlation=ell, seed=1, settings=FLAT)
    assert len(scan.V) > 0.25 * 256 * 256  # the square inside the image that holds its bounding sphere
    assert _one_over_e(_image(scan, _along(scan))) == pytest.approx(ell, rel=0.1)


def test_no_correlation_is_white(wall):
    scan = simulate_scan(wall, resolution=(128, 128), fov=70, noise=0.3, seed=2, settings=FLAT)
    assert abs(_lag_correlation(_image(scan, _along(scan)), 1)) < 0.03


def test_noise_grows_with_depth():
    V, F = grid(100, 100, size=2.0)
    V = V - [1.0, 1.0, 0.0]
    scan = simulate_scan((V, F), view=(0, 55), resolution=(128, 128), fov=60, noise=0.3, seed=4)
    d, t = _along(scan), scan.depth
    near, far = t < np.quantile(t, 0.2), t > np.quantile(t, 0.8)
    ratio = np.sqrt(np.mean(d[far] ** 2) / np.mean(d[near] ** 2))
    expected = np.sqrt(np.mean(t[far] ** 4) / np.mean(t[near] ** 4))  # depth_power 2
    assert ratio == pytest.approx(expected, rel=0.15) and expected > 1.3


def test_stripes_are_per_scanline(wall):
    scan = simulate_scan(wall, resolution=(128, 128), fov=70, noise=0.3, stripes=1.0, seed=5, settings=FLAT)
    img = _image(scan, _along(scan))
    rows = np.isfinite(img).sum(1) > 20
    share = np.var(np.nanmean(img[rows], axis=1)) / np.nanvar(img[rows])
    assert share == pytest.approx(0.5, abs=0.1)  # grain and stripes of equal strength
    plain = simulate_scan(wall, resolution=(128, 128), fov=70, noise=0.3, seed=5, settings=FLAT)
    img = _image(plain, _along(plain))[rows]
    assert np.var(np.nanmean(img, axis=1)) / np.nanvar(img) < 0.05


def test_outliers(wall):
    scan = simulate_scan(wall, resolution=(64, 64), fov=70, noise=0.3, outliers=0.02, seed=6, settings=FLAT)
    d = np.abs(_along(scan))
    far = d > 2.9 * scan.rho
    assert far.sum() == pytest.approx(0.02 * len(d), abs=0.004 * len(d) + 3)
    assert d.max() <= 6.0 * scan.rho + 5 * scan.rho  # 3 to 6 levels on top of the grain


def test_seeds_and_geometry():
    mesh = torus(80, 40)
    a = simulate_scan(mesh, view=(20, 30), resolution=(96, 72), noise=0.3, correlation=1.5, seed=7)
    b = simulate_scan(mesh, view=(20, 30), resolution=(96, 72), noise=0.3, correlation=1.5, seed=7)
    c = simulate_scan(mesh, view=(20, 30), resolution=(96, 72), noise=0.3, correlation=1.5, seed=8)
    assert np.array_equal(a.V, b.V) and not np.allclose(a.V, c.V)
    assert np.array_equal(a.V_clean, c.V_clean) and np.array_equal(a.F, c.F)  # the seed moves the noise only


def test_faces_face_the_camera_and_nothing_is_grazing():
    mesh = torus(80, 40)
    scan = simulate_scan(mesh, view=(30, 40), resolution=(120, 90), noise=0.0, seed=0)
    n = face_normals(scan.V_clean, scan.F)
    to_face = scan.V_clean[scan.F].mean(1) - scan.camera
    cos = -np.einsum("ij,ij->i", n, to_face) / np.linalg.norm(to_face, axis=1)
    assert cos.min() >= math.cos(math.radians(75)) - 1e-9
    assert np.array_equal(scan.V, scan.V_clean)  # noise 0


def test_depth_jumps_are_not_bridged():
    """Two parallel squares, one behind the other: no triangle joins them."""
    V1, F1 = grid(60, 60, size=1.0)
    V2, F2 = grid(60, 60, size=2.0)
    V = np.concatenate([V1 - [0.5, 0.5, 0.0], V2 - [1.0, 1.0, 1.0]])
    F = np.concatenate([F1, F2 + len(V1)])
    scan = simulate_scan((V, F), resolution=(100, 100), fov=50, noise=0.0)
    z = scan.V_clean[:, 2]
    front = np.isclose(z, 0.0)
    assert front.any() and (~front).any() and np.allclose(z[~front], -1.0)
    mixed = front[scan.F].any(1) & ~front[scan.F].all(1)
    assert not mixed.any()


def test_too_grazing_a_view_sees_nothing():
    V, F = grid(30, 30)
    with pytest.raises(ValueError, match="sees no surface"):
        simulate_scan((V - [0.5, 0.5, 0], F), view=(0, 85), resolution=(32, 32))


def test_grid_triangulation_against_a_loop():
    rng = np.random.default_rng(0)
    index = np.arange(7 * 9).reshape(7, 9)
    index[rng.random(index.shape) < 0.25] = -1
    P = rng.standard_normal((63, 3))
    expected = set()
    for i in range(6):
        for j in range(8):
            a, b, c, d = index[i, j], index[i, j + 1], index[i + 1, j], index[i + 1, j + 1]
            valid = [x >= 0 for x in (a, b, c, d)]
            if all(valid):
                if np.linalg.norm(P[b] - P[c]) <= np.linalg.norm(P[a] - P[d]):
                    expected |= {(a, c, b), (b, c, d)}
                else:
                    expected |= {(a, d, b), (a, c, d)}
            elif sum(valid) == 3:
                tri = {3: (a, c, b), 0: (b, c, d), 2: (a, d, b), 1: (a, c, d)}[valid.index(False)]
                expected.add(tuple(int(x) for x in tri))
    got = {tuple(int(x) for x in f) for f in _grid_faces(index, P)}
    assert got == {tuple(int(x) for x in f) for f in expected}


def test_view_direction_matches_render_convention():
    assert np.allclose(view_direction(0, 90), [0, 1, 0])
    assert np.allclose(view_direction(180, 0), [0, 0, -1])


@pytest.mark.parametrize("kind", MESH_KINDS)
def test_every_mesh_type(kind):
    V, F = icosphere(3)
    ref = simulate_scan((V, F), resolution=(40, 30), noise=0.3, seed=0)
    scan = simulate_scan(make_mesh(kind, V, F), resolution=(40, 30), noise=0.3, seed=0)
    assert np.allclose(scan.V, ref.V, atol=1e-12) and np.array_equal(scan.F, ref.F)


@pytest.mark.parametrize("kwargs, error", [
    ({"resolution": (4, 64)}, ValueError), ({"resolution": (64.0, 64)}, ValueError), ({"resolution": 64}, TypeError),
    ({"fov": 0}, ValueError), ({"fov": 175}, ValueError), ({"fov": "wide"}, TypeError),
    ({"noise": -0.1}, ValueError), ({"noise": float("nan")}, ValueError), ({"correlation": -1}, ValueError),
    ({"stripes": -1}, ValueError), ({"outliers": 0.9}, ValueError), ({"view": (0, float("inf"))}, ValueError),
    ({"view": "front"}, TypeError), ({"settings": {"depth_power": 1}}, TypeError),
])
def test_bad_arguments(kwargs, error):
    with pytest.raises(error, match="simulate_scan"):
        simulate_scan(icosphere(2), **kwargs)


@pytest.mark.parametrize("kwargs", [{"max_incidence_deg": 90}, {"min_component_faces": 0}, {"depth_power": -1},
                                    {"margin": 0.5}])
def test_bad_settings(kwargs):
    with pytest.raises(ValueError, match="ScannerSettings"):
        ScannerSettings(**kwargs)


# --- the command --------------------------------------------------------------------------------
@pytest.fixture
def clean_file(tmp_path):
    path = tmp_path / "clean.ply"
    save_arrays(path, *torus(60, 30))
    return path


def test_cli_writes_noisy_and_clean_scans(clean_file, tmp_path):
    noisy, clean = tmp_path / "out" / "noisy.ply", tmp_path / "out" / "clean_scan.obj"
    r = CliRunner().invoke(cli, ["simulate-scan", str(clean_file), str(noisy), "--clean-out", str(clean),
                                 "--view", "30,20", "--resolution", "80x60", "--noise", "0.25h", "--correlation", "2",
                                 "--stripes", "0.3", "--seed", "3"])
    assert r.exit_code == 0, r.output
    assert "vertices" in r.output and "0.25 mean edge lengths" in r.output
    Vn, Fn = load_arrays(noisy)
    Vc, Fc = load_arrays(clean)
    api = simulate_scan(load_arrays(clean_file), view=(30, 20), resolution=(80, 60), noise=0.25, correlation=2,
                        stripes=0.3, seed=3)
    assert np.array_equal(Fn, Fc) and np.array_equal(Fn, api.F)
    assert np.allclose(Vn, api.V, atol=1e-12) and np.allclose(Vc, api.V_clean, atol=1e-12)


@pytest.mark.parametrize("args, message", [
    (["--view", "30"], "--view 30"), (["--resolution", "80by60"], "--resolution"), (["--noise", "-1h"], "--noise"),
    (["--noise", "0.3h,2"], "--correlation"), (["--fov", "0"], "fov"), (["--correlation", "-2"], "correlation"),
    (["--outliers", "0.8"], "outliers"), (["--seed", "-1"], "--seed"),
])
def test_cli_bad_options_exit_2_in_one_line(clean_file, tmp_path, args, message):
    r = CliRunner().invoke(cli, ["simulate-scan", str(clean_file), str(tmp_path / "n.ply"), *args])
    assert r.exit_code == 2, r.output
    lines = r.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:") and message in lines[0]
    assert "Traceback" not in r.output and not (tmp_path / "n.ply").exists()


def test_cli_never_overwrites_its_input(clean_file, tmp_path):
    before = clean_file.read_bytes()
    for args in ([str(clean_file), str(clean_file)],
                 [str(clean_file), str(tmp_path / "n.ply"), "--clean-out", str(clean_file)],
                 [str(clean_file), str(tmp_path / "n.ply"), "--clean-out", str(tmp_path / "n.ply")],
                 [str(clean_file), str(tmp_path / "n.xyz")],
                 [str(tmp_path / "missing.ply"), str(tmp_path / "n.ply")]):
        r = CliRunner().invoke(cli, ["simulate-scan", *args])
        assert r.exit_code == 2 and r.output.startswith("error:"), r.output
    assert clean_file.read_bytes() == before and not (tmp_path / "n.ply").exists()
