"""The ``meshdenoise`` command line. Exit codes: 0 success, 1 runtime failure, 2 bad usage or input."""

from __future__ import annotations

import re
import sys

from ._launch import INTERRUPTED, exit_if_the_command, interrupt_as_usual

try:  # Ctrl-C while the command line loads: exit 130, no traceback (meshdenoise._launch)
    import click
    from rich.console import Console
    from rich.text import Text

    from .registry import list_filters
except KeyboardInterrupt:
    exit_if_the_command()
    raise

# User text is never read as rich markup (a mesh called "scan [final].ply" is printed as it is).
console = Console(markup=False, highlight=False)


# `meshdenoise --help` lists the commands by what the user does; a command in no section is listed under "other"
SECTIONS = (
    ("Denoise", ("denoise", "filters", "demo")),
    ("Inspect", ("info", "show", "render", "report")),
    ("Pipelines", ("run", "steps", "mlx2yaml", "yaml2mlx")),
    ("Evaluate", ("simulate-scan", "reproduce")),
)


class OneLineError(click.ClickException):
    """Bad usage said as the commands say bad input: one ``error: ...`` line on stderr, exit code 2."""

    exit_code = 2

    def show(self, file=None) -> None:
        Console(stderr=True, markup=False, highlight=False, soft_wrap=True).print(
            Text.assemble(("error:", "red"), " ", self.message))


# click.Path's complaints: "File 'x.ply' is a directory." and the like
_PATH_PROBLEM = re.compile(r"^(?:File|Directory|Path) (['\"])(?P<path>.*)\1 (?P<what>is a directory|is a file|does not exist|"
                           r"is not readable|is not writable|is not executable)\.$", re.S)
_PATH_WORDS = {"is a directory": "a folder, not a file", "is a file": "a file, not a folder",
               "does not exist": "no such file or folder", "is not readable": "cannot be read (permission denied)",
               "is not writable": "cannot be written (permission denied)", "is not executable": "not executable"}


def path_error(exc: click.BadParameter) -> OneLineError:
    """A file or folder argument click refused (``IN`` is a folder, ``--mesh`` does not exist), as one line naming it."""
    hint = (exc.param_hint if isinstance(exc.param_hint, str) else None) or (
        exc.param.get_error_hint(exc.ctx) if exc.param is not None and exc.ctx is not None else "")
    hint = hint.replace("'", "") if hint else ""
    if isinstance(exc, click.MissingParameter):  # its message is empty: "Missing option '--png'." comes from format_message
        return OneLineError(" ".join(exc.format_message().split()))
    m = _PATH_PROBLEM.match(exc.message)
    if m:
        return OneLineError(f"{m['path']}: {_PATH_WORDS[m['what']]}" + (f" ({hint})" if hint else ""))
    return OneLineError(f"{hint}: {exc.message}" if hint else exc.message)


def usage_error(exc: click.UsageError, command_path: str | None = None) -> OneLineError:
    """Any usage error click raises while reading a command's arguments (a value not among the choices or out of
    range, an unknown option, a missing argument) as one ``error:`` line, exit code 2, instead of click's usage block:
    ``--backend: 'foo' is not one of 'auto', 'open3d', 'matplotlib' (meshdenoise render --help)``. A file argument
    click refused reads as :func:`path_error` says."""
    if (isinstance(exc, click.BadParameter) and not isinstance(exc, click.MissingParameter)
            and isinstance(getattr(exc.param, "type", None), click.Path)):
        return path_error(exc)
    if isinstance(exc, click.BadParameter) and not isinstance(exc, click.MissingParameter):
        hint = (exc.param_hint if isinstance(exc.param_hint, str) else None) or (
            exc.param.get_error_hint(exc.ctx) if exc.param is not None and exc.ctx is not None else "")
        hint = hint.replace("'", "").replace('"', "") if hint else ""
        m = re.match(r"^(.*) is not a valid (?:float|integer) range\.?$", exc.message, re.S)
        message = f"expected a number, got {m[1]}" if m else exc.message
        text = f"{hint}: {message}" if hint else message
    else:
        text = exc.format_message()
    text = " ".join(text.split()).rstrip(".")
    command_path = command_path or (exc.ctx.command_path if exc.ctx is not None else None)
    return OneLineError(f"{text} ({command_path} --help)" if command_path else text)


