"""Renders are checked by their pixels: coverage, camera sharing, heat-map colours, both backends."""

from __future__ import annotations

import matplotlib
import numpy as np
import pytest

from meshdenoise.render import RenderSettings, frame_camera, render_comparison, render_mesh, vertex_error
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


# --- a scan's change without a reference, zoom, file mode, Open3D failing fast ---------------------
def test_change_without_reference_is_the_displacement_from_the_first_mesh_on_a_99th_percentile_bar(tmp_path):
    bumped, flat = bump_plane()
    res = render_comparison([flat, bumped], tmp_path / "change.png", size=(121, 121), show_change=True,
                            backend="matplotlib")
    assert res.heat == "change" and res.error_mode == "vertex" and res.percentile == 99.0
    assert res.titles == ["mesh 1", "mesh 2", "change: mesh 1 → mesh 2"]
    height = 0.2 * np.exp(-(flat[0][:, 0] ** 2 + flat[0][:, 1] ** 2) / 0.02)  # the displacement, from the formula
    np.testing.assert_allclose(res.errors[0], height, atol=1e-15)
    assert res.vmax == pytest.approx(np.percentile(height, 99), rel=1e-12)
    assert res.vmax < height.max()  # robust: the top 1 % saturate
    heat = res.panels[-1]
    edge = np.flatnonzero(covered(heat)[60]).max()  # the plane's right edge in this row
    t = colormap_position(heat[60, 60:edge - 1])
    assert t[0] > 0.97 and t[-1] < 0.05 and (np.diff(t) <= 0.03).all(), t
    # a reference still wins: its error, topped at the maximum
    ref = render_comparison([flat, bumped], tmp_path / "ref.png", reference=flat, size=(64, 64), show_change=True,
                            backend="matplotlib")
    assert ref.heat == "error" and ref.percentile == 100.0 and ref.vmax == pytest.approx(height.max())


def test_change_of_every_later_mesh_shares_one_bar(tmp_path):
    V, F = icosphere(2)
    res = render_comparison([(V, F), (V * 1.01, F), (V * 1.03, F)], tmp_path / "all.png", size=(48, 48),
                            show_change=True, error_of="all", percentile=50, backend="matplotlib")
    assert len(res.panels) == 5 and [e.max() for e in res.errors] == pytest.approx([0.01, 0.03])
    assert res.vmax == pytest.approx(np.percentile(np.concatenate(res.errors), 50))
    with pytest.raises(ValueError, match=r"percentile must be a number in \(0, 100\], got 0"):
        render_comparison([(V, F), (V, F)], tmp_path / "x.png", show_change=True, percentile=0)


def test_zoom_on_a_vertex_crops_a_ball_and_fills_the_picture(tmp_path):
    V, F = grid(81, 81)
    sides, diagonals = 2 * 81 * 80, 80 * 80  # edges of the grid: sides of 1/80 and one diagonal per square
    h = (sides + diagonals * np.sqrt(2)) / (sides + diagonals) / 80  # its mean edge length
    centre = 40 * 81 + 40  # the middle vertex
    noisy = V + [0, 0, 0.001] * np.random.default_rng(0).standard_normal((len(V), 1))
    res = render_comparison([(V, F), (noisy, F)], tmp_path / "zoom.png", size=(64, 64), show_change=True,
                            zoom=(centre, 6.0), backend="matplotlib")
    point, radius = res.zoom
    assert point == pytest.approx(tuple(V[centre])) and radius == pytest.approx(6 * h, rel=1e-9)
    near = np.linalg.norm(V - V[centre], axis=1) <= radius  # the faces drawn: those with a vertex in the ball
    kept = np.unique(F[near[F].any(axis=1)])
    assert res.errors[0].shape == kept.shape
    np.testing.assert_allclose(res.errors[0], np.abs(noisy - V)[kept, 2], atol=1e-15)
    assert res.camera.project(V[centre][None], (64, 64))[0, :2] == pytest.approx([32, 32])
    assert covered(res.panels[0]).mean() > 0.6  # the ball fills the panel: a disc
    alone = render_comparison([(V, F)], tmp_path / "whole.png", size=(64, 64), backend="matplotlib")
    assert covered(alone.panels[0]).mean() < covered(res.panels[0]).mean()
    by_point = render_comparison([(V, F)], tmp_path / "p.png", size=(64, 64), zoom=(tuple(V[centre]), 6.0),
                                 backend="matplotlib")
    assert np.array_equal(by_point.panels[0], res.panels[0])


