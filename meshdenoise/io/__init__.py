"""Reading and writing mesh files: strict readers, errors that name the file, atomic writes.

The readers are pure Python/numpy (no C++ loader), so a hostile or broken file can raise
:class:`MeshFileError` but cannot crash the process: pymeshlab's loaders silently accept
truncated STL and OFF files and out-of-range OBJ indices, drop NaN vertices and duplicate
faces, read an OFF file with comments as empty and refuse CR line endings (see
the README section "Robustness"). Header counts are checked against the file size before anything is
allocated. Unusual but legal input (polygons, CR or CRLF line endings, negative OBJ
indices, STL's unshared corners) is read and described in :attr:`MeshFile.notes`.

The first 64 KiB are checked before the rest is read, so garbage is refused without loading it.
Binary PLY is read element by element from the file into the arrays, and ASCII PLY (and plain
OBJ/OFF) as one number stream, without a Python object per line. What is accepted, refused and
guaranteed: docs/file-formats.md.

Writers are numpy too: PLY stores ``double`` coordinates (``float`` on request), OFF and OBJ 17
significant digits, so a write-read round trip is exact (binary STL stores float32 by definition).
A temporary file being written is removed on SIGTERM/SIGHUP (see :class:`atomic_path`).

The modules, by what they hold: :mod:`~meshdenoise.io.load` and :mod:`~meshdenoise.io.save` (any
format), :mod:`~meshdenoise.io.ply_read`, :mod:`~meshdenoise.io.ply_write`, :mod:`~meshdenoise.io.obj`,
:mod:`~meshdenoise.io.off`, :mod:`~meshdenoise.io.stl` (the formats), :mod:`~meshdenoise.io.tables`
(number tables the text formats share), :mod:`~meshdenoise.io.atomic` (atomic writing and signal
cleanup), :mod:`~meshdenoise.io.topology` (the notes on a mesh read), :mod:`~meshdenoise.io.meshfile`
and :mod:`~meshdenoise.io.errors`.
"""

from __future__ import annotations

from .atomic import _UMASK, atomic_path
from .errors import STL_TOLERANCE, SUPPORTED_EXTENSIONS, MeshFileError, PrecisionWarning, _Malformed
from .load import load_arrays, load_mesh
from .meshfile import MeshFile, PlyExtras
from .save import _WRITERS, float32_move, save_arrays, save_mesh
from .topology import topology_notes

# the public exceptions name the module they are imported from (tracebacks and doctests read
# meshdenoise.io.MeshFileError, not the submodule that defines it)
MeshFileError.__module__ = PrecisionWarning.__module__ = __name__

__all__ = [
    "MeshFile",
    "load_mesh",
    "save_mesh",
    "load_arrays",
    "save_arrays",
    "atomic_path",
    "MeshFileError",
    "PrecisionWarning",
    "SUPPORTED_EXTENSIONS",
    "STL_TOLERANCE",
    "topology_notes",
]
