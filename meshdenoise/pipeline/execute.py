"""Running the pipeline steps :mod:`meshdenoise.pipeline.steps` parsed: one input's state going through them."""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..progress import stage
from ..registry import get_filter
from . import pymeshlab_steps
from .state import MeshState
from .steps import Step

__all__ = ["RunContext", "run_step"]


@dataclass
class RunContext:
    """State of one input going through the steps.

    Attributes
    ----------
    state : MeshState
        The working mesh (arrays and attributes); each step replaces it.
    input_path : Path
    input_arrays : tuple
        ``(V, F)`` as loaded (the ``input`` of ``metrics`` and ``render``).
    output_paths : dict
        Path template of a ``save``/``render`` step -> the resolved output path (made by the plan).
    reference_paths : dict
        A ``metrics`` reference pattern (``{dir}/Original.obj``) -> this input's file (made by the plan).
    snapshots : dict
        Step label -> ``(V, F)`` before that step.
    row : dict
        The results row being filled.
    staged, staged_files : list
        Meshes ``(path, V, F, colors, binary)`` and files ``(temporary, path)`` written once every step succeeded.
    echo : callable, optional
        Called with a message (automatic parameters).
    """

    state: MeshState
    input_path: Path
    input_arrays: tuple
    output_paths: dict = field(default_factory=dict)
    reference_paths: dict = field(default_factory=dict)
    snapshots: dict = field(default_factory=dict)
    row: dict = field(default_factory=dict)
    staged: list = field(default_factory=list)
    staged_files: list = field(default_factory=list)
    echo: Any = None

    def resolve_path(self, template: str) -> Path:
        """The output path the plan resolved for a ``save``/``render`` path template."""
        try:
            return Path(self.output_paths[template])
        except KeyError:
            raise KeyError(f"no output path was resolved for {template!r}: build the task with build_plan") from None


def run_step(step: Step, ctx: RunContext) -> None:
    """Apply one step to ``ctx.state`` (replacing it) and record what it measured in ``ctx.row``."""
    state = ctx.state
    if step.label:
        ctx.snapshots[step.label] = state.arrays()
    if step.kind == "ours":
        _run_ours(step, ctx)
    elif step.kind == "default":
        _run_default(step, ctx)
    elif step.kind == "pymeshlab":
        params = {k: pymeshlab_steps.to_pymeshlab_value(step.name, k, v) for k, v in step.params.items()}
        ms = state.meshset()
        ms.apply_filter(step.name, **params)
        ctx.state = MeshState.from_meshset(ms, state.extras)
    elif step.kind == "open3d":
        _run_open3d(step, ctx)
    elif step.kind == "add_noise":
        from ..noise import add_normal_noise

        rho = step.params["rho"]
        if step.params["relative"]:
            rho *= float(np.linalg.norm(state.V.max(axis=0) - state.V.min(axis=0)))
        V, _ = add_normal_noise(state.arrays(), rho=rho, seed=step.params["seed"])
        ctx.state = state.with_vertices(V)
    elif step.kind == "metrics":
        _run_metrics(step, ctx)
    elif step.kind == "save":
        path = ctx.resolve_path(step.params["path"])
        colors = state.vertex_colors if step.params["colors"] else None
        extras = state.extras_to_write()
        if not step.params["normals"] and extras is not None:
            from dataclasses import replace

            extras = replace(extras, normals=False)
        normals = state.vertex_normals if step.params["normals"] else None
        ctx.staged.append((path, state.V, state.F, colors, step.params["binary"], extras,
                           {"vertex_normals": normals, "precision": step.params["precision"]}))
        ctx.row.setdefault("outputs", []).append(str(path))
    elif step.kind == "render":
        from ..render import new_file_mode, render_comparison  # written separately; imported only when used

        p = step.params
        named = {"input": tuple(ctx.input_arrays[:2]), **{k: v[:2] for k, v in ctx.snapshots.items()}, "result": state.arrays()}
        path = ctx.resolve_path(p["path"])
        # staged like a saved mesh: drawn into a hidden file beside the target, renamed once every step succeeded
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=".png", dir=path.parent)
        os.close(fd)
        os.chmod(tmp, new_file_mode(path))  # mkstemp's 0600 would be kept by the rename
        ctx.staged_files.append((Path(tmp), path))
        result = render_comparison(
            [named[m] for m in p["meshes"]], tmp, reference=named[p["reference"]] if p["reference"] else None,
            titles=p["titles"], size=p["size"], backend=p["backend"], cmap=p["cmap"], vmax=p["vmax"],
            show_change=p["change"], percentile=p["percentile"], zoom=p["zoom"],
        )
        ctx.row[f"{step.label + '.' if step.label else ''}render.backend"] = result.backend
        ctx.row.setdefault("outputs", []).append(str(path))
    else:  # pragma: no cover - parse_step only makes the kinds above
        raise AssertionError(step.kind)


def _vertex_option(value: Any, state: MeshState, key: str) -> Any:
    """``pinned``/``region`` for the array core: ``"selection"`` becomes the state's selection mask."""
    if isinstance(value, list):
        return np.asarray(value, dtype=np.int64)
    if value == "selection":
        if state.vertex_selection is None:  # pinning nothing, or moving nothing, is never what was meant
            from ..arrays import MeshValidationError

            raise MeshValidationError(
                f"{key}: selection: the mesh has no selected vertex (the file stores no selection, or selects none, "
                "and no earlier step selected any; save it from MeshLab as PLY with the vertex 'Flags' option)")
        return np.asarray(state.vertex_selection, dtype=bool)
    return value