def test_zoom_bad_values_are_named(tmp_path):
    V, F = grid(5, 5)
    with pytest.raises(ValueError, match="vertex 99 does not exist"):
        render_comparison([(V, F)], tmp_path / "x.png", zoom=(99, 3))
    with pytest.raises(ValueError, match="zoom radius must be a number > 0"):
        render_comparison([(V, F)], tmp_path / "x.png", zoom=(0, 0))
    with pytest.raises(ValueError, match="no face has a vertex within"):
        render_comparison([(V, F)], tmp_path / "x.png", zoom=((10.0, 10.0, 10.0), 1))
    with pytest.raises(ValueError, match="zoom must be"):
        render_comparison([(V, F)], tmp_path / "x.png", zoom=5)
    assert not (tmp_path / "x.png").exists()


def test_render_cli_without_reference_and_with_zoom(tmp_path):
    from click.testing import CliRunner

    from meshdenoise.cli import cli
    from meshdenoise.io import save_arrays

    V, F = icosphere(3)
    save_arrays(tmp_path / "scan.ply", V, F)
    save_arrays(tmp_path / "den.ply", V * 1.01, F)
    base = ["render", str(tmp_path / "scan.ply"), str(tmp_path / "den.ply"), "--size", "48x48",
            "--backend", "matplotlib"]
    res = CliRunner().invoke(cli, [*base, "--png", str(tmp_path / "a.png")])
    assert res.exit_code == 0, res.output
    assert "3 panels" in res.output and "99th percentile" in res.output and "0.01" in res.output
    res = CliRunner().invoke(cli, [*base, "--png", str(tmp_path / "b.png"), "--zoom", "0,3", "--percentile", "90"])
    assert res.exit_code == 0, res.output
    assert "zoomed on (-0.5257, 0.8507, 0), radius" in res.output and "90th percentile" in res.output
    res = CliRunner().invoke(cli, [*base, "--png", str(tmp_path / "c.png"), "--zoom", "1,2,3"])
    assert res.exit_code == 2 and "VERTEX,RADIUS or X,Y,Z,RADIUS" in res.output and "Traceback" not in res.output
    res = CliRunner().invoke(cli, [*base, "--png", str(tmp_path / "c.png"), "--zoom", "5000,3"])
    assert res.exit_code == 2 and "vertex 5000 does not exist" in res.output
    assert not (tmp_path / "c.png").exists()


def test_png_mode_follows_the_umask_like_other_outputs(tmp_path):
    import os
    import stat

    from click.testing import CliRunner

    from meshdenoise.cli import cli
    from meshdenoise.io import _UMASK, save_mesh

    expected = 0o666 & ~_UMASK  # 0644 under umask 022
    V, F = icosphere(1)
    render_comparison([(V, F)], tmp_path / "api.png", size=(32, 32), backend="matplotlib")
    save_mesh(tmp_path / "mesh.ply", V, F)
    assert stat.S_IMODE(os.stat(tmp_path / "api.png").st_mode) == expected
    assert stat.S_IMODE(os.stat(tmp_path / "mesh.ply").st_mode) == expected
    (tmp_path / "pipe.yaml").write_text(
        f"inputs: {tmp_path / 'mesh.ply'}\noutput_dir: {tmp_path / 'out'}\nsteps:\n"
        "  - render: {path: '{stem}.png', backend: matplotlib, size: [32, 32]}\n")
    res = CliRunner().invoke(cli, ["run", str(tmp_path / "pipe.yaml"), "--serial"])
    assert res.exit_code == 0, res.output
    assert stat.S_IMODE(os.stat(tmp_path / "out" / "mesh.png").st_mode) == expected
    os.chmod(tmp_path / "api.png", 0o640)  # a replaced picture keeps its mode
    render_comparison([(V, F)], tmp_path / "api.png", size=(32, 32), backend="matplotlib")
    assert stat.S_IMODE(os.stat(tmp_path / "api.png").st_mode) == 0o640


@pytest.fixture
def fresh_verdict(monkeypatch, tmp_path):
    """No Open3D failure remembered in this process; the settings of a machine with a GPU device node (a file made here)."""
    from meshdenoise.render import backends

    monkeypatch.setattr(backends, "_OPEN3D_VERDICT", None)  # process state, as in a fresh process
    (tmp_path / "dev" / "dri").mkdir(parents=True)
    (tmp_path / "dev" / "dri" / "renderD128").touch()
    return RenderSettings(devices=str(tmp_path / "dev"))


