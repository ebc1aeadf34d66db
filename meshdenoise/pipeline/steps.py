"""Pipeline steps: parsing and checking each step before anything runs (running them:
:mod:`meshdenoise.pipeline.execute`).

The working mesh of a pipeline is a :class:`~meshdenoise.pipeline.state.MeshState` (arrays
and attributes): our filters, Open3D operations and the built-in steps work on the arrays; a
``pymeshlab.MeshSet`` is made only around pymeshlab steps.
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..registry import COMMON_OPTIONS, MAX_ITERATIONS, STEP_OPTIONS, FilterSpec, Param, get_filter, list_filters
from . import pymeshlab_steps
from .errors import PipelineValidationError, where
from .noise_option import parse_noise_option

__all__ = ["Step", "parse_step", "denoise_step", "BUILTIN_STEPS", "OPEN3D_OPS", "step_names", "describe_steps", "describe_pymeshlab_step"]

# Open3D's clean-up and smoothing operations, under "open3d.<method name>", with their parameters.
OPEN3D_OPS: dict[str, list[Param]] = {
    "remove_degenerate_triangles": [],
    "remove_duplicated_triangles": [],
    "remove_duplicated_vertices": [],
    "remove_non_manifold_edges": [],
    "remove_unreferenced_vertices": [],
    "compute_vertex_normals": [Param("normalized", bool, True, help="unit-length normals")],
    "filter_smooth_simple": [Param("number_of_iterations", int, 1, low=0, high=MAX_ITERATIONS)],
    # a step weight above 1 overshoots (and 1e300 blows the mesh up): refused before running
    "filter_smooth_laplacian": [
        Param("number_of_iterations", int, 1, low=0, high=MAX_ITERATIONS),
        Param("lambda_filter", float, 0.5, low=0.0, high=1.0, low_open=True, help="step weight"),
    ],
    "filter_smooth_taubin": [
        Param("number_of_iterations", int, 1, low=0, high=MAX_ITERATIONS),
        Param("lambda_filter", float, 0.5, low=0.0, high=1.0, low_open=True, help="shrinking step weight"),
        Param("mu", float, -0.53, low=-1.0, high=0.0, high_open=True, help="inflating step weight (negative)"),
    ],
}

BUILTIN_STEPS: dict[str, list[Param]] = {
    "add_noise": [
        Param("rho", float, 0.01, low=0.0, help="noise amplitude (absolute, or x bbox diagonal if relative)"),
        Param("relative", bool, False, help="rho is a fraction of the bounding-box diagonal"),
        Param("seed", int, 0, low=0, help="random seed (numpy takes non-negative seeds)"),
    ],
    "save": [
        Param("path", str, "", help="output file; {stem} {name} {parent} {dir} {setting} {index} are filled in"),
        Param("binary", bool, True, help="binary PLY/STL"),
        Param("colors", bool, True, help="write vertex colours when the mesh has them"),
        Param("normals", bool, True, help="write the vertex normals a pymeshlab normal step computed (recomputed "
              "from the vertices if a later step moved them), or the input PLY had; PLY and OBJ"),
        Param("precision", str, "float64", choices=("float64", "float32"),
              help="PLY coordinates and normals: double, or float (half the size; warns when it moves vertices)"),
    ],
    "denoise": [],  # the goal: its keys are DENOISE_KEYS and, with method, the filter's; described in describe_steps
    "metrics": [],  # checked by _check_metrics, described by METRICS_DOC
    "render": [],  # checked by _check_render, described by RENDER_DOC
}
#: The keys a step of one of our filters takes besides the filter's parameters (registry.COMMON_OPTIONS).
COMMON = STEP_OPTIONS
_STEP_OPTION = {o.name: o for o in COMMON_OPTIONS if o.step}
#: The keys of the ``denoise`` step besides a method's parameters: the filter options but ``parameters`` (a
#: denoise step with a method chooses what is not given; ``defaults: true`` runs the filter's defaults instead).
DENOISE_KEYS = ("method", "defaults", "explain") + tuple(n for n in _STEP_OPTION if n != "parameters")
RESERVED = {"label"}


@dataclass
class Step:
    """One checked step: plain data, so a plan can be sent to Dask workers."""

    index: int
    name: str
    kind: str  # "ours", "default", "pymeshlab", "open3d", "add_noise", "save", "metrics", "render"
    params: dict
    label: str | None
    source: str
    line: int | None
    options: dict = field(default_factory=dict)  # pinned / region / preserve_volume / parameters / boundary_motion / noise
    notes: list = field(default_factory=list)  # things worth telling (a MeshLab GUI name was used...)

    @property
    def where(self) -> str:
        # `meshdenoise denoise --method M` (a step in no file) is said as its option: --method 'M'
        name = self.options.get("method", self.name) if self.index is None else self.name
        return _step_at(self.source, self.line, self.index, name)


def _step_at(source: str, line: int | None, index: int | None, name: str) -> str:
    """Where a step is, for messages: ``file:line: step 3 'sobolev'``, or ``--method 'sobolev'``
    for a step that is not in a file (``index`` None, ``source`` the option that gave it)."""
    if index is None:
        return f"{source} '{name}'"
    return where(source, line, f"step {index} '{name}'")


def step_names() -> list[str]:
    """Every name a step may have."""
    names = [s.name for s in list_filters()] + list(BUILTIN_STEPS) + [f"open3d.{k}" for k in OPEN3D_OPS]
    return names + list(pymeshlab_steps.filter_names())


def _unknown_step(name: str, at: str) -> PipelineValidationError:
    from .meshlab_names import FILTERS

    gui = {entry["meshlab"]: py for py, entry in FILTERS.items()}  # a misspelt MeshLab GUI name ("Taubin Smoth")
    hint = difflib.get_close_matches(name, step_names() + list(gui), n=1, cutoff=0.6)
    extra = ""
    if hint:
        extra = f" (did you mean '{hint[0]}'?)" if hint[0] not in gui else f" (did you mean '{gui[hint[0]]}', MeshLab's '{hint[0]}'?)"
    return PipelineValidationError(
        f"{at}: unknown step '{name}'{extra}; a step is one of our filters (meshdenoise filters), "
        "a pymeshlab filter, open3d.<operation>, denoise, add_noise, metrics, save or render"
    )


def _check_params(params: list[Param], given: dict, at: str) -> dict:
    """Names, types and ranges of a built-in step's parameters, by the registry's one check (FilterSpec.resolve / Param.check)."""
    try:
        return FilterSpec("", "", tuple(params), core=None).resolve(given, at)
    except (TypeError, ValueError) as exc:
        raise PipelineValidationError(str(exc), getattr(exc, "parameter", None)) from None


def _check_vertex_spec(key: str, value: Any, at: str, keywords: tuple[str, ...]) -> Any:
    if isinstance(value, str):
        if value not in keywords:
            hint = difflib.get_close_matches(value, keywords, n=1)
            extra = f" (did you mean '{hint[0]}'?)" if hint else ""
            raise PipelineValidationError(f"{at}: {key}: {value!r} is not understood{extra}; use {', '.join(keywords)} "
                                          "or a list of vertex indices", key)
        return value
    if isinstance(value, list) and all(isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in value):
        return list(value)
    raise PipelineValidationError(f"{at}: {key}: expected {', '.join(keywords)} or a list of vertex indices, got {value!r}",
                                  key)


def _filter_options(given: dict, at: str, allowed: tuple[str, ...] = tuple(sorted(COMMON))) -> tuple[dict, dict]:
    """Split a filter step's keys into the common options (checked as registry.COMMON_OPTIONS declares them)
    and the filter's own parameters."""
    options = {}
    rest = {}
    for key, value in given.items():
        if key not in allowed or key not in _STEP_OPTION:
            rest[key] = value
            continue
        option = _STEP_OPTION[key]
        if option.indices:  # pinned, region: a keyword or vertex indices
            options[key] = _check_vertex_spec(key, value, at, option.choices)
        elif option.type == "bool":
            if not isinstance(value, bool):
                raise PipelineValidationError(f"{at}: {key} must be true or false, got {value!r}", key)
            options[key] = value
        elif key == "noise":
            try:
                options[key] = parse_noise_option(value, f"{at}: noise")
            except ValueError as exc:
                raise PipelineValidationError(str(exc), key) from None
        else:
            if value not in option.choices:
                hint = difflib.get_close_matches(str(value), option.choices, n=1)
                extra = f" (did you mean '{hint[0]}'?)" if hint else ""
                raise PipelineValidationError(f"{at}: {key} must be {_in_words(option.choices)}, got {value!r}{extra}",
                                              key)
            options[key] = value
    return options, rest


