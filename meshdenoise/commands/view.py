"""``meshdenoise show``, ``render`` and ``report``: look at meshes and at a run's results."""

from __future__ import annotations

import json
import math
import os
import sys
import warnings
from pathlib import Path

import click

MESH = click.Path(exists=True, dir_okay=False, path_type=Path)


class _OneLineUsage(click.Command):
    """A command whose usage errors (a bad option value, an unknown option, a missing argument) are one
    ``error: ...`` line and exit code 2, as its other bad input (:func:`meshdenoise.cli.usage_error`)."""

    def make_context(self, info_name, args, parent=None, **extra):
        try:
            return super().make_context(info_name, args, parent=parent, **extra)
        except click.UsageError as exc:
            from ..cli import usage_error

            path = f"{parent.command_path} {info_name}" if parent is not None else info_name
            raise usage_error(exc, path) from None


def _fail(message: str, code: int = 2) -> None:
    """One line on stderr, exit code 2 (bad input); the message is printed as it is (no markup)."""
    click.echo(f"error: {message}", err=True)
    sys.exit(code)


def _parse_size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        _fail(f"--size: expected WIDTHxHEIGHT in pixels, e.g. 400x400; got {text!r}")
    if not (16 <= w <= 4096 and 16 <= h <= 4096):
        _fail(f"--size: {text!r}: width and height must be 16..4096 pixels")
    return w, h


def _parse_view(text: str | None) -> tuple[float, float] | str | None:
    """'AZ,EL' -> (azimuth, elevation), 'facing' as it is; None without --view (0,0, or 'facing' with --zoom)."""
    if text is None:
        return None
    if text.strip().lower() == "facing":
        return "facing"
    try:
        az, el = (float(x) for x in text.split(","))
    except ValueError:
        _fail(f"--view: expected AZIMUTH,ELEVATION in degrees, e.g. 30,20, or facing; got {text!r}")
    if not (math.isfinite(az) and math.isfinite(el)):
        _fail(f"--view: {text!r}: azimuth and elevation must be finite numbers of degrees")
    return az, el


def _parse_zoom(text: str | None):
    """'VERTEX,RADIUS' or 'X,Y,Z,RADIUS' (radius in mean edge lengths) -> (centre, radius)."""
    if text is None:
        return None
    parts = text.split(",")
    try:
        if len(parts) == 2:
            return int(parts[0]), float(parts[1])
        if len(parts) == 4:
            return tuple(float(x) for x in parts[:3]), float(parts[3])
    except ValueError:
        pass
    _fail(f"--zoom: expected VERTEX,RADIUS or X,Y,Z,RADIUS (radius in mean edge lengths), e.g. 1200,15; got {text!r}")


_common = [
    click.option("--size", default="400x400", show_default=True, help="Pixels of one panel, WIDTHxHEIGHT."),
    click.option("--view", default=None, metavar="AZ,EL | facing",
                 help="AZIMUTH,ELEVATION in degrees; 0,0 (the default) looks from +z with +y up. facing: along "
                      "the first mesh's mean normal (a range scan faces you), the default with --zoom; a --view "
                      "given wins."),
    click.option("--error-mode", type=click.Choice(["auto", "vertex", "nearest"]), default="auto", show_default=True,
                 help="vertex: displacement of vertex i from reference vertex i; nearest: distance to the "
                      "reference surface; auto: vertex when the faces are the same."),
    click.option("--vmax", type=click.FloatRange(min=0, min_open=True), default=None,
                 help="Top of the colour bar (default: the --percentile of the values shown)."),
    click.option("--percentile", type=click.FloatRange(min=0, max=100, min_open=True), default=None,
                 help="Where the colour bar tops without --vmax: default 100 (the largest error) with --reference, "
                      "99 for the change from the first mesh."),
    click.option("--zoom", default=None, metavar="VERTEX,R | X,Y,Z,R",
                 help="Look at a detail: the ball of radius R (mean edge lengths) around a vertex of the first "
                      "mesh or a point; only it is drawn, seen along its mean normal (unless --view is given)."),
    click.option("--backend", type=click.Choice(["auto", "open3d", "matplotlib"]), default="auto", show_default=True,
                 help="Rasteriser; auto: Open3D's OffscreenRenderer when there is a GPU (else, or when it fails, "
                      "matplotlib)."),
]


