"""A known noise level instead of the estimate: ``--noise RHO[h][,L]``, ``noise:`` in pipelines, ``given_noise_model``."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

import meshdenoise as md
from meshdenoise.cli import cli
from meshdenoise.io import load_mesh, save_mesh
from meshdenoise.pipeline.mlx import mlx_to_steps, steps_to_mlx
from meshdenoise.pipeline.noise_option import NoiseOption, parse_noise_option
from meshdenoise.shapes import icosphere
from meshdenoise.tuning import choose_parameters, given_noise_model


def edge_length_by_hand(V, F):
    """Mean length of the unique undirected edges, from the faces alone."""
    e = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    e = np.unique(e, axis=0)
    return float(np.linalg.norm(V[e[:, 0]] - V[e[:, 1]], axis=1).mean())


@pytest.mark.parametrize("text, expected", [
    ("0.002", NoiseOption(0.002)),
    ("0.4h", NoiseOption(0.4, True)),
    ("0.4h,2", NoiseOption(0.4, True, 2.0)),
    (" 1e-3 , 1.5 ", NoiseOption(1e-3, False, 1.5)),
    (".5h", NoiseOption(0.5, True)),
    (0.25, NoiseOption(0.25)),
    (3, NoiseOption(3.0)),
])
def test_the_noise_option_reads_level_unit_and_correlation_length(text, expected):
    assert parse_noise_option(text) == expected


@pytest.mark.parametrize("text", ["x", "0.4x", "0.4h,", "0.4hh", ",2", "-1", "0.4h,-2", "nan", "inf", True, [0.1], None,
                                  float("nan"), -0.5])
def test_a_bad_noise_option_is_a_value_error_naming_where_and_the_syntax(text):
    with pytest.raises(ValueError, match=r"^step 2: noise: .*RHO\[h\]\[,L\]"):
        parse_noise_option(text, "step 2: noise")


def test_a_level_in_edge_lengths_is_that_many_mean_edge_lengths():
    V, F = icosphere(2)
    V = V * 3.0
    h = edge_length_by_hand(V, F)
    model = parse_noise_option("0.4h").model(V, F)
    assert model.rho == pytest.approx(0.4 * h, rel=1e-12) and not model.correlated
    assert parse_noise_option("0.01").model(V, F).rho == 0.01


def test_given_noise_model_is_built_as_the_estimate_builds_it_and_checks_its_values():
    V, F = icosphere(3)
    Vn = md.add_normal_noise((V, F), 0.02, seed=0)[0]
    model = given_noise_model((Vn, F), 0.02, 2.0)
    assert model.correlated and model.correlation_length == 2.0 and model.V.shape == Vn.shape
    Z = np.random.default_rng(0).choice([-1.0, 1.0], size=(Vn.shape[0], 4))
    Y = model.colour(Z, 1.0)
    assert np.sum(Y * Y) == pytest.approx(Vn.shape[0], rel=1e-12)  # tr(Sigma) = n, the model's normalisation
    # correlated: neighbouring vertices' coloured probes agree far more than the raw ones
    e = np.unique(np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]]]), axis=1), axis=0)
    corr = np.mean(Y[e[:, 0]] * Y[e[:, 1]]) / np.mean(Y * Y)
    assert corr > 0.5
    assert not given_noise_model((Vn, F), 0.02).correlated
    with pytest.raises(ValueError, match="'rho' = -1"):
        given_noise_model((Vn, F), -1.0)
    with pytest.raises(TypeError, match="correlation_length must be a number"):
        given_noise_model((Vn, F), 0.02, "2")


@pytest.fixture
def noisy_sphere_file(tmp_path):
    V, F = icosphere(3)
    Vn = md.add_normal_noise((V, F), 0.02, seed=1)[0]
    return save_mesh(tmp_path / "sphère [a].ply", Vn, F), Vn, F


def test_cli_dry_run_uses_the_given_level_in_edge_lengths(noisy_sphere_file):
    src, Vn, F = noisy_sphere_file
    h = edge_length_by_hand(Vn, F)
    result = CliRunner().invoke(cli, ["denoise", str(src), "--dry-run", "--method", "sobolev_bilaplacian",
                                      "--noise", "0.5h"])
    assert result.exit_code == 0, result.output
    mu = choose_parameters((Vn, F), "sobolev_bilaplacian", noise=0.5 * h, criterion="normals")["mu"]  # as denoise(method=)
    assert f"mu={mu!r}" in result.output and "given by --noise" in result.output


def test_a_larger_given_level_smooths_more():
    V, F = icosphere(3)
    Vn = md.add_normal_noise((V, F), 0.02, seed=2)[0]
    mus = [choose_parameters((Vn, F), "sobolev_bilaplacian", noise=parse_noise_option(t).model(Vn, F))["mu"]
           for t in ("0.1h", "0.3h", "1h")]
    assert mus[0] < mus[1] < mus[2]


@pytest.mark.parametrize("args, message", [
    (["--noise", "0.3x"], "error: --noise: '0.3x' is not understood; give RHO[h][,L]"),
    (["--noise", "-1"], "error: --noise: '-1': the level must be a finite number >= 0"),
    (["--noise", "0.3h", "--method", "sobolev", "--defaults"],
     "error: --noise 0.3h: the noise level is used only by a filter's own rule, and --defaults chooses none"),
    (["--noise", "0.3h"], "error: --noise 0.3h: the noise level is used only by a filter's own rule"),
    (["--dry-run", "--noise", "0.3h"], "with no method the default reads the noise from held-out vertices"),
])
def test_cli_bad_noise_is_one_line_and_exit_2(noisy_sphere_file, tmp_path, args, message):
    src, _, _ = noisy_sphere_file
    result = CliRunner().invoke(cli, ["denoise", str(src), str(tmp_path / "o.ply"), *args])
    assert result.exit_code == 2, result.output
    assert result.output.strip() == result.output.strip().splitlines()[0] and message in result.output
    assert not (tmp_path / "o.ply").exists()


def test_pipeline_noise_option_for_automatic_parameters(noisy_sphere_file, tmp_path):
    src, Vn, F = noisy_sphere_file
    out = tmp_path / "out"
    p = tmp_path / "p.yaml"
    p.write_text(f"inputs: '{src.name}'\noutput_dir: {out}\nsteps:\n"
                 "  - sobolev_bilaplacian: {parameters: auto, noise: '0.5h'}\n  - save: {path: a.ply}\n")
    result = CliRunner().invoke(cli, ["run", str(p), "--serial"])
    assert result.exit_code == 0, result.output
    mu = choose_parameters((Vn, F), "sobolev_bilaplacian", noise=0.5 * edge_length_by_hand(Vn, F))["mu"]
    np.testing.assert_allclose(load_mesh(out / "a.ply").V, md.apply_filter("sobolev_bilaplacian", (Vn, F), mu=mu)[0], atol=1e-9)


@pytest.mark.parametrize("step, expected", [
    ("  - sobolev: {noise: 0.01}\n", "step 1 'sobolev': noise: the noise level is used only to choose parameters"),
    ("  - sobolev: {parameters: auto, noise: 'lots'}\n", "noise: 'lots' is not understood"),
    ("  - denoise: {noise: 0.01}\n", "'noise' needs method: the default reads the noise from held-out vertices"),
    ("  - denoise: {method: sobolev, defaults: true, noise: 0.01}\n", "noise says how the parameters are chosen and "
     "defaults: true chooses none"),
])
def test_pipeline_bad_noise_option_names_file_line_step(noisy_sphere_file, tmp_path, step, expected):
    src, _, _ = noisy_sphere_file
    p = tmp_path / "p.yaml"
    p.write_text(f"inputs: '{src.name}'\noutput_dir: {tmp_path / 'out'}\nsteps:\n{step}  - save: {{path: x.ply}}\n")
    result = CliRunner().invoke(cli, ["run", str(p)])
    assert result.exit_code == 2, result.output
    assert f"{p}:4" in result.output and expected in result.output
    assert not (tmp_path / "out").exists()


def test_noise_option_survives_a_filter_script_round_trip():
    steps = [{"sobolev": {"parameters": "auto", "noise": "0.4h,2"}}, {"taubin": {"parameters": "auto", "noise": 0.01}}]
    assert mlx_to_steps(steps_to_mlx(steps)) == steps
