"""Each kind of bad input gets a clear error or a defined, documented behaviour."""

import numpy as np
import pytest

import meshdenoise as md
from meshdenoise.shapes import grid, icosphere

FILTERS = [("filtering", {"iterations": 3}), ("heat", {"tau": 0.5, "time": 2}), ("sobolev", {"mu": 2.0})]


@pytest.mark.parametrize("name,params", FILTERS)
def test_isolated_and_unreferenced_vertices_stay_put(name, params):
    V, F = icosphere(2)
    V2 = np.vstack([V, [[5.0, 5, 5], [7.0, 7, 7]]])
    F2 = np.vstack([F, [[len(V) + 1] * 3]])  # last vertex only in a degenerate "point" face
    out = md.apply_filter(name, (V2, F2), **params)[0]
    np.testing.assert_array_equal(out[-2:], V2[-2:])
    np.testing.assert_allclose(out[:-2], md.apply_filter(name, (V, F), **params)[0], atol=1e-12)


@pytest.mark.parametrize("name,params", FILTERS)
def test_duplicate_and_degenerate_faces_change_nothing(name, params):
    V, F = icosphere(2)
    a, b, c = F[0]
    F2 = np.vstack([F, F[:10], [[a, a, b]], [[c, b, c]]])  # degenerate faces on existing edges
    np.testing.assert_allclose(md.apply_filter(name, (V, F2), **params)[0], md.apply_filter(name, (V, F), **params)[0], atol=1e-12)


def test_zero_area_faces_do_not_make_nan():
    V, F = grid(5, 5)
    V = V.copy()
    V[6] = V[7]  # two vertices on top of each other: zero-area faces, zero-length edges
    for name, params in FILTERS:
        assert np.isfinite(md.apply_filter(name, (V, F), **params)[0]).all()
    assert np.isfinite(md.filtering((V, F), weights="inverse_distance", iterations=3)[0]).all()
    assert np.isfinite(md.add_normal_noise((V, F), rho=0.1, seed=0)[0]).all()


@pytest.mark.parametrize(
    "V,F,exc,match",
    [
        (np.zeros((0, 3)), np.zeros((0, 3), int), ValueError, "no vertices"),
        (np.random.rand(5, 3), np.zeros((0, 3), int), ValueError, "no faces"),
        (np.random.rand(5, 2), [[0, 1, 2]], ValueError, r"shape \(n, 3\)"),
        (np.random.rand(5, 3), [[0, 1, 2, 3]], ValueError, r"shape \(m, 3\)"),
        (np.random.rand(5, 3), [[0, 1, 5]], ValueError, "outside 0..4"),
        (np.random.rand(5, 3), [[0, -1, 2]], ValueError, "outside 0..4"),
        (np.random.rand(5, 3), [[0.0, 1.0, 2.0]], TypeError, "integer"),
        (np.array([["a", "b", "c"]] * 3), [[0, 1, 2]], TypeError, "numeric"),
        (np.array([[0, 0, 0], [1, 0, np.nan], [0, 1, 0]]), [[0, 1, 2]], ValueError, "vertex 1"),
        (np.array([[0, 0, 0], [1, 0, 0], [0, np.inf, 0]]), [[0, 1, 2]], ValueError, "NaN or infinite"),
    ],
)
def test_bad_arrays_raise_clear_errors(V, F, exc, match):
    for name, params in FILTERS:
        with pytest.raises(exc, match=match):
            md.apply_filter(name, (V, F), **params)


@pytest.mark.parametrize(
    "name,params,exc,match",
    [
        ("filtering", {"iterations": -1}, ValueError, r"'iterations' = -1 is out of range: 0 <= iterations"),
        ("filtering", {"iterations": 2.5}, TypeError, "must be an int"),
        ("filtering", {"iterations": True}, TypeError, "must be an int"),
        ("filtering", {"weights": "cotan"}, ValueError, r"'weights' = 'cotan' is not allowed: one of"),
        ("filtering", {"weights": "meshlab_"}, ValueError, "did you mean 'meshlab'"),
        ("filtering", {"lam": 1.5}, ValueError, r"'lam' = 1.5 is out of range: 0 < lam <= 1"),
        ("filtering", {"boundary": False}, ValueError, "applies only to weights='meshlab'"),
        ("filtering", {"iteration": 3}, TypeError, "unknown parameter 'iteration' \\(did you mean 'iterations'\\?\\)"),
        ("heat", {"tau": 0.0}, ValueError, r"'tau' = 0.0 is out of range: 0 < tau <= 2"),
        ("heat", {"tau": 2.5}, ValueError, "out of range"),
        ("heat", {"time": -1.0}, ValueError, r"'time' = -1.0 is out of range: 0 <= time"),
        ("heat", {"time": float("nan")}, ValueError, "must be finite"),
        ("sobolev", {"mu": -0.1}, ValueError, r"'mu' = -0.1 is out of range: 0 <= mu"),
        ("sobolev", {"mu": "big"}, TypeError, "must be a float"),
    ],
)
def test_parameter_validation_names_parameter_value_and_range(name, params, exc, match):
    V, F = icosphere(1)
    with pytest.raises(exc, match=match):
        md.apply_filter(name, (V, F), **params)


