"""MeshLab filter scripts (.mlx) <-> pipeline steps.

MeshLab's GUI saves MeshLab's names ("Laplacian Smooth", ``stepSmoothNum``); pipelines
use pymeshlab's (``apply_coord_laplacian_smoothing``, ``stepsmoothnum``). The table
between them was recorded from pymeshlab's own ``save_filter_script``
(``meshdenoise/pipeline/meshlab_filters.json``, read by :mod:`~meshdenoise.pipeline.meshlab_names`); a filter missing from it falls back to
pymeshlab's rule (lower-cased MeshLab name, then pymeshlab's ``keys.txt`` renaming).

Our own denoisers are written as ``<filter name="meshdenoise:sobolev">`` with
``RichFloat``/``RichInt``/``RichBool``/``RichString`` parameters. MeshLab and pymeshlab
do not know them (MeshLab reports an unknown filter); ``meshdenoise run`` does. Steps
that are neither (Open3D operations, add_noise, metrics, save, render) have no filter
script form and are refused by :func:`steps_to_mlx`.
"""

from __future__ import annotations

import functools
import keyword
import re
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

from .meshlab_names import FILTERS
from .pymeshlab_steps import PERCENT, filter_names, parameter_types

__all__ = ["mlx_to_steps", "steps_to_mlx", "OURS_PREFIX", "pythonize"]

OURS_PREFIX = "meshdenoise:"


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


def _pymeshlab_name(meshlab_name: str) -> str:
    if meshlab_name in _by_meshlab_name():
        return _by_meshlab_name()[meshlab_name]
    guess = _renamed().get(pythonize(meshlab_name), pythonize(meshlab_name))
    if guess in filter_names():
        return guess
    raise ValueError(f"MeshLab filter {meshlab_name!r} has no pymeshlab equivalent in this pymeshlab version")


def _param_name(meshlab_param: str) -> str:
    low = meshlab_param.lower()
    return low + "_" if keyword.iskeyword(low) else low


def _number(text: str) -> int | float:
    value = float(text)
    return int(value) if value.is_integer() and re.fullmatch(r"[-+]?\d+", text.strip()) else value


def _read_param(p: ET.Element, where: str) -> Any:
    t = p.get("type")
    v = p.get("value")
    if t == "RichBool":
        return v.strip().lower() == "true"
    if t in ("RichInt", "RichMesh"):
        return int(float(v))
    if t in ("RichFloat", "RichDynamicFloat", "RichAbsPerc"):
        return float(v)
    if t == "RichEnum":
        n = int(p.get("enum_cardinality", 0))
        labels = [p.get(f"enum_val{i}") for i in range(n)]
        k = int(float(v))
        return labels[k] if 0 <= k < len(labels) and labels[k] is not None else k
    if t in ("RichPosition", "RichDirection"):
        return [float(p.get(c)) for c in "xyz"]
    if t == "RichColor":
        return [int(float(p.get(c))) for c in "rgba"]
    if t == "RichMatrix44f":
        return [float(p.get(f"val{i}")) for i in range(16)]
    if t in ("RichString", "RichOpenFile", "RichSaveFile", None):
        return v if v is not None else ""
    raise ValueError(f"{where}: parameter {p.get('name')!r} has type {t!r}, which pipelines do not support")


def mlx_to_steps(text: str, source: str = "<mlx>") -> list[dict]:
    """Steps (``[{pymeshlab_name: {param: value}}, ...]``) of a MeshLab filter script.

    Every parameter is written out, as in the script (MeshLab saves all of them).
    ``RichAbsPerc`` values are absolute (MeshLab stores them so).

    Raises
    ------
    ValueError
        Not a filter script, or a filter unknown to pymeshlab (naming it and its position).
    """
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise ValueError(f"{source}: not an XML filter script ({exc})") from None
    if root.tag != "FilterScript":
        raise ValueError(f"{source}: the root element is <{root.tag}>, expected <FilterScript>")
    steps = []
    for k, node in enumerate(root, start=1):
        if node.tag not in ("filter", "xmlfilter"):
            continue
        name = node.get("name", "")
        where = f"{source}: filter {k} {name!r}"
        params = {}
        if name.startswith(OURS_PREFIX):
            ours = name[len(OURS_PREFIX):]
            for p in node.findall("Param"):
                params[p.get("name")] = _read_param(p, where)
            steps.append({ours: params})
            continue
        py = _pymeshlab_name(name)
        for p in node.findall("Param"):
            params[_param_name(p.get("name"))] = _read_param(p, where)
        steps.append({py: params} if params else py)
    return steps


