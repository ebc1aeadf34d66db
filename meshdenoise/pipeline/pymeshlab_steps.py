"""pymeshlab filters as pipeline steps: names and parameters checked before anything runs.

Parameter names come from pymeshlab itself (``MeshSet.filter_parameter_values`` on a tiny
mesh); their types from the MeshLab types recorded in
:mod:`~meshdenoise.pipeline.meshlab_names` (pymeshlab returns an enum as ``int`` and a
percentage as ``float``, so the default's Python type alone would mislead).

YAML values by MeshLab type:

=================  =========================================================
RichInt            an integer
RichFloat          a number (RichDynamicFloat too)
RichBool           true / false
RichString         a string
RichEnum           one of the labels (``By Angle``) or its index
RichAbsPerc        a number (absolute, in mesh units) or ``"2%"`` (pymeshlab's
                   ``PercentageValue``: of the parameter's range on each
                   mesh, for most filters 0 to the bounding-box diagonal)
RichPosition,      a list of 3 numbers
RichDirection
RichColor          a list of 3 or 4 integers 0..255
RichMatrix44f      16 numbers (row-major) or a 4x4 list
RichMesh           a mesh index (integer)
=================  =========================================================
"""

from __future__ import annotations

import difflib
import functools
import re
from typing import Any

import numpy as np

from ..registry import Param, ParameterValueError
from .meshlab_names import FILTERS, _probe

__all__ = ["filter_names", "parameter_types", "check_parameters", "check_value", "to_pymeshlab_value", "PERCENT"]

PERCENT = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*%\s*$")


@functools.lru_cache(maxsize=1)
def filter_names() -> tuple[str, ...]:
    import pymeshlab

    return tuple(pymeshlab.filter_list())


@functools.lru_cache(maxsize=None)
def parameter_types(name: str) -> dict[str, dict]:
    """``{param: {"type": MeshLab type or Python type name, "default": value[, "enum": labels]}}``."""
    defaults = _probe().filter_parameter_values(name)
    recorded = FILTERS.get(name, {}).get("params", {})
    out = {}
    for key, default in defaults.items():
        entry = {"default": default}
        if key in recorded:
            entry["type"] = recorded[key]["type"]
            if "enum" in recorded[key]:
                entry["enum"] = recorded[key]["enum"]
        else:
            entry["type"] = {bool: "RichBool", int: "RichInt", float: "RichFloat", str: "RichString"}.get(
                type(default), "unknown"
            )
        out[key] = entry
    return out


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))


# MeshLab types checked by our one parameter check, registry.Param.check (type, finiteness)
_SCALAR_KINDS = {"RichBool": bool, "RichInt": int, "RichMesh": int, "RichFloat": float, "RichDynamicFloat": float, "RichString": str}


def _check_other(value: Any, info: dict) -> str | None:
    """A complaint about ``value`` for a non-scalar MeshLab type, or None if it is acceptable."""
    t = info["type"]
    if t == "RichEnum":
        labels = info.get("enum", [])
        if isinstance(value, str):
            if value in labels:
                return None
            hint = difflib.get_close_matches(value, labels, n=1)
            extra = f" (did you mean {hint[0]!r}?)" if hint else ""
            return f"is not one of {', '.join(repr(x) for x in labels)}{extra}"
        if isinstance(value, int) and not isinstance(value, bool) and 0 <= value < max(len(labels), 1):
            return None
        return f"must be one of {', '.join(repr(x) for x in labels)}"
    if t == "RichAbsPerc":
        if (_is_number(value) and np.isfinite(value)) or (isinstance(value, str) and PERCENT.match(value)):
            return None
        return "must be a number (absolute, in mesh units) or a percentage of its range on each mesh like '2%'"
    if t in ("RichPosition", "RichDirection"):
        ok = isinstance(value, (list, tuple)) and len(value) == 3 and all(_is_number(v) and np.isfinite(v) for v in value)
        return None if ok else "must be a list of 3 numbers"
    if t == "RichColor":
        ok = isinstance(value, (list, tuple)) and len(value) in (3, 4)
        ok = ok and all(isinstance(v, int) and not isinstance(v, bool) and 0 <= v <= 255 for v in value)
        return None if ok else "must be a list of 3 or 4 integers 0..255 (RGB[A])"
    if t == "RichMatrix44f":
        flat = np.asarray(value, dtype=object).ravel().tolist() if isinstance(value, (list, tuple)) else None
        ok = flat is not None and len(flat) == 16 and all(_is_number(v) and np.isfinite(v) for v in flat)
        return None if ok else "must be 16 numbers (a 4x4 matrix, row-major)"
    return None  # a type pymeshlab checks itself when the filter runs


def check_value(param: str, value: Any, info: dict, where: str) -> Any:
    """One parameter of a pymeshlab step checked against its MeshLab type; returns it converted.

    Scalars go through :meth:`meshdenoise.registry.Param.check` (the one check of every
    parameter: ``True`` is not an int, ``2.0`` is, non-finite floats are refused).

    Raises
    ------
    meshdenoise.registry.ParameterValueError
        Naming ``where``, the parameter, the value and the MeshLab type; ``parameter`` is ``param``.
    """
    t = info["type"]
    kind = _SCALAR_KINDS.get(t)
    if kind is not None:
        # MeshLab's integers are C++ ints: larger ones fail late with pybind11's "Unable to cast"
        low, high = (-(2**31), 2**31 - 1) if kind is int else (None, None)
        try:
            return Param(param, kind, info.get("default"), low=low, high=high).check(value, where)
        except (TypeError, ValueError, OverflowError) as exc:
            raise ParameterValueError(f"{exc} ({t})", param) from None
    problem = _check_other(value, info)
    if problem:
        raise ParameterValueError(f"{where}: parameter '{param}' = {value!r} {problem} ({t})", param)
    return value


def check_parameters(name: str, given: dict, where: str) -> dict:
    """Check a pymeshlab step's parameters (names, types); return them (scalars converted).

    Raises
    ------
    meshdenoise.registry.ParameterValueError
        Unknown parameter (with "did you mean" and the full list) or a badly typed value,
        naming ``where`` (file, line, step); ``parameter`` is the key.
    """
    types = parameter_types(name)
    out = {}
    for key, value in given.items():
        if key not in types:
            hint = difflib.get_close_matches(str(key), list(types), n=1)
            extra = f" (did you mean '{hint[0]}'?)" if hint else ""
            allowed = ", ".join(types) or "none"
            raise ParameterValueError(f"{where}: pymeshlab filter '{name}' has no parameter '{key}'{extra}; "
                                      f"its parameters: {allowed}", key)
        out[key] = check_value(key, value, types[key], where)
    return out


def to_pymeshlab_value(name: str, param: str, value: Any) -> Any:
    """The object pymeshlab's ``apply_filter`` wants for a checked YAML value."""
    import pymeshlab

    t = parameter_types(name)[param]["type"]
    if t == "RichAbsPerc":
        m = PERCENT.match(value) if isinstance(value, str) else None
        return pymeshlab.PercentageValue(float(m.group(1))) if m else pymeshlab.PureValue(float(value))
    if t in ("RichPosition", "RichDirection"):
        return np.asarray(value, dtype=np.float64)
    if t == "RichMatrix44f":
        return np.asarray(value, dtype=np.float64).reshape(4, 4)
    if t == "RichColor":
        return pymeshlab.Color(*value)
    if t in ("RichFloat", "RichDynamicFloat"):
        return float(value)
    return value
