"""``denoise`` means one thing in the API, on the command line and in a pipeline's ``denoise`` step.

With a method, every parameter the filter's own rule tunes and the caller did not give is chosen by
that rule; ``defaults`` (``--defaults``, ``defaults: true``) runs the filter's defaults instead. The
options every filter takes are declared once (``registry.COMMON_OPTIONS``).
"""

from __future__ import annotations

import inspect

import numpy as np
import pytest
from click.testing import CliRunner

import meshdenoise as md
from meshdenoise.cli import cli
from meshdenoise.io import load_mesh, save_mesh
from meshdenoise.registry import COMMON_OPTIONS, KEYWORD_OPTIONS, STEP_OPTIONS, ParameterError
from meshdenoise.shapes import icosphere


@pytest.fixture(scope="module")
def noisy():
    V, F = icosphere(3)
    Vn, _ = md.add_normal_noise((V, F), rho=0.02, seed=3)
    return Vn, F


def _run(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def test_method_alone_chooses_as_the_api_and_defaults_runs_the_filters_defaults(noisy, tmp_path):
    Vn, F = noisy
    src = save_mesh(tmp_path / "n.ply", Vn, F)
    (V_api, _), used = md.denoise((Vn, F), method="sobolev", return_params=True)
    assert set(used) >= {"mu"} and used["mu"] != md.get_filter("sobolev").param("mu").default
    r = _run("denoise", src, tmp_path / "a.ply", "--method", "sobolev")
    assert r.exit_code == 0, r.output
    assert "chosen automatically" in r.output and "(criterion normals)" in r.output
    np.testing.assert_allclose(load_mesh(tmp_path / "a.ply").V, V_api, atol=1e-9)

    (V_def, _), kept = md.denoise((Vn, F), method="sobolev", defaults=True, return_params=True)
    assert kept == {}
    np.testing.assert_allclose(V_def, md.apply_filter("sobolev", (Vn, F), boundary_motion="normal")[0])
    r = _run("denoise", src, tmp_path / "d.ply", "--method", "sobolev", "--defaults")
    assert r.exit_code == 0, r.output
    assert "chosen automatically" not in r.output
    np.testing.assert_allclose(load_mesh(tmp_path / "d.ply").V, V_def, atol=1e-9)


def test_the_pipeline_denoise_step_with_a_method_means_the_same(noisy, tmp_path):
    Vn, F = noisy
    src = save_mesh(tmp_path / "n.ply", Vn, F)
    p = tmp_path / "p.yaml"
    p.write_text(f"inputs: '{src.name}'\noutput_dir: {tmp_path / 'out'}\nsteps:\n"
                 "  - denoise: {method: sobolev}\n  - save: {path: a.ply}\n"
                 "  - denoise: {method: heat, defaults: true, label: h}\n  - save: {path: b.ply}\n")
    r = _run("run", p, "--serial")
    assert r.exit_code == 0, r.output
    first = md.denoise((Vn, F), method="sobolev")[0]
    np.testing.assert_allclose(load_mesh(tmp_path / "out" / "a.ply").V, first, atol=1e-9)
    second = md.denoise((first, F), method="heat", defaults=True)[0]
    np.testing.assert_allclose(load_mesh(tmp_path / "out" / "b.ply").V, second, atol=1e-9)


@pytest.mark.parametrize("step, message", [
    ("{method: sobolv}", "unknown filter 'sobolv' (did you mean 'sobolev'?)"),
    ("{method: sobolev, explain: true}", "explain says why the default chose its filter"),
    ("{method: sobolev, parameters: auto}", "chooses the parameters not given by itself"),
    ("{method: sobolev_normal, criterion: normals}", "criterion 'normals' is for the filters with a rule for it"),
    ("{method: sobolev, muu: 2}", "unknown parameter 'muu' (did you mean 'mu'?)"),
    ("{mu: 2}", "unknown parameter 'mu': the default chooses the filter and its parameters"),
    ("{defaults: true}", "'defaults' needs method"),
])
def test_bad_denoise_steps_are_refused_before_anything_runs(noisy, tmp_path, step, message):
    Vn, F = noisy
    src = save_mesh(tmp_path / "n.ply", Vn, F)
    p = tmp_path / "p.yaml"
    p.write_text(f"inputs: '{src.name}'\noutput_dir: {tmp_path / 'out'}\nsteps:\n  - denoise: {step}\n")
    r = _run("run", p, "--check")
    assert r.exit_code == 2 and message in r.output, r.output
    assert f"{p}:4" in r.output


@pytest.mark.parametrize("args, message", [
    (["--method", "sobolev", "--auto"], "error: no such option --auto: --method M chooses the parameters not given"),
    (["--defaults"], "error: --defaults: it runs a filter's own defaults: give --method M"),
    (["--method", "sobolev", "--defaults", "--criterion", "sure"], "--defaults chooses none"),
    (["--method", "sobolev", "--explain"], "error: --explain: it says why the default chose its filter"),
    (["--method", "sobolev", "--bogus"], "error: No such option '--bogus'"),
])
def test_usage_errors_of_denoise_are_one_line_exit_2(noisy, tmp_path, args, message):
    Vn, F = noisy
    src = save_mesh(tmp_path / "n.ply", Vn, F)
    r = _run("denoise", src, tmp_path / "o.ply", *args)
    assert r.exit_code == 2, r.output
    assert len(r.output.strip().splitlines()) == 1 and message in r.output, r.output
    assert "Usage:" not in r.output and not (tmp_path / "o.ply").exists()


def test_help_says_what_method_and_defaults_mean():
    text = " ".join(_run("denoise", "--help").output.split())
    assert "--auto" not in text
    assert "every other parameter its own rule tunes chosen for the mesh by that rule" in text
    assert "--defaults With --method: choose nothing, run the filter's own defaults" in text


def test_api_defaults_needs_a_method_and_chooses_nothing(noisy):
    Vn, F = noisy
    with pytest.raises(TypeError, match="defaults=True needs method="):
        md.denoise((Vn, F), defaults=True)
    with pytest.raises(TypeError, match="defaults=True chooses none"):
        md.denoise((Vn, F), method="sobolev", defaults=True, noise=0.01)
    _, used = md.denoise((Vn, F), method="sobolev", mu=0.3, return_params=True)
    assert used == {"mu": 0.3}  # every tuned parameter given: nothing to choose


def test_common_options_are_declared_once():
    names = [o.name for o in COMMON_OPTIONS]
    assert len(names) == len(set(names))
    assert KEYWORD_OPTIONS == {"pinned", "region", "preserve_volume", "operators", "boundary_motion"}
    assert STEP_OPTIONS == {"pinned", "region", "preserve_volume", "boundary_motion", "parameters", "noise", "criterion"}
    for spec in md.list_filters():  # every filter's signature: its parameters, then the keyword options
        sig = inspect.signature(spec.public)
        tail = [p for p in sig.parameters.values()][-len(KEYWORD_OPTIONS):]
        assert [(p.name, p.default) for p in tail] == [(o.name, o.default) for o in COMMON_OPTIONS if o.keyword]
    from meshdenoise.cli import filters_json
    from meshdenoise.pipeline.steps import COMMON, describe_steps

    assert {o["name"] for o in filters_json()["filter_options"]} == COMMON == STEP_OPTIONS
    sobolev = next(s for s in describe_steps() if s["name"] == "sobolev")
    assert {p["name"] for p in sobolev["params"]} >= STEP_OPTIONS


def test_a_cores_parameter_error_passes_as_it_is_and_other_failures_are_worded(noisy):
    from meshdenoise.registry import REGISTRY, Param, register

    Vn, F = noisy
    with pytest.raises(ParameterError, match=r"^parameter 'tau' = 1.9 is out of the stable range"):
        md.heat((Vn, F), tau=1.9)

    def core(V, F, *, ops, pinned, k, typed):
        if typed:
            raise ParameterError(f"parameter 'k' = {k!r} is too large for this mesh: use k <= 1")
        raise ValueError("matrix is singular")  # says no parameter: the registry words it

    try:
        run = register("_failing", params=[Param("k", float, 2.0), Param("typed", bool, True)], summary="test")(core)
        with pytest.raises(ParameterError, match=r"^parameter 'k' = 2.0 is too large for this mesh: use k <= 1$"):
            run((Vn, F))
        with pytest.raises(ParameterError, match=r"^filter '_failing' with k=2.0, typed=False failed on this mesh: "
                                                 r"matrix is singular \(a parameter is too large or too small for it\)"):
            run((Vn, F), typed=False)
    finally:
        REGISTRY.pop("_failing", None)


def test_no_page_pipeline_or_benchmark_uses_the_removed_auto_flag():
    import re
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent
    files = [root / "README.md", root / "Makefile", *(root / "docs").glob("*.md"), *(root / "pipelines").glob("*.yaml"),
             *(root / "benchmarks").glob("*.py"), *(root / "benchmarks" / "results").glob("*.txt"),
             *(root / "meshdenoise").rglob("*.py")]
    used = [f"{path.relative_to(root)}:{n}" for path in files if path.is_file()
            for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
            if re.search(r"--auto\b(?!-)", line) or re.search(r"['\"]--auto['\"]", line)]
    assert not [u for u in used if not u.startswith("meshdenoise/commands/pipeline.py")], used