def _in_words(choices: tuple[str, ...]) -> str:
    """``'auto'``, ``'free' or 'normal'``, ``one of 'a', 'b', 'c'``."""
    quoted = [repr(c) for c in choices]
    return quoted[0] if len(quoted) == 1 else " or ".join(quoted) if len(quoted) == 2 else "one of " + ", ".join(quoted)


def _check_criterion(name: str, criterion: str, at: str) -> None:
    """``criterion: normals`` only for the filters that have it."""
    from ..tuning.choose import normal_filters

    if criterion == "normals" and name not in normal_filters():
        raise PipelineValidationError(f"{at}: criterion 'normals' is for the filters with a rule for it "
                                      f"({', '.join(normal_filters())}), not '{name}'", "criterion")


def _our_filter(index, name, given, label, source, line) -> Step:
    spec = get_filter(name)
    at = _step_at(source, line, index, name)
    options, rest = _filter_options(given, at)
    if "noise" in options and options.get("parameters") != "auto":
        raise PipelineValidationError(f"{at}: noise: the noise level is used only to choose parameters: add "
                                      "'parameters: auto', or leave noise out", "noise")
    if "criterion" in options:
        if options.get("parameters") != "auto":
            raise PipelineValidationError(f"{at}: criterion: it says how parameters are chosen: add 'parameters: auto', "
                                          "or leave criterion out", "criterion")
        _check_criterion(name, options["criterion"], at)
    try:
        if options.get("parameters") == "auto":
            spec.resolve(rest, at)  # explicit values are still checked; auto fills the others
            params = rest
        else:
            params = spec.resolve(rest, at)
    except (TypeError, ValueError) as exc:
        raise PipelineValidationError(str(exc), getattr(exc, "parameter", None)) from None
    return Step(index, name, "ours", params, label, source, line, options)


