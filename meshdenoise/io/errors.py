"""The errors and warnings of mesh files, and the extensions they may have."""

from __future__ import annotations

from pathlib import Path


SUPPORTED_EXTENSIONS = (".ply", ".obj", ".off", ".stl")


#: Largest move, in mean edge lengths, that binary STL's float32 rounding may give a vertex before
#: :func:`save_mesh` warns (a georeferenced scan: coordinates near 1e6, millimetre detail).
STL_TOLERANCE = 0.01


class PrecisionWarning(UserWarning):
    """A file format cannot hold the coordinates as they are: binary STL's float32 moves vertices by more
    than :data:`STL_TOLERANCE` mean edge lengths. The message names the file and the largest move."""


class MeshFileError(ValueError):
    """A mesh file that cannot be read or written; the message names the file and the problem."""


class _Malformed(Exception):
    """Raised by a reader; :func:`load_mesh` prefixes the path."""


def _check_extension(path: Path) -> None:
    if path.suffix.lower() not in SUPPORTED_EXTENSIONS:
        raise MeshFileError(
            f"{path}: unsupported extension {path.suffix!r}; use one of {', '.join(SUPPORTED_EXTENSIONS)}"
        )
