"""Renders are checked by their pixels: coverage, camera sharing, heat-map colours, both backends."""

from __future__ import annotations

import matplotlib
import numpy as np
import pytest

from meshdenoise.render import frame_camera, render_comparison, render_mesh, vertex_error
from meshdenoise.shapes import grid, icosphere, torus

SIZE = (96, 96)


def covered(img: np.ndarray) -> np.ndarray:
    """Pixels that are not the white background."""
    return (img < 250).any(axis=2)


def bump_plane(height=0.2, n=41):
    """A unit square with a Gaussian bump in its middle, and the flat square: error known per vertex."""
    V, F = grid(n, n)
    V = V - [0.5, 0.5, 0.0]
    bumped = V.copy()
    bumped[:, 2] = height * np.exp(-(V[:, 0] ** 2 + V[:, 1] ** 2) / 0.02)
    return (bumped, F), (V, F)


def colormap_position(rgb: np.ndarray, cmap="viridis") -> np.ndarray:
    """Invert the colour map: position in [0, 1] of the nearest of its 1024 colours (a lookup written for the test)."""
    lut = matplotlib.colormaps[cmap](np.linspace(0, 1, 1024))[:, :3] * 255
    d = ((rgb.reshape(-1, 1, 3).astype(float) - lut[None]) ** 2).sum(axis=2)
    return d.argmin(axis=1).reshape(rgb.shape[:-1]) / 1023


def test_picture_is_not_blank_and_mesh_covers_a_sane_share():
    img = render_mesh(icosphere(3), SIZE, backend="matplotlib")
    share = covered(img).mean()
    assert img.shape == (96, 96, 3) and img.dtype == np.uint8
    assert 0.05 < share < 0.8, share
    # a sphere fills a disc: pi/4 of the square over margin^2 (1.08)
    assert share == pytest.approx(np.pi / 4 / 1.08**2, abs=0.04)
    assert len(np.unique(img[covered(img)].reshape(-1, 3), axis=0)) > 20  # shaded, not a flat silhouette


def test_different_meshes_give_different_pictures():
    a = render_mesh(icosphere(3), SIZE, backend="matplotlib")
    b = render_mesh(torus(24, 12), SIZE, backend="matplotlib")
    assert (covered(a) != covered(b)).mean() > 0.05


def test_same_mesh_in_two_panels_gives_identical_panels_and_png_holds_them(tmp_path):
    V, F = icosphere(2)
    res = render_comparison([(V, F), (V.copy(), F)], tmp_path / "same.png", size=SIZE, backend="matplotlib")
    assert np.array_equal(res.panels[0], res.panels[1])
    png = (matplotlib.image.imread(tmp_path / "same.png")[:, :, :3] * 255).round().astype(np.uint8)
    for (r, c, h, w), panel in zip(res.boxes, res.panels):
        assert np.array_equal(png[r:r + h, c:c + w], panel)  # pasted pixel for pixel


def test_compared_meshes_share_one_camera(tmp_path):
    V, F = icosphere(3)
    res = render_comparison([(V * 0.5, F), (V, F)], tmp_path / "two.png", size=SIZE, backend="matplotlib")
    small, big = (covered(p).sum() for p in res.panels)
    assert small / big == pytest.approx(0.25, rel=0.15)  # half the radius: a quarter of the area
    alone = render_mesh((V * 0.5, F), SIZE, backend="matplotlib")
    assert covered(alone).sum() > 3 * small  # framed alone it fills the picture


def test_camera_projection_matches_a_pinhole_written_here():
    cam = frame_camera([np.array([[-1.0, -1, 0], [1, 1, 0]])], (200, 100), fov=40)
    p = np.array([[0.3, -0.2, 0.1]])
    f = 50 / np.tan(np.radians(20))
    z = cam.eye[2] - 0.1  # the camera looks down -z from +z
    expected = [100 + f * 0.3 / z, 50 + f * 0.2 / z]
    assert np.allclose(cam.project(p, (200, 100))[0, :2], expected)


