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

import keyword
import math
import re
import xml.etree.ElementTree as ET
from typing import Any

from .meshlab_gui import gui_names, pymeshlab_name, pythonize  # noqa: F401 - pythonize named here too
from .meshlab_names import FILTERS
from .pymeshlab_steps import PERCENT, check_value, filter_names, parameter_types
from .steps import COMMON

__all__ = ["mlx_to_steps", "steps_to_mlx", "OURS_PREFIX", "pythonize", "pymeshlab_name", "NO_SCRIPT_FORM"]

OURS_PREFIX = "meshdenoise:"


def _pymeshlab_name(meshlab_name: str, where: str = "") -> str | None:
    """pymeshlab's name of a MeshLab filter; ``ValueError`` naming ``where`` when there is none."""
    found = pymeshlab_name(meshlab_name)
    if found is None:
        raise ValueError(f"{where + ': ' if where else ''}MeshLab filter {meshlab_name!r} has no pymeshlab equivalent in this pymeshlab version")
    return found



def _param_name(meshlab_param: str) -> str:
    low = meshlab_param.lower()
    return low + "_" if keyword.iskeyword(low) else low


def _number(text: str) -> int | float:
    value = float(text)
    return int(value) if value.is_integer() and re.fullmatch(r"[-+]?\d+", text.strip()) else value


# MeshLab's older scripts write a point as RichPoint3f (x, y, z attributes), as the newer RichPosition / RichDirection
POINT_TYPES = ("RichPosition", "RichDirection", "RichPoint3f")


def _attribute(p: ET.Element, key: str) -> str:
    v = p.get(key)
    if v is None:
        raise ValueError(f"has no {key!r} attribute")
    return v


def _float(p: ET.Element, key: str) -> float:
    text = _attribute(p, key)
    try:
        return float(text)
    except ValueError:
        raise ValueError(f"{key}={text!r} is not a number") from None


# MeshLab writes its percentage parameters (class RichPercentage, pymeshlab's PercentageValue) as "RichAbsPerc"
PERCENT_TYPES = ("RichAbsPerc", "RichPercentage")


def _percentage(p: ET.Element) -> float | str:
    """A percentage parameter as pymeshlab's ``PercentageValue``: ``"5%"`` of the parameter's range.

    MeshLab saves the absolute value it had on the mesh it ran on, with the range ``min``..``max``
    of that mesh (for most such parameters 0 to the bounding-box diagonal). Kept as a value in mesh
    units, a 5 % piece size of a 136-unit scan would be 6.8 units on every mesh (a smaller scan
    loses every face); so it is written back as the percentage of that range, which pymeshlab applies
    to each mesh (``PercentageValue``). Without a range (an old script) the value stays absolute.

    >>> _percentage(ET.fromstring('<Param name="TargetLen" type="RichAbsPerc" value="6.81822" min="0" max="136.364"/>'))
    '5%'
    """
    value = _float(p, "value")
    if p.get("min") is None or p.get("max") is None:
        return value
    low, high = _float(p, "min"), _float(p, "max")
    if not (math.isfinite(low) and math.isfinite(high) and high > low):
        return value
    # MeshLab writes value and range with 6 significant digits: their ratio holds 5
    return f"{100.0 * (value - low) / (high - low):.5g}%"


class UnsupportedType(ValueError):
    """A parameter type pipelines cannot express (a camera ``RichShotf``, a mesh chooser...)."""


def _read_param(p: ET.Element, where: str) -> Any:
    """The YAML value of one ``<Param>``; ``ValueError`` naming ``where`` and the parameter."""
    t = p.get("type")
    name = p.get("name")
    try:
        return _read_value(p, t)
    except UnsupportedType as exc:
        raise UnsupportedType(f"{where}: parameter {name!r} {exc}") from None
    except ValueError as exc:
        raise ValueError(f"{where}: parameter {name!r} ({t}) {exc}") from None