def test_no_vulkan_falls_back_at_once_without_a_child(fresh_verdict, monkeypatch, tmp_path):
    import subprocess
    import time

    from meshdenoise.render import offscreen

    settings = fresh_verdict
    monkeypatch.setattr(offscreen, "_vulkan_missing", lambda: "no Vulkan driver is installed")
    monkeypatch.setattr(subprocess, "Popen", lambda *a, **k: pytest.fail("no child may start"))
    start = time.perf_counter()
    with pytest.warns(UserWarning, match="cannot start: no Vulkan driver"):
        res = render_comparison([icosphere(1)], tmp_path / "a.png", size=(32, 32), settings=settings)
    assert res.backend == "matplotlib" and time.perf_counter() - start < 10
    monkeypatch.setattr(offscreen, "_vulkan_missing", lambda: pytest.fail("the verdict is remembered"))
    with pytest.warns(UserWarning, match="failed earlier in this process"):
        assert render_comparison([icosphere(1)], tmp_path / "b.png", size=(32, 32),
                                 settings=settings).backend == "matplotlib"


def test_a_stalled_frame_is_retried_once_then_falls_back_fast(fresh_verdict, monkeypatch, tmp_path):
    import dataclasses
    import functools
    import time

    from meshdenoise.render import backends, offscreen

    settings = dataclasses.replace(fresh_verdict, frame_seconds=1.0)
    monkeypatch.setattr(offscreen, "_vulkan_missing", lambda: None)
    # a child whose renderer starts and whose first frame never comes
    child = offscreen._Child
    stalls = "import time; print('MESHDENOISE_READY', flush=True); time.sleep(120)"
    monkeypatch.setattr(offscreen, "_Child", functools.partial(child, program=stalls))
    start = time.perf_counter()
    with pytest.warns(UserWarning, match=r"waited for frame 1 of 1 \(1 s allowed\); then waited for frame 1 of 1"):
        res = render_comparison([icosphere(1)], tmp_path / "a.png", size=(32, 32), settings=settings)
    assert res.backend == "matplotlib" and time.perf_counter() - start < 30
    # a renderer that never starts is not tried twice
    backends._OPEN3D_VERDICT = None
    monkeypatch.setenv("MESHDENOISE_RENDER_STARTUP", "1")
    never_starts = "import time; time.sleep(120)"
    monkeypatch.setattr(offscreen, "_Child", functools.partial(child, program=never_starts))
    with pytest.warns(UserWarning) as caught:
        render_comparison([icosphere(1)], tmp_path / "b.png", size=(32, 32), settings=settings)
    text = str(caught[0].message)
    assert "waited for the renderer to start (1 s allowed" in text and "then" not in text


def test_software_zbuffer_keeps_the_nearest_surface_and_covers_exactly_the_pixel_centres_inside():
    from matplotlib.path import Path as MplPath

    from meshdenoise.render.raster import _draw_matplotlib

    square = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    quad = np.array([[0, 1, 2], [0, 2, 3]])
    far_v, near_v = square - [0.6, 0.6, 0], square - [0.2, 0.2, -0.5]  # the near square is 0.5 closer to the eye
    V = np.vstack([far_v, near_v])
    colors = np.array([[1.0, 0, 0]] * 4 + [[0, 0, 1.0]] * 4)
    cam = frame_camera([V], (80, 80))
    both = []
    for F in (np.vstack([quad, quad + 4]), np.vstack([quad + 4, quad])):  # drawing order must not matter
        both.append(_draw_matplotlib({"V": V, "F": F, "colors": colors}, (80, 80), cam))
    assert np.array_equal(both[0], both[1])
    img = both[0]
    centres = np.stack(np.meshgrid(np.arange(80) + 0.5, np.arange(80) + 0.5), -1).reshape(-1, 2)
    proj = cam.project(V, (80, 80))[:, :2]
    inside_far = MplPath(proj[:4]).contains_points(centres).reshape(80, 80)
    inside_near = MplPath(proj[4:]).contains_points(centres).reshape(80, 80)
    blue = (img[:, :, 2] > 200) & (img[:, :, 0] < 50)
    red = (img[:, :, 0] > 200) & (img[:, :, 2] < 50)
    assert (blue != inside_near).sum() <= 4  # only pixel centres on an edge may differ
    assert (red != (inside_far & ~inside_near)).sum() <= 4
    assert (inside_far & inside_near).sum() > 100  # the overlap is real, and blue there


