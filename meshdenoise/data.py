"""Where meshes live: the third-party data folder and the meshes pymeshlab's wheel ships."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["data_dir", "data_file", "sample_mesh"]


def data_dir() -> Path:
    """The third-party mesh folder: ``$MESHDENOISE_DATA``, else ``../shared/meshes`` from the repository root."""
    env = os.environ.get("MESHDENOISE_DATA")
    if env:
        return Path(env)
    return Path(__file__).resolve().parent.parent.parent / "shared" / "meshes"


def data_file(name: str) -> Path:
    """A file of the data folder; ``FileNotFoundError`` naming where it was looked for."""
    path = data_dir() / name
    if not path.is_file():
        raise FileNotFoundError(
            f"{path} not found: set MESHDENOISE_DATA to the folder holding the paper's meshes ({name})"
        )
    return path


def sample_mesh(name: str = "bunny.obj") -> str:
    """The path (a ``str``) of a sample mesh from pymeshlab's wheel (``bunny.obj``, ``rangemaps/face000.ply``, ...).

    A ``str``, because pymeshlab's ``MeshSet.load_new_mesh`` takes nothing else:

    >>> import pymeshlab
    >>> ms = pymeshlab.MeshSet()
    >>> ms.load_new_mesh(sample_mesh())
    >>> ms.current_mesh().vertex_number() > 0
    True
    """
    import pymeshlab

    path = Path(pymeshlab.__file__).parent / "tests" / "sample_meshes" / name
    if not path.is_file():
        raise FileNotFoundError(f"{path} not found in the installed pymeshlab wheel")
    return str(path)
