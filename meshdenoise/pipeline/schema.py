"""The pipeline file: its keys, and the checked plan made from it before anything runs.

.. code-block:: yaml

    variables: {mu: 1.0}              # ${mu} in parameters; --set mu=5 overrides
    inputs: scans/*.ply               # a file, a glob or a list; relative to this file;
                                      # {samples}/ = pymeshlab's sample meshes, {data}/ = MESHDENOISE_DATA
    output_dir: out/scans             # relative to the working directory; --out overrides
    steps:
      - meshing_remove_duplicate_vertices          # a pymeshlab filter
      - open3d.remove_degenerate_triangles         # an Open3D operation
      - sobolev: {mu: "${mu}", pinned: boundary}   # one of our filters
      - save: {path: "{stem}_clean.ply"}
    sweep: {mu: [0.5, 1, 2]}          # optional grid: one run per setting and input
    results: results                  # results.csv / results.json in output_dir
"""

from __future__ import annotations

import glob
import itertools
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .errors import PipelineValidationError, where
from .steps import Step, parse_step
from .sweep import check_sweep_size
from .variables import check_template, substitute
from .yamlsource import LineDict, LineList, line_of, load_yaml, read_text

__all__ = ["Plan", "Task", "load_pipeline", "build_plan", "TOP_LEVEL_KEYS"]

TOP_LEVEL_KEYS = ("variables", "inputs", "output_dir", "steps", "sweep", "results", "description")


@dataclass
class Task:
    """One run: an input file under one setting of the variables."""

    index: int
    input: Path
    setting: dict
    setting_text: str
    steps: list[Step]
    output_paths: dict = field(default_factory=dict)  # template -> resolved Path


@dataclass
class Plan:
    """A checked pipeline: every task with its steps and output paths known before anything runs."""

    source: str
    inputs: list[Path]
    output_dir: Path
    tasks: list[Task]
    results: str | None
    variables: dict
    sweep: dict

    @property
    def writes_results(self) -> bool:
        return bool(self.sweep) or len(self.tasks) > 1 or any(s.kind == "metrics" for t in self.tasks for s in t.steps)


def _placeholders() -> dict[str, str]:
    from ..data import data_dir

    try:
        from ..data import sample_mesh

        samples = str(sample_mesh("bunny.obj").parent)
    except FileNotFoundError:
        samples = "{samples}"
    return {"samples": samples, "data": str(data_dir())}


def _expand_inputs(spec: Any, base: Path, at: str) -> list[Path]:
    items = spec if isinstance(spec, list) else [spec]
    found: list[Path] = []
    for k, item in enumerate(items):
        line_at = where(at.split(":")[0], line_of(spec, k) if isinstance(spec, LineList) else None) if isinstance(spec, list) else at
        if not isinstance(item, str):
            raise PipelineValidationError(f"{line_at}: inputs: expected a file name or glob, got {item!r}")
        text = item
        for key, value in _placeholders().items():
            text = text.replace("{" + key + "}", value)
        path = Path(text).expanduser()
        if not path.is_absolute():
            path = base / path
        if glob.has_magic(str(path)) and not path.is_file():  # "scan [final].ply" is a file, not a glob
            matches = sorted(Path(p) for p in glob.glob(str(path), recursive=True) if Path(p).is_file())
            if not matches:
                raise PipelineValidationError(f"{line_at}: inputs: no file matches {item!r} (looked for {path})")
            found.extend(matches)
        else:
            if not path.is_file():
                raise PipelineValidationError(f"{line_at}: inputs: no such file {item!r} ({path})")
            found.append(path)
    return [p.resolve() for p in found]


def _setting_text(setting: dict) -> str:
    return ",".join(f"{k}={v}" for k, v in setting.items())