def _warning_line(message, category=None, filename=None, lineno=None, file=None, line=None) -> None:
    """``warnings.showwarning`` of the command line: ``warning: <message>``, one plain line (no source file or line)."""
    text = " ".join(str(message).split())
    Console(stderr=True, markup=False, highlight=False, soft_wrap=True).print(Text.assemble(("warning:", "yellow"), " ", text))


class SectionedGroup(click.Group):
    """A click group whose help lists its commands in :data:`SECTIONS` (every command name still works).

    It also gives every command the exit codes the documentation promises: Ctrl-C ends it with 130 (click
    would print ``Aborted!`` and exit 1), and a file or folder argument click refuses is one ``error:`` line
    (:func:`path_error`), exit code 2.
    """

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except KeyboardInterrupt:  # cleanup ran as the exception unwound (temporary files, workers)
            raise click.exceptions.Exit(INTERRUPTED) from None
        except click.BadParameter as exc:
            if isinstance(getattr(exc.param, "type", None), click.Path):
                raise path_error(exc) from None
            raise

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        commands = {name: self.get_command(ctx, name) for name in self.list_commands(ctx)}
        commands = {name: c for name, c in commands.items() if c is not None and not c.hidden}
        if not commands:
            return
        longest = max(len(name) for name in commands)
        width = formatter.width - 6 - longest
        placed = set()
        for title, names in SECTIONS + (("Other", tuple(sorted(commands))),):
            rows = [(n.ljust(longest), commands[n].get_short_help_str(width)) for n in names if n in commands and n not in placed]
            placed.update(n.strip() for n, _ in rows)
            if rows:
                with formatter.section(title):
                    formatter.write_dl(rows)


@click.group(cls=SectionedGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="meshdenoise")
@click.pass_context
def cli(ctx: click.Context) -> None:
    """Mesh-denoising filters for pymeshlab, Open3D and numpy arrays."""
    import warnings

    import numpy as np

    # Overflow and invalid-value warnings of numpy would be printed before the one-line error that
    # refuses the non-finite result they lead to; the command's own check says what went wrong.
    ctx.with_resource(np.errstate(over="ignore", invalid="ignore", divide="ignore", under="ignore"))
    ctx.with_resource(warnings.catch_warnings())
    warnings.filterwarnings("ignore", category=RuntimeWarning)
    warnings.showwarning = _warning_line  # restored with the rest when the command ends


def _fail(message: str, code: int = 2) -> None:
    Console(stderr=True, markup=False, highlight=False, soft_wrap=True).print(
        Text.assemble(("error:", "red"), " ", str(message)))
    sys.exit(code)


@cli.command()
@click.option("--out", "out_dir", default="out/demo", show_default=True, type=click.Path(file_okay=False),
              help="Folder for the noisy and denoised meshes.")
@click.option("--mesh", "mesh_path", default=None, type=click.Path(exists=True, dir_okay=False),
              help="Mesh to use instead of pymeshlab's sample bunny.")
@click.option("--noise", default=0.01, show_default=True, type=click.FloatRange(min=0, max=1),
              help="Noise amplitude rho as a fraction of the bounding-box diagonal.")
@click.option("--seed", default=0, show_default=True, type=click.IntRange(min=0), help="Noise seed.")
def demo(out_dir: str, mesh_path: str | None, noise: float, seed: int) -> None:
    """Add normal noise to a built-in mesh, denoise it with the three filters (parameters chosen from the noisy mesh alone), print a table."""
    from .arrays import MeshValidationError
    from .demo import demo_table, run_demo
    from .io import MeshFileError
    from .registry import ParameterError

    try:
        rows, path, n = run_demo(out_dir, mesh_path, noise, seed)
    except (MeshFileError, MeshValidationError, ParameterError) as exc:  # NaN coordinates, a point cloud, an unwritable --out
        text = str(exc)
        _fail(text if mesh_path is None or str(mesh_path) in text else f"{mesh_path}: {text}", 2)
    except OSError as exc:
        _fail(f"{out_dir}: {exc.strerror or exc}", 2)
    console.print(demo_table(rows, path, n, noise, seed, width=console.width))
    console.print(f"meshes written to {click.format_filename(out_dir)}/", soft_wrap=True)