# render's parameters, with what `meshdenoise steps` says of each: (name, type, default, help)
RENDER_DOC = (
    ("path", "str", None, "image file to write, ending in .png (required); {stem} {name} {parent} {dir} {setting} {index} are filled in"),
    ("meshes", "list of str", ["input", "result"], "meshes drawn side by side: input, result, or a step label (the mesh before that step)"),
    ("reference", "str", None, "draw an error heat map of each mesh against this one (input, result or a step label)"),
    ("titles", "list of str", None, "one title per mesh (default: the names in meshes)"),
    ("size", "[int, int]", [400, 400], "width and height of each panel in pixels, 16..4096"),
    ("backend", "str", "auto", "rasteriser: one of the meshdenoise.render backends (auto picks the first that works)"),
    ("cmap", "str", "viridis", "matplotlib colour map of the heat map"),
    ("vmax", "float", None, "top of the colour bar (default: the largest error); > 0"),
    ("change", "bool", False, "without reference: heat maps of the displacement from the first mesh (a scan's change)"),
    ("percentile", "float", None, "where the colour bar tops when vmax is not given, 0 < p <= 100 (default 100, 99 for change)"),
    ("zoom", "[vertex, r] or [x, y, z, r]", None, "draw only the ball of radius r (mean edge lengths) around a vertex or point"),
)
RENDER_PARAMS = tuple(d[0] for d in RENDER_DOC)
METRICS_DOC = (
    ("reference", "str or {before: LABEL}", "input",
     "what the mesh is compared with: input, a mesh file, a per-input pattern like '{dir}/Original.obj', "
     "or {before: LABEL} (the mesh before the step labelled LABEL)"),
    ("metrics", "list of str", "all", "metric names (meshdenoise.metrics.METRICS)"),
)
# what `meshdenoise steps` says of the options of our filters' steps: (name, type, default, help)
OURS_OPTIONS_DOC = tuple((o.name, o.type, o.default, f"{o.help} ({o.range_text()}"
                          + (", with parameters: auto)" if o.name in ("noise", "criterion") else ")"))
                         for o in COMMON_OPTIONS if o.step)