def build_plan(
    doc: Any,
    source: str,
    *,
    base_dir: Path,
    overrides: dict | None = None,
    inputs: list[str] | None = None,
    output_dir: str | Path | None = None,
) -> Plan:
    """Check a parsed pipeline document and expand it into tasks. Raises :class:`PipelineValidationError`."""
    if not isinstance(doc, dict):
        raise PipelineValidationError(f"{source}: a pipeline is a mapping with 'inputs' and 'steps', got {type(doc).__name__}")
    doc = doc if isinstance(doc, LineDict) else LineDict(doc)
    if not hasattr(doc, "key_lines"):
        doc.key_lines, doc.line = {}, 1
    import difflib

    for key in doc:
        if key not in TOP_LEVEL_KEYS:
            hint = difflib.get_close_matches(str(key), TOP_LEVEL_KEYS, n=1)
            extra = f" (did you mean '{hint[0]}'?)" if hint else ""
            raise PipelineValidationError(
                f"{where(source, line_of(doc, key))}: unknown key '{key}'{extra}; the keys are {', '.join(TOP_LEVEL_KEYS)}"
            )
    variables = doc.get("variables") or {}
    if not isinstance(variables, dict):
        raise PipelineValidationError(f"{where(source, line_of(doc, 'variables'))}: variables must be a mapping")
    variables = dict(variables)
    overrides = dict(overrides or {})
    sweep = doc.get("sweep") or {}
    if not isinstance(sweep, dict):
        raise PipelineValidationError(f"{where(source, line_of(doc, 'sweep'))}: sweep must be a mapping name: [values]")
    sweep = {k: (v if isinstance(v, list) else [v]) for k, v in sweep.items() if k not in overrides}
    for k, v in sweep.items():
        if not v:
            raise PipelineValidationError(f"{where(source, line_of(doc['sweep'], k))}: sweep: '{k}' has no values")
    variables.update(overrides)

    if inputs is not None:
        input_paths = _expand_inputs(list(inputs), Path.cwd(), f"{source}: --input")
    else:
        if "inputs" not in doc:
            raise PipelineValidationError(f"{source}: no 'inputs' (a file, a glob or a list) and no --input given")
        input_paths = _expand_inputs(
            substitute(doc["inputs"], variables, where(source, line_of(doc, "inputs"))),
            base_dir,
            where(source, line_of(doc, "inputs")),
        )
    if not input_paths:
        raise PipelineValidationError(f"{where(source, line_of(doc, 'inputs'))}: inputs: the list is empty")

    out = output_dir if output_dir is not None else doc.get("output_dir", f"out/{Path(source).stem}")
    if not isinstance(out, (str, Path)):
        raise PipelineValidationError(f"{where(source, line_of(doc, 'output_dir'))}: output_dir must be a folder name")
    out_dir = Path(str(out)).expanduser().resolve()

    raw_steps = doc.get("steps")
    if not isinstance(raw_steps, list) or not raw_steps:
        raise PipelineValidationError(f"{where(source, line_of(doc, 'steps'))}: 'steps' must be a non-empty list")

    check_sweep_size(sweep, len(input_paths), where(source, line_of(doc, "sweep")))  # before expanding anything
    settings = [dict(zip(sweep, values)) for values in itertools.product(*sweep.values())] if sweep else [{}]
    tasks: list[Task] = []
    steps_by_setting = []
    for setting in settings:
        values = {**variables, **setting}
        steps = []
        for k, item in enumerate(raw_steps):
            line = line_of(raw_steps, k)
            item = substitute(item, values, where(source, line, f"step {k + 1}"))
            steps.append(parse_step(item, k + 1, source, line))
        _check_labels(steps, base_dir)
        steps_by_setting.append(steps)
    for s_index, setting in enumerate(settings):
        for inp in input_paths:
            tasks.append(Task(len(tasks), inp, setting, _setting_text(setting), steps_by_setting[s_index]))
    _resolve_outputs(tasks, out_dir, input_paths, source)
    results = doc.get("results", "results")
    if results is not None and not isinstance(results, str):
        raise PipelineValidationError(f"{where(source, line_of(doc, 'results'))}: results must be a file stem")
    return Plan(source, input_paths, out_dir, tasks, results, variables, sweep)


