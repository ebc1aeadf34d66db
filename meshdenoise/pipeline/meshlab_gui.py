"""MeshLab's GUI names of pymeshlab filters and parameters -> pymeshlab's names.

MeshLab's GUI saves MeshLab's names ("Laplacian Smooth", ``stepSmoothNum``); pipelines
use pymeshlab's (``apply_coord_laplacian_smoothing``, ``stepsmoothnum``). The table
between them is :mod:`~meshdenoise.pipeline.meshlab_names`'s; a filter missing from it falls back to
pymeshlab's rule (lower-cased MeshLab name, then pymeshlab's ``keys.txt`` renaming). Read by
the pipeline steps (a step may be written by its GUI name) and by the filter scripts
(:mod:`~meshdenoise.pipeline.mlx`), both above this module.
"""

from __future__ import annotations

import functools
import re
from pathlib import Path

from .meshlab_names import FILTERS
from .pymeshlab_steps import filter_names, parameter_types

__all__ = ["gui_names", "pymeshlab_name", "pythonize"]


@functools.lru_cache(maxsize=1)
def _by_meshlab_name() -> dict[str, str]:
    return {entry["meshlab"]: name for name, entry in FILTERS.items()}


@functools.lru_cache(maxsize=1)
def _renamed() -> dict[str, str]:
    import pymeshlab

    keys = Path(pymeshlab.__file__).parent / "keys.txt"
    out = {}
    if keys.is_file():
        for line in keys.read_text().splitlines():
            parts = line.split()
            if len(parts) == 2:
                out[parts[0]] = parts[1]
    return out


def pythonize(meshlab_name: str) -> str:
    """pymeshlab's old rule for a MeshLab name: lower case, runs of other characters -> ``_``.

    >>> pythonize("Remeshing: Isotropic Explicit Remeshing")
    'remeshing_isotropic_explicit_remeshing'
    """
    return re.sub(r"[^0-9a-z]+", "_", meshlab_name.lower()).strip("_")


def pymeshlab_name(meshlab_name: str) -> str | None:
    """pymeshlab's name of a filter known by its MeshLab (GUI) name (``"Taubin Smooth"``), or None."""
    if meshlab_name in _by_meshlab_name():
        return _by_meshlab_name()[meshlab_name]
    guess = _renamed().get(pythonize(meshlab_name), pythonize(meshlab_name))
    if guess in filter_names():
        return guess
    return None


def gui_names(name: str, params: dict) -> tuple[str, dict, list[str]]:
    """Accept MeshLab's GUI names for a pymeshlab step: ``("Taubin Smooth", {"lambda": ..})`` ->
    ``("apply_coord_taubin_smoothing", {"lambda_": ..})``, with one note per renaming naming the canonical name.

    Names that are already pymeshlab's (or not MeshLab's) are returned unchanged, with no note.
    """
    notes = []
    canonical = name
    if name not in filter_names():
        found = pymeshlab_name(name) if not name.startswith("open3d.") else None
        if found is None or found == name:
            return name, params, notes
        canonical = found
        notes.append(f"'{name}' is MeshLab's name of the pymeshlab filter '{canonical}': write '{canonical}'")
    entry = FILTERS.get(canonical)
    if entry is None:
        return canonical, params, notes
    known = parameter_types(canonical)
    by_gui = {info["name"]: py for py, info in entry["params"].items()}
    by_gui.update({info["name"].lower(): py for py, info in entry["params"].items() if info["name"].lower() not in known})
    out = {}
    for key, value in params.items():
        if isinstance(key, str) and key not in known and (key in by_gui or key.lower() in by_gui):
            py = by_gui.get(key, by_gui.get(key.lower()))
            notes.append(f"'{key}' is MeshLab's name of {canonical}'s parameter '{py}': write '{py}'")
            key = py
        out[key] = value
    return canonical, out, notes