def denoise_options_doc() -> list[dict]:
    """The keys of the ``denoise`` step, ``{"name", "type", "default", "range", "help"}`` (``meshdenoise steps``,
    ``meshdenoise filters --json``): ``method``, ``defaults``, ``explain`` and the filter options but ``parameters``
    (registry.COMMON_OPTIONS), borders along normals by default; with a method, that filter's parameters too."""
    out = [
        {"name": "method", "type": "str", "default": None, "range": "one of our filters (meshdenoise filters)",
         "help": "run this filter, every parameter its own rule tunes and the step does not give chosen by that rule "
                 "(its parameters are keys of the step too); without: the default chooses the filter and its "
                 "parameters"},
        {"name": "defaults", "type": "bool", "default": False, "range": "True or False",
         "help": "with method: the filter's own defaults for the parameters not given (nothing chosen)"},
        {"name": "explain", "type": "bool", "default": False, "range": "True or False",
         "help": "without method: print why (every candidate's held-out error)"},
    ]
    for o in COMMON_OPTIONS:
        if o.step and o.name != "parameters":
            d = o.describe()
            if o.name == "boundary_motion":
                d["default"] = "normal"
            elif o.name in ("noise", "criterion"):  # said by the filter's rule when not given
                d["help"] = "with method (not defaults): " + d["help"]
                d["default"] = None if o.name == "criterion" else d["default"]
                if o.name == "criterion":
                    d["help"] += " (default: normals where the filter has it, else sure)"
            out.append(d)
    return out
STEP_CRITERIA = _STEP_OPTION["criterion"].choices


def describe_pymeshlab_step(name: str) -> dict:
    """A pymeshlab filter as :func:`describe_steps` describes a step (MeshLab types, defaults on a small sphere, enum labels).

    Raises
    ------
    KeyError
        Not a pymeshlab filter (nor a MeshLab GUI name of one), with the closest names.
    """
    from .meshlab_gui import gui_names

    canonical, _, _ = gui_names(name, {})
    if canonical not in pymeshlab_steps.filter_names():
        hint = difflib.get_close_matches(name, step_names(), n=1)
        raise KeyError(f"unknown step '{name}'" + (f" (did you mean '{hint[0]}'?)" if hint else ""))
    from .meshlab_names import FILTERS

    params = []
    recorded = FILTERS.get(canonical, {}).get("params", {})
    for key, info in pymeshlab_steps.parameter_types(canonical).items():
        default = info["default"]
        labels = info.get("enum") or []
        if labels and isinstance(default, int) and 0 <= default < len(labels):
            default = labels[default]
        elif isinstance(default, float):
            default = float(f"{default:.7g}")  # MeshLab stores floats: 0.53 reads back as 0.5299999713897705
        elif not isinstance(default, (bool, int, str)):
            default = str(default)
        parts = [f"MeshLab name '{recorded[key]['name']}'"] if key in recorded else []
        if labels:
            parts.append("one of " + ", ".join(repr(x) for x in labels))
        params.append({"name": key, "type": info["type"], "default": default, "help": "; ".join(parts)})
    meshlab = FILTERS.get(canonical, {}).get("meshlab")
    summary = f"pymeshlab filter (MeshLab: '{meshlab}')" if meshlab else "pymeshlab filter"
    return {"name": canonical, "summary": summary + "; defaults measured on a small sphere (lengths depend on the mesh)", "params": params}