def _check_labels(steps: list[Step], base_dir: Path) -> None:
    seen: set[str] = set()
    for step in steps:
        if step.kind == "render":
            wanted = list(step.params["meshes"]) + ([step.params["reference"]] if step.params["reference"] else [])
            for name in wanted:
                if name not in ("input", "result") and name not in seen:
                    raise PipelineValidationError(
                        f"{step.where}: '{name}' is neither input, result nor the label of an earlier step "
                        f"(labels so far: {', '.join(sorted(seen)) or 'none'})"
                    )
        if step.kind == "metrics":
            ref = step.params["reference"]
            if isinstance(ref, dict) and ref["before"] not in seen:
                raise PipelineValidationError(
                    f"{step.where}: reference: no earlier step has label '{ref['before']}' "
                    f"(labels so far: {', '.join(sorted(seen)) or 'none'}; add 'label: {ref['before']}' to a step)"
                )
            if isinstance(ref, str) and ref != "input":
                path = Path(ref).expanduser()
                path = path if path.is_absolute() else base_dir / path
                if not path.is_file():
                    raise PipelineValidationError(f"{step.where}: reference: no such file {ref!r} ({path})")
                step.params["reference"] = str(path.resolve())
        if step.label:
            if step.label in seen:
                raise PipelineValidationError(f"{step.where}: label '{step.label}' is used twice")
            seen.add(step.label)


def fill_template(template: str, task: Task) -> str:
    inp = task.input
    fields = {"stem": inp.stem, "name": inp.name, "suffix": inp.suffix, "index": task.index, "setting": task.setting_text}
    fields.update({k: v for k, v in task.setting.items() if isinstance(k, str)})
    check_template(template)  # plain {name} placeholders, bounded widths: before formatting
    try:
        return template.format(**fields)
    except (KeyError, IndexError, ValueError) as exc:
        raise ValueError(f"path template {template!r}: {exc!r} is not a field; use {{stem}} {{name}} {{setting}} {{index}}") from None


def _resolve_outputs(tasks: list[Task], out_dir: Path, inputs: list[Path], source: str) -> None:
    owner: dict[Path, str] = {}
    protected = set(inputs)
    for task in tasks:
        for step in task.steps:
            if step.kind not in ("save", "render"):
                continue
            template = step.params["path"]
            try:
                text = fill_template(template, task)
            except ValueError as exc:
                raise PipelineValidationError(f"{step.where}: {exc}") from None
            path = Path(text).expanduser()
            path = (path if path.is_absolute() else out_dir / path).resolve()
            if path in protected:
                raise PipelineValidationError(f"{step.where}: path {template!r} would overwrite the input file {path}: input files are never written")
            me = f"{task.input.name} {task.setting_text}".strip() + f" step {step.index}"
            if path in owner:
                raise PipelineValidationError(
                    f"{step.where}: path {template!r} gives {path} for both {owner[path]} and {me}; "
                    "add {stem}, {setting} or {index} to the path"
                )
            owner[path] = me
            task.output_paths[template] = path


def load_pipeline(
    path: str | Path,
    *,
    overrides: dict | None = None,
    inputs: list[str] | None = None,
    output_dir: str | Path | None = None,
) -> Plan:
    """Read and check a pipeline file; nothing is run or written.

    Raises
    ------
    PipelineValidationError
        Naming the file, the line and the step.
    """
    path = Path(path)
    if not path.is_file():
        raise PipelineValidationError(f"{path}: no such pipeline file")
    doc = load_yaml(read_text(path), path)
    return build_plan(doc, str(path), base_dir=path.resolve().parent, overrides=overrides, inputs=inputs, output_dir=output_dir)