def test_show_png_without_reference_adds_the_change_of_every_later_mesh(tmp_path, monkeypatch):
    from click.testing import CliRunner

    from meshdenoise.cli import cli
    from meshdenoise.io import save_arrays

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    V, F = icosphere(2)
    for name, s in (("a", 1.0), ("b", 1.01), ("c", 1.02)):
        save_arrays(tmp_path / f"{name}.ply", V * s, F)
    res = CliRunner().invoke(cli, ["show", *(str(tmp_path / f"{n}.ply") for n in "abc"), "--png",
                                   str(tmp_path / "s.png"), "--size", "40x40", "--backend", "matplotlib"])
    assert res.exit_code == 0, res.output
    assert "5 panels" in res.output and "displacement from the first mesh" in res.output


def test_software_zbuffer_batches_do_not_change_the_picture(tmp_path):
    from meshdenoise.render import raster

    V, F = icosphere(1)  # few, large triangles: each covers hundreds of pixels
    cam = frame_camera([V], (90, 90))
    job = raster._job(V, F, cam)
    whole = raster._draw_matplotlib(job, (90, 90), cam)
    assert np.array_equal(raster._draw_matplotlib(job, (90, 90), cam, chunk=37), whole)  # smaller than one
    # triangle: cut into bands of rows; and through render_comparison's settings
    batched = render_comparison([(V, F)], tmp_path / "b.png", size=(90, 90), backend="matplotlib",
                                settings=RenderSettings(zbuffer_chunk=37))
    assert np.array_equal(batched.panels[0], whole)
    assert 0.3 < covered(whole).mean() < 0.8


# --- headless without a GPU: matplotlib at once; zoom faces the detail; panels in a grid -------------------
def test_without_a_gpu_auto_draws_with_matplotlib_at_once(fresh_verdict, monkeypatch, tmp_path):
    """No GPU device node: no Open3D child, no warning, and the decision is made in well under a second."""
    import subprocess
    import time
    import warnings

    from meshdenoise.render import backends, offscreen, raster

    settings = RenderSettings(devices=str(tmp_path / "empty"))  # a machine without /dev/dri or /dev/nvidia*
    monkeypatch.setattr(subprocess, "Popen", lambda *a, **k: pytest.fail("no child may start"))
    monkeypatch.setattr(offscreen, "_draw_open3d", lambda *a, **k: pytest.fail("Open3D may not be tried"))
    monkeypatch.delenv("MESHDENOISE_RENDER_BACKEND", raising=False)
    started, first_frame = time.perf_counter(), []
    draw = raster._draw_matplotlib
    monkeypatch.setattr(raster, "_draw_matplotlib",
                        lambda *a: (first_frame.append(first_frame or time.perf_counter() - started), draw(*a))[1])
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the expected case on a server: said in backend_detail, not warned
        res = render_comparison([icosphere(1)], tmp_path / "a.png", size=(32, 32), settings=settings)
    assert res.backend == "matplotlib" and "no GPU device" in res.backend_detail
    assert first_frame[0] < 0.5, first_frame  # from the call to the first matplotlib frame
    assert backends._OPEN3D_VERDICT is None  # nothing failed: a GPU showing up later is used
    start = time.perf_counter()
    for _ in range(100):
        assert offscreen._no_gpu(settings)
    assert (time.perf_counter() - start) / 100 < 0.01


def test_with_a_gpu_auto_tries_open3d_and_an_explicit_backend_always_does(fresh_verdict, monkeypatch, tmp_path):
    from meshdenoise.render import offscreen, raster

    settings = fresh_verdict
    tried = []

    class FakeChild:  # started early by render_comparison; must be closed
        def __init__(self, size):
            tried.append(("child", size))

        def close(self):
            tried.append("closed")

    def fake_open3d(jobs, size, camera, timeout, child=None, settings=None):
        tried.append(("draw", len(jobs)))
        return [raster._draw_matplotlib(j, size, camera) for j in jobs], "fake Open3D"

    monkeypatch.setattr(offscreen, "_Child", FakeChild)
    monkeypatch.setattr(offscreen, "_draw_open3d", fake_open3d)
    monkeypatch.setattr(offscreen, "_vulkan_missing", lambda: None)
    res = render_comparison([icosphere(1)], tmp_path / "a.png", size=(32, 32), settings=settings)
    assert res.backend == "open3d" and tried == [("child", (32, 32)), ("draw", 1), "closed"]
    tried.clear()
    no_gpu = RenderSettings(devices=str(tmp_path / "empty"))  # no GPU, but Open3D asked for by name
    assert render_comparison([icosphere(1)], tmp_path / "b.png", size=(32, 32), backend="open3d",
                             settings=no_gpu).backend == "open3d"
    assert tried == [("child", (32, 32)), ("draw", 1), "closed"]


