"""The README and docs/ pages: short start, code that runs when pasted, commands and links that exist."""

import re
import shlex
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import meshdenoise as md
from meshdenoise.metrics import normal_error_deg
from meshdenoise.cli import cli
from meshdenoise.shapes import icosphere

ROOT = Path(__file__).resolve().parent.parent
README = (ROOT / "README.md").read_text(encoding="utf-8")

# Pages of docs/ a link may name before the page exists; a link to one is checked once it exists.
PAGES_FROM_OTHER_BRANCHES = {"file-formats.md", "reliability.md", "pipelines.md", "scale.md", "scans.md", "peers.md"}


def _blocks(text: str, lang: str) -> list[str]:
    """The fenced code blocks whose info string is ``lang`` ("" for a bare fence)."""
    blocks, current = [], None
    for line in text.splitlines(keepends=True):
        if line.startswith("```"):
            if current is None:
                current = (line[3:].strip(), [])
            else:
                if current[0] == lang:
                    blocks.append("".join(current[1]))
                current = None
        elif current is not None:
            current[1].append(line)
    return blocks


def test_readme_is_a_short_start_that_says_how_the_code_is_organised():
    assert len(README.splitlines()) <= 150
    section = README.split("\n## How the code is organised\n", 1)[1].split("\n## ", 1)[0]
    for floor in ("plugins", "tuning", "solvers/", "docs/design.md"):
        assert floor in section


def test_readme_python_runs_when_pasted(tmp_path, monkeypatch):
    V, F = icosphere(3)
    Vn, _ = md.add_normal_noise((V, F), rho=0.01, seed=0)
    md.save_mesh(tmp_path / "scan.ply", Vn, F)
    monkeypatch.chdir(tmp_path)
    blocks = _blocks(README, "python")
    assert len(blocks) == 2
    for block in blocks:
        exec(compile(block, "README.md", "exec"), {})
    Y = md.load_mesh(tmp_path / "scan_denoised.ply").V
    # the default really denoised: its face normals (what it chooses by) much nearer the clean ones
    assert normal_error_deg((V, F), Y) < 0.2 * normal_error_deg((V, F), Vn)
    assert (tmp_path / "scan_taubin.ply").is_file()


def test_readme_pipeline_is_the_shipped_one_and_checks():
    (block,) = _blocks(README, "yaml")
    shipped = (ROOT / "pipelines" / "scan_cleanup.yaml").read_text()
    for line in block.splitlines():
        code = line.split("#")[0].rstrip()
        assert code and code in shipped, line
    res = CliRunner().invoke(cli, ["run", str(ROOT / "pipelines" / "scan_cleanup.yaml"), "--check"])
    assert res.exit_code == 0, res.output


def _help(command: str) -> str:
    res = CliRunner().invoke(cli, [command, "--help"], terminal_width=200)
    assert res.exit_code == 0, (command, res.output)
    return res.output


def test_readme_commands_and_their_options_exist():
    listing = next(b for b in _blocks(README, "") if b.startswith("meshdenoise "))
    seen = set()
    for line in listing.splitlines():
        words = shlex.split(line.split("#")[0].replace("[", " ").replace("]", " "))
        assert words[0] == "meshdenoise", line
        command = words[1]
        text = _help(command)
        for option in (w.split("=")[0] for w in words[2:] if w.startswith("--")):
            assert option in text, (command, option)
        seen.add(command)
    assert {"denoise", "info", "filters", "run", "render", "report", "reproduce", "demo", "mlx2yaml"} <= seen


def _links(path: Path) -> list[tuple[str, str]]:
    text = path.read_text(encoding="utf-8")
    text = re.sub(r"```.*?```", "", text, flags=re.S)
    return [(m, path.name) for m in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text) if "://" not in m]


@pytest.mark.parametrize("page", [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))], ids=lambda p: p.name)
def test_relative_links_resolve(page):
    for target, _ in _links(page):
        path = (page.parent / target).resolve()
        if path.name in PAGES_FROM_OTHER_BRANCHES and path.parent == ROOT / "docs" and not path.exists():
            continue
        assert path.exists(), f"{page.name} links to {target}, which does not exist"


def test_docs_anchors_resolve():
    """Links of the form page.md#anchor point at a heading of that page (GitHub's anchor rule)."""

    def anchors(path: Path) -> set[str]:
        out = set()
        for line in path.read_text(encoding="utf-8").splitlines():
            if line.startswith("#"):
                title = line.lstrip("#").strip().lower()
                out.add(re.sub(r"[^\w\- ]", "", title).replace(" ", "-"))
        return out

    for page in [ROOT / "README.md", *(ROOT / "docs").glob("*.md")]:
        text = re.sub(r"```.*?```", "", page.read_text(encoding="utf-8"), flags=re.S)
        for target, anchor in re.findall(r"\]\(([^)#\s]*)#([^)\s]+)\)", text):
            path = (page.parent / target).resolve() if target else page
            if not path.exists():
                continue
            assert anchor in anchors(path), f"{page.name}: #{anchor} is not a heading of {path.name}"


def test_the_long_prose_moved_with_its_numbers():
    """A few measured numbers from the old README, each on exactly one docs page now."""
    docs = {p.name: p.read_text(encoding="utf-8") for p in (ROOT / "docs").glob("*.md")}
    for number, page in [("sobolev_gls 41.61", "benchmarks.md"), ("0.988-1.011", "automatic-parameters.md"),
                         ("27.26", "optimal-transport.md"), ("**25.6x**", "benchmarks.md"),
                         ("121.6 MiB", "robustness.md"),
                         ("3.0 deg mean normal error", "filters.md"), ("26.81 / 26.81 / 25.27", "command-line.md")]:
        assert number in docs[page], (number, page)
    assert np.sum([("## Layout" in t) for t in docs.values()]) == 1