def _with_common(f):
    for option in reversed(_common):
        f = option(f)
    return f


def _render(meshes, png, reference, titles, size, view, error_mode, vmax, backend, error_of="last",
            percentile=None, zoom=None):
    from ..io import MeshFileError
    from ..render import RenderError, render_comparison

    if vmax is not None and not math.isfinite(vmax):  # click's FloatRange lets nan and inf through
        _fail(f"--vmax: {vmax!r}: the top of the colour bar must be a finite positive number")
    size, view, zoom = _parse_size(size), _parse_view(view), _parse_zoom(zoom)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", UserWarning)
            result = render_comparison(list(meshes), png, reference=reference, titles=titles,
                                       size=size, view=view, error_of=error_of,
                                       error_mode=error_mode, vmax=vmax, backend=backend,
                                       show_change=reference is None, percentile=percentile, zoom=zoom)
    except (ValueError, TypeError, MeshFileError) as exc:
        _fail(" ".join(str(exc).split()))
    except OSError as exc:  # the PNG's folder is missing or not writable
        _fail(f"{png}: cannot be written: {exc.strerror or exc}")
    except RenderError as exc:  # --backend open3d asked for, and it failed: not bad input
        _fail(" ".join(str(exc).split()), code=1)
    for w in caught:  # one line each, not Python's warning format with a source line
        click.echo(f"warning: {w.message}", err=True)
    click.echo(f"wrote {result.path} ({len(result.panels)} panels) with {result.backend_detail}")
    if result.facing is not None:
        seen = "seen along its mean normal ({:.3g}, {:.3g}, {:.3g})".format(*result.facing)
    elif isinstance(view, tuple):
        seen = f"seen from --view {view[0]:g},{view[1]:g}"
    else:
        seen = "seen from 0,0 (its normals cancel out: no side faces the camera)"
    if result.zoom is not None:
        (x, y, z), r = result.zoom
        click.echo(f"zoomed on ({x:.4g}, {y:.4g}, {z:.4g}), radius {r:.4g} (mesh units), {seen}")
    elif view == "facing":
        click.echo(seen.replace("its", "the first mesh's"))
    if result.vmax is not None:
        what = "error" if result.heat == "error" else "displacement from the first mesh"
        top = "maximum" if result.percentile in (None, 100.0) else f"{result.percentile:g}th percentile"
        if result.percentile is None:
            top = "--vmax"
        click.echo(f"colour bar 0 to {result.vmax:.4g} ({result.error_mode} {what}; top = {top})")


def _has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


