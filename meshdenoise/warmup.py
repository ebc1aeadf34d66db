"""Compile the numerical kernels once, at installation: ``python -m meshdenoise.warmup`` (``make`` runs it).

numba compiles each kernel of :mod:`meshdenoise.kernels` on its first call and caches the machine code beside the
sources (or in ``NUMBA_CACHE_DIR``); a new installation's first run pays for it: 31 kernels, 0.4 to 1.1 s each, the
main job of ``make demo`` 19.5 s the first time against 3.6 to 3.8 s from the cache (docs/install.md). Running that
job once at installation moves the compilation there, so that the first command a user types takes the time every
later one takes.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

__all__ = ["compile_kernels", "main"]

WARMUP_MESH = "rangemaps/face000.ply"  # the main job's scan (pymeshlab's wheel ships it): the same code paths


def compile_kernels(mesh: str | Path | None = None) -> dict:
    """Run the default automatic denoise once on ``mesh`` (default: pymeshlab's ``rangemaps/face000.ply``, the scan
    ``make demo`` cleans), discarding the result, so that numba compiles and caches the kernels it calls.

    Parameters
    ----------
    mesh : str or Path, optional
        A mesh file Open3D or pymeshlab reads.

    Returns
    -------
    dict
        ``mesh`` (the path), ``vertices``, ``seconds`` (the call, compilation included) and ``compiled`` (whether the
        cache held no kernel before: :func:`~meshdenoise.kernels.compiled_here`).

    Examples
    --------
    >>> from meshdenoise.warmup import compile_kernels
    >>> compile_kernels()["vertices"]  # doctest: +SKIP
    85182
    """
    from .data import sample_mesh
    from .default import denoise
    from .io import load_arrays
    from .kernels import compiled_here

    path = Path(mesh if mesh is not None else sample_mesh(WARMUP_MESH))
    V, F = load_arrays(path)
    fresh = not compiled_here()
    t = time.perf_counter()
    denoise((V, F))
    return {"mesh": str(path), "vertices": int(V.shape[0]), "seconds": time.perf_counter() - t, "compiled": fresh}


def main(argv: list[str] | None = None) -> int:
    """``python -m meshdenoise.warmup [MESH]``: :func:`compile_kernels`, one line on stdout."""
    args = sys.argv[1:] if argv is None else list(argv)
    if len(args) > 1:
        print("usage: python -m meshdenoise.warmup [MESH]", file=sys.stderr)
        return 2
    try:
        done = compile_kernels(args[0] if args else None)
    except (OSError, ValueError) as err:  # an unreadable or empty mesh: one line, no traceback
        print(f"meshdenoise.warmup: {args[0] if args else WARMUP_MESH}: {err}", file=sys.stderr)
        return 2
    what = "compiled and cached the numerical kernels" if done["compiled"] else "the numerical kernels were cached"
    print(f"meshdenoise: {what}: the default on {Path(done['mesh']).name} ({done['vertices']:,} vertices) "
          f"in {done['seconds']:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
