"""Package metadata agrees with the code: POT is a test-only dependency, the licence is declared once."""

import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _pyproject() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())


def _names(requirements: list[str]) -> set[str]:
    import re

    return {re.split(r"[\s<>=!~;\[]", r, maxsplit=1)[0].lower() for r in requirements}


def test_pot_is_a_dev_dependency_only():
    project = _pyproject()["project"]
    assert "pot" not in _names(project["dependencies"])
    assert "pot" in _names(project["optional-dependencies"]["dev"])


def test_the_package_and_every_filter_run_without_pot():
    """``import ot`` made to fail: the package, its plugins and the OT filter still work."""
    code = (
        "import sys; sys.modules['ot'] = None\n"
        "import meshdenoise as md\n"
        "from meshdenoise.shapes import icosphere\n"
        "V, F = icosphere(2)\n"
        "Vn, _ = md.add_normal_noise((V, F), rho=0.02, seed=0)\n"
        "for spec in md.list_filters():\n"
        "    md.apply_filter(spec.name, (Vn, F))\n"
        "Y, _ = md.sinkhorn((Vn, F), t=0.1)\n"
        "assert md.snr(V, Y) > md.snr(V, Vn)\n"
        "assert 'ot' not in [m for m in sys.modules if sys.modules[m] is not None]\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]


def test_licence_is_an_spdx_expression_with_its_file():
    project = _pyproject()["project"]
    assert project["license"] == "MIT"
    assert project["license-files"] == ["LICENSE"]
    assert (ROOT / "LICENSE").read_text().startswith("MIT License")
    build = _pyproject()["build-system"]["requires"]
    assert any(r.replace(" ", "") == "setuptools>=77" for r in build)  # the first to accept an SPDX string
