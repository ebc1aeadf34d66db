"""CLI commands: run, denoise, info, mlx2yaml, yaml2mlx, steps. Exit codes: 0 ok, 1 runtime failure, 2 bad input."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import click
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table
from rich.text import Text

# User text (paths, file content, parameter values, messages) is never read as rich markup:
# "scan [final].ply" and "out/r[/b].ply" are printed as they are. Styles go through Text.
console = Console(soft_wrap=True, markup=False, highlight=False)
err_console = Console(stderr=True, soft_wrap=True, markup=False, highlight=False)


def _fail(message: str, code: int) -> None:
    err_console.print(Text.assemble(("error:", "red"), " ", str(message)), soft_wrap=True)
    sys.exit(code)


def _assignments(values: tuple[str, ...], option: str) -> dict:
    from ..pipeline.variables import parse_assignment

    out = {}
    for text in values:
        try:
            name, value = parse_assignment(text)
        except ValueError as exc:
            raise click.BadParameter(str(exc), param_hint=option) from None
        out[name] = value
    return out


@click.command("run")
@click.argument("pipeline", type=click.Path(dir_okay=False))
@click.option("--set", "sets", multiple=True, metavar="NAME=VALUE", help="Override a ${variable} (repeatable).")
@click.option("--input", "inputs", multiple=True, metavar="PATH", help="Input file or glob instead of the pipeline's inputs (repeatable).")
@click.option("--out", "out_dir", default=None, type=click.Path(file_okay=False), help="Output folder (default: the pipeline's output_dir).")
@click.option("--scheduler", default=None, metavar="ADDRESS", help="Dask distributed scheduler to submit to (tcp://host:8786).")
@click.option("--workers", default=None, type=click.IntRange(min=1), help="Local Dask worker processes (default: cores).")
@click.option("--serial", is_flag=True, help="Run every input in this process, one after another.")
@click.option("--check", is_flag=True, help="Only check the pipeline and list its tasks; run nothing.")
def run_command(pipeline, sets, inputs, out_dir, scheduler, workers, serial, check):
    """Run a YAML PIPELINE on its inputs (several inputs run in parallel on Dask)."""
    from ..io import MeshFileError
    from ..pipeline import PipelineValidationError, load_pipeline, run_tasks, write_results
    from ..pipeline.errors import BAD_INPUT_FAILURES

    overrides = _assignments(sets, "--set")
    try:
        plan = load_pipeline(pipeline, overrides=overrides, inputs=list(inputs) or None, output_dir=out_dir)
    except PipelineValidationError as exc:
        problems = getattr(exc, "problems", None)  # every problem --check (or a run) found, one line each
        _fail("\nerror: ".join(problems) + f"\n{len(problems)} problems; nothing was run" if problems else str(exc), 2)
    for note in plan.notes:
        _note(note)
    n = len(plan.tasks)
    console.print(f"{pipeline}: {n} task(s) ({len(plan.inputs)} input(s) x {n // max(len(plan.inputs), 1)} setting(s)), "
                  f"outputs in {plan.output_dir}")
    if check:
        for t in plan.tasks:
            console.print(f"  {t.label or t.input.name} {t.setting_text}: {', '.join(s.name for s in t.steps)}", highlight=False, markup=False)
        return
    if scheduler is not None:
        _check_scheduler(scheduler)
    cores = os.cpu_count() or 1
    if workers is not None and workers > MAX_WORKERS_PER_CORE * cores:
        _fail(f"--workers {workers}: at most {MAX_WORKERS_PER_CORE} x {cores} cores = {MAX_WORKERS_PER_CORE * cores} "
              "local worker processes", 2)
    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                  console=err_console, transient=True, disable=n < 2) as progress:
        bar = progress.add_task("meshes", total=n)

        def done(row):
            progress.advance(bar)
            if row.get("status") != "ok":
                from rich.text import Text  # the error names user paths: never markup

                err_console.print(Text.assemble(("failed: ", "red"), str(row.get("error"))), highlight=False)

        rows = run_tasks(plan.tasks, scheduler=scheduler, workers=workers, serial=serial, on_done=done)
    _print_rows(rows)
    if plan.writes_results and plan.results:
        try:
            csv_path, _ = write_results(rows, plan.output_dir, plan.results)
        except (MeshFileError, OSError) as exc:  # read-only folder, full disk: the outputs of the tasks are kept
            _fail(f"results table not written: {exc}", 2)
        console.print(f"results: {csv_path} and .json")
    failed = [r for r in rows if r.get("status") != "ok"]
    if failed:
        # each failure was printed as it happened; bad inputs alone are bad input (2), anything else a failure (1)
        err_console.print(f"{len(failed)} of {n} task(s) failed")
        sys.exit(2 if all(r.get("failure") in BAD_INPUT_FAILURES for r in failed) else 1)


#: Local Dask worker processes allowed per core (``--workers``): each is a Python process of 100+ MB.
MAX_WORKERS_PER_CORE = 4

#: Seconds to wait for a Dask scheduler to accept a connection before giving up.
SCHEDULER_TIMEOUT = 3.0


def _check_scheduler(address: str) -> None:
    """Exit 2 at once (one line) when ``--scheduler`` is not an address or nothing listens there."""
    import socket
    from urllib.parse import urlsplit

    text = address if "://" in address else f"tcp://{address}"
    try:
        parts = urlsplit(text)
        host, port = parts.hostname, parts.port
    except ValueError as exc:
        _fail(f"--scheduler {address!r}: not an address like tcp://host:8786 ({exc})", 2)
    if parts.scheme not in ("tcp", "tls", "ws", "wss") or not host or port is None or parts.path not in ("", "/"):
        _fail(f"--scheduler {address!r}: not an address like tcp://host:8786", 2)
    try:
        with socket.create_connection((host, port), timeout=SCHEDULER_TIMEOUT):
            pass
    except OSError as exc:
        reason = exc.strerror or str(exc) or type(exc).__name__
        _fail(f"--scheduler {address!r}: no scheduler answers at {host}:{port} ({reason}, waited at most "
              f"{SCHEDULER_TIMEOUT:g} s); start one with `dask scheduler` or leave out --scheduler", 2)
    # Something listens: check that it speaks Dask (a proxy or another service may accept any connection).
    import logging

    from distributed import Client

    quiet = [logging.getLogger(n) for n in ("distributed", "distributed.comm", "distributed.client")]
    levels = [q.level for q in quiet]
    for q in quiet:
        q.setLevel(logging.CRITICAL)
    try:
        Client(address, timeout=f"{SCHEDULER_TIMEOUT}s").close()
    except (Exception, MemoryError) as exc:  # a garbage reply can ask for an absurd buffer
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        _fail(f"--scheduler {address!r}: {host}:{port} does not answer as a Dask scheduler "
              f"within {SCHEDULER_TIMEOUT:g} s ({type(exc).__name__}: {reason})", 2)
    finally:
        for q, level in zip(quiet, levels):
            q.setLevel(level)


def _print_rows(rows: list[dict]) -> None:
    """The results as a table: inputs by their shortest distinguishing path, no column cut.

    On a terminal, a cell too wide for its column is folded onto more lines; into a file or
    a pipe the table gets the width it needs (nothing is cut at 80 characters).
    """
    from ..pipeline.schema import distinguishing_names
    from ..pipeline.sweep import columns

    # The terminal shows the measurements; the chosen parameters, mesh sizes and output paths are in
    # the CSV/JSON (a table of every column does not fit a terminal).
    hidden = ("outputs", "error", "vertices", "faces")
    cols = [c for c in columns(rows) if c not in hidden and not c.startswith("auto.")]
    names = distinguishing_names([Path(r["input"]) for r in rows if r.get("input")])
    from rich.text import Text  # user text (paths, variable names) is never read as markup

    table = Table()
    for c in cols:
        table.add_column(Text(c), overflow="fold")
    for r in rows:
        cells = []
        for c in cols:
            v = r.get(c, "")
            cells.append(names.get(Path(v), str(v)) if c == "input" and v else f"{v:.4g}" if isinstance(v, float) else str(v))
        table.add_row(*(Text(cell) for cell in cells))
    if not console.is_terminal:  # a file or a pipe: the width the table needs
        needed = console.measure(table, options=console.options.update_width(100_000)).maximum
        table.width = max(console.width, needed) if needed > console.width else None
    console.print(table)


class _OneLineUsage(click.Command):
    """A command whose usage errors (an unknown option, a bad choice, a missing argument) are one ``error: ...``
    line and exit code 2, as its other bad input (:func:`meshdenoise.cli.usage_error`)."""

    def make_context(self, info_name, args, parent=None, **extra):
        try:
            return super().make_context(info_name, args, parent=parent, **extra)
        except click.NoSuchOption as exc:
            if exc.option_name == "--auto":  # the flag of earlier versions: say what replaced it
                _fail("no such option --auto: --method M chooses the parameters not given with --param by the "
                      "filter's own rule (--defaults runs the filter's defaults instead)", 2)
            raise self._one_line(exc, info_name, parent) from None
        except click.UsageError as exc:
            raise self._one_line(exc, info_name, parent) from None

    @staticmethod
    def _one_line(exc, info_name, parent):
        from ..cli import usage_error

        return usage_error(exc, f"{parent.command_path} {info_name}" if parent is not None else info_name)


@click.command("denoise", cls=_OneLineUsage)
@click.argument("input_path", metavar="IN", type=click.Path(dir_okay=False))
@click.argument("output_path", metavar="OUT", type=click.Path(dir_okay=False), required=False)
@click.option("--method", default=None, metavar="FILTER",
              help="Run this filter of ours (see `meshdenoise filters`): the parameters given with --param are held, "
                   "every other parameter its own rule tunes is chosen for the mesh by that rule (printed), as "
                   "meshdenoise.denoise(mesh, method=M) does. Default: the filter and its parameters chosen for the "
                   "mesh by held-out vertices; three lines printed (--explain: why).")
@click.option("--param", "params", multiple=True, metavar="NAME=VALUE", help="A filter parameter (repeatable; needs --method).")
@click.option("--defaults", is_flag=True,
              help="With --method: choose nothing, run the filter's own defaults for the parameters not given "
                   "(denoise(mesh, method=M, defaults=True)).")
@click.option("--pinned", type=click.Choice(["boundary", "selection"]), default=None, help="Keep these vertices exactly fixed.")
@click.option("--region-from-selection", is_flag=True, help="Move only the vertices selected in IN (PLY vertex flags).")
@click.option("--preserve-volume", is_flag=True, help="Rescale so the enclosed volume equals the input's.")
@click.option("--boundary-motion", type=click.Choice(["normal", "free"]), default="normal", show_default=True,
              help="normal: vertices on open borders move along their normals only, so borders do not shrink inward; "
                   "free: as the filter moves them.")
@click.option("--noise", "noise", default=None, metavar="RHO[h][,L]",
              help="The noise level to choose the parameters for, instead of the estimate: RHO in mesh units, or in "
                   "mean edge lengths with h (0.4h); L its correlation length in mean edge lengths (0.4h,2). "
                   "With --method (not --defaults).")
@click.option("--criterion", type=click.Choice(["normals", "sure"]), default=None,
              help="With --method (not --defaults): what the choice of its parameters minimises. normals (default "
                   "where the filter has it: filtering, heat, taubin, sinkhorn, sobolev, sobolev_bilaplacian, "
                   "sobolev_axes, sobolev_gls): the face-normal error, what a rendering shows; it smooths and shrinks "
                   "more. sure: the position error (SNR), the default of the other filters.")
@click.option("--explain", is_flag=True, help="With no --method: also print why (every candidate's held-out error).")
@click.option("--dry-run", is_flag=True, help="Only print what would be chosen; write nothing.")
def denoise_command(input_path, output_path, method, params, defaults, pinned, region_from_selection, preserve_volume,
                    boundary_motion, noise, criterion, explain, dry_run):
    """Denoise the mesh IN and write OUT (PLY, OBJ, OFF or STL; colours kept).

    With no --method the filter and its parameters are chosen from the mesh alone (the default
    for scans) and three lines are printed: the noise removed, the filter with its parameters, and
    how far the vertices moved with the faces flipped; --explain adds why.

    With --method M, M runs: the parameters given with --param as given, every other parameter
    its own rule tunes chosen for the mesh by that rule (--noise, --criterion: how), as
    meshdenoise.denoise(mesh, method=M) does; with --defaults, M's own defaults instead (nothing
    chosen). A pipeline's denoise step means the same (method: M, defaults: true).
    """
    from ..pipeline.errors import InputError, PipelineValidationError, StepFailure
    from ..pipeline.runner import run_task
    from ..pipeline.schema import Task
    from ..pipeline.steps import denoise_step

    given = _assignments(params, "--param")
    if noise is not None:
        from ..pipeline.noise_option import parse_noise_option

        try:
            parse_noise_option(noise, "--noise")  # said here with the option's name; the step reads it again
        except ValueError as exc:
            _fail(str(exc), 2)
    if method is None:  # each says what it needs, and what happens with no method
        if given:
            _fail(f"--param {next(iter(given))}: a filter parameter needs --method (with no method the filter and "
                  "its parameters are chosen for the mesh)", 2)
        if defaults:
            _fail("--defaults: it runs a filter's own defaults: give --method M (with no method the filter and its "
                  "parameters are chosen for the mesh)", 2)
        if criterion is not None:
            _fail(f"--criterion {criterion}: it says how --method M chooses the filter's parameters: give --method "
                  "(with no method the default chooses by its own estimates)", 2)
        if noise is not None:
            _fail(f"--noise {noise}: the noise level is used only by a filter's own rule: give --method M "
                  "(with no method the default reads the noise from held-out vertices)", 2)
    else:
        from ..registry import get_filter

        try:
            get_filter(method)  # the registry says an unknown name (with the closest) before anything else
        except KeyError as exc:
            _fail(f"--method: {exc}", 2)
        given["method"] = method
    if defaults:
        for flag, value in (("--criterion", criterion), ("--noise", noise)):
            if value is not None:
                what = "the noise level is used only by a filter's own rule" if flag == "--noise" else \
                    "it says how --method M chooses the filter's parameters"
                _fail(f"{flag} {value}: {what}, and --defaults chooses none: leave out one of them", 2)
        given["defaults"] = True
    if pinned:
        given["pinned"] = pinned
    if region_from_selection:
        given["region"] = _selected_vertices(input_path)
    if preserve_volume:
        given["preserve_volume"] = True
    if criterion is not None:
        given["criterion"] = criterion
    given["boundary_motion"] = boundary_motion
    if explain:
        if method is not None:
            _fail("--explain: it says why the default chose its filter: drop --method", 2)
        given["explain"] = True
    if noise is not None:
        given["noise"] = noise
    try:
        step = denoise_step(given, None, None, "--method" if method else "denoise")
    except PipelineValidationError as exc:
        _fail(str(exc), 2)
    src = Path(input_path)
    if not src.is_file():
        _fail(f"{src}: no such file", 2)
    if dry_run:
        _dry_run(src, step)
        return
    if output_path is None:
        _fail("OUT is missing: give the output file (or --dry-run to only see the choice)", 2)
    dst = Path(output_path)
    _refuse_overwriting_inputs(dst, [src], "OUT")
    target = _output_target(dst, "OUT")  # OUT itself, or the file a symbolic link OUT points to
    from ..io import SUPPORTED_EXTENSIONS

    for path in dict.fromkeys([dst, target]):
        if path.suffix.lower() not in SUPPORTED_EXTENSIONS:
            shown = str(dst) if path == dst else f"{dst} (a link to {path})"
            _fail(f"{shown}: unsupported extension {path.suffix!r}; use one of {', '.join(SUPPORTED_EXTENSIONS)}", 2)
    from ..pipeline.steps import parse_step

    try:
        save = parse_step({"save": {"path": str(target)}}, 2, "denoise", None)
    except PipelineValidationError as exc:
        _fail(str(exc), 2)
    task = Task(0, src.resolve(), {}, "", [step, save], {str(target): target})

    def echo(message) -> None:
        console.print(str(message))

    from ..kernels import compiled_here
    from ..progress import LogProgress, RichProgress, listening

    if not compiled_here():  # a new clone's first run: the kernels compile on first use (docs/install.md)
        err_console.print(f"{src.name}: first run of this installation: compiling the numerical kernels once "
                          "(about 15 s; later runs load them)")

    # stages: (the default's choice,) parameters, filter; a bar on a terminal after 2 s, else a line per stage over 2 s
    total = None if method is None else 1 if defaults else 2  # the default's stages depend on the mesh; a
    # method's: its parameters chosen (unless --defaults), then the filter
    listener = (RichProgress(src.name, err_console, total) if err_console.is_terminal
                else LogProgress(src.name, lambda line: err_console.print(line)))
    try:
        with listening(listener):
            row = run_task(task, echo=echo)
    except InputError as exc:  # also a bad parameter on this mesh and an output that cannot be written
        _fail(str(exc), 2)
    except StepFailure as exc:
        _fail(str(exc), 1)
    used = row.get("denoise.method", method)
    console.print(f"{dst}: {row['vertices']} vertices, {row['faces']} faces, {used} in {row['seconds']:.2f} s")


def _dry_run(src: Path, step) -> None:
    """``denoise --dry-run``: the noise estimate and the choice the checked ``denoise`` step would make, nothing written."""
    from ..io import MeshFileError, load_mesh

    try:
        mesh = load_mesh(src)
    except MeshFileError as exc:
        _fail(str(exc), 2)
    arrays = (mesh.V, mesh.F)
    options = step.options
    method = options.get("method")
    try:
        if method is None:
            from ..policy import choose_default

            choice = choose_default(arrays)
            lines = choice.lines()[1:2] + (choice.explain() if options.get("explain") else [])
        else:
            from ..default import method_parameters
            from ..operators import get_operators
            from ..registry import get_filter
            from ..tuning import estimate_noise_model
            from ..tuning.noise_level import mean_edge_length

            known = options["noise"].model(mesh.V, mesh.F) if "noise" in options else None
            spec = get_filter(method)
            h = mean_edge_length(mesh.V, get_operators(mesh.F, mesh.V.shape[0]))
            model = known if known is not None else estimate_noise_model(arrays)
            rho = model.rho
            # the estimate is shown; a choice by held-out vertices reads none (only a given level, refused there)
            held_out = spec.auto is not None and spec.auto.held_out is not None and options.get("criterion") != "sure"
            params, criterion = method_parameters(arrays, method, noise=known if held_out else model,
                                                  criterion=options.get("criterion"),
                                                  defaults=options.get("defaults", False), **step.params)
            settings = spec.resolve(params, f"--method '{method}'")
            spread = (f"correlated over {model.correlation_length:.3g} edge lengths" if model.correlated
                      else "independent") + ("; given by --noise" if known is not None else "")
            how = (f"chosen for criterion {criterion}" if criterion is not None
                   else "its defaults" if options.get("defaults") else "as given")
            lines = [f"noise: {rho:.4g} ({rho / h:.3g} mean edge lengths; mean edge {h:.4g}; {spread})",
                     f"method: {method} ({', '.join(f'{k}={v!r}' for k, v in settings.items())}; {how})"]
    except (TypeError, ValueError) as exc:
        _fail(f"{src}: {exc}", 2)
    for line in lines:
        console.print(f"{src.name}: {line}")
    console.print(f"{src.name}: dry run: nothing written")


def _selected_vertices(path: str) -> list[int]:
    """Indices of the vertices selected in a mesh file (MeshLab keeps the selection in PLY vertex flags).

    Read by our own reader (no C++ loader sees the file first): a broken file gets its real problem.
    """
    import numpy as np

    from ..io import MeshFileError, load_mesh

    try:
        mesh = load_mesh(path)
    except MeshFileError as exc:
        _fail(f"--region-from-selection: {exc}", 2)
    if mesh.selection is None:
        _fail(f"{path}: --region-from-selection: the file stores no selection (save it from MeshLab as PLY "
              "with the vertex 'Flags' option)", 2)
    selected = np.flatnonzero(mesh.selection)
    if selected.size == 0:
        _fail(f"{path}: --region-from-selection: the file has no selected vertex (its vertex flags select none)", 2)
    return selected.tolist()


@click.command("info")
@click.argument("mesh", type=click.Path(dir_okay=False))
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of a table.")
def info_command(mesh, as_json):
    """Vertices, faces, bounding box, components, boundary loops, non-manifold and duplicate elements of MESH."""
    from ..io import MeshFileError, load_mesh
    from ..meshinfo import mesh_info

    try:
        m = load_mesh(mesh)
    except MeshFileError as exc:
        _fail(str(exc), 2)
    info = mesh_info(m.V, m.F)
    info["vertex_colors"] = m.vertex_colors is not None
    if as_json:
        click.echo(json.dumps(_finite_json(info), indent=1, allow_nan=False))
        return
    table = Table(title=str(mesh))
    table.add_column("property")
    table.add_column("value", justify="right")
    for k, v in info.items():
        text = ", ".join(f"{x:.6g}" for x in v) if isinstance(v, list) else f"{v:.6g}" if isinstance(v, float) else str(v)
        table.add_row(k.replace("_", " "), text)
    console.print(table)


def _finite_json(value):
    """``value`` with every NaN or infinite float written as the string "nan", "inf" or "-inf" (JSON has none)."""
    import math

    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if isinstance(value, dict):
        return {k: _finite_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite_json(v) for v in value]
    return value


def _same_file(a: str | Path, b: str | Path) -> bool:
    """Whether two spellings name one file: the same path once links and ``..`` are resolved, or the same inode
    (a hard link, a bind mount)."""
    a, b = Path(a), Path(b)
    try:
        if a.resolve() == b.resolve():
            return True
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except (OSError, RuntimeError):  # a link loop, an unreadable folder: not provably the same
        return False


def _refuse_overwriting_inputs(output: str | Path | None, inputs: list, what: str) -> None:
    """Exit 2 (one line naming both) when the output would be one of the inputs, however spelt."""
    if output is None:
        return
    for inp in inputs:
        if _same_file(output, inp):
            shown = str(output) if str(output) == str(inp) else f"{output} (the same file as {inp})"
            _fail(f"{shown}: {what} is the input file; input files are never overwritten", 2)


def _output_target(path: Path, what: str) -> Path:
    """The file an output path writes (a symbolic link's target); exit 2 when that is not a file one can replace
    (a device such as /dev/full, a pipe, a folder)."""
    try:
        target = path.resolve()
    except (OSError, RuntimeError) as exc:  # a link loop
        _fail(f"{path}: {what} cannot be resolved ({exc})", 2)
    if target.exists() and not target.is_file():
        kind = "a folder" if target.is_dir() else "a device, pipe or socket"
        shown = str(path) if target == path.absolute() else f"{path} (a link to {target})"
        _fail(f"{shown}: {what} is {kind}, not a file", 2)
    return target


def _write_text(path: str | None, text: str, notes: list[str] = ()) -> None:
    """Write ``text`` to stdout or atomically to ``path`` (its folder is made, as for every output), then print the
    ``notes`` about it; exit 2 when it cannot be written (then no note: the error is all there is to say)."""
    if path is None:
        for note in notes:
            _note(note)
        click.echo(text, nl=False)
        return
    from ..io import MeshFileError, atomic_path

    _output_target(Path(path), "-o")
    try:
        with atomic_path(path) as tmp:
            Path(tmp).write_text(text, encoding="utf-8")
    except MeshFileError as exc:
        _fail(str(exc), 2)
    for note in notes:
        _note(note)
    err_console.print(f"written {path}", highlight=False, markup=False)


def _note(text: str) -> None:
    err_console.print(f"note: {text}", highlight=False, markup=False)


def _read_text(path: str) -> str:
    try:
        return Path(path).read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        _fail(f"{path}: not UTF-8 text (byte {exc.start}: {exc.reason})", 2)
    except OSError as exc:
        _fail(f"{path}: cannot be read ({exc.strerror or exc})", 2)


@click.command("mlx2yaml")
@click.argument("script", type=click.Path(exists=True, dir_okay=False))
@click.option("-o", "--output", default=None, type=click.Path(dir_okay=False), help="Write here instead of stdout (its folder is made).")
@click.option("--input", "input_glob", default=None,
              help="The 'inputs' of the pipeline written (default: a placeholder you must set, or pass --input to run).")
def mlx2yaml_command(script, output, input_glob):
    """Convert a MeshLab filter SCRIPT (.mlx) to a pipeline YAML (pymeshlab names)."""
    import yaml

    from ..pipeline.mlx import mlx_to_steps
    from ..pipeline.schema import PLACEHOLDER_INPUT

    _refuse_overwriting_inputs(output, [script], "-o")
    notes: list[str] = []
    try:
        steps = mlx_to_steps(_read_text(script), script, warn=notes.append)
    except ValueError as exc:
        _fail(str(exc), 2)
    if input_glob is None:
        inputs = (f"inputs: {PLACEHOLDER_INPUT}   # set your mesh file(s): a file, a glob or a list "
                  "(or give meshdenoise run --input FILE)\n")
        notes.append(f"the pipeline's inputs are a placeholder ({PLACEHOLDER_INPUT}): set them, or run it with --input FILE")
    else:
        inputs = yaml.safe_dump({"inputs": input_glob}, sort_keys=False)
    body = yaml.safe_dump({"steps": steps + [{"save": {"path": "{stem}_out.ply"}}]}, sort_keys=False)
    _write_text(output, f"# converted from {Path(script).name} by meshdenoise mlx2yaml\n" + inputs + body, notes)


@click.command("yaml2mlx")
@click.argument("pipeline", type=click.Path(exists=True, dir_okay=False))
@click.option("-o", "--output", default=None, type=click.Path(dir_okay=False), help="Write here instead of stdout (its folder is made).")
@click.option("--skip-other", is_flag=True, help="Leave out steps with no filter-script form (metrics, render, add_noise, open3d.*); save is always left out.")
def yaml2mlx_command(pipeline, output, skip_other):
    """Convert the steps of a PIPELINE YAML to a MeshLab filter script (.mlx)."""
    from ..pipeline.errors import PipelineValidationError
    from ..pipeline.mlx import steps_to_mlx
    from ..pipeline.yamlsource import line_of, load_yaml

    _refuse_overwriting_inputs(output, [pipeline], "-o")
    try:
        doc = load_yaml(_read_text(pipeline), pipeline)
    except PipelineValidationError as exc:
        _fail(str(exc), 2)
    steps = doc.get("steps") if isinstance(doc, dict) else None
    if not isinstance(steps, list):
        _fail(f"{pipeline}: no 'steps' list", 2)
    notes: list[str] = []
    try:
        text = steps_to_mlx(steps, skip_other=skip_other, notes=notes)
    except ValueError as exc:
        index = getattr(exc, "index", None)  # the step's position, for its line
        line = line_of(steps, index - 1) if index else None
        _fail(f"{pipeline}{':' + str(line) if line else ''}: {exc}", 2)
    _write_text(output, text, [f"{pipeline}: {note}" for note in notes])


@click.command("steps")
@click.argument("names", nargs=-1, metavar="[NAME]...")
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of text.")
def steps_command(names, as_json):
    """List every step a pipeline may use, with its parameters (types, defaults, what they do); NAME: only these
    steps (a pymeshlab filter too, by its pymeshlab or MeshLab name)."""
    from ..pipeline.steps import describe_pymeshlab_step, describe_steps

    steps = describe_steps()
    if names:
        by_name = {s["name"]: s for s in steps}
        chosen = []
        for name in names:
            if name in by_name:
                chosen.append(by_name[name])
                continue
            try:
                chosen.append(describe_pymeshlab_step(name))
            except KeyError as exc:
                _fail(str(exc.args[0]), 2)
        steps = chosen
    if as_json:
        click.echo(json.dumps(steps, indent=1, default=str))
        return
    for step in steps:
        click.echo(f"{step['name']}: {step['summary']}")
        for p in step["params"]:
            default = "" if p["default"] is None else f", default {p['default']!r}"
            click.echo(f"    {p['name']} ({p['type']}{default}): {p['help']}")


COMMANDS = [run_command, denoise_command, info_command, mlx2yaml_command, yaml2mlx_command, steps_command]