_RICH = {bool: "RichBool", int: "RichInt", float: "RichFloat", str: "RichString"}


def _fmt(v: float) -> str:
    return repr(float(v)) if not float(v).is_integer() else str(int(v)) if abs(v) < 1e15 else repr(float(v))


def _write_param(parent: ET.Element, mesh_name: str, value: Any, info: dict) -> None:
    t = info["type"]
    attrs = {"name": mesh_name, "type": t}
    if t == "RichBool":
        attrs["value"] = "true" if value else "false"
    elif t in ("RichInt", "RichMesh"):
        attrs["value"] = str(int(value))
    elif t in ("RichFloat", "RichDynamicFloat"):
        attrs["value"] = _fmt(value)
        if t == "RichDynamicFloat":
            attrs["min"], attrs["max"] = _fmt(min(0.0, value)), _fmt(max(1.0, value))
    elif t == "RichAbsPerc":
        if isinstance(value, str) and PERCENT.match(value):
            raise ValueError(
                f"parameter {mesh_name!r} = {value!r}: a filter script stores absolute values; "
                "write the value in mesh units"
            )
        attrs["value"] = _fmt(value)
        attrs["min"], attrs["max"] = "0", _fmt(max(float(value), 1.0) * 100)
    elif t == "RichEnum":
        labels = info.get("enum", [])
        index = labels.index(value) if isinstance(value, str) else int(value)
        attrs["value"] = str(index)
        attrs["enum_cardinality"] = str(len(labels))
        for i, label in enumerate(labels):
            attrs[f"enum_val{i}"] = label
    elif t in ("RichPosition", "RichDirection"):
        attrs.update({c: _fmt(x) for c, x in zip("xyz", value)})
    elif t == "RichColor":
        rgba = list(value) + [255] * (4 - len(value))
        attrs.update({c: str(int(x)) for c, x in zip("rgba", rgba)})
    elif t == "RichMatrix44f":
        import numpy as np

        attrs.update({f"val{i}": _fmt(x) for i, x in enumerate(np.asarray(value, dtype=float).ravel())})
    else:
        attrs["value"] = str(value)
    ET.SubElement(parent, "Param", attrs)


def steps_to_mlx(steps: list) -> str:
    """A MeshLab filter script for pipeline steps (pymeshlab filters and our denoisers).

    Only the parameters the step gives are written, in its order: MeshLab and pymeshlab
    use their defaults for the others (which for lengths depend on the mesh, so writing
    them out would fix them to one mesh's values).
    """
    from ..registry import REGISTRY, _load_plugins

    _load_plugins()
    root = ET.Element("FilterScript")
    for k, item in enumerate(steps, start=1):
        name, params = (item, {}) if isinstance(item, str) else next(iter(item.items()))
        params = dict(params or {})
        params.pop("label", None)
        if name in REGISTRY:
            node = ET.SubElement(root, "filter", {"name": OURS_PREFIX + name})
            for key, value in params.items():
                if isinstance(value, (list, dict)) or value is None:
                    raise ValueError(f"step {k} '{name}': parameter {key!r} = {value!r} cannot be written to a filter script")
                ET.SubElement(node, "Param", {"name": key, "type": _RICH[type(value)], "value": _fmt(value) if type(value) is float else str(value).lower() if isinstance(value, bool) else str(value)})
            continue
        if name not in filter_names():
            raise ValueError(f"step {k} '{name}': only pymeshlab filters and our denoisers have a filter-script form")
        if name not in FILTERS:
            raise ValueError(f"step {k} '{name}': its MeshLab name is not known (not in the recorded table)")
        entry = FILTERS[name]
        node = ET.SubElement(root, "filter", {"name": entry["meshlab"]})
        types = parameter_types(name)
        for key, value in params.items():
            if key not in entry["params"]:
                raise ValueError(f"step {k} '{name}': unknown parameter {key!r}")
            info = entry["params"][key]
            try:
                _write_param(node, info["name"], value, {**types.get(key, {}), **info})
            except ValueError as exc:
                raise ValueError(f"step {k} '{name}': {exc}") from None
    ET.indent(root, " ")
    return "<!DOCTYPE FilterScript>\n" + ET.tostring(root, encoding="unicode") + "\n"