def test_unknown_filter_suggests_a_name():
    with pytest.raises(KeyError, match="did you mean 'sobolev'"):
        md.get_filter("sobolv")


def test_heat_tau_between_one_and_bound_is_accepted_on_non_bipartite_mesh():
    V, F = icosphere(2)
    lam = md.get_operators(F, len(V)).lambda_max()
    assert lam < 2
    md.heat((V, F), tau=1.0 + 0.5 * (2 / lam - 1), time=3)


# --- the command line and pipelines on bad input --------------------------------------------------------
# Every case: exit code 2, one line naming the file / step / parameter, no traceback, nothing written,
# the input unchanged. Cases are counted in docs/reliability.md.

import hashlib  # noqa: E402
from pathlib import Path  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import re  # noqa: E402
import socket  # noqa: E402
import time  # noqa: E402

from click.testing import CliRunner  # noqa: E402
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from meshdenoise.cli import cli  # noqa: E402
from meshdenoise.io import load_mesh, save_arrays  # noqa: E402
from meshdenoise.pipeline.sweep import MAX_SETTINGS  # noqa: E402
from meshdenoise.registry import MAX_ITERATIONS, ParameterError, parse_number  # noqa: E402


def _cli(*args):
    return CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=True)


def _one_line_error(result, *needles, code=2):
    """Exit ``code``, no traceback or uncaught exception, a single ``error:`` line containing every needle."""
    assert result.exception is None or isinstance(result.exception, SystemExit), (
        f"uncaught {type(result.exception).__name__}: {result.exception}"
    )
    text = result.output + result.stderr
    assert "Traceback" not in text and "Warning" not in text, text
    assert result.exit_code == code, text
    errors = [line for line in result.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1, result.stderr
    for needle in needles:
        assert needle in errors[0], (needle, errors[0])
    return errors[0]


def _sha(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture
def mesh_file(tmp_path):
    V, F = icosphere(1)
    return save_arrays(tmp_path / "sphere.ply", V, F)


def _pipeline(tmp_path, body: str, name: str = "p.yaml"):
    path = tmp_path / name
    path.write_text(body, encoding="utf-8")
    return path


# item 9: scientific notation, one conversion for --param, --set and YAML -------------------------------
@settings(max_examples=200, deadline=None)
@given(st.floats(allow_nan=False, allow_infinity=False), st.sampled_from(["{:e}", "{:E}", "{!r}", "{:.3e}", " {:g} "]))
def test_parse_number_reads_every_float_text_as_float_does(x, fmt):
    text = fmt.format(x)
    assert parse_number(text, float) == float(text)


@pytest.mark.parametrize("text,value", [("1e3", 1000), ("10", 10), ("-2E1", -20), ("1_000", 1000), ("7.0", 7),
                                        ("123456789012345678901234567890", 123456789012345678901234567890)])
def test_parse_number_takes_integral_texts_for_ints(text, value):
    assert parse_number(text, int) == value and type(parse_number(text, int)) is int


@pytest.mark.parametrize("text", ["1.5", "1e-3", "nan", "inf", "abc", "", "True"])
def test_parse_number_refuses_fractional_or_non_numeric_ints(text):
    with pytest.raises(TypeError):
        parse_number(text, int)


def test_scientific_notation_through_param_set_and_yaml_gives_the_same_mesh(tmp_path, mesh_file):
    V, F = load_mesh(mesh_file).V, load_mesh(mesh_file).F
    expected = md.sobolev((V, F), mu=0.001)[0]
    r = _cli("denoise", mesh_file, tmp_path / "a.ply", "--method", "sobolev", "--param", "mu=1e-3")
    assert r.exit_code == 0, r.stderr
    yaml_text = f"inputs: {mesh_file}\noutput_dir: {tmp_path}\nsteps:\n  - sobolev: {{mu: MU}}\n  - save: {{path: NAME}}\n"
    _pipeline(tmp_path, yaml_text.replace("MU", "1e-3").replace("NAME", "b.ply"), "yaml.yaml")
    _pipeline(tmp_path, yaml_text.replace("MU", '"${mu}"').replace("NAME", "c.ply"), "set.yaml")
    assert _cli("run", tmp_path / "yaml.yaml").exit_code == 0
    assert _cli("run", tmp_path / "set.yaml", "--set", "mu=1e-3").exit_code == 0
    for name in "abc":
        np.testing.assert_allclose(load_mesh(tmp_path / f"{name}.ply").V, expected, rtol=0, atol=1e-6)  # float32 PLY


def test_scientific_notation_for_int_parameters_of_ours_and_pymeshlab(tmp_path, mesh_file):
    body = (f"inputs: {mesh_file}\noutput_dir: {tmp_path}\nsteps:\n  - filtering: {{iterations: 2e0}}\n"
            "  - apply_coord_laplacian_smoothing: {stepsmoothnum: 1e0}\n  - save: {path: o.ply}\n")
    r = _cli("run", _pipeline(tmp_path, body))
    assert r.exit_code == 0, r.stderr
    r = _cli("run", _pipeline(tmp_path, body.replace("2e0", "2.5e0")))
    _one_line_error(r, "'iterations'", "must be an int")


# item 10: resource bombs are refused before allocating -------------------------------------------------
def test_sweep_of_a_billion_settings_is_refused_under_check_before_expanding(tmp_path, mesh_file):
    sweep = ", ".join(f"v{i}: *a" for i in range(9))
    body = f"variables: {{a: &a [1, 2, 3, 4, 5, 6, 7, 8, 9, 10]}}\ninputs: {mesh_file}\nsteps: [sobolev]\nsweep: {{{sweep}}}\n"
    path = _pipeline(tmp_path, body)
    assert path.stat().st_size < 250
    t0 = time.perf_counter()
    line = _one_line_error(_cli("run", path, "--check"), "p.yaml:4", "1000000000 settings", str(MAX_SETTINGS))
    assert time.perf_counter() - t0 < 10, line


def test_billion_laughs_and_deep_nesting_are_refused(tmp_path, mesh_file):
    levels = "".join(f"  a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 10)}]\n" for i in range(1, 9))
    body = f"variables:\n  a0: &a0 [x, x, x, x, x, x, x, x, x, x]\n{levels}inputs: {mesh_file}\nsteps: [sobolev]\n"
    _one_line_error(_cli("run", _pipeline(tmp_path, body), "--check"), "p.yaml:", "values (aliases counted)")
    deep = f"inputs: {mesh_file}\nsteps: " + "[" * 3000 + "]" * 3000 + "\n"
    _one_line_error(_cli("run", _pipeline(tmp_path, deep, "deep.yaml"), "--check"), "deep.yaml", "nested")
    recursive = f"inputs: {mesh_file}\nsteps: &s [sobolev, *s]\n"
    _one_line_error(_cli("run", _pipeline(tmp_path, recursive, "rec.yaml"), "--check"), "rec.yaml:", "itself")


@pytest.mark.parametrize(
    "method,param,match",
    [
        ("filtering", "iterations=1e25", "'iterations'"),
        ("taubin", "iterations=100000000", "'iterations'"),
        ("heat", "tau=1e-300", "'tau'"),
        ("heat", "time=1e300", "'time'"),
        ("sobolev", "tol=1e-300", "'tol'"),
    ],
)
def test_step_counts_above_the_limit_are_refused_at_once(tmp_path, mesh_file, method, param, match):
    t0 = time.perf_counter()
    r = _cli("denoise", mesh_file, tmp_path / "o.ply", "--method", method, "--defaults", "--param", param)
    _one_line_error(r, match)
    assert time.perf_counter() - t0 < 10 and not (tmp_path / "o.ply").exists()


def test_heat_limits_hold_in_the_api_for_both_methods():
    V, F = icosphere(1)
    with pytest.raises(ValueError, match=f"'time' = 1e\\+300 needs .* Chebyshev terms, more than the limit {MAX_ITERATIONS}"):
        md.heat((V, F), time=1e300, method="chebyshev")
    with pytest.raises(ValueError, match=r"ceil\(time / tau\) = 1e\+301 Euler steps"):
        md.heat((V, F), tau=1e-300)
    md.heat((V, F), tau=1.0, time=MAX_ITERATIONS)  # the limit itself is allowed (100000 steps on 42 vertices)


# item 11: in-range parameters that fail late -----------------------------------------------------------
def test_sobolev_with_huge_mu_names_the_filter_and_parameter():
    V, F = icosphere(1)
    with pytest.raises(ParameterError, match=r"filter 'sobolev' with mu=1e\+20.*not positive definite"):
        md.sobolev((V, F), mu=1e20)


def test_sobolev_huge_mu_in_a_pipeline_is_bad_input(tmp_path, mesh_file):
    body = f"inputs: {mesh_file}\noutput_dir: {tmp_path / 'out'}\nsteps:\n  - sobolev: {{mu: 1e20}}\n  - save: {{path: o.ply}}\n"
    r = _cli("run", _pipeline(tmp_path, body))
    assert r.exit_code == 2 and "mu=1e+20" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "out" / "o.ply").exists()


@pytest.mark.parametrize(
    "step,match",
    [
        ("apply_coord_laplacian_smoothing: {stepsmoothnum: 99999999999}", "'stepsmoothnum' = 99999999999 is out of range"),
        ("apply_coord_laplacian_smoothing: {stepsmoothnum: -99999999999}", "out of range"),
        ("open3d.filter_smooth_laplacian: {lambda_filter: 1e300}", "'lambda_filter' = 1e+300 is out of range"),
        ("open3d.filter_smooth_taubin: {mu: -1e300}", "'mu' = -1e+300 is out of range"),
        ("open3d.filter_smooth_simple: {number_of_iterations: 1e12}", "'number_of_iterations'"),
        ("taubin: {iterations: 1e8}", "'iterations'"),
        ("save: {path: '{stem:>99999999999}.ply'}", "width 99999999999"),
        ("save: {path: '{stem.__class__}.ply'}", "only plain names"),
        ("save: {path: '{0}.ply'}", "only plain names"),
        ("save: {path: '{stem!r}.ply'}", "conversions"),
        ("save: {path: '{stem:.9999}.ply'}", "precision 9999"),
    ],
)
def test_out_of_range_step_parameters_are_refused_before_running(tmp_path, mesh_file, step, match):
    body = f"inputs: {mesh_file}\noutput_dir: {tmp_path / 'out'}\nsteps:\n  - {step}\n  - save: {{path: o.ply}}\n"
    _one_line_error(_cli("run", _pipeline(tmp_path, body), "--check"), "p.yaml:4", match)


def test_a_step_with_non_finite_output_is_blamed_with_its_parameters(tmp_path, mesh_file):
    """add_noise rho=1e308 overflows: step 1 is blamed (not the filter after it), class 'parameter', exit 2."""
    out = tmp_path / "out"
    body = (f"inputs: {mesh_file}\noutput_dir: {out}\nsteps:\n  - add_noise: {{rho: 1e308}}\n  - sobolev: {{mu: 1}}\n"
            "  - save: {path: o.ply}\nsweep: {s: [0]}\n")  # a sweep: the results table is written
    digest = _sha(mesh_file)
    r = _cli("run", _pipeline(tmp_path, body), "--serial")
    assert r.exit_code == 2 and "Traceback" not in r.stderr and "Warning" not in r.stderr, r.stderr
    failed = [line for line in r.stderr.splitlines() if line.startswith("failed:")]
    assert len(failed) == 1 and "step 1 'add_noise' with rho=1e+308" in failed[0] and "non-finite" in failed[0]
    assert json.loads((out / "results.json").read_text())[0]["failure"] == "parameter"
    assert not (out / "o.ply").exists() and _sha(mesh_file) == digest


# item 7: write failures, encodings, scheduler, demo, report --------------------------------------------
def test_denoise_into_an_unwritable_place_exits_2_with_the_message(tmp_path, mesh_file):
    _one_line_error(_cli("denoise", mesh_file, "/proc/x.ply", "--method", "sobolev", "--defaults"), "/proc/x.ply")
    blocker = tmp_path / "file"
    blocker.write_text("a file where a folder should be")
    _one_line_error(_cli("denoise", mesh_file, blocker / "o.ply", "--method", "sobolev", "--defaults"), str(blocker))


def test_run_with_an_unwritable_output_folder_reports_every_task_and_the_table(tmp_path, mesh_file):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    body = f"inputs: [{mesh_file}, {mesh_file}]\nsteps:\n  - sobolev\n  - save: {{path: '{{index}}.ply'}}\n"
    r = _cli("run", _pipeline(tmp_path, body), "--serial", "--out", blocker / "out")
    _one_line_error(r, "results table not written", str(blocker))
    assert len([line for line in r.stderr.splitlines() if line.startswith("failed:")]) == 2
    assert blocker.read_text() == "x"


@pytest.mark.parametrize(
    "data,needles",
    [
        ("inputs: x.ply\n# caf\xe9\nsteps: [sobolev]\n".encode("latin-1"), ["p.yaml:2", "byte 0xe9 at byte offset 19"]),
        ("steps: [sobolev]\n".encode("utf-16-le"), ["p.yaml:1", "NUL byte at byte offset 1"]),  # UTF-16, no BOM
        (b"steps: [sobolev]\n\x00\xff\xfe", ["p.yaml:2", "byte 0xff at byte offset 18"]),
    ],
)
def test_pipeline_files_that_are_not_utf8_are_named_with_the_byte_offset(tmp_path, data, needles):
    (tmp_path / "p.yaml").write_bytes(data)
    _one_line_error(_cli("run", tmp_path / "p.yaml"), *needles)


@pytest.mark.parametrize("encoding", ["utf-16", "utf-8-sig", "utf-32"])
def test_pipeline_files_with_a_byte_order_mark_are_read(tmp_path, mesh_file, encoding):
    body = f"inputs: {mesh_file}\noutput_dir: {tmp_path / 'out'}\nsteps:\n  - sobolev: {{mu: 0.5}}  # café\n  - save: {{path: o.ply}}\n"
    (tmp_path / "p.yaml").write_bytes(body.encode(encoding))
    r = _cli("run", tmp_path / "p.yaml")
    assert r.exit_code == 0, r.stderr
    assert (tmp_path / "out" / "o.ply").is_file()


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.parametrize("address", ["not a url", "http://x", "tcp://", "tcp://127.0.0.1:99999", "CLOSED"])
def test_bad_or_unreachable_scheduler_fails_fast_in_one_line(tmp_path, mesh_file, address):
    address = f"tcp://127.0.0.1:{_closed_port()}" if address == "CLOSED" else address
    body = f"inputs: {mesh_file}\noutput_dir: {tmp_path / 'out'}\nsteps: [sobolev, {{save: {{path: o.ply}}}}]\n"
    t0 = time.perf_counter()
    _one_line_error(_cli("run", _pipeline(tmp_path, body), "--scheduler", address), "--scheduler", address)
    assert time.perf_counter() - t0 < 8
    assert not (tmp_path / "out").exists()


def test_a_listener_that_is_not_a_dask_scheduler_fails_fast(tmp_path, mesh_file):
    """Something accepts the connection and answers garbage: refused within the timeout, one line."""
    import threading

    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(4)
    stop = threading.Event()

    def answer():
        server.settimeout(0.2)
        while not stop.is_set():
            try:
                conn, _ = server.accept()
            except OSError:
                continue
            conn.sendall(b"HTTP/1.1 400 Bad Request\r\n\r\n" * 8)
            conn.close()

    thread = threading.Thread(target=answer, daemon=True)
    thread.start()
    try:
        address = f"tcp://127.0.0.1:{server.getsockname()[1]}"
        body = f"inputs: {mesh_file}\noutput_dir: {tmp_path / 'out'}\nsteps: [sobolev, {{save: {{path: o.ply}}}}]\n"
        t0 = time.perf_counter()
        _one_line_error(_cli("run", _pipeline(tmp_path, body), "--scheduler", address), "Dask scheduler")
        assert time.perf_counter() - t0 < 10
    finally:
        stop.set()
        thread.join()
        server.close()


@pytest.mark.parametrize(
    "text,needle",
    [
        ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
         "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 nan\n0 1 0\n3 0 1 2\n", "NaN"),
        ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
         "end_header\n0 0 0\n1 0 0\n0 1 0\n", "point cloud"),
    ],
)
def test_demo_on_a_nan_file_or_point_cloud_exits_2(tmp_path, text, needle):
    src = tmp_path / "bad.ply"
    src.write_text(text)
    _one_line_error(_cli("demo", "--mesh", src, "--out", tmp_path / "out"), "bad.ply", needle)
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_report_on_deeply_nested_json_exits_2(tmp_path):
    (tmp_path / "results.json").write_text("[" * 100000 + "]" * 100000)
    _one_line_error(_cli("report", tmp_path), str(tmp_path), "nested too deeply")
    assert not (tmp_path / "report.html").exists()