def describe_steps() -> list[dict]:
    """Every built-in step with its parameters (``meshdenoise steps``): name, what it is, and
    ``params`` as ``{"name", "type", "default", "help"}``; our filters and pymeshlab's are summarised."""

    def entry(name, summary, params):
        return {"name": name, "summary": summary,
                "params": [{"name": n, "type": t, "default": d, "help": h} for n, t, d, h in params]}

    def from_params(params):
        out = []
        for p in params:
            allowed = p.range_text()
            allowed = "" if p.kind is bool or allowed.startswith("any ") else allowed
            out.append((p.name, p.kind.__name__, p.default, "; ".join(x for x in (p.help, allowed) if x)))
        return out

    out = [
        entry("denoise", "the goal, as meshdenoise.denoise(): without method the default for scans chooses the filter "
              "and its parameters from the mesh alone (candidates scored on held-out vertices) and runs it with a "
              "flipped-face guard; with method that filter, its parameters not given chosen by its own rule (defaults: "
              "true: its defaults); the choice is recorded (denoise.* and auto.* columns)",
              [(d["name"], d["type"], d["default"], d["help"] if d["type"] == "bool" else f"{d['help']} ({d['range']})")
               for d in denoise_options_doc()]),
        entry("add_noise", "displace every vertex along its normal by Gaussian noise", from_params(BUILTIN_STEPS["add_noise"])),
        entry("save", "write the current mesh (PLY, OBJ, OFF, STL) once every step succeeded", from_params(BUILTIN_STEPS["save"])),
        entry("metrics", "measure the current mesh against a reference; values go to the results table", METRICS_DOC),
        entry("render", "draw meshes side by side into a PNG, with an error heat map against a reference", RENDER_DOC),
    ]
    for op, params in OPEN3D_OPS.items():
        out.append(entry(f"open3d.{op}", f"Open3D's TriangleMesh.{op}", from_params(params)))
    for spec in list_filters():
        out.append(entry(spec.name, f"our filter: {spec.summary}", from_params(spec.params) + list(OURS_OPTIONS_DOC)))
    out.append(entry("<any pymeshlab filter>",
                     f"one of pymeshlab's {len(pymeshlab_steps.filter_names())} filters by its pymeshlab name (or MeshLab's GUI name); "
                     "parameters: python -c \"import pymeshlab; pymeshlab.print_filter_parameter_list('NAME')\"", []))
    out.append(entry("(every step)", "keys every step takes", [("label", "str", None, "name the mesh before this step (for metrics and render)")]))
    return out


def _check_render(given: dict, at: str) -> dict:
    """``render``: the named meshes side by side (``input``, ``result`` or a step label: the mesh
    before that step), with an error heat map against ``reference`` when one is named."""
    from ..render import BACKENDS

    for key in given:
        if key not in RENDER_PARAMS:
            hint = difflib.get_close_matches(str(key), RENDER_PARAMS, n=1)
            extra = f" (did you mean '{hint[0]}'?)" if hint else ""
            raise PipelineValidationError(f"{at}: unknown parameter '{key}'{extra}; its parameters: {', '.join(RENDER_PARAMS)}")
    path = given.get("path")
    if not isinstance(path, str) or not path.lower().endswith(".png"):
        raise PipelineValidationError(f"{at}: render needs path: an image file ending in .png, got {path!r}")
    meshes = given.get("meshes", ["input", "result"])
    if isinstance(meshes, str):
        meshes = [meshes]
    if not isinstance(meshes, list) or not meshes or not all(isinstance(m, str) for m in meshes):
        raise PipelineValidationError(f"{at}: meshes: expected a list of names (input, result or step labels), got {meshes!r}")
    reference = given.get("reference")
    if reference is not None and not isinstance(reference, str):
        raise PipelineValidationError(f"{at}: reference: expected input, result or a step label, got {reference!r}")
    titles = given.get("titles")
    if titles is not None and (not isinstance(titles, list) or len(titles) != len(meshes)):
        raise PipelineValidationError(f"{at}: titles: expected a list of {len(meshes)} strings (one per mesh), got {titles!r}")
    size = given.get("size", [400, 400])
    if (not isinstance(size, list) or len(size) != 2
            or not all(isinstance(v, int) and not isinstance(v, bool) and 16 <= v <= 4096 for v in size)):
        raise PipelineValidationError(f"{at}: size: expected [width, height] in pixels (16..4096), got {size!r}")
    backend = given.get("backend", "auto")
    if backend not in BACKENDS:
        raise PipelineValidationError(f"{at}: backend = {backend!r} is not allowed: one of {', '.join(BACKENDS)}")
    vmax = given.get("vmax")
    if vmax is not None and (isinstance(vmax, bool) or not isinstance(vmax, (int, float)) or not vmax > 0):
        raise PipelineValidationError(f"{at}: vmax: expected a positive number (top of the colour bar), got {vmax!r}")
    change = given.get("change", False)
    if not isinstance(change, bool):
        raise PipelineValidationError(f"{at}: change: expected true or false, got {change!r}")
    if change and reference is not None:
        raise PipelineValidationError(f"{at}: change: draws the displacement from the first mesh; it goes without reference")
    percentile = given.get("percentile")
    if percentile is not None and (isinstance(percentile, bool) or not isinstance(percentile, (int, float))
                                   or not 0 < percentile <= 100):
        raise PipelineValidationError(f"{at}: percentile: expected a number with 0 < p <= 100, got {percentile!r}")
    zoom = given.get("zoom")
    if zoom is not None:
        numbers = isinstance(zoom, list) and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in zoom)
        ok = numbers and len(zoom) in (2, 4) and math.isfinite(sum(zoom)) and zoom[-1] > 0
        if ok and len(zoom) == 2:
            ok = isinstance(zoom[0], int) and zoom[0] >= 0
        if not ok:
            raise PipelineValidationError(
                f"{at}: zoom: expected [vertex, radius] or [x, y, z, radius], radius > 0 in mean edge lengths, got {zoom!r}"
            )
        zoom = (zoom[0], float(zoom[1])) if len(zoom) == 2 else (tuple(float(v) for v in zoom[:3]), float(zoom[3]))
    return {"path": path, "meshes": meshes, "reference": reference, "titles": titles or list(meshes),
            "size": tuple(size), "backend": backend, "cmap": str(given.get("cmap", "viridis")), "vmax": vmax,
            "change": change, "percentile": None if percentile is None else float(percentile), "zoom": zoom}


