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
from .variables import check_template, substitute, used_variables
from .yamlsource import LineDict, LineList, line_of, load_yaml, read_text

__all__ = ["Plan", "Task", "load_pipeline", "build_plan", "TOP_LEVEL_KEYS", "PipelineProblems", "PLACEHOLDER_INPUT", "fill_template", "distinguishing_names"]

# what ``mlx2yaml`` writes as the inputs when none is given: --check says to set it
PLACEHOLDER_INPUT = "SET-YOUR-MESH.ply"

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
    reference_paths: dict = field(default_factory=dict)  # metrics reference pattern ({dir}/Original.obj) -> Path
    label: str = ""  # the shortest part of the input's path that tells it from the other inputs


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
    def notes(self) -> list[str]:
        """Things worth telling about the pipeline (MeshLab GUI names used...), each once."""
        return list(dict.fromkeys(n for t in self.tasks for s in t.steps for n in s.notes))

    @property
    def writes_results(self) -> bool:
        return bool(self.sweep) or len(self.tasks) > 1 or any(s.kind == "metrics" for t in self.tasks for s in t.steps)


def _placeholders() -> dict[str, str]:
    from ..data import data_dir

    try:
        from ..data import sample_mesh

        samples = str(Path(sample_mesh("bunny.obj")).parent)
    except FileNotFoundError:
        samples = "{samples}"
    return {"samples": samples, "data": str(data_dir())}


def _expand_inputs(spec: Any, base: Path, at: str, problems: list[str] | None = None) -> list[Path]:
    """Files named by ``inputs`` (a file, a glob or a list of them); with ``problems``, every bad item is reported there."""
    items = spec if isinstance(spec, list) else [spec]
    found: list[Path] = []
    for k, item in enumerate(items):
        line_at = where(at.split(":")[0], line_of(spec, k) if isinstance(spec, LineList) else None) if isinstance(spec, list) else at
        try:
            found.extend(_expand_one(item, base, line_at))
        except PipelineValidationError as exc:
            if problems is None:
                raise
            problems.append(str(exc))
    return [p.resolve() for p in found]


def _expand_one(item: Any, base: Path, line_at: str) -> list[Path]:
    if not isinstance(item, str):
        raise PipelineValidationError(f"{line_at}: inputs: expected a file name or glob, got {item!r}")
    if item == PLACEHOLDER_INPUT:
        raise PipelineValidationError(
            f"{line_at}: inputs: {item!r} is the placeholder mlx2yaml writes: set your mesh file(s) there "
            "(a file, a glob or a list), or give run --input FILE"
        )
    text = item
    for key, value in _placeholders().items():
        text = text.replace("{" + key + "}", value)
    path = Path(text).expanduser()
    if not path.is_absolute():
        path = base / path
    if glob.has_magic(str(path)) and not path.is_file():  # a file literally named 'scan [final].ply' is that file
        matches = sorted(Path(p) for p in glob.glob(str(path), recursive=True) if Path(p).is_file())
        if not matches:
            raise PipelineValidationError(f"{line_at}: inputs: no file matches {item!r} (looked for {path})")
        return matches
    if not path.is_file():
        raise PipelineValidationError(f"{line_at}: inputs: no such file {item!r} ({path})")
    return [path]


def _setting_text(setting: dict) -> str:
    return ",".join(f"{k}={v}" for k, v in setting.items())


class PipelineProblems(PipelineValidationError):
    """Several problems found in one pipeline: :attr:`problems` holds one line each (file:line: step: what)."""

    def __init__(self, problems: list[str]):
        self.problems = list(dict.fromkeys(problems))  # the same problem under several settings is said once
        super().__init__("\n".join(self.problems))


