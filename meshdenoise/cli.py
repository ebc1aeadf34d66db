"""The ``meshdenoise`` command line. Exit codes: 0 success, 1 runtime failure, 2 bad usage or input."""

from __future__ import annotations

import sys

import click
from rich.console import Console
from rich.table import Table

from .registry import list_filters

console = Console()


# `meshdenoise --help` lists the commands by what the user does; a command in no section is listed under "other"
SECTIONS = (
    ("Denoise", ("denoise", "filters", "demo")),
    ("Inspect", ("info", "show", "render", "report")),
    ("Pipelines", ("run", "steps", "mlx2yaml", "yaml2mlx")),
    ("Reproduce", ("reproduce",)),
)


class SectionedGroup(click.Group):
    """A click group whose help lists its commands in :data:`SECTIONS` (every command name still works)."""

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
def cli() -> None:
    """Mesh-denoising filters for pymeshlab, Open3D and numpy arrays."""


@cli.command()
@click.option("--out", "out_dir", default="out/demo", show_default=True, type=click.Path(file_okay=False),
              help="Folder for the noisy and denoised meshes.")
@click.option("--mesh", "mesh_path", default=None, type=click.Path(exists=True, dir_okay=False),
              help="Mesh to use instead of pymeshlab's sample bunny.")
@click.option("--noise", default=0.01, show_default=True, type=click.FloatRange(min=0),
              help="Noise amplitude rho as a fraction of the bounding-box diagonal.")
@click.option("--seed", default=0, show_default=True, type=int, help="Noise seed.")
def demo(out_dir: str, mesh_path: str | None, noise: float, seed: int) -> None:
    """Add normal noise to a built-in mesh, denoise it with the three filters (parameters chosen from the noisy mesh alone), print a table."""
    from .demo import demo_table, run_demo

    rows, path, n = run_demo(out_dir, mesh_path, noise, seed)
    console.print(demo_table(rows, path, n, noise, seed, width=console.width))
    console.print(f"meshes written to {click.format_filename(out_dir)}/")


@cli.command()
def filters() -> None:
    """List every filter with its parameters, types, ranges and defaults."""
    for spec in list_filters():
        console.print(f"[bold]{spec.name}[/bold]: {spec.summary}")
        for p in spec.params:
            console.print(f"    {p.name} ({p.kind.__name__}, default {p.default!r}, {p.range_text()}): {p.help}")


def _add_commands() -> None:
    """Add the commands of every module in ``meshdenoise/commands`` (each lists its own in ``COMMANDS``)."""
    import importlib
    import pkgutil

    from . import commands

    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        if not info.name.startswith("_"):
            for command in importlib.import_module(f"{commands.__name__}.{info.name}").COMMANDS:
                cli.add_command(command)


_add_commands()


def main() -> None:
    """Console-script entry point."""
    try:
        cli.main(standalone_mode=True)
    except KeyboardInterrupt:
        sys.exit(130)