@pytest.mark.parametrize("mode", ["vertex", "nearest"])
def test_heat_map_colours_follow_the_error(tmp_path, mode):
    bumped, flat = bump_plane()
    res = render_comparison([bumped], tmp_path / "heat.png", reference=flat, size=(121, 121),
                            error_mode=mode, backend="matplotlib")
    heat = res.panels[-1]
    assert res.error_mode == mode and res.vmax == pytest.approx(res.errors[0].max())
    edge = np.flatnonzero(covered(heat)[60]).max()  # the plane's right edge in this row
    assert edge > 90
    t = colormap_position(heat[60, 60:edge - 1])  # from the bump's top to the flat part, along +x
    assert t[0] > 0.85 and t[-1] < 0.05, t
    assert (np.diff(t) <= 0.03).all(), t  # larger error, further along the colour map
    # the positions agree with the error at those points, computed here from the bump's formula
    cam = res.camera
    xs = np.linspace(0, 0.5, 200)
    pix = cam.project(np.stack([xs, np.zeros_like(xs), 0.2 * np.exp(-xs**2 / 0.02)], 1), (121, 121))[:, 0]
    for col in (62, 70, 78, 86):
        x = np.interp(col + 0.5, pix, xs)
        assert colormap_position(heat[60, col][None])[0] == pytest.approx(np.exp(-x**2 / 0.02), abs=0.08)


def test_vertex_error_nearest_against_distances_written_here():
    V, F = grid(5, 5)  # the unit square at z = 0
    q = np.array([[0.3, 0.6, 0.25], [0.5, 0.5, -0.1], [1.3, 0.5, 0.0], [-0.3, -0.4, 0.0]])
    expected = [0.25, 0.1, 0.3, 0.5]  # above the square: height; beside it: distance to edge or corner
    Fq = np.array([[0, 1, 2], [0, 2, 3]])
    err, mode = vertex_error((q, Fq), (V, F), mode="nearest")
    assert mode == "nearest" and np.allclose(err, expected, atol=1e-6)
    auto, how = vertex_error((V + [0, 0, 0.1], F), (V, F))
    assert how == "vertex" and np.allclose(auto, 0.1)


def test_open3d_offscreen_renderer_draws_the_same_picture(tmp_path, monkeypatch):
    monkeypatch.setenv("MESHDENOISE_RENDER_TIMEOUT", "240")
    V, F = icosphere(3)
    bumped, flat = bump_plane(n=21)
    res = render_comparison([(V, F), (V, F)], tmp_path / "o3d.png", size=(64, 64), backend="open3d")
    assert res.backend == "open3d" and "OffscreenRenderer" in res.backend_detail
    assert np.array_equal(res.panels[0], res.panels[1])
    ref = render_comparison([(V, F)], tmp_path / "mpl.png", size=(64, 64), backend="matplotlib").panels[0]
    a, b = covered(res.panels[0]), covered(ref)
    assert 0.05 < a.mean() < 0.8
    assert (a & b).sum() / (a | b).sum() > 0.9  # same camera, same silhouette in both rasterisers
    heat = render_comparison([bumped], tmp_path / "o3d-heat.png", reference=flat, size=(64, 64),
                             backend="open3d").panels[0 + 1]
    edge = np.flatnonzero(covered(heat)[32]).max()
    t = colormap_position(heat[32, 32:edge - 1])
    assert t[0] > 0.85 and t[-1] < 0.05 and (np.diff(t) <= 0.05).all(), t


def test_bad_input_names_the_problem(tmp_path):
    V, F = icosphere(1)
    with pytest.raises(ValueError, match="must end in .png"):
        render_comparison([(V, F)], tmp_path / "x.jpg")
    with pytest.raises(ValueError, match="titles: 1 given for 2 meshes"):
        render_comparison([(V, F), (V, F)], tmp_path / "x.png", titles=["a"])
    with pytest.raises(ValueError, match="has 42 vertices, the reference 12"):
        vertex_error(icosphere(1), icosphere(0), mode="vertex")
    with pytest.raises(ValueError, match="size must be"):
        render_mesh((V, F), size=(4, 4))
    with pytest.raises(ValueError, match="backend must be one of"):
        render_mesh((V, F), size=SIZE, backend="vtk")
    assert not (tmp_path / "x.png").exists()


def test_render_cli_writes_before_after_error(tmp_path):
    from click.testing import CliRunner

    from meshdenoise.cli import cli
    from meshdenoise.io import save_arrays

    V, F = icosphere(2)
    save_arrays(tmp_path / "clean.ply", V, F)
    save_arrays(tmp_path / "noisy.ply", V * 1.05, F)
    save_arrays(tmp_path / "den.ply", V * 1.01, F)
    args = ["render", str(tmp_path / "noisy.ply"), str(tmp_path / "den.ply"), "--reference", str(tmp_path / "clean.ply"),
            "--png", str(tmp_path / "out.png"), "--size", "64x64", "--backend", "matplotlib"]
    res = CliRunner().invoke(cli, args)
    assert res.exit_code == 0, res.output
    assert "3 panels" in res.output and "matplotlib" in res.output and "0.01" in res.output
    png = matplotlib.image.imread(tmp_path / "out.png")
    assert png.shape[1] > 3 * 64