def _run_ours(step: Step, ctx: RunContext) -> None:
    spec = get_filter(step.name)
    state = ctx.state
    params = dict(step.params)
    options = {k: v for k, v in step.options.items() if k not in ("parameters", "noise", "criterion")}
    for key in ("pinned", "region"):
        if key in options:
            options[key] = _vertex_option(options[key], state, key)
    if step.options.get("parameters") == "auto":
        from ..tuning import choose_parameters  # imported only when used
        from ..tuning.memo import release_before_filter

        given_noise = step.options.get("noise")
        noise = given_noise.model(state.V, state.F) if given_noise is not None else None
        criterion = step.options.get("criterion", "sure")
        chosen = choose_parameters(state.arrays(), method=step.name, noise=noise, criterion=criterion)
        chosen = {**chosen, **params}  # values written in the pipeline win
        params = spec.resolve(chosen, step.where)
        _record_choice(ctx, step.name, params, criterion)
        release_before_filter()
    _filter_state(ctx, spec, params, options)


def _record_choice(ctx: RunContext, method: str, params: dict, criterion: str) -> None:
    """The chosen parameters as the row's ``auto.<filter>.<param>`` columns, and the line said about them."""
    for k, v in params.items():
        ctx.row[f"auto.{method}.{k}"] = v
    if ctx.echo:
        what = "the face-normal error" if criterion == "normals" else "the position error"
        ctx.echo(f"{ctx.input_path.name}: {method} parameters chosen automatically for {what} "
                 f"(criterion {criterion}): {params}")


def _filter_state(ctx: RunContext, spec: Any, params: dict, options: dict) -> None:
    """Our filter ``spec`` on the state's mesh with ``params`` and the common ``options``; the state moves on."""
    with stage(f"running {spec.name}"):
        V, _ = spec.public(ctx.state.arrays(), **params, **options)
    ctx.state = ctx.state.with_vertices(V)


def _run_default(step: Step, ctx: RunContext) -> None:
    """The ``denoise`` step: what ``meshdenoise.denoise()`` runs, the decision recorded.

    Without a method :func:`meshdenoise.policy.run_default`; with one, the parameters
    :func:`meshdenoise.default.method_parameters` gives (chosen by the filter's rule where not given, unless
    ``defaults``), then the filter.
    """
    state = ctx.state
    options = dict(step.options)
    for key in ("pinned", "region"):
        if key in options:
            options[key] = _vertex_option(options[key], state, key)
    method = options.pop("method", None)
    if method is not None:
        _run_method(step, ctx, method, options)
        return
    from ..policy import run_default

    options.pop("noise", None)  # the default reads the noise from held-out vertices
    explain = bool(options.pop("explain", False))
    (V, _), choice = run_default(state.arrays(), **options)
    if ctx.echo:
        for line in choice.lines() + (choice.explain() if explain else []):
            ctx.echo(f"{ctx.input_path.name}: {line}")
    row = ctx.row
    row["denoise.method"] = choice.method
    row["denoise.noise"] = choice.noise
    row["denoise.noise_edges"] = choice.noise_in_edges
    row["denoise.flipped"] = choice.flipped
    row["denoise.moved_rms_edges"] = choice.moved_rms
    for k, v in choice.params.items():
        row[f"auto.{choice.method}.{k}"] = v
    ctx.state = state.with_vertices(V)


def _run_method(step: Step, ctx: RunContext, method: str, options: dict) -> None:
    """``denoise`` with ``method``: the filter, its parameters not given chosen by its rule (``defaults``: its own)."""
    from ..default import method_parameters

    state = ctx.state
    spec = get_filter(method)
    given_noise = options.pop("noise", None)
    noise = given_noise.model(state.V, state.F) if given_noise is not None else None
    params, criterion = method_parameters(state.arrays(), method, noise=noise, criterion=options.pop("criterion", None),
                                          defaults=options.pop("defaults", False), **step.params)
    params = spec.resolve(params, step.where)
    ctx.row["denoise.method"] = method
    if criterion is not None:  # chosen: recorded as a filter step's parameters: auto records them
        _record_choice(ctx, method, params, criterion)
    _filter_state(ctx, spec, params, options)


def _run_open3d(step: Step, ctx: RunContext) -> None:
    import open3d as o3d

    state = ctx.state
    V, F, colors = state.V, state.F, state.vertex_colors
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
    ctx.state = state.with_mesh(V2, F2, c2)


def _run_metrics(step: Step, ctx: RunContext) -> None:
    from ..io import load_mesh
    from ..metrics import compute_metrics

    ref = step.params["reference"]
    # whole meshes, not coordinates: normal and distance metrics need the faces too
    if isinstance(ref, dict):
        reference = ctx.snapshots[ref["before"]][:2]
    elif ref == "input":
        reference = tuple(ctx.input_arrays[:2])
    else:  # a file made absolute when the plan was checked, or a pattern the plan filled for this input
        loaded = load_mesh(ctx.reference_paths.get(ref, ref))
        reference = (loaded.V, loaded.F)
    values = compute_metrics(reference, ctx.state.arrays(), step.params["metrics"])
    prefix = f"{step.label}." if step.label else ""
    for k, v in values.items():
        ctx.row[f"{prefix}{k}"] = v