@click.command(cls=_OneLineUsage)
@click.argument("meshes", nargs=-1, required=True, type=MESH)
@click.option("--png", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Render to this PNG instead of opening a window (default without a display: show.png).")
@click.option("--reference", type=MESH, default=None,
              help="Clean mesh: add error heat maps of every mesh (without it, the PNG shows how far each later "
                   "mesh moved from the first).")
@_with_common
def show(meshes, png, reference, size, view, error_mode, vmax, percentile, zoom, backend):
    """Look at MESHES: Open3D's viewer with a display, else (or with --png) a headless PNG.

    In the viewer the meshes stand side by side along x (coloured by their error when
    --reference is given); in the PNG they share one camera, followed by heat maps of the
    error against --reference or, without one, of the displacement of every later mesh from
    the first.
    """
    if png is None and _has_display():
        _open_viewer(meshes, reference, error_mode, vmax)
        return
    if png is None:
        png = Path("show.png")
        click.echo("no display found: rendering headless to show.png (use --png to choose)")
    _render(meshes, png, reference, None, size, view, error_mode, vmax, backend, error_of="all",
            percentile=percentile, zoom=zoom)


def _open_viewer(paths, reference, error_mode, vmax):
    import numpy as np
    import open3d as o3d

    from ..io import load_mesh
    from ..render.heatmaps import _default_vmax, error_colors, vertex_error

    geoms, offset = [], 0.0
    errors = [vertex_error(p, reference, error_mode)[0] for p in paths] if reference else None
    top = (vmax or _default_vmax(errors)) if errors else None
    for k, path in enumerate(paths):
        m = load_mesh(path)
        V = m.V.copy()
        width = float(np.ptp(V[:, 0]))
        V[:, 0] += offset - V[:, 0].min()
        offset += width * 1.1
        mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(m.F.astype(np.int32)))
        mesh.compute_vertex_normals()
        if errors is not None:
            mesh.vertex_colors = o3d.utility.Vector3dVector(error_colors(errors[k], top))
        geoms.append(mesh)
    o3d.visualization.draw_geometries(geoms, window_name="meshdenoise: " + ", ".join(p.name for p in paths))


@click.command(cls=_OneLineUsage)
@click.argument("before", type=MESH)
@click.argument("after", type=MESH)
@click.option("--reference", type=MESH, default=None,
              help="The clean mesh the error is measured against; without it (a scan) the third panel is the "
                   "displacement from BEFORE to AFTER.")
@click.option("--png", type=click.Path(dir_okay=False, path_type=Path), required=True, help="PNG to write.")
@_with_common
def render(before, after, reference, png, size, view, error_mode, vmax, percentile, zoom, backend):
    """Before / after / a heat map, side by side in one PNG.

    The heat map is the error of AFTER against --reference, or without a reference the
    displacement of every vertex from BEFORE to AFTER, on a colour bar topped at the 99th
    percentile (--percentile, --vmax). --zoom VERTEX,R or X,Y,Z,R draws only a ball of
    radius R mean edge lengths, seen along the detail's mean normal unless --view is given;
    --view facing turns a whole scan to the camera. Without a GPU the software rasteriser
    draws at once (--backend open3d forces Open3D).
    """
    _render([before, after], png, reference, [f"before: {before.name}", f"after: {after.name}"],
            size, view, error_mode, vmax, backend, percentile=percentile, zoom=zoom)


@click.command(cls=_OneLineUsage)
@click.argument("run_dir", type=click.Path(exists=True, file_okay=False, path_type=Path))
@click.option("--embed", is_flag=True, help="Put the pictures inside the page (it can then be moved alone).")
@click.option("--pipeline", type=click.Path(exists=True, dir_okay=False, path_type=Path), default=None,
              help="The run's pipeline file, shown in the page (run does not copy it into RUN_DIR).")
@click.option("--no-renders", is_flag=True, help="Leave out the before / after / change picture of each output.")
def report(run_dir, embed, pipeline, no_renders):
    """Write RUN_DIR/report.html: the results table and a chart per swept parameter (with a sweep), each
    output before / after / change, the plots and renders, the pipeline.

    The pictures go into RUN_DIR/report-renders/ (inside the page with --embed).
    """
    from ..report import write_report

    try:
        path = write_report(run_dir, embed=embed, pipeline=pipeline, renders=not no_renders)
    except RecursionError:  # json.load on [[[[...]]]]: a results file nested thousands of levels deep
        _fail(f"{run_dir}: a JSON file there is nested too deeply to be a results table")
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        _fail(f"{run_dir}: a JSON file there cannot be read: {exc}")
    except (ValueError, TypeError, OSError) as exc:
        _fail(f"{run_dir}: {exc}")
    click.echo(f"wrote {path}")
    sys.stdout.flush()


COMMANDS = [show, render, report]
