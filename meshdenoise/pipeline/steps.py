"""Pipeline steps: parsing and checking each step before anything runs, and running it.

The working mesh of a pipeline is a ``pymeshlab.MeshSet``: pymeshlab filters apply to it
directly, our filters change it in place keeping colours (see :mod:`meshdenoise.adapters`),
Open3D operations go through arrays and back.
"""

from __future__ import annotations

import os
import tempfile

import difflib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..registry import MAX_ITERATIONS, Param, get_filter, list_filters
from . import pymeshlab_steps
from .errors import PipelineValidationError, where

__all__ = ["Step", "parse_step", "run_step", "RunContext", "BUILTIN_STEPS", "OPEN3D_OPS", "step_names"]

# Open3D's clean-up and smoothing operations, under "open3d.<method name>", with their parameters.
OPEN3D_OPS: dict[str, list[Param]] = {
    "remove_degenerate_triangles": [],
    "remove_duplicated_triangles": [],
    "remove_duplicated_vertices": [],
    "remove_non_manifold_edges": [],
    "remove_unreferenced_vertices": [],
    "compute_vertex_normals": [Param("normalized", bool, True, help="unit-length normals")],
    # bounded: a step of lambda >> 1 only blows the mesh up (lambda_filter: 1e300 gave a mesh at 1e300)
    "filter_smooth_simple": [Param("number_of_iterations", int, 1, low=0, high=MAX_ITERATIONS)],
    "filter_smooth_laplacian": [
        Param("number_of_iterations", int, 1, low=0, high=MAX_ITERATIONS),
        Param("lambda_filter", float, 0.5, low=-1.0, high=1.0),
    ],
    "filter_smooth_taubin": [
        Param("number_of_iterations", int, 1, low=0, high=MAX_ITERATIONS),
        Param("lambda_filter", float, 0.5, low=-1.0, high=1.0),
        Param("mu", float, -0.53, low=-1.0, high=1.0),
    ],
}

BUILTIN_STEPS: dict[str, list[Param]] = {
    "add_noise": [
        Param("rho", float, 0.01, low=0.0, help="noise amplitude (absolute, or x bbox diagonal if relative)"),
        Param("relative", bool, False, help="rho is a fraction of the bounding-box diagonal"),
        Param("seed", int, 0, low=0, help="random seed (numpy takes non-negative seeds)"),
    ],
    "save": [
        Param("path", str, "", help="output file; {stem} {name} {setting} {index} are filled in"),
        Param("binary", bool, True, help="binary PLY/STL"),
        Param("colors", bool, True, help="write vertex colours when the mesh has them"),
    ],
    "metrics": [],  # checked by _check_metrics
    "render": [],  # passed to meshdenoise.render.render_comparison
}
COMMON = {"pinned", "region", "preserve_volume", "parameters"}
RESERVED = {"label"}


@dataclass
class Step:
    """One checked step: plain data, so a plan can be sent to Dask workers."""

    index: int
    name: str
    kind: str  # "ours", "pymeshlab", "open3d", "add_noise", "save", "metrics", "render"
    params: dict
    label: str | None
    source: str
    line: int | None
    options: dict = field(default_factory=dict)  # pinned / region / preserve_volume / parameters

    @property
    def where(self) -> str:
        return where(self.source, self.line, f"step {self.index} '{self.name}'")


def step_names() -> list[str]:
    """Every name a step may have."""
    names = [s.name for s in list_filters()] + list(BUILTIN_STEPS) + [f"open3d.{k}" for k in OPEN3D_OPS]
    return names + list(pymeshlab_steps.filter_names())


def _unknown_step(name: str, at: str) -> PipelineValidationError:
    hint = difflib.get_close_matches(name, step_names(), n=1, cutoff=0.6)
    extra = f" (did you mean '{hint[0]}'?)" if hint else ""
    return PipelineValidationError(
        f"{at}: unknown step '{name}'{extra}; a step is one of our filters (meshdenoise filters), "
        "a pymeshlab filter, open3d.<operation>, add_noise, metrics, save or render"
    )


def _check_params(params: list[Param], given: dict, at: str) -> dict:
    known = {p.name: p for p in params}
    for key in given:
        if key not in known:
            hint = difflib.get_close_matches(str(key), list(known), n=1)
            extra = f" (did you mean '{hint[0]}'?)" if hint else ""
            raise PipelineValidationError(
                f"{at}: unknown parameter '{key}'{extra}; its parameters: {', '.join(known) or 'none'}"
            )
    try:
        return {p.name: p.check(given.get(p.name, p.default), at) for p in params}
    except (TypeError, ValueError) as exc:
        raise PipelineValidationError(str(exc)) from None