def _check_metrics(given: dict, at: str) -> dict:
    from ..metrics import METRICS

    allowed = {"reference", "metrics"}
    for key in given:
        if key not in allowed:
            hint = difflib.get_close_matches(str(key), allowed, n=1)
            extra = f" (did you mean '{hint[0]}'?)" if hint else ""
            raise PipelineValidationError(f"{at}: unknown parameter '{key}'{extra}; its parameters: reference, metrics")
    ref = given.get("reference", "input")
    if isinstance(ref, dict):
        if set(ref) != {"before"} or not isinstance(ref["before"], str):
            raise PipelineValidationError(f"{at}: reference: expected 'input', a file, or {{before: STEP_LABEL}}, got {ref!r}")
        ref = {"before": ref["before"]}
    elif not isinstance(ref, str):
        raise PipelineValidationError(f"{at}: reference: expected 'input', a file, or {{before: STEP_LABEL}}, got {ref!r}")
    names = given.get("metrics", list(METRICS))
    if isinstance(names, str):
        names = [names]
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        raise PipelineValidationError(f"{at}: metrics: expected a metric name or a list of them ({', '.join(METRICS)}), got {names!r}")
    for n in names:
        if n not in METRICS:
            hint = difflib.get_close_matches(str(n), list(METRICS), n=1)
            extra = f" (did you mean '{hint[0]}'?)" if hint else ""
            raise PipelineValidationError(f"{at}: unknown metric '{n}'{extra}; known: {', '.join(METRICS)}")
    return {"reference": ref, "metrics": list(names)}