def build_plan(
    doc: Any,
    source: str,
    *,
    base_dir: Path,
    overrides: dict | None = None,
    inputs: list[str] | None = None,
    output_dir: str | Path | None = None,
) -> Plan:
    """Check a parsed pipeline document and expand it into tasks.

    Every problem that can be found is reported at once (top-level keys, inputs, each step);
    checks that need earlier parts to be right (labels, output paths) run when those are.

    Raises
    ------
    PipelineValidationError
        A :class:`PipelineProblems` when there are several problems (one line each).
    """
    if not isinstance(doc, dict):
        raise PipelineValidationError(f"{source}: a pipeline is a mapping with 'inputs' and 'steps', got {type(doc).__name__}")
    doc = doc if isinstance(doc, LineDict) else LineDict(doc)
    if not hasattr(doc, "key_lines"):
        doc.key_lines, doc.line = {}, 1
    import difflib

    problems: list[str] = []

    def problem(text: str) -> None:
        problems.append(text)

    for key in doc:
        if key not in TOP_LEVEL_KEYS:
            hint = difflib.get_close_matches(str(key), TOP_LEVEL_KEYS, n=1)
            extra = f" (did you mean '{hint[0]}'?)" if hint else ""
            problem(f"{where(source, line_of(doc, key))}: unknown key '{key}'{extra}; the keys are {', '.join(TOP_LEVEL_KEYS)}")
    variables = doc.get("variables") or {}
    if not isinstance(variables, dict):
        problem(f"{where(source, line_of(doc, 'variables'))}: variables must be a mapping")
        variables = {}
    variables = dict(variables)
    overrides = dict(overrides or {})
    sweep = doc.get("sweep") or {}
    if not isinstance(sweep, dict):
        problem(f"{where(source, line_of(doc, 'sweep'))}: sweep must be a mapping name: [values]")
        sweep = {}
    # --set of a name the pipeline neither declares (variables:, sweep:) nor uses (${name}) would change nothing
    defined = {str(k) for k in (*variables, *sweep)} | used_variables(doc)
    for name in overrides:
        if name not in defined:
            hint = difflib.get_close_matches(str(name), sorted(defined), n=1)
            extra = f" (did you mean '{hint[0]}'?)" if hint else ""
            problem(f"{source}: --set {name}: the pipeline has no variable '{name}'{extra}; its variables: "
                    f"{', '.join(sorted(defined)) or 'none'} (declare it under 'variables:' or use it as ${{{name}}})")
    sweep = {k: (v if isinstance(v, list) else [v]) for k, v in sweep.items() if k not in overrides}
    for k, v in list(sweep.items()):
        if not v:
            problem(f"{where(source, line_of(doc['sweep'], k))}: sweep: '{k}' has no values")
            del sweep[k]
    variables.update(overrides)

    input_paths: list[Path] = []
    n_problems = len(problems)
    if inputs is not None:
        input_paths = _expand_inputs(list(inputs), Path.cwd(), f"{source}: --input", problems)
    elif "inputs" not in doc:
        problem(f"{source}: no 'inputs' (a file, a glob or a list) and no --input given")
    else:
        try:
            spec = substitute(doc["inputs"], variables, where(source, line_of(doc, "inputs")))
        except PipelineValidationError as exc:
            problem(str(exc))
        else:
            input_paths = _expand_inputs(spec, base_dir, where(source, line_of(doc, "inputs")), problems)
            if not input_paths and len(problems) == n_problems:
                problem(f"{where(source, line_of(doc, 'inputs'))}: inputs: the list is empty")

    out = output_dir if output_dir is not None else doc.get("output_dir", f"out/{Path(source).stem}")
    out_dir = Path()
    if not isinstance(out, (str, Path)):
        problem(f"{where(source, line_of(doc, 'output_dir'))}: output_dir must be a folder name")
    else:
        out_dir = Path(str(out)).expanduser().resolve()

    results = doc.get("results", "results")
    if results is not None and not isinstance(results, str):
        problem(f"{where(source, line_of(doc, 'results'))}: results must be a file stem")

    raw_steps = doc.get("steps")
    steps_by_setting: list[list[Step]] = []
    try:  # refused before the grid is built: a few lines of YAML can ask for 10^9 settings
        check_sweep_size(sweep, max(len(input_paths), 1), where(source, line_of(doc, "sweep")))
    except PipelineValidationError as exc:
        problem(str(exc))
        raise PipelineProblems(problems) if len(set(problems)) > 1 else PipelineValidationError(problems[0])
    settings = [dict(zip(sweep, values)) for values in itertools.product(*sweep.values())] if sweep else [{}]
    if not isinstance(raw_steps, list) or not raw_steps:
        problem(f"{where(source, line_of(doc, 'steps'))}: 'steps' must be a non-empty list")
    else:
        for setting in settings:
            values = {**variables, **setting}
            steps = []
            before = len(problems)
            for k, item in enumerate(raw_steps):
                line = line_of(raw_steps, k)
                try:
                    item = substitute(item, values, where(source, line, f"step {k + 1}"))
                    steps.append(parse_step(item, k + 1, source, line))
                except PipelineValidationError as exc:
                    problem(str(exc))
            if len(problems) == before:
                try:
                    _check_labels(steps, base_dir)
                except PipelineValidationError as exc:
                    problem(str(exc))
            steps_by_setting.append(steps)
    if problems:
        raise PipelineProblems(problems) if len(set(problems)) > 1 else PipelineValidationError(problems[0])
    tasks: list[Task] = []
    labels = distinguishing_names(input_paths)
    for s_index, setting in enumerate(settings):
        for inp in input_paths:
            tasks.append(Task(len(tasks), inp, setting, _setting_text(setting), steps_by_setting[s_index], label=labels[inp]))
    _resolve_outputs(tasks, out_dir, input_paths, source)
    _resolve_references(tasks, base_dir)
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
            if isinstance(ref, str) and ref != "input" and "{" not in ref:  # a pattern is filled per input
                path = Path(ref).expanduser()
                path = path if path.is_absolute() else base_dir / path
                if not path.is_file():
                    raise PipelineValidationError(f"{step.where}: reference: no such file {ref!r} ({path})")
                step.params["reference"] = str(path.resolve())
        if step.label:
            if step.label in seen:
                raise PipelineValidationError(f"{step.where}: label '{step.label}' is used twice")
            seen.add(step.label)