def _auto_json(spec) -> dict | None:
    """A filter's automatic rule for ``filters --json``: what it chooses, the criteria it takes and its default
    (``denoise --method M``); ``None`` for a filter without one."""
    from .tuning.choose import normal_filters, rule_criterion

    if spec.auto is None:
        return None
    normals = spec.name in normal_filters()
    return {"tunes": list(spec.auto.tunes), "criteria": ["sure", "normals"] if normals else ["sure"],
            "default_criterion": rule_criterion(spec.name)}


def filters_json() -> dict:
    """Every filter and built-in pipeline step with its parameters (:meth:`Param.describe`), for ``filters --json``.

    ``{"filters": [{"name", "summary", "params": [...], "auto"}], "steps": [{"name", "kind", "params": [...]}]}``
    (``auto``: ``{"tunes", "criteria", "default_criterion"}`` or ``None``);
    the options a pipeline's step of one of our filters takes besides the filter's parameters
    (:data:`meshdenoise.registry.COMMON_OPTIONS`: ``pinned``, ``region``, ``preserve_volume``, ``boundary_motion``,
    ``parameters``, ``noise``, ``criterion``) are listed once under ``"filter_options"``. pymeshlab's own filters
    are not listed (``pymeshlab.filter_list()``).
    """
    from .pipeline.steps import BUILTIN_STEPS, OPEN3D_OPS, RENDER_PARAMS, denoise_options_doc
    from .registry import COMMON_OPTIONS

    steps = [{"name": name, "kind": "builtin", "params": [p.describe() for p in params]}
             for name, params in BUILTIN_STEPS.items() if params]
    steps.append({"name": "denoise", "kind": "builtin", "params": denoise_options_doc()})
    steps.append({"name": "metrics", "kind": "builtin", "params": [
        {"name": "reference", "type": "str", "default": "input", "range": "input, a mesh file or {before: LABEL}",
         "help": "the mesh the metrics compare with"},
        {"name": "metrics", "type": "list", "default": None, "range": "names of meshdenoise.metrics.METRICS",
         "help": "metrics to compute (default: all)"}]})
    steps.append({"name": "render", "kind": "builtin", "params": [
        {"name": k, "type": "any", "default": None, "range": "see the render step", "help": ""} for k in RENDER_PARAMS]})
    steps += [{"name": f"open3d.{op}", "kind": "open3d", "params": [p.describe() for p in params]}
              for op, params in OPEN3D_OPS.items()]
    return {
        "filters": [{"name": f.name, "summary": f.summary, "params": [p.describe() for p in f.params],
                     "auto": _auto_json(f)} for f in list_filters()],
        "filter_options": [o.describe() for o in COMMON_OPTIONS if o.step],
        "steps": steps,
    }


@cli.command()
@click.option("--json", "as_json", is_flag=True, help="Print every filter and built-in pipeline step as JSON.")
def filters(as_json: bool) -> None:
    """List every filter with its parameters, types, ranges and defaults."""
    if as_json:
        import json

        click.echo(json.dumps(filters_json(), indent=1, allow_nan=False))
        return
    for spec in list_filters():
        console.print(Text.assemble((spec.name, "bold"), f": {spec.summary}"))
        for p in spec.params:
            console.print(f"    {p.name} ({p.kind.__name__}, default {p.default!r}, {p.range_text()}): {p.help}")
        auto = _auto_json(spec)
        if auto is not None:
            console.print(f"    denoise --method {spec.name} chooses {', '.join(auto['tunes'])} when not given "
                          f"(criterion {auto['default_criterion']}; takes {' or '.join(auto['criteria'])})")


def _add_commands() -> None:
    """Add the commands of every module in ``meshdenoise/commands`` (each lists its own in ``COMMANDS``)."""
    import importlib
    import pkgutil

    from . import commands

    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        if not info.name.startswith("_"):
            for command in importlib.import_module(f"{commands.__name__}.{info.name}").COMMANDS:
                cli.add_command(command)


try:
    _add_commands()
except KeyboardInterrupt:
    exit_if_the_command()
    raise


def main() -> None:
    """Console-script entry point: Ctrl-C anywhere ends it with exit code 130 and no traceback."""
    try:
        interrupt_as_usual()  # loaded: Ctrl-C now unwinds the command (meshdenoise._launch)
        cli.main(standalone_mode=True)
    except KeyboardInterrupt:
        sys.exit(INTERRUPTED)