def _read_value(p: ET.Element, t: str | None) -> Any:
    if t == "RichBool":
        v = _attribute(p, "value").strip().lower()
        if v not in ("true", "false"):
            raise ValueError(f"value={p.get('value')!r} is not true or false")
        return v == "true"
    if t in ("RichInt", "RichMesh"):
        v = _float(p, "value")
        if not v.is_integer():
            raise ValueError(f"value={p.get('value')!r} is not an integer")
        return int(v)
    if t in PERCENT_TYPES:
        return _percentage(p)
    if t in ("RichFloat", "RichDynamicFloat"):
        return _float(p, "value")
    if t == "RichEnum":
        n = int(_float(p, "enum_cardinality")) if p.get("enum_cardinality") is not None else 0
        labels = [p.get(f"enum_val{i}") for i in range(n)]
        k = int(_float(p, "value"))
        return labels[k] if 0 <= k < len(labels) and labels[k] is not None else k
    if t in POINT_TYPES:
        return [_float(p, c) for c in "xyz"]
    if t == "RichColor":
        return [int(_float(p, c)) for c in "rgba"]
    if t == "RichMatrix44f":
        return [_float(p, f"val{i}") for i in range(16)]
    if t in ("RichString", "RichOpenFile", "RichSaveFile", "RichFileOpen", "RichFileSave", None):
        v = p.get("value")
        return v if v is not None else ""
    raise UnsupportedType(f"has type {t!r}, which pipelines cannot express")


def mlx_to_steps(text: str, source: str = "<mlx>", warn: Any = None) -> list[dict]:
    """Steps (``[{pymeshlab_name: {param: value}}, ...]``) of a MeshLab filter script.

    Every parameter is written out, as in the script (MeshLab saves all of them).
    Percentages (``RichAbsPerc``, which MeshLab saves as the absolute value on the mesh it ran on,
    with that mesh's range) become pymeshlab percentages (``"5%"``, :func:`_percentage`), so they
    scale with each mesh as in MeshLab's dialog. Points (``RichPosition``,
    ``RichDirection``, older scripts' ``RichPoint3f``) become 3 numbers, matrices 16.
    A parameter of a type pipelines cannot express (a camera, ``RichShotf``) is left out,
    so pymeshlab's default is used, and ``warn`` (a callable, default :func:`warnings.warn`)
    is told which.

    Raises
    ------
    ValueError
        Not a filter script, a filter unknown to pymeshlab, or a malformed parameter: the
        message names ``source``, the filter's position and name, and the parameter.
    """
    if warn is None:
        import warnings

        def warn(message):
            warnings.warn(message, UserWarning, stacklevel=3)

    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise ValueError(f"{source}: not an XML filter script ({exc})") from None
    if root.tag != "FilterScript":
        raise ValueError(f"{source}: the root element is <{root.tag}>, expected <FilterScript>")
    steps = []
    k = 0
    for node in root:
        if node.tag not in ("filter", "xmlfilter"):
            continue
        k += 1
        name = node.get("name", "")
        where = f"{source}: filter {k} {name!r}"
        ours = name.startswith(OURS_PREFIX)
        py = name[len(OURS_PREFIX):] if ours else _pymeshlab_name(name, where)
        params = {}
        for p in node.findall("Param"):
            pname = p.get("name")
            if not pname:
                raise ValueError(f"{where}: a <Param> has no name")
            try:
                value = _read_param(p, where)
            except UnsupportedType as exc:
                warn(f"{exc}; left out, so pymeshlab's default is used (set it in the YAML if needed)")
                continue
            if isinstance(value, str) and p.get("type") in PERCENT_TYPES:
                warn(f"{where}: parameter {pname!r} = {value} of its range ({p.get('value')} on the mesh the script "
                     f"was saved from): kept as a percentage, which scales with each mesh; write {p.get('value')} "
                     "for that absolute length")
            params[pname if ours else _param_name(pname)] = value
        steps.append({py: params} if params or ours else py)
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
            raise ValueError("a filter script stores one mesh's absolute length (MeshLab and pymeshlab replay it as "
                             "it is, on every mesh); write the value in mesh units")
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


class ScriptStepError(ValueError):
    """A step that cannot be written to a filter script; :attr:`index` is its position (from 1)."""

    def __init__(self, index: int, message: str):
        super().__init__(message)
        self.index = index


# steps with no filter-script form: ``save`` is always left out (MeshLab saves the mesh itself), the
# others only with ``skip_other``
NO_SCRIPT_FORM = ("save", "metrics", "render", "add_noise", "denoise")  # denoise: its filter is chosen per mesh


def _step_parts(item: Any, k: int) -> tuple[str, dict]:
    """``(name, parameters)`` of one YAML step; ``ValueError`` naming the step for anything else."""
    if isinstance(item, str):
        return item, {}
    if isinstance(item, dict) and len(item) == 1:
        name, params = next(iter(item.items()))
        if not isinstance(name, str):
            raise ScriptStepError(k, f"step {k}: a step's name is a string, got {name!r}")
        if params is None:
            return name, {}
        if not isinstance(params, dict):
            raise ScriptStepError(k, f"step {k} '{name}': parameters must be a mapping (name: value), got {params!r}")
        return name, dict(params)
    if isinstance(item, dict):
        keys = ", ".join(repr(key) for key in item) or "none"
        raise ScriptStepError(
            k, f"step {k}: a step is one name with its parameters, this one has {len(item)} keys ({keys}); "
            "indent the parameters under the name, or write two steps"
        )
    raise ScriptStepError(k, f"step {k}: a step is a name or a one-key mapping 'name: {{parameters}}', got {item!r}")