TEMPLATE_FIELDS = ("stem", "name", "suffix", "parent", "dir", "setting", "index")


def fill_template(template: str, task: Task) -> str:
    """A path template filled for one task: ``{stem}`` ``{name}`` ``{suffix}`` of the input, ``{parent}``
    (its folder's name), ``{dir}`` (its folder), ``{setting}`` (``mu=1,k=2``), ``{index}`` and the sweep variables."""
    inp = task.input
    fields = {"stem": inp.stem, "name": inp.name, "suffix": inp.suffix, "parent": inp.parent.name, "dir": str(inp.parent),
              "index": task.index, "setting": task.setting_text}
    fields.update({k: v for k, v in task.setting.items() if isinstance(k, str)})
    check_template(template)  # plain {name} placeholders, bounded widths: before formatting
    try:
        return template.format(**fields)
    except (KeyError, IndexError, AttributeError) as exc:
        raise ValueError(
            f"path template {template!r}: {exc!r} is not a field; use {' '.join('{' + f + '}' for f in TEMPLATE_FIELDS)}"
        ) from None
    except ValueError as exc:  # a bad format ({stem:d}) or brace ({stem)
        raise ValueError(f"path template {template!r}: {exc}; the fields are {' '.join('{' + f + '}' for f in TEMPLATE_FIELDS)}") from None


def distinguishing_names(paths: list[Path]) -> dict[Path, str]:
    """For each path, its shortest trailing part (``name``, ``folder/name``, ...) that no other path ends with.

    >>> names = distinguishing_names([Path("/b/Bunny/Noisy.obj"), Path("/b/Block/Noisy.obj"), Path("/b/x.ply")])
    >>> [names[Path(p)] for p in ("/b/Bunny/Noisy.obj", "/b/Block/Noisy.obj", "/b/x.ply")]
    ['Bunny/Noisy.obj', 'Block/Noisy.obj', 'x.ply']
    """
    unique = list(dict.fromkeys(Path(p) for p in paths))
    out = {}
    for p in unique:
        parts = p.parts
        for k in range(1, len(parts) + 1):
            tail = parts[-k:]
            if not any(q != p and q.parts[-k:] == tail for q in unique):
                break
        out[p] = "/".join(tail) if k < len(parts) else str(p)
    return out


def _resolve_outputs(tasks: list[Task], out_dir: Path, inputs: list[Path], source: str) -> None:
    owner: dict[Path, str] = {}
    protected = set(inputs)
    problems: list[str] = []
    for task in tasks:
        for step in task.steps:
            if step.kind not in ("save", "render"):
                continue
            template = step.params["path"]
            try:
                text = fill_template(template, task)
            except ValueError as exc:
                problems.append(f"{step.where}: {exc}")
                continue
            path = Path(text).expanduser()
            path = (path if path.is_absolute() else out_dir / path).resolve()
            if path in protected:
                problems.append(f"{step.where}: path {template!r} would overwrite the input file {path}: input files are never written")
                continue
            me = f"{task.label} {task.setting_text}".strip() + f" (step {step.index})"
            if path in owner:
                problems.append(
                    f"{step.where}: path {template!r} gives {path} for both {owner[path]} and {me}; "
                    "add {stem}, {parent}, {setting} or {index} to the path"
                )
                continue
            owner[path] = me
            task.output_paths[template] = path
    if problems:
        raise PipelineProblems(problems) if len(set(problems)) > 1 else PipelineValidationError(problems[0])


def _resolve_references(tasks: list[Task], base_dir: Path) -> None:
    """Per-input metrics references (``reference: "{dir}/Original.obj"``): filled for each task, each checked to exist."""
    problems: list[str] = []
    for task in tasks:
        for step in task.steps:
            ref = step.params.get("reference") if step.kind == "metrics" else None
            if not isinstance(ref, str) or "{" not in ref:
                continue
            try:
                text = fill_template(ref, task)
            except ValueError as exc:
                problems.append(f"{step.where}: reference: {exc}")
                continue
            path = Path(text).expanduser()
            path = path if path.is_absolute() else base_dir / path
            if not path.is_file():
                problems.append(f"{step.where}: reference: no such file {text!r} ({path}) for input {task.label}")
                continue
            task.reference_paths[ref] = path.resolve()
    if problems:
        raise PipelineProblems(problems) if len(set(problems)) > 1 else PipelineValidationError(problems[0])


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