# item 13: messages -------------------------------------------------------------------------------------
@pytest.mark.parametrize("option,value", [("--view", "nan,nan"), ("--view", "inf,0"), ("--view", "0,-inf"),
                                          ("--vmax", "nan"), ("--vmax", "inf"), ("--size", "0x0"), ("--size", "99999x99999")])
def test_render_options_must_be_finite_and_bounded(tmp_path, mesh_file, option, value):
    r = _cli("render", mesh_file, mesh_file, "--reference", mesh_file, "--png", tmp_path / "x.png", option, value)
    assert r.exit_code == 2 and option in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert not (tmp_path / "x.png").exists()


def test_info_json_is_strict_json(mesh_file):
    r = _cli("info", "--json", mesh_file)
    json.loads(r.output, parse_constant=lambda c: pytest.fail(f"{c} is not JSON"))


# filters --json ---------------------------------------------------------------------------------------
def test_filters_json_lists_every_filter_and_step_as_the_registry_has_them():
    from meshdenoise.pipeline.steps import BUILTIN_STEPS, OPEN3D_OPS

    r = _cli("filters", "--json")
    assert r.exit_code == 0
    doc = json.loads(r.output, parse_constant=lambda c: pytest.fail(f"{c} is not JSON"))
    listed = {f["name"]: f for f in doc["filters"]}
    assert sorted(listed) == sorted(s.name for s in md.list_filters())
    for spec in md.list_filters():
        params = listed[spec.name]["params"]
        assert [p["name"] for p in params] == [p.name for p in spec.params]
        for p, q in zip(spec.params, params):
            assert q["type"] == p.kind.__name__ and q["low"] == p.low and q["high"] == p.high
            assert q["default"] == (list(p.default) if isinstance(p.default, tuple) else p.default)
            assert q["choices"] == (None if p.choices is None else list(p.choices))
            assert (q["low_open"], q["high_open"]) == (p.low_open, p.high_open)
            p.check(q["default"])  # every default is a legal value
    steps = {s["name"]: s for s in doc["steps"]}
    assert set(BUILTIN_STEPS) | {f"open3d.{k}" for k in OPEN3D_OPS} == set(steps)
    assert [p["name"] for p in steps["add_noise"]["params"]] == ["rho", "relative", "seed"]
    from meshdenoise.pipeline.steps import COMMON

    assert {o["name"] for o in doc["filter_options"]} == COMMON  # every option a pipeline's filter step takes
    assert listed["filtering"]["params"][0]["high"] == MAX_ITERATIONS
    from meshdenoise.tuning.choose import normal_filters

    for spec in md.list_filters():  # the automatic rule: what it tunes, the criteria it takes, its default
        auto = listed[spec.name]["auto"]
        if spec.auto is None:
            assert auto is None
            continue
        assert auto["tunes"] == list(spec.auto.tunes)
        assert auto["criteria"] == (["sure", "normals"] if spec.name in normal_filters() else ["sure"])
        assert auto["default_criterion"] == auto["criteria"][-1]
    assert listed["sobolev_normal"]["auto"]["criteria"] == ["sure"] and listed["taubin"]["auto"]["criteria"][-1] == "normals"