def _check_vertex_spec(key: str, value: Any, at: str, keywords: tuple[str, ...]) -> Any:
    if isinstance(value, str):
        if value not in keywords:
            hint = difflib.get_close_matches(value, keywords, n=1)
            extra = f" (did you mean '{hint[0]}'?)" if hint else ""
            raise PipelineValidationError(f"{at}: {key}: {value!r} is not understood{extra}; use {', '.join(keywords)} or a list of vertex indices")
        return value
    if isinstance(value, list) and all(isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in value):
        return list(value)
    raise PipelineValidationError(f"{at}: {key}: expected {', '.join(keywords)} or a list of vertex indices, got {value!r}")


def _our_filter(index, name, given, label, source, line) -> Step:
    spec = get_filter(name)
    at = where(source, line, f"step {index} '{name}'")
    options = {}
    rest = {}
    for key, value in given.items():
        if key == "pinned":
            options[key] = _check_vertex_spec(key, value, at, ("boundary", "selection"))
        elif key == "region":
            options[key] = _check_vertex_spec(key, value, at, ("selection",))
        elif key == "preserve_volume":
            if not isinstance(value, bool):
                raise PipelineValidationError(f"{at}: preserve_volume must be true or false, got {value!r}")
            options[key] = value
        elif key == "parameters":
            if value != "auto":
                raise PipelineValidationError(f"{at}: parameters: only 'auto' is understood, got {value!r}")
            options[key] = value
        else:
            rest[key] = value
    try:
        if options.get("parameters") == "auto":
            spec.resolve(rest, at)  # explicit values are still checked; auto fills the others
            params = rest
        else:
            params = spec.resolve(rest, at)
    except (TypeError, ValueError) as exc:
        raise PipelineValidationError(str(exc)) from None
    return Step(index, name, "ours", params, label, source, line, options)


RENDER_PARAMS = ("path", "meshes", "reference", "titles", "size", "backend", "cmap", "vmax")


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
    return {"path": path, "meshes": meshes, "reference": reference, "titles": titles or list(meshes),
            "size": tuple(size), "backend": backend, "cmap": str(given.get("cmap", "viridis")), "vmax": vmax}


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
    for n in names:
        if n not in METRICS:
            hint = difflib.get_close_matches(str(n), list(METRICS), n=1)
            extra = f" (did you mean '{hint[0]}'?)" if hint else ""
            raise PipelineValidationError(f"{at}: unknown metric '{n}'{extra}; known: {', '.join(METRICS)}")
    return {"reference": ref, "metrics": list(names)}


