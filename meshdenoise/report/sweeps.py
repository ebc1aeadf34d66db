"""What a pipeline's results hold: the swept parameters, the measurements to chart, a line per setting."""

from __future__ import annotations

import json
import math
import re

from .text import _number, _short_names

MAX_CHART_METRICS = 4  # panels per chart

# Keys a pipeline's runner writes into every results row; every other key that is not a metric
# (see _is_measurement) is a sweep variable.
_ROW_KEYS = {"input", "status", "outputs", "vertices", "faces", "seconds", "error", "traceback", "failure"}


def _is_measurement(key: str) -> bool:
    """A key a pipeline step writes: a metric (``snr``, ``clean.snr``), a chosen parameter (``auto.*``), a render."""
    from ..metrics import METRICS

    last = key.rsplit(".", 1)[-1]
    return last in METRICS or key.startswith("auto.") or ".auto." in key or "render." in key or key.startswith("render")


def sweep_parameters(rows: list[dict], sweep_keys: list[str] | None = None) -> tuple[list[str], list[str]]:
    """The swept parameters of a pipeline's results rows, and the metrics to chart against them.

    Parameters
    ----------
    rows : list of dict
        The results rows (``results.json``).
    sweep_keys : list of str, optional
        The pipeline's ``sweep:`` keys (``[]``: it has no sweep). Without them, a sweep variable is
        a key that is a plain name (a pipeline variable: no dot, as the columns steps add have) and
        neither the runner's own (input, status, outputs, vertices, faces, seconds, error) nor a
        measurement.

    Returns
    -------
    params : list of str
        Swept keys taking at least two values (numbers, or names such as a ``method``), in row order.
    metrics : list of str
        Numeric measurements (metrics, ``auto.*`` choices), at most ``MAX_CHART_METRICS``.
    """
    keys = list(dict.fromkeys(k for r in rows for k in r))
    swept = [k for k in keys if _is_swept(k, sweep_keys)]
    ok = [r for r in rows if r.get("status", "ok") == "ok"]

    def numeric(k):
        vals = [_number(r.get(k)) for r in ok if k in r]
        return bool(vals) and all(v is not None and math.isfinite(v) for v in vals)

    params = [k for k in swept if len({_key(r[k]) for r in ok if k in r}) >= 2]
    metrics = [k for k in keys if k not in _ROW_KEYS and k not in swept and _is_measurement(k) and numeric(k)]
    return params, metrics[:MAX_CHART_METRICS]


def _is_swept(key: str, sweep_keys: list[str] | None) -> bool:
    """Whether a results column is a swept variable: one of ``sweep_keys``, or without them a plain variable name."""
    if sweep_keys is not None:
        return key in sweep_keys
    return (key not in _ROW_KEYS and not _is_measurement(key) and "." not in key
            and re.fullmatch(r"[A-Za-z][A-Za-z0-9_]*", key) is not None)


def _key(value) -> str:
    return json.dumps(value, sort_keys=True) if isinstance(value, (list, dict)) else str(value)


def _is_numeric_param(rows: list[dict], param: str) -> bool:
    vals = [_number(r[param]) for r in rows if param in r]
    return bool(vals) and all(v is not None and math.isfinite(v) for v in vals)


def sweep_series(rows: list[dict], param: str, metric: str, swept: list[str]) -> dict[str, list[tuple]]:
    """One line of ``metric`` against ``param`` per input and setting of the other swept keys.

    Parameters
    ----------
    rows : list of dict
        Results rows; rows whose status is not ``ok`` or that lack either key are left out.
    param, metric : str
        The x and y keys.
    swept : list of str
        Every swept key (numeric or not): those other than ``param`` name the lines.

    Returns
    -------
    dict
        Line label -> points ``(x, y)``: sorted by x for a numeric parameter, in row order with x the
        value's text for any other (a ``method``). The label is the input's file name (when there are
        several inputs) and ``key=value`` of the other swept keys; ``""`` for a single line.
    """
    ok = [r for r in rows if r.get("status", "ok") == "ok" and param in r and _number(r.get(metric)) is not None]
    numeric = _is_numeric_param(ok, param)
    inputs = {str(r.get("input", "")) for r in ok}
    names = _short_names(sorted(inputs))
    lines: dict[str, list[tuple[float, float]]] = {}
    for r in ok:
        label = []
        if len(inputs) > 1:
            label.append(names[str(r.get("input", ""))])
        label += [f"{k}={r[k]}" for k in swept if k != param and k in r]
        x = float(_number(r[param])) if numeric else _key(r[param])
        lines.setdefault(", ".join(label), []).append((x, float(_number(r[metric]))))
    return {k: sorted(v) for k, v in lines.items()} if numeric else lines


def _pipeline_facts(text: str) -> tuple[list[str] | None, str | None]:
    """A pipeline file's swept keys (``[]`` for a pipeline without ``sweep:``) and its description.

    (None, None) for text that is not a pipeline (no ``steps:``).
    """
    import yaml

    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError:
        return None, None
    if not isinstance(doc, dict) or "steps" not in doc:
        return None, None
    sweep = doc.get("sweep")
    about = doc.get("description")
    return ([str(k) for k in sweep] if isinstance(sweep, dict) else []), (str(about) if about else None)