# item 1: square brackets in names and content are printed as they are ----------------------------------
_COMPONENT = st.text(alphabet="[]ab /_-=", min_size=1, max_size=10).map(lambda s: s.strip("/ ")).filter(
    lambda s: s and all(part not in ("", ".", "..") and part.strip() == part for part in s.split("/")))
NAMED = ["scan [final]", "x[/bad]", "r[/b]", "[bold]red[/bold]", "[link=http://x]a", "[/]", "a[b]c[/d]e", "[[x]]"]


def _bracket_roundtrip(root, name: str) -> None:
    """info, denoise, run and run --check on an input called ``name`` (with brackets), writing to bracketed paths."""
    V, F = icosphere(1)
    src = root / "in" / f"{name}.ply"
    src.parent.mkdir(parents=True, exist_ok=True)
    save_arrays(src, V, F)
    digest = _sha(src)
    flat = lambda text: re.sub(r"\s+", "", text)  # noqa: E731  (a table may wrap a long title)

    r = _cli("info", src)
    assert r.exit_code == 0 and flat(str(src)) in flat(r.output), r.output
    dst = root / "out" / f"{name}.ply"
    r = _cli("denoise", src, dst, "--method", "sobolev", "--defaults")
    assert r.exit_code == 0, r.stderr
    assert f"{dst}: {len(V)} vertices" in r.output and dst.is_file()
    out = root / "run"
    body = f"inputs: [{json.dumps(str(src))}]\noutput_dir: {json.dumps(str(out))}\nsteps:\n  - sobolev: {{mu: '${{mu}}'}}\n  - save: {{path: '{{stem}}_o.ply'}}\nsweep: {{mu: [1]}}\n"
    pipe = root / "in" / f"{name}.yaml"
    pipe.write_text(body)
    r = _cli("run", pipe, "--check")
    assert r.exit_code == 0 and f"{src.name} mu=1: sobolev, save" in r.output, r.output
    r = _cli("run", pipe, "--serial")
    assert r.exit_code == 0, r.stderr
    assert (out / f"{src.stem}_o.ply").is_file()
    assert json.loads((out / "results.json").read_text())[0]["input"] == str(src)
    assert _sha(src) == digest


