"""``meshdenoise simulate-scan``: a virtual range scan of a clean mesh, noisy and noise-free."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import click
from rich.console import Console
from rich.text import Text

__all__ = ["COMMANDS", "simulate_scan_command"]

console = Console(soft_wrap=True, markup=False, highlight=False)  # paths are printed as they are, never as markup


def _fail(message: str) -> None:
    """One line on stderr, exit 2 (bad input)."""
    Console(stderr=True, soft_wrap=True, markup=False, highlight=False).print(
        Text.assemble(("error:", "red"), " ", str(message)))
    sys.exit(2)


def _pair(text: str, option: str, kind: type, example: str, separator: str = ",") -> tuple:
    parts = text.lower().split(separator)
    try:
        if len(parts) != 2:
            raise ValueError
        values = tuple(kind(p.strip()) for p in parts)
    except ValueError:
        _fail(f"{option} {text}: expected two numbers as {example}")
    if kind is float and not all(math.isfinite(v) for v in values):
        _fail(f"{option} {text}: the numbers must be finite")
    return values


@click.command("simulate-scan")
@click.argument("clean", type=click.Path(dir_okay=False, path_type=Path))
@click.argument("noisy", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--clean-out", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Also write the noise-free scan of the same rays here (same vertices and faces as NOISY).")
@click.option("--view", default="0,0", show_default=True, metavar="AZ,EL",
              help="Camera azimuth and elevation around the mesh, degrees; 0,0 looks from +z with +y up.")
@click.option("--resolution", default="640x480", show_default=True, metavar="WxH", help="Pixels of the range image.")
@click.option("--fov", default=40.0, show_default=True, type=float, help="Horizontal field of view, degrees.")
@click.option("--noise", default="0.3h", show_default=True, metavar="RHO[h]",
              help="Noise along the rays (rms): in mesh units, or in mean edge lengths of the scan with h.")
@click.option("--correlation", default=0.0, show_default=True, type=float, metavar="PIXELS",
              help="Correlation length of the noise in pixels (0: independent).")
@click.option("--stripes", default=0.0, show_default=True, type=float, metavar="S",
              help="Per-scanline offsets, as a fraction of the grain (0: none).")
@click.option("--outliers", default=0.0, show_default=True, type=float, metavar="FRACTION",
              help="Fraction of flying pixels, moved 3 to 6 noise levels along their ray.")
@click.option("--seed", default=0, show_default=True, type=int, help="Same seed, same noise.")
def simulate_scan_command(clean, noisy, clean_out, view, resolution, fov, noise, correlation, stripes, outliers, seed):
    """Scan the mesh CLEAN with a virtual range camera and write the noisy scan NOISY.

    The noise is added along the rays, grows with depth, and can be correlated over pixels,
    striped by scanline and have flying pixels; grazing surfaces and depth jumps are dropped,
    as a scanner does (open borders, holes). --clean-out writes the same scan without noise:
    a denoiser's result can be compared with it vertex to vertex.
    """
    from ..io import SUPPORTED_EXTENSIONS, MeshFileError, load_mesh, save_arrays
    from ..pipeline.noise_option import parse_noise_option
    from ..scanner import simulate_scan

    az_el = _pair(view, "--view", float, "AZ,EL in degrees, e.g. 30,20")
    size = _pair(resolution, "--resolution", int, "WIDTHxHEIGHT, e.g. 640x480", separator="x")
    try:
        level = parse_noise_option(noise, "--noise")
    except ValueError as exc:
        _fail(str(exc))
    if level.correlation_length:
        _fail(f"--noise {noise}: give the correlation in pixels with --correlation, not after a comma")
    if seed < 0:
        _fail(f"--seed {seed}: must be >= 0")
    outputs = [("NOISY", noisy)] + ([("--clean-out", clean_out)] if clean_out is not None else [])
    if not clean.is_file():
        _fail(f"{clean}: no such file")
    for what, path in outputs:
        if path.suffix.lower() not in SUPPORTED_EXTENSIONS:
            _fail(f"{path}: {what} has unsupported extension {path.suffix!r}; use one of {', '.join(SUPPORTED_EXTENSIONS)}")
        if path.resolve() == clean.resolve():
            _fail(f"{path}: {what} is the input file; input files are never overwritten")
    if clean_out is not None and clean_out.resolve() == noisy.resolve():
        _fail(f"{clean_out}: --clean-out and NOISY name the same file")
    try:
        mesh = load_mesh(clean)
        scan = simulate_scan((mesh.V, mesh.F), view=az_el, resolution=size, fov=fov, noise=level.level,
                             noise_in_edges=level.in_edges, correlation=correlation, stripes=stripes,
                             outliers=outliers, seed=seed)
    except MeshFileError as exc:
        _fail(str(exc))
    except (ValueError, TypeError) as exc:
        _fail(f"{clean}: {str(exc).removeprefix('simulate_scan: ')}")
    try:
        for what, path in outputs:
            path.parent.mkdir(parents=True, exist_ok=True)
            save_arrays(path, scan.V if what == "NOISY" else scan.V_clean, scan.F)
    except MeshFileError as exc:
        _fail(str(exc))
    except OSError as exc:
        _fail(f"{exc.filename or noisy}: {exc.strerror or exc}")
    w, h = scan.resolution
    console.print(f"{noisy}: {len(scan.V)} vertices, {len(scan.F)} faces ({len(scan.V) / (w * h):.0%} of {w}x{h} "
                  f"pixels); noise {scan.rho:.4g} rms along the rays ({scan.rho / scan.mean_edge:.3g} mean edge "
                  f"lengths of {scan.mean_edge:.4g})" + (f"; clean scan {clean_out}" if clean_out is not None else ""))


COMMANDS = [simulate_scan_command]