def parse_step(item: Any, index: int | None, source: str, line: int | None) -> Step:
    """Check one step of the ``steps:`` list (a name, or ``{name: {params}}``) and return it.

    ``index`` is the step's position (from 1) in ``source``; ``None`` for a step given
    another way (``denoise --method``: messages then read ``--method 'sobolev': ...``).
    """
    if isinstance(item, str):
        name, given = item, {}
    elif isinstance(item, dict) and len(item) == 1:
        name, given = next(iter(item.items()))
        line = getattr(item, "key_lines", {}).get(name, line)
        if given is None:
            given = {}
        if not isinstance(given, dict):
            raise PipelineValidationError(
                f"{_step_at(source, line, index, name)}: parameters must be a mapping "
                f"(name: value), got {given!r}"
            )
    else:
        raise PipelineValidationError(
            f"{where(source, line, f'step {index}')}: a step is a name or a one-key mapping "
            f"'name: {{parameters}}', got {item!r}"
        )
    name = str(name)
    given = dict(given)
    label = given.pop("label", None)
    at = _step_at(source, line, index, name)
    if label is not None and not isinstance(label, str):
        raise PipelineValidationError(f"{at}: label must be a string, got {label!r}")
    param_lines = getattr(item, "get", lambda *_: None)(name) if isinstance(item, dict) else None
    # A parameter's own line makes the message point at the bad value.
    def at_param(key):
        return _step_at(source, getattr(param_lines, "key_lines", {}).get(key, line), index, name)

    try:
        return _parse(name, given, index, label, source, line, at_param)
    except PipelineValidationError as exc:
        raise exc from None


def _parse(name, given, index, label, source, line, at_param) -> Step:
    at = _step_at(source, line, index, name)
    bad_key = next(iter(given), None)
    if name in {s.name for s in list_filters()}:
        try:
            return _our_filter(index, name, given, label, source, line)
        except PipelineValidationError as exc:
            if exc.parameter is None:
                raise
            raise _at_its_key(exc, at, at_param) from None
    if name.startswith("open3d."):
        op = name[len("open3d."):]
        if op not in OPEN3D_OPS:
            raise _unknown_step(name, at)
        return Step(index, name, "open3d", _check_params(OPEN3D_OPS[op], given, at), label, source, line)
    if name == "denoise":
        return denoise_step(given, index, label, source, line, at_param)
    if name in ("add_noise", "save"):
        params = _check_params(BUILTIN_STEPS[name], given, at)
        if name == "save" and not params["path"]:
            raise PipelineValidationError(f"{at}: save needs a path (e.g. path: '{{stem}}_clean.ply')")
        if name == "save":
            from ..io import SUPPORTED_EXTENSIONS

            if Path(params["path"]).suffix.lower() not in SUPPORTED_EXTENSIONS:
                raise PipelineValidationError(
                    f"{at_param('path')}: path {params['path']!r}: unsupported extension; use one of {', '.join(SUPPORTED_EXTENSIONS)}"
                )
            if params["precision"] == "float32" and Path(params["path"]).suffix.lower() != ".ply":
                raise PipelineValidationError(
                    f"{at_param('precision')}: precision 'float32' is for PLY only (path {params['path']!r}: OBJ and "
                    "OFF write 17 significant digits, binary STL is always float32)")
        return Step(index, name, name, params, label, source, line)
    if name == "metrics":
        return Step(index, name, "metrics", _check_metrics(given, at), label, source, line)
    if name == "render":
        return Step(index, name, "render", _check_render(given, at), label, source, line)
    from .meshlab_gui import gui_names  # MeshLab's GUI names ("Taubin Smooth", "stepSmoothNum") are accepted, with a note

    canonical, given, renamed = gui_names(name, given)
    if canonical in pymeshlab_steps.filter_names():
        try:
            params = pymeshlab_steps.check_parameters(canonical, given, at)
        except ValueError as exc:
            raise _at_its_key(exc, at, at_param) from None
        return Step(index, canonical, "pymeshlab", params, label, source, line, notes=[f"{at}: {n}" for n in renamed])
    _ = bad_key
    raise _unknown_step(name, at)