@pytest.mark.parametrize("name", NAMED)
def test_bracketed_names_are_kept_by_every_mesh_command(tmp_path, name):
    _bracket_roundtrip(tmp_path, name)


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(name=_COMPONENT)
def test_random_bracketed_names_are_kept(tmp_path_factory, name):
    _bracket_roundtrip(tmp_path_factory.mktemp("br"), name)


def test_bracketed_text_in_messages_and_failures_is_shown_and_the_batch_goes_on(tmp_path):
    """A corrupt file whose content has brackets among good ones: its message is printed whole, the others run."""
    V, F = icosphere(1)
    good = [save_arrays(tmp_path / f"good [{k}].ply", V, F) for k in range(2)]
    bad = tmp_path / "bad [final].obj"
    bad.write_text("v 0 0 0\nv [/x] 0 0\nv 0 1 0\nf 1 2 3\n")
    out = tmp_path / "o[/b]"
    body = (f"inputs: {json.dumps([str(p) for p in (good[0], bad, good[1])])}\noutput_dir: {json.dumps(str(out))}\n"
            "steps:\n  - sobolev\n  - save: {path: '{stem}.ply'}\n")
    r = _cli("run", _pipeline(tmp_path, body), "--serial")
    assert r.exit_code == 2 and "Traceback" not in r.stderr
    failed = [line for line in r.stderr.splitlines() if line.startswith("failed:")]
    assert len(failed) == 1 and str(bad) in failed[0] and "[/x]" in failed[0], r.stderr
    rows = json.loads((out / "results.json").read_text())
    assert [row["status"] for row in rows] == ["ok", "failed", "ok"]
    assert all((out / f"good [{k}].ply").is_file() for k in range(2))
    r = _cli("denoise", bad, tmp_path / "x.ply", "--method", "sobolev", "--defaults")
    _one_line_error(r, str(bad), "[/x]")
    r = _cli("info", bad)
    _one_line_error(r, str(bad), "[/x]")