def parse_step(item: Any, index: int, source: str, line: int | None) -> Step:
    """Check one step of the ``steps:`` list (a name, or ``{name: {params}}``) and return it."""
    if isinstance(item, str):
        name, given = item, {}
    elif isinstance(item, dict) and len(item) == 1:
        name, given = next(iter(item.items()))
        line = getattr(item, "key_lines", {}).get(name, line)
        if given is None:
            given = {}
        if not isinstance(given, dict):
            raise PipelineValidationError(
                f"{where(source, line, f'step {index} {name!r}')}: parameters must be a mapping "
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
    at = where(source, line, f"step {index} '{name}'")
    if label is not None and not isinstance(label, str):
        raise PipelineValidationError(f"{at}: label must be a string, got {label!r}")
    param_lines = getattr(item, "get", lambda *_: None)(name) if isinstance(item, dict) else None
    # A parameter's own line makes the message point at the bad value.
    def at_param(key):
        return where(source, getattr(param_lines, "key_lines", {}).get(key, line), f"step {index} '{name}'")

    try:
        return _parse(name, given, index, label, source, line, at_param)
    except PipelineValidationError as exc:
        raise exc from None


def _parse(name, given, index, label, source, line, at_param) -> Step:
    at = where(source, line, f"step {index} '{name}'")
    bad_key = next(iter(given), None)
    if name in {s.name for s in list_filters()}:
        try:
            return _our_filter(index, name, given, label, source, line)
        except PipelineValidationError as exc:
            key = _named_key(str(exc), given)
            if key is not None:
                raise PipelineValidationError(str(exc).replace(at, at_param(key), 1)) from None
            raise
    if name.startswith("open3d."):
        op = name[len("open3d."):]
        if op not in OPEN3D_OPS:
            raise _unknown_step(name, at)
        return Step(index, name, "open3d", _check_params(OPEN3D_OPS[op], given, at), label, source, line)
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
        return Step(index, name, name, params, label, source, line)
    if name == "metrics":
        return Step(index, name, "metrics", _check_metrics(given, at), label, source, line)
    if name == "render":
        return Step(index, name, "render", _check_render(given, at), label, source, line)
    if name in pymeshlab_steps.filter_names():
        try:
            params = pymeshlab_steps.check_parameters(name, given, at)
        except ValueError as exc:
            key = _named_key(str(exc), given)
            msg = str(exc) if key is None else str(exc).replace(at, at_param(key), 1)
            raise PipelineValidationError(msg) from None
        return Step(index, name, "pymeshlab", params, label, source, line)
    _ = bad_key
    raise _unknown_step(name, at)


def _named_key(message: str, given: dict) -> str | None:
    for key in given:
        if f"'{key}'" in message or f"{key}:" in message:
            return key
    return None


# --- running ------------------------------------------------------------------------------------
@dataclass
class RunContext:
    """State of one input going through the steps."""

    ms: Any  # pymeshlab.MeshSet
    input_path: Path
    input_arrays: tuple  # (V, F) as loaded
    snapshots: dict = field(default_factory=dict)  # label -> (V, F) before that step
    row: dict = field(default_factory=dict)
    staged: list = field(default_factory=list)  # (path, V, F, colors, binary) written at the end
    staged_files: list = field(default_factory=list)  # (temporary, path) renamed at the end (images)
    resolve_path: Any = None  # template -> Path
    echo: Any = None  # callable(str) for messages (auto parameters)


def meshset_from_arrays(V: np.ndarray, F: np.ndarray, colors: np.ndarray | None = None,
                        selection: np.ndarray | None = None):
    """A new MeshSet holding one mesh made of these arrays (colours RGBA in [0, 1] and a vertex
    selection (n,) bool, as read from a MeshLab PLY, optional)."""
    import pymeshlab

    kwargs = {}
    if colors is not None:
        kwargs["v_color_matrix"] = np.asarray(colors, dtype=np.float64)
    if selection is not None and np.any(selection):  # no setter in pymeshlab: select by a temporary quality
        kwargs["v_scalar_array"] = np.asarray(selection, dtype=np.float64)
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=V, face_matrix=np.asarray(F, dtype=np.int32).reshape(-1, 3), **kwargs))
    if "v_scalar_array" in kwargs:
        ms.apply_filter("compute_selection_by_condition_per_vertex", condselect="q > 0.5")
        ms.apply_filter("compute_scalar_by_function_per_vertex", q="0")  # the quality a new mesh has
    return ms


def current_arrays(ms) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """``(V, F, colours or None)`` of the MeshSet's current mesh (compacted first)."""
    m = ms.current_mesh()
    if not m.is_compact():
        m.compact()
    colors = m.vertex_color_matrix() if m.has_vertex_color() else None
    return (np.array(m.vertex_matrix(), dtype=np.float64), np.array(m.face_matrix(), dtype=np.int64), colors)


def _replace_mesh(ctx: RunContext, V, F, colors) -> None:
    import pymeshlab

    kwargs = {} if colors is None else {"v_color_matrix": colors}
    ctx.ms.add_mesh(pymeshlab.Mesh(vertex_matrix=V, face_matrix=np.asarray(F, dtype=np.int32).reshape(-1, 3), **kwargs))