def _our_param(spec, key: str, value: Any, k: int, name: str) -> dict:
    """A ``<Param>``'s attributes for a parameter of our filter, typed by its declaration (``mu: 1`` is a RichFloat)."""
    try:
        param = spec.param(key)
    except KeyError:
        param = None
    if param is not None:
        try:
            value = param.check(value)
        except (TypeError, ValueError) as exc:
            raise ScriptStepError(k, f"step {k} '{name}': {exc}") from None
        kind = param.kind
    else:
        if key not in COMMON:
            known = ", ".join(p.name for p in spec.params)
            raise ScriptStepError(k, f"step {k} '{name}': unknown parameter {key!r}; its parameters: {known}")
        if isinstance(value, (list, dict)) or value is None:
            raise ScriptStepError(k, f"step {k} '{name}': parameter {key!r} = {value!r} cannot be written to a filter script")
        kind = type(value)
    text = _fmt(value) if kind is float else str(value).lower() if kind is bool else str(value)
    return {"name": key, "type": _RICH[kind], "value": text}


def steps_to_mlx(steps: list, *, skip_other: bool = False, notes: list | None = None) -> str:
    """A MeshLab filter script for pipeline steps (pymeshlab filters and our denoisers).

    Only the parameters the step gives are written, in its order: MeshLab and pymeshlab
    use their defaults for the others (which for lengths depend on the mesh, so writing
    them out would fix them to one mesh's values). ``save`` steps are left out (MeshLab
    saves the mesh itself); other steps with no filter-script form (:data:`NO_SCRIPT_FORM`,
    ``open3d.*``) are refused unless ``skip_other``. MeshLab's GUI names are accepted.
    What was left out or renamed is appended to ``notes`` when given.

    Raises
    ------
    ValueError
        Naming the step (its position and name) and the parameter.
    """
    from ..registry import REGISTRY, _load_plugins

    _load_plugins()
    notes = notes if notes is not None else []
    if not isinstance(steps, list):
        raise ValueError(f"'steps' must be a list, got {steps!r}")
    root = ET.Element("FilterScript")
    for k, item in enumerate(steps, start=1):
        name, params = _step_parts(item, k)
        params.pop("label", None)
        if name in NO_SCRIPT_FORM or name.startswith("open3d."):
            if name == "save" or skip_other:
                notes.append(f"step {k} '{name}': left out (a filter script has no such step)")
                continue
            raise ScriptStepError(
                k, f"step {k} '{name}': only pymeshlab filters and our denoisers have a filter-script form "
                "(--skip-other leaves such steps out)"
            )
        if name in REGISTRY:
            spec = REGISTRY[name]
            node = ET.SubElement(root, "filter", {"name": OURS_PREFIX + name})
            for key, value in params.items():
                ET.SubElement(node, "Param", _our_param(spec, key, value, k, name))
            continue
        name, params, renamed = gui_names(name, params)
        notes.extend(f"step {k}: {text}" for text in renamed)
        if name not in filter_names():
            raise ScriptStepError(k, f"step {k} '{name}': not a pymeshlab filter nor one of ours; only those have a filter-script form")
        if name not in FILTERS:
            raise ScriptStepError(k, f"step {k} '{name}': its MeshLab name is not known (not in the recorded table)")
        entry = FILTERS[name]
        node = ET.SubElement(root, "filter", {"name": entry["meshlab"]})
        types = parameter_types(name)
        for key, value in params.items():
            if key not in entry["params"]:
                known = ", ".join(entry["params"])
                raise ScriptStepError(k, f"step {k} '{name}': unknown parameter {key!r}; its parameters: {known}")
            info = entry["params"][key]
            if key in types:
                try:
                    value = check_value(key, value, types[key], f"step {k} '{name}'")
                except ValueError as exc:
                    raise ScriptStepError(k, str(exc)) from None
            try:
                _write_param(node, info["name"], value, {**types.get(key, {}), **info})
            except (TypeError, ValueError) as exc:
                raise ScriptStepError(k, f"step {k} '{name}': parameter {key!r} = {value!r}: {exc}") from None
    ET.indent(root, " ")
    return "<!DOCTYPE FilterScript>\n" + ET.tostring(root, encoding="unicode") + "\n"