def _plane_facing(direction, n=81):
    """The grid turned so that its normal is ``direction``: grid triangles (i, j), (i+1, j), (i+1, j+1) turn
    counter-clockwise seen from +z, so +z goes to ``direction`` by a rotation (u, v, d) with u x v = d."""
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    u = np.cross(d, [0.3, 0.2, 0.9])
    u /= np.linalg.norm(u)
    v = np.cross(d, u)
    V, F = grid(n, n)
    V = V - [0.5, 0.5, 0.0]
    return V[:, :1] * u + V[:, 1:2] * v + V[:, 2:] * d, F, d


@pytest.mark.parametrize("direction", [(1.0, 0.0, 0.0), (0.5, 0.5, -0.7)])
def test_zoom_looks_along_the_details_mean_normal(tmp_path, direction):
    V, F, d = _plane_facing(direction)
    centre = 40 * 81 + 40
    res = render_comparison([(V, F)], tmp_path / "z.png", size=(64, 64), zoom=(centre, 6.0), backend="matplotlib")
    assert res.facing == pytest.approx(tuple(d), abs=1e-9)
    eye = np.subtract(res.camera.eye, res.camera.center)
    assert eye / np.linalg.norm(eye) == pytest.approx(d, abs=1e-9)  # the camera in front of the detail
    assert covered(res.panels[0]).mean() > 0.6  # seen face on: a disc filling the panel
    lit = res.panels[0][covered(res.panels[0])].mean()
    # a --view given wins: from +z this plane is seen edge-on (x facing) or from behind at a slant
    side = render_comparison([(V, F)], tmp_path / "v.png", size=(64, 64), zoom=(centre, 6.0), view=(0, 0),
                             backend="matplotlib")
    assert side.facing is None
    eye = np.subtract(side.camera.eye, side.camera.center)
    assert eye / np.linalg.norm(eye) == pytest.approx([0, 0, 1], abs=1e-12)
    if direction[2] == 0:
        assert covered(side.panels[0]).mean() < 0.1  # edge-on: a line
    else:
        assert covered(side.panels[0]).mean() < covered(res.panels[0]).mean()
    assert lit > 100


def test_mean_normal_is_the_area_weighted_normal_or_none():
    from meshdenoise.render import mean_normal

    # two triangles in the x = 0 plane (areas 1/2 and 2), both counter-clockwise seen from +x: (1, 0, 0)
    V = np.array([[0.0, 0, 0], [0, 1, 0], [0, 0, 1], [0, 2, 0], [0, 0, 2]])
    assert mean_normal(V, np.array([[0, 1, 2], [0, 3, 4]])) == pytest.approx((1, 0, 0))
    # area 1/2 facing +x and area 2 facing +y: (1/2, 2, 0) normalised, (1, 4, 0) / sqrt(17)
    W = np.array([[0.0, 0, 0], [0, 1, 0], [0, 0, 1], [2, 0, 0], [0, 0, -2]])
    assert mean_normal(W, np.array([[0, 1, 2], [0, 3, 4]])) == pytest.approx(np.array([1, 4, 0]) / np.sqrt(17))
    assert mean_normal(*icosphere(2)) is None  # closed: the normals cancel out
    assert mean_normal(V, np.zeros((0, 3), dtype=int)) is None


def test_view_facing_turns_an_open_scan_to_the_camera(tmp_path):
    """view='facing' without zoom: the whole first mesh's mean normal, as a range scan seen from its scanner."""
    V, F, d = _plane_facing((-0.6, 0.3, -0.5), n=41)
    res = render_comparison([(V, F), (V * 1.01, F)], tmp_path / "f.png", size=(48, 48), view="facing",
                            show_change=True, backend="matplotlib")
    assert res.facing == pytest.approx(tuple(d), abs=1e-9)
    eye = np.subtract(res.camera.eye, res.camera.center)
    assert eye / np.linalg.norm(eye) == pytest.approx(d, abs=1e-9)
    default = render_comparison([(V, F)], tmp_path / "d.png", size=(48, 48), backend="matplotlib")
    assert default.facing is None and covered(default.panels[0]).mean() < covered(res.panels[0]).mean()
    with pytest.raises(ValueError, match="view must be"):
        render_comparison([(V, F)], tmp_path / "x.png", view="sideways")