def run_step(step: Step, ctx: RunContext) -> None:
    """Apply one step to ``ctx.ms`` (in place) and record what it measured in ``ctx.row``."""
    if step.label:
        V, F, _ = current_arrays(ctx.ms)
        ctx.snapshots[step.label] = (V, F)
    if step.kind == "ours":
        _run_ours(step, ctx)
    elif step.kind == "pymeshlab":
        params = {k: pymeshlab_steps.to_pymeshlab_value(step.name, k, v) for k, v in step.params.items()}
        ctx.ms.apply_filter(step.name, **params)
    elif step.kind == "open3d":
        _run_open3d(step, ctx)
    elif step.kind == "add_noise":
        from ..noise import add_normal_noise

        V, _, _ = current_arrays(ctx.ms)
        rho = step.params["rho"]
        if step.params["relative"]:
            rho *= float(np.linalg.norm(V.max(axis=0) - V.min(axis=0)))
        add_normal_noise(ctx.ms, rho=rho, seed=step.params["seed"])
    elif step.kind == "metrics":
        _run_metrics(step, ctx)
    elif step.kind == "save":
        V, F, colors = current_arrays(ctx.ms)
        path = ctx.resolve_path(step.params["path"])
        ctx.staged.append((path, V, F, colors if step.params["colors"] else None, step.params["binary"]))
        ctx.row.setdefault("outputs", []).append(str(path))
    elif step.kind == "render":
        from ..render import new_file_mode, render_comparison  # written separately; imported only when used

        p = step.params
        V, F, _ = current_arrays(ctx.ms)
        named = {"input": tuple(ctx.input_arrays[:2]), **{k: v[:2] for k, v in ctx.snapshots.items()}, "result": (V, F)}
        path = Path(ctx.resolve_path(p["path"]))
        # staged like a saved mesh: drawn into a hidden file beside the target, renamed once every step succeeded
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=".png", dir=path.parent)
        os.close(fd)
        os.chmod(tmp, new_file_mode(path))  # mkstemp's 0600 would be kept by the rename
        ctx.staged_files.append((Path(tmp), path))
        result = render_comparison(
            [named[m] for m in p["meshes"]], tmp, reference=named[p["reference"]] if p["reference"] else None,
            titles=p["titles"], size=p["size"], backend=p["backend"], cmap=p["cmap"], vmax=p["vmax"],
        )
        ctx.row[f"{step.label + '.' if step.label else ''}render.backend"] = result.backend
        ctx.row.setdefault("outputs", []).append(str(path))
    else:  # pragma: no cover - parse_step only makes the kinds above
        raise AssertionError(step.kind)


def _run_ours(step: Step, ctx: RunContext) -> None:
    spec = get_filter(step.name)
    params = dict(step.params)
    options = {k: v for k, v in step.options.items() if k != "parameters"}
    for key in ("pinned", "region"):
        if isinstance(options.get(key), list):
            options[key] = np.asarray(options[key], dtype=np.int64)
    if step.options.get("parameters") == "auto":
        from ..auto import choose_parameters  # written separately; imported only when used

        V, F, _ = current_arrays(ctx.ms)
        chosen = choose_parameters((V, F), method=step.name)
        chosen = {**chosen, **params}  # values written in the pipeline win
        params = spec.resolve(chosen, step.where)
        for k, v in params.items():
            ctx.row[f"auto.{step.name}.{k}"] = v
        if ctx.echo:
            ctx.echo(f"{ctx.input_path.name}: {step.name} parameters chosen automatically: {params}")
    spec.public(ctx.ms, **params, **options)


def _run_open3d(step: Step, ctx: RunContext) -> None:
    import open3d as o3d

    V, F, colors = current_arrays(ctx.ms)
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V), o3d.utility.Vector3iVector(F.astype(np.int32)))
    if colors is not None:
        mesh.vertex_colors = o3d.utility.Vector3dVector(colors[:, :3])
    op = step.name[len("open3d."):]
    result = getattr(mesh, op)(**step.params)
    if isinstance(result, o3d.geometry.TriangleMesh):
        mesh = result
    V2 = np.asarray(mesh.vertices, dtype=np.float64)
    F2 = np.asarray(mesh.triangles, dtype=np.int64)
    c2 = None
    if mesh.has_vertex_colors():
        c2 = np.hstack([np.asarray(mesh.vertex_colors), np.ones((V2.shape[0], 1))])
        if colors is not None and V2.shape[0] == V.shape[0]:
            c2[:, 3] = colors[:, 3]  # Open3D has no alpha: keep the input's when vertices are unchanged
    _replace_mesh(ctx, V2, F2, c2)


def _run_metrics(step: Step, ctx: RunContext) -> None:
    from ..io import load_mesh
    from ..metrics import compute_metrics

    ref = step.params["reference"]
    # whole meshes, not coordinates: normal and distance metrics need the faces too
    if isinstance(ref, dict):
        reference = ctx.snapshots[ref["before"]][:2]
    elif ref == "input":
        reference = tuple(ctx.input_arrays[:2])
    else:
        loaded = load_mesh(ctx.resolve_input(ref) if hasattr(ctx, "resolve_input") else ref)
        reference = (loaded.V, loaded.F)
    V, F, _ = current_arrays(ctx.ms)
    values = compute_metrics(reference, (V, F), step.params["metrics"])
    prefix = f"{step.label}." if step.label else ""
    for k, v in values.items():
        ctx.row[f"{prefix}{k}"] = v