def test_bracketed_names_in_the_other_commands(tmp_path):
    """show, render, report, demo, mlx2yaml and yaml2mlx with [ ] in every path they print."""
    V, F = icosphere(1)
    src = save_arrays(tmp_path / "m [a].ply", V, F)
    png = tmp_path / "r[/b]"
    png.mkdir(parents=True)
    r = _cli("render", src, src, "--reference", src, "--png", png / "x [1].png", "--backend", "matplotlib", "--size", "64x64")
    assert r.exit_code == 0 and str(png / "x [1].png") in r.output, r.output + r.stderr
    r = _cli("show", src, "--png", png / "s [2].png", "--backend", "matplotlib", "--size", "64x64")
    assert r.exit_code == 0 and str(png / "s [2].png") in r.output, r.output + r.stderr
    run_dir = tmp_path / "run [x]"
    run_dir.mkdir()
    (run_dir / "results.json").write_text(json.dumps([{"input": "[bold]a[/bold].ply", "status": "ok", "snr": 1.0}]))
    r = _cli("report", run_dir)
    assert r.exit_code == 0 and str(run_dir / "report.html") in r.output, r.output + r.stderr
    yaml_path = tmp_path / "p [1].yaml"
    yaml_path.write_text("inputs: x.ply\nsteps:\n  - apply_coord_laplacian_smoothing: {stepsmoothnum: 2}\n")
    mlx = tmp_path / "s [/x].mlx"
    r = _cli("yaml2mlx", yaml_path, "-o", mlx)
    assert r.exit_code == 0 and str(mlx) in r.stderr and mlx.is_file(), r.stderr
    r = _cli("mlx2yaml", mlx, "-o", tmp_path / "back [2].yaml")
    assert r.exit_code == 0 and str(tmp_path / "back [2].yaml") in r.stderr, r.stderr
    demo_out = tmp_path / "demo [out]"
    r = _cli("demo", "--mesh", src, "--out", demo_out)
    assert r.exit_code == 0 and f"meshes written to {demo_out}/" in r.output and "m [a].ply" in r.output, r.output