def test_zoom_on_a_closed_part_keeps_the_default_view(tmp_path):
    V, F = icosphere(2)
    res = render_comparison([(V, F)], tmp_path / "z.png", size=(48, 48), zoom=(0, 100.0), backend="matplotlib")
    assert res.facing is None
    eye = np.subtract(res.camera.eye, res.camera.center)
    assert eye / np.linalg.norm(eye) == pytest.approx([0, 0, 1], abs=1e-12)


def test_render_cli_zoom_says_where_it_looks_from(tmp_path):
    from click.testing import CliRunner

    from meshdenoise.cli import cli
    from meshdenoise.io import save_arrays

    V, F, _ = _plane_facing((1.0, 0.0, 0.0), n=41)
    save_arrays(tmp_path / "a.ply", V, F)
    save_arrays(tmp_path / "b.ply", V * 1.01, F)
    base = ["render", str(tmp_path / "a.ply"), str(tmp_path / "b.ply"), "--size", "40x40", "--backend", "matplotlib",
            "--zoom", f"{20 * 41 + 20},4"]
    res = CliRunner().invoke(cli, [*base, "--png", str(tmp_path / "a.png")])
    assert res.exit_code == 0, res.output
    assert "seen along its mean normal (1, 0, 0)" in res.output
    res = CliRunner().invoke(cli, [*base, "--png", str(tmp_path / "b.png"), "--view", "0,0"])
    assert res.exit_code == 0, res.output
    assert "seen from --view 0,0" in res.output
    res = CliRunner().invoke(cli, [*base[:-2], "--png", str(tmp_path / "d.png"), "--view", "facing"])
    assert res.exit_code == 0, res.output
    assert "seen along the first mesh's mean normal (1, 0, 0)" in res.output
    res = CliRunner().invoke(cli, [*base, "--png", str(tmp_path / "c.png"), "--view", "north"])
    assert res.exit_code == 2
    assert res.output.strip().splitlines() == ["error: --view: expected AZIMUTH,ELEVATION in degrees, e.g. 30,20, or "
                                               "facing; got 'north'"]


def test_show_puts_four_meshes_and_their_changes_in_a_grid(tmp_path, monkeypatch):
    """Seven panels: the four meshes in a row, each change map under its mesh; the PNG is 4 panels wide."""
    from click.testing import CliRunner

    from meshdenoise.cli import cli
    from meshdenoise.io import save_arrays

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    V, F = icosphere(2)
    for name, s in (("a", 1.0), ("b", 1.01), ("c", 1.02), ("d", 1.04)):
        save_arrays(tmp_path / f"{name}.ply", V * s, F)
    res = CliRunner().invoke(cli, ["show", *(str(tmp_path / f"{n}.ply") for n in "abcd"), "--png",
                                   str(tmp_path / "s.png"), "--size", "40x40", "--backend", "matplotlib"])
    assert res.exit_code == 0, res.output
    assert "7 panels" in res.output
    png = matplotlib.image.imread(tmp_path / "s.png")
    # 4 panels of 40 px with 3 gaps of 8 and the colour bar's 110 px; two rows of 40 px under 40-px title bands
    assert png.shape[:2] == (2 * (40 + 40), 4 * 40 + 3 * 8 + 110)
    again = render_comparison([(V * s, F) for s in (1.0, 1.01, 1.02, 1.04)], tmp_path / "api.png", size=(40, 40),
                              show_change=True, error_of="all", backend="matplotlib")
    rows = [r for r, c, h, w in again.boxes]
    cols = [c for r, c, h, w in again.boxes]
    assert rows == [40] * 4 + [120] * 3
    assert cols == [0, 48, 96, 144, 48, 96, 144]  # the change to b under b, to c under c, to d under d
    img = (matplotlib.image.imread(tmp_path / "api.png")[:, :, :3] * 255).round().astype(np.uint8)
    for (r, c, h, w), panel in zip(again.boxes, again.panels):
        assert np.array_equal(img[r:r + h, c:c + w], panel)
    assert not covered(img[120:160, 0:40]).any()  # nothing under the first mesh
    # three panels (render: before / after / change) stay in one row
    three = render_comparison([(V, F), (V * 1.01, F)], tmp_path / "three.png", size=(40, 40), show_change=True,
                              backend="matplotlib")
    assert [b[0] for b in three.boxes] == [40, 40, 40]
    assert matplotlib.image.imread(tmp_path / "three.png").shape[:2] == (80, 3 * 40 + 2 * 8 + 110)