def denoise_step(given: dict, index: int | None = None, label: str | None = None, source: str = "denoise",
                 line: int | None = None, at_param=None) -> Step:
    """The ``denoise`` step, checked: what ``meshdenoise.denoise(mesh, ...)`` and the command's ``denoise`` do.

    Without ``method`` the default for scans chooses the filter and its parameters (``explain: true``
    prints why). With ``method: M`` (one of our filters, looked up in the registry) the filter runs,
    every parameter its own rule tunes and the step does not give chosen by that rule (``noise``,
    ``criterion``: how), or with ``defaults: true`` its own defaults for them. Both take ``pinned``,
    ``region``, ``preserve_volume`` and ``boundary_motion`` (default ``normal``). ``index`` ``None``: a step
    given another way than a file (the command line: messages read ``--method 'sobolev': ...``).
    """
    given = dict(given)
    method = given.pop("method", None)
    # a step in no file is said as the option that gave it: --method 'sobolev' (Step.where alike)
    at = _step_at(source, line, index, method if index is None and isinstance(method, str) else "denoise")
    at_param = at_param or (lambda key: at)

    def options_of(allowed: tuple[str, ...]) -> tuple[dict, dict]:
        try:
            return _filter_options(given, at, allowed)
        except PipelineValidationError as exc:  # said at the line of the option it is about
            raise _at_its_key(exc, at, at_param) from None

    flags = {}
    for key in ("explain", "defaults"):
        value = given.pop(key, False)
        if not isinstance(value, bool):
            raise PipelineValidationError(f"{at_param(key)}: {key} must be true or false, got {value!r}")
        if value:
            flags[key] = True
    if method is None:
        options, rest = options_of(("pinned", "region", "preserve_volume", "boundary_motion"))
        if rest or "defaults" in flags:
            key = next(iter(rest), "defaults")
            if key == "noise":
                why = ("the default reads the noise from held-out vertices; to choose a filter's parameters for a "
                       "known level add method: M")
            else:
                why = ("the default chooses the filter and its parameters (without method its keys are pinned, region, "
                       "preserve_volume, boundary_motion, explain); to choose or set a filter's parameters, add method: M")
            what = f"'{key}' needs method" if key in DENOISE_KEYS else f"unknown parameter '{key}'"
            raise PipelineValidationError(f"{at_param(key)}: {what}: {why}")
        options.update(flags)
        options.setdefault("boundary_motion", "normal")
        return Step(index, "denoise", "default", {}, label, source, line, options)
    if not isinstance(method, str):
        raise PipelineValidationError(f"{at_param('method')}: method must be the name of one of our filters "
                                      f"(meshdenoise filters), got {method!r}")
    try:
        spec = get_filter(method)
    except KeyError as exc:
        raise PipelineValidationError(f"{at_param('method')}: {exc}") from None
    if "explain" in flags:
        raise PipelineValidationError(f"{at_param('explain')}: explain says why the default chose its filter: "
                                      "leave out method, or explain")
    if "parameters" in given:
        raise PipelineValidationError(f"{at_param('parameters')}: a denoise step with a method chooses the "
                                      "parameters not given by itself (defaults: true runs the filter's defaults "
                                      "instead); leave out parameters")
    options, rest = options_of(tuple(k for k in DENOISE_KEYS if k in _STEP_OPTION))
    chooses = "defaults" not in flags and spec.auto is not None
    for key in ("noise", "criterion"):
        if key in options and not chooses:
            why = "defaults: true chooses none" if "defaults" in flags else f"'{method}' has no automatic rule"
            raise PipelineValidationError(f"{at_param(key)}: {key} says how the parameters are chosen and {why}; "
                                          f"leave out {key}")
    if "criterion" in options:
        _check_criterion(method, options["criterion"], at_param("criterion"))
    if "noise" in options and chooses and spec.auto.held_out is not None and options.get("criterion") != "sure":
        raise PipelineValidationError(f"{at_param('noise')}: '{method}' chooses for the face normals by held-out "
                                      "vertices, which read no noise level; add criterion: sure (--criterion sure) to "
                                      "choose by SURE for this level, or leave noise out")
    try:
        checked = spec.resolve(rest, at)  # the values given, checked; the rule (or the defaults) fills the others
    except (TypeError, ValueError) as exc:
        raise _at_its_key(exc, at, at_param) from None
    options.update(flags)
    options["method"] = method
    options.setdefault("boundary_motion", "normal")
    return Step(index, "denoise", "default", {k: checked[k] for k in rest}, label, source, line, options)


def _at_its_key(exc: Exception, at: str, at_param) -> PipelineValidationError:
    """``exc`` as a validation error said at the line of the key it is about (its ``parameter``, set where it was
    raised), or at the step's line ``at`` when it is about no one key."""
    key = getattr(exc, "parameter", None)
    text = str(exc) if key is None else str(exc).replace(at, at_param(key), 1)
    return PipelineValidationError(text, key)