def test_no_numpy_warning_before_the_error_line(tmp_path, mesh_file):
    """RuntimeWarnings of an overflowing step are not printed: the one error line says what happened."""
    r = _cli("denoise", mesh_file, tmp_path / "o.ply", "--method", "sobolev", "--param", "mu=1e20")
    line = _one_line_error(r, "'sobolev'", "mu=1e+20")
    assert math.isfinite(len(line))


def test_a_full_disk_while_writing_is_exit_2_with_the_message(tmp_path, mesh_file, monkeypatch):
    """ENOSPC from the writer (simulated: no file system to fill here) in denoise, in a task and in the results table."""
    import errno

    import meshdenoise.io
    import meshdenoise.pipeline.sweep

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(meshdenoise.io, "save_mesh", full)
    _one_line_error(_cli("denoise", mesh_file, tmp_path / "o.ply", "--method", "sobolev", "--defaults"), "No space left on device")
    monkeypatch.setattr(meshdenoise.pipeline.sweep, "atomic_path", full)
    body = f"inputs: {mesh_file}\noutput_dir: {tmp_path / 'out'}\nsteps: [sobolev, {{save: {{path: o.ply}}}}]\nsweep: {{s: [0]}}\n"
    r = _cli("run", _pipeline(tmp_path, body), "--serial")
    _one_line_error(r, "results table not written", "No space left on device")
    assert "failed:" in r.stderr and "No space left on device" in r.stderr.split("failed:")[1]
    assert not (tmp_path / "o.ply").exists() and not (tmp_path / "out" / "o.ply").exists()


@pytest.mark.parametrize(
    "step,match",
    [
        ("sobolev: {mu: 1" + "0" * 400 + "}", "'mu' = 1" + "0" * 400 + " is too large for a float"),
        ("add_noise: {seed: -1}", "'seed' = -1 is out of range"),
        ("two_stage: {iterations: 100000, normal_iterations: 1000}", None),  # the product is checked when run
        ("apply_coord_laplacian_smoothing: {stepsmoothnum: 1" + "0" * 400 + "}", "out of range"),
        ("apply_coord_taubin_smoothing: {lambda_: 1" + "0" * 400 + "}", "too large for a float"),
    ],
)
def test_more_out_of_range_values_are_exit_2(tmp_path, mesh_file, step, match):
    body = f"inputs: {mesh_file}\noutput_dir: {tmp_path / 'out'}\nsteps:\n  - {step}\n  - save: {{path: o.ply}}\n"
    r = _cli("run", _pipeline(tmp_path, body), "--serial")
    if match is None:
        assert r.exit_code == 2 and "110000 passes, more than the limit" not in r.stderr and "passes, more than" in r.stderr
        assert "Traceback" not in r.stderr
    else:
        _one_line_error(r, "p.yaml:4", match)
    assert not (tmp_path / "out" / "o.ply").exists()


@pytest.mark.parametrize("args,match", [(["--noise", "1e308"], "--noise"), (["--seed", "-1"], "--seed")])
def test_demo_options_out_of_range(tmp_path, args, match):
    r = _cli("demo", "--out", tmp_path / "out", *args)
    assert r.exit_code == 2 and match in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "out").exists()


