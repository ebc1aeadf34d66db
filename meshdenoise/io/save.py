"""Writing any mesh file atomically (:func:`save_mesh`), the format from the extension."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..arrays import MeshValidationError, check_mesh_arrays
from .atomic import atomic_path
from .errors import _check_extension, MeshFileError, PrecisionWarning, STL_TOLERANCE
from .meshfile import PlyExtras
from .obj import _write_obj
from .off import _write_off
from .ply_write import _write_ply
from .stl import _write_stl


def save_mesh(
    path: str | os.PathLike,
    V: np.ndarray,
    F: np.ndarray,
    vertex_colors: np.ndarray | None = None,
    *,
    binary: bool = True,
    extras: PlyExtras | None = None,
    vertex_normals: np.ndarray | None = None,
    precision: str = "float64",
) -> Path:
    """Write a mesh atomically (temporary file, then rename); the format comes from the extension.

    PLY (binary little-endian, or ASCII with ``binary=False``) stores ``double``
    coordinates (``float`` with ``precision="float32"``) and ``uchar`` RGBA colours; OFF (COFF with colours) and OBJ (``v x y z r g b``)
    store 17 significant digits, so reading the file back gives the same arrays. STL
    stores float32 corners (binary) or 17 digits (ASCII), and no colours. Nothing is left at ``path``
    if writing fails, and an existing file there is replaced only once the new one is complete.

    Parameters
    ----------
    path : str or PathLike
    V : array_like, shape (n, 3)
    F : array_like of int, shape (m, 3)
        ``m`` may be 0 (a point cloud), except for STL.
    vertex_colors : array_like, shape (n, 3) or (n, 4), in [0, 1], optional
    binary : bool
        PLY and STL only.
    extras : PlyExtras, optional
        A PLY file's other properties and elements (:attr:`MeshFile.extras`), written to a PLY
        (other formats cannot hold them): what stays valid for ``V`` and ``F``
        (:meth:`PlyExtras.for_mesh`), normals recomputed from ``V`` (unless ``vertex_normals`` are given).
    vertex_normals : array_like, shape (n, 3), optional
        Per-vertex normals written as they are: PLY ``nx ny nz`` (in the coordinates' type), OBJ
        ``vn`` lines (faces ``f a//a b//b c//c``). OFF and STL have no per-vertex normals: not written.
    precision : {"float64", "float32"}
        PLY's coordinate type: ``double`` (exact) or ``float`` (half the size, what MeshLab's float
        build and most viewers write). A :class:`PrecisionWarning` says when float32 moves a vertex by
        more than :data:`STL_TOLERANCE` mean edge lengths (a georeferenced scan), as for binary STL.

    Returns
    -------
    Path

    Raises
    ------
    MeshFileError
        Naming the file: bad arrays (NaN, bad indices), bad colours or normals, a point cloud as
        STL, ``precision="float32"`` for another format than PLY, or an OS error (permission, disk full).

    Examples
    --------
    >>> import tempfile, pathlib, numpy as np
    >>> from meshdenoise.io import load_mesh
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "t.ply"
    >>> _ = save_mesh(p, np.eye(3), np.array([[0, 1, 2]]))
    >>> load_mesh(p).V.tolist()
    [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    """
    path = Path(path)
    _check_extension(path)
    try:
        V, F = check_mesh_arrays(V, F, allow_no_faces=True)
    except (MeshValidationError, TypeError) as exc:
        raise MeshFileError(f"{path}: cannot be written: {exc}") from None
    C = None
    if vertex_colors is not None:
        C = np.asarray(vertex_colors, dtype=np.float64)
        if C.shape not in ((V.shape[0], 3), (V.shape[0], 4)):
            raise MeshFileError(f"{path}: vertex_colors must have shape ({V.shape[0]}, 3 or 4), got {C.shape}")
        if not np.isfinite(C).all() or C.min() < 0 or C.max() > 1:
            raise MeshFileError(f"{path}: vertex_colors must lie in [0, 1], got values in [{C.min()}, {C.max()}]")
        if C.shape[1] == 3:
            C = np.hstack([C, np.ones((C.shape[0], 1))])
    ext = path.suffix.lower()
    if precision not in ("float64", "float32"):
        raise MeshFileError(f"{path}: precision must be 'float64' or 'float32', got {precision!r}")
    if precision == "float32" and ext != ".ply":
        raise MeshFileError(f"{path}: precision 'float32' is for PLY only (OBJ and OFF write 17 significant digits, "
                            "binary STL is always float32)")
    N = None
    if vertex_normals is not None:
        N = np.asarray(vertex_normals, dtype=np.float64)
        if N.shape != V.shape:
            raise MeshFileError(f"{path}: vertex_normals must have shape {V.shape}, got {N.shape}")
        if not np.isfinite(N).all():
            raise MeshFileError(f"{path}: vertex_normals must be finite")
    if ext == ".stl" and F.shape[0] == 0:
        raise MeshFileError(f"{path}: STL stores triangles only and this mesh has no faces; use .ply for a point cloud")
    if ext == ".stl" and binary:
        _warn_if_float32_moves(path, V, F)
    if ext == ".ply" and precision == "float32":
        _warn_if_float32_moves(path, V, F, "PLY (precision float32)", "save with precision float64")
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        more = (N, "f4" if precision == "float32" else "f8") if N is not None or precision == "float32" else ()
        _WRITERS[ext](fh, V, F, C, binary, extras, *more)
    return path


def float32_move(V: np.ndarray, F: np.ndarray) -> tuple[float, float]:
    """``(largest move, mean edge length)``: how far float32 rounding (binary STL) moves a vertex of a face of ``(V, F)``.

    >>> import numpy as np
    >>> V = np.array([[1e6, 0, 0], [1e6 + 1e-3, 0, 0], [1e6, 1e-3, 0]]) + 0.01
    >>> move, h = float32_move(V, np.array([[0, 1, 2]]))
    >>> bool(move > STL_TOLERANCE * h), bool(float32_move(V - 1e6, np.array([[0, 1, 2]]))[0] < STL_TOLERANCE * h)
    (True, False)
    """
    used = np.zeros(V.shape[0], dtype=bool)
    used[F.ravel()] = True
    U = V[used]
    move = float(np.sqrt((np.square(U - U.astype(np.float32).astype(np.float64))).sum(axis=1)).max()) if U.size else 0.0
    edges = [V[F[:, (k + 1) % 3]] - V[F[:, k]] for k in range(3)]
    h = float(np.mean([np.sqrt(np.square(e).sum(axis=1)).mean() for e in edges])) if F.size else 0.0
    return move, h


def _warn_if_float32_moves(path: Path, V: np.ndarray, F: np.ndarray, what: str = "binary STL",
                           keep: str = "write PLY (double) or ASCII STL") -> None:
    """Binary STL (or PLY asked for float32) stores float32: say so (:class:`PrecisionWarning`) when that moves a
    vertex by more than :data:`STL_TOLERANCE` mean edge lengths; the file is still written, as MeshLab writes it."""
    import warnings

    move, h = float32_move(V, F)
    if h > 0 and move > STL_TOLERANCE * h:
        warnings.warn(
            f"{path}: {what} stores float32 coordinates: vertices move by up to {move:.3g} "
            f"({move / h:.3g} mean edge lengths); {keep} to keep them",
            PrecisionWarning, stacklevel=3)


def save_arrays(path: str | os.PathLike, V: np.ndarray, F: np.ndarray, *, binary: bool = True) -> Path:
    """Write ``(V, F)`` to ``path`` (format from the extension) atomically; see :func:`save_mesh`."""
    return save_mesh(path, V, F, binary=binary)


_WRITERS = {".off": _write_off, ".obj": _write_obj, ".ply": _write_ply, ".stl": _write_stl}