def test_too_many_local_workers_are_refused(tmp_path, mesh_file):
    body = f"inputs: {mesh_file}\noutput_dir: {tmp_path / 'out'}\nsteps: [sobolev, {{save: {{path: o.ply}}}}]\n"
    _one_line_error(_cli("run", _pipeline(tmp_path, body), "--workers", "100000"), "--workers 100000")


def test_every_refused_corpus_file_under_a_bracketed_name_is_named_whole(tmp_path):
    """The broken-file corpus (tests/brokenmeshes.py) under names like "[bold]x[/bold] [final].ply":
    denoise and info stop with exit 2 and print the whole name; nothing is written."""
    from .brokenmeshes import cases

    refused = [c for c in cases() if c.expect == "refuse"]
    assert len(refused) >= 30
    bad = {}
    for k, case in enumerate(refused):
        src = tmp_path / f"[bold]{k}[" / f"bold] [{case.name}]{Path(case.name).suffix}"  # .../[bold]0[/bold] [x].ply
        src.parent.mkdir()
        src.write_bytes(case.data)
        out = tmp_path / f"out{k}"
        out.mkdir()
        for args in (["info", src], ["denoise", src, out / "o [/x].ply", "--method", "sobolev", "--defaults"]):
            r = _cli(*args)
            flat = re.sub(r"\s", "", r.stderr)
            if r.exit_code != 2 or re.sub(r"\s", "", str(src)) not in flat or "Traceback" in r.stderr:
                bad[f"{args[0]} {case.name}"] = (r.exit_code, r.stderr[-300:])
        assert list(out.iterdir()) == []
    assert bad == {}


def test_sweep_values_in_scientific_notation_are_numbers_in_the_results(tmp_path, mesh_file):
    out = tmp_path / "out"
    body = (f"inputs: {mesh_file}\noutput_dir: {out}\nsteps:\n  - sobolev: {{mu: '${{mu}}'}}\n"
            "  - save: {path: '{stem}_{mu:.0e}.ply'}\nsweep: {mu: [1e-3, 2E-2]}\n")
    r = _cli("run", _pipeline(tmp_path, body), "--serial")
    assert r.exit_code == 0, r.stderr
    rows = json.loads((out / "results.json").read_text())
    assert [row["mu"] for row in rows] == [0.001, 0.02]
    assert sorted(p.name for p in out.glob("*.ply")) == ["sphere_1e-03.ply", "sphere_2e-02.ply"]


def test_a_failed_factorisation_prints_one_line_and_no_cholmod_warning(tmp_path):
    """CHOLMOD prints its own warning through C's stdout; only our error line may reach the terminal."""
    import subprocess
    import sys

    from meshdenoise import save_mesh
    from meshdenoise.shapes import icosphere

    save_mesh(tmp_path / "s.ply", *icosphere(2))
    out = subprocess.run(
        [sys.executable, "-c", "from meshdenoise.cli import main; main()", "denoise", str(tmp_path / "s.ply"), str(tmp_path / "o.ply"),
         "--method", "sobolev", "--param", "mu=1e20"],
        capture_output=True, text=True, timeout=120,
    )
    lines = (out.stdout + out.stderr).strip().splitlines()
    assert out.returncode == 2 and len(lines) == 1 and "CHOLMOD" not in out.stdout + out.stderr, lines
    assert "mu=1e+20" in lines[0] and lines[0].startswith("error:")
    assert not (tmp_path / "o.ply").exists()


def test_factorisations_built_at_once_on_threads_leave_stdout_and_stderr_where_they_were(capfd):
    """Threads building factors at once (the default's rules side by side) share one redirection of descriptors 1
    and 2: afterwards both are the files they were (not a deleted temporary file), CHOLMOD's lines are dropped and
    every other line written meanwhile is written back."""
    import os
    import threading

    from meshdenoise.solvers import factor as solvers

    before = {fd: (os.fstat(fd).st_dev, os.fstat(fd).st_ino) for fd in (1, 2)}
    inside = threading.Barrier(3, timeout=10)

    def build(i):
        def factor():
            inside.wait()  # all three inside the redirection at once
            os.write(1, f"CHOLMOD warning: not positive definite {i}\nkept out {i}\n".encode())
            os.write(2, f"kept err {i}\n".encode())
            inside.wait()
            return i
        return solvers._without_cholmod_warnings(factor)

    got = {}
    threads = [threading.Thread(target=lambda i=i: got.setdefault(i, build(i))) for i in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert got == {0: 0, 1: 1, 2: 2}
    assert {fd: (os.fstat(fd).st_dev, os.fstat(fd).st_ino) for fd in (1, 2)} == before
    assert solvers._quiet["depth"] == 0 and solvers._quiet["saved"] == {}
    out, err = capfd.readouterr()
    assert "CHOLMOD" not in out + err
    assert sorted(out.splitlines()) == [f"kept out {i}" for i in range(3)]
    assert sorted(err.splitlines()) == [f"kept err {i}" for i in range(3)]
