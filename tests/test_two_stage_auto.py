"""two_stage's keep_tangential step, its run iterator and its automatic rule, against computations written
here: numpy projections, runs of the filter one count at a time, held-out losses read by hand."""

from __future__ import annotations

import numpy as np
import pytest

from meshdenoise import add_normal_noise, snr
from meshdenoise.geometry import face_normals, vertex_normals
from meshdenoise.metrics import normal_error_deg
from meshdenoise.normal_filter import _corner_lists
from meshdenoise.operators import get_operators
from meshdenoise.plugins import two_stage as ts
from meshdenoise.registry import apply_filter, get_filter
from meshdenoise.shapes import box, grid, icosphere
from meshdenoise.tuning import choose_parameters
from meshdenoise.tuning.holdout import holdout, path_losses, region


def noisy_box(seed=3):
    V, F = box(12)
    rho = 0.3 / 11
    return V, add_normal_noise((V, F), rho, seed=seed)[0], F, rho


# --- the kernels ------------------------------------------------------------------------------
def test_restore_tangential_is_the_tangent_projection_of_the_move():
    from meshdenoise import kernels

    V, F = icosphere(2)
    rng = np.random.default_rng(0)
    Y = V + 0.05 * rng.standard_normal(V.shape)
    X = V + 0.05 * rng.standard_normal(V.shape)
    N = face_normals(X, F)
    ptr, corners = _corner_lists(np.asarray(F, dtype=np.int64), len(V))
    got = X.copy()
    kernels.restore_tangential(got, Y, N, ptr, corners)
    u = vertex_normals(X, F)  # written independently: normalised sum of the unit face normals
    R = Y - X
    expected = X + R - np.einsum("ij,ij->i", R, u)[:, None] * u
    np.testing.assert_allclose(got, expected, atol=1e-14)
    # the normal component of the move is kept, the tangential one undone
    np.testing.assert_allclose(np.einsum("ij,ij->i", got - X, u), 0.0, atol=1e-14)


def test_face_geometry_with_the_unit_helper_equals_numpy_bit_for_bit():
    from meshdenoise import kernels

    V, F = icosphere(2)
    X = V + 0.01 * np.random.default_rng(1).standard_normal(V.shape)
    X[F[0, 1]] = X[F[0, 0]]  # a zero-area face: zero normal
    X[F[0, 2]] = X[F[0, 0]]
    m = len(F)
    N, A, C = np.empty((m, 3)), np.empty(m), np.empty((m, 3))
    kernels.face_geometry(X, np.asarray(F, dtype=np.int64), N, A, C)
    np.testing.assert_array_equal(N, face_normals(X, F))
    assert not N[0].any()


# --- the filter with keep_tangential -----------------------------------------------------------
def test_outer_iterates_yield_the_runs_of_every_iteration_count():
    V, Vn, F, _ = noisy_box()
    ops = get_operators(F, len(V))
    for kt in (False, True):
        params = dict(normal_iterations=3, vertex_iterations=4, sigma_r=0.3, sigma_s=1.0, guidance="guided", keep_tangential=kt)
        got = list(ts.outer_iterates(Vn, ops, None, iterations=3, **params))
        assert len(got) == 3
        for k, X in enumerate(got, start=1):
            np.testing.assert_array_equal(X, apply_filter("two_stage", (Vn, F), iterations=k, **params)[0])


def test_keep_tangential_keeps_planes_pinned_vertices_and_the_input_tangential_positions():
    V, F = grid(10, 8)
    np.testing.assert_allclose(apply_filter("two_stage", (V, F), keep_tangential=True)[0], V, atol=1e-12)
    ops = get_operators(F, len(V))
    inner = ~ops.boundary_vertices
    Vn = V.copy()
    Vn[inner, 2] += 0.02 * np.random.default_rng(1).standard_normal(inner.sum())
    Y = apply_filter("two_stage", (Vn, F), pinned="boundary", keep_tangential=True)[0]
    np.testing.assert_array_equal(Y[~inner], V[~inner])
    assert Y[inner, 2].std() < 0.5 * Vn[inner, 2].std()
    Y_free = apply_filter("two_stage", (Vn, F), pinned="boundary")[0]

    def tangential_move(X):  # the part of the move from the input across the output's vertex normals
        u, M = vertex_normals(X, F), (X - Vn)[inner]
        return np.linalg.norm(M - np.einsum("ij,ij->i", M, u[inner])[:, None] * u[inner]) / np.linalg.norm(M)

    # without it the vertex update drifts sideways (first order); with it only the change of the
    # normals during the last restore remains (second order)
    assert tangential_move(Y_free) > 1e-3
    assert tangential_move(Y) < 1e-2 * tangential_move(Y_free)


def test_keep_tangential_raises_the_snr_on_a_noisy_box():
    V, Vn, F, _ = noisy_box()
    free = apply_filter("two_stage", (Vn, F))[0]
    kept = apply_filter("two_stage", (Vn, F), keep_tangential=True)[0]
    assert snr(V, kept) > snr(V, free) + 0.5


# --- the pieces of the rule --------------------------------------------------------------------


def test_relax_tangential_is_the_fit_then_the_tangent_projection_of_the_neighbours_mean():
    """Each outer iteration (keep_tangential off, so the run goes on from its last state) then the relaxation written
    here: x + (I - u u^T)(P x - x), u the normalised sum of the unit face normals; border and pinned vertices stay."""
    V, F = icosphere(3)
    Vn = V + 0.02 * np.random.default_rng(0).standard_normal(V.shape)
    ops = get_operators(F, len(V))
    step = dict(normal_iterations=1, vertex_iterations=5, sigma_r=0.35, sigma_s=1.0, guidance="bilateral")
    X = Vn.copy()
    for _ in range(4):
        X = apply_filter("two_stage", (X, F), iterations=1, **step)[0]
        u = vertex_normals(X, F)
        d = ops.P @ X - X
        X = X + d - np.einsum("ij,ij->i", d, u)[:, None] * u
    got = apply_filter("two_stage", (Vn, F), iterations=4, relax_tangential=True, **step)[0]
    np.testing.assert_allclose(got, X, rtol=0, atol=1e-12)
    from meshdenoise import kernels  # the neighbours' mean read from the faces: P X on a closed mesh

    F64 = np.asarray(F, dtype=np.int64)
    ptr, corners = _corner_lists(F64, len(V))
    mean = np.empty_like(Vn)
    kernels.face_corner_mean(Vn, F64, ptr, corners, mean)
    np.testing.assert_allclose(mean, ops.P @ Vn, rtol=0, atol=1e-15)
    # a plane stays a plane; its border and pinned vertices do not move along it
    G, FG = grid(10, 8)
    Gn = G + 0.01 * np.random.default_rng(1).standard_normal(G.shape) * [1, 1, 0]  # noise in the plane only
    border = get_operators(FG, len(G)).boundary_vertices
    pinned = np.zeros(len(G), dtype=bool)
    pinned[40] = True
    out = apply_filter("two_stage", (Gn, FG), iterations=3, relax_tangential=True, pinned=pinned, **step)[0]
    np.testing.assert_allclose(out[:, 2], 0.0, atol=1e-12)
    np.testing.assert_array_equal(out[border | pinned], Gn[border | pinned])
    inner = ~(border | pinned)
    assert np.linalg.norm(out[inner] - G[inner]) < 0.6 * np.linalg.norm(Gn[inner] - G[inner])
    from meshdenoise.registry import ParameterError

    with pytest.raises(ParameterError, match="keep_tangential' and 'relax_tangential' are both True"):
        apply_filter("two_stage", (Vn, F), keep_tangential=True, relax_tangential=True)


# --- the automatic rule -------------------------------------------------------------------------
def _one_count_at_a_time(Vn, F, sweep, ops):
    """path(Y): two_stage run from Y once per count of the sweep (not along one run as the rule reads it)."""
    def path(Y):
        for k in sweep.values:
            yield apply_filter("two_stage", (Y, F), **sweep.params(sweep.values.index(k)), operators=ops)[0]
    return path


def _every_count(F, sweep, ops):
    """path(Y): two_stage's run of the sweep's last count, every state (outer_iterates, tested above against
    the filter run once per count); the rule reads its states through the sweep instead."""
    fixed = dict(sweep.fixed)
    return lambda Y: ts.outer_iterates(Y, ops, None, max(sweep.values), **fixed)


def test_rule_is_the_least_held_out_loss_along_each_run_and_the_defaults_choice():
    V, Vn, F, _ = noisy_box()
    ops = get_operators(F, len(V))
    c = ts.TWO_STAGE_NORMALS.config
    part = region(Vn, F, ops, c.region_vertices, c.region_patches, margin=2 * c.radius + 4)
    assert part.vertices.size == len(V)  # the whole box is scored
    held = holdout(Vn, ops, c.radius, c.masks, allowed=part.inner, centres=c.centres)
    best = None
    for sweep in ts.TWO_STAGE_NORMALS.sweeps:
        losses = path_losses(_every_count(F, sweep, ops), Vn, F, held, len(sweep.values), c.patience)
        k = int(np.argmin(losses))
        if best is None or losses[k] < best[0]:
            best = (float(losses[k]), sweep.params(k))
    chosen = choose_parameters((Vn, F), "two_stage")
    assert chosen == best[1]
    get_filter("two_stage").resolve(chosen)  # names, types and ranges
    # the default's candidates are these sweeps, read the same way: it chooses the same
    from meshdenoise.policy import choose_default

    default = choose_default((Vn, F))
    assert (default.method, default.params) == ("two_stage", chosen)


def test_rule_on_a_noisy_box_beats_the_defaults_and_reads_no_noise_level():
    V, Vn, F, rho = noisy_box()
    params = choose_parameters((Vn, F), "two_stage", criterion="normals")
    got = apply_filter("two_stage", (Vn, F), **params)[0]
    default = apply_filter("two_stage", (Vn, F))[0]
    assert normal_error_deg((V, F), got) < 0.3 * normal_error_deg((V, F), Vn)
    assert normal_error_deg((V, F), got) <= normal_error_deg((V, F), default)
    assert snr(V, got) >= snr(V, default)
    # two_stage has no SURE: the criteria "sure" and "gcv" choose as "normals" (a noise level given is not read)
    assert choose_parameters((Vn, F), "two_stage", noise=rho) == params
    assert choose_parameters((Vn, F), "two_stage", criterion="gcv") == params
    with pytest.raises(ValueError, match="held-out"):
        choose_parameters((Vn, F), "two_stage", criterion="normals", noise=rho)


def test_rule_holds_given_parameters_and_is_the_same_on_renumbered_vertices():
    V, Vn, F, _ = noisy_box()
    held = choose_parameters((Vn, F), "two_stage", criterion="normals", sigma_r=0.3, normal_iterations=2,
                             keep_tangential=False)
    assert (held["sigma_r"], held["normal_iterations"], held["keep_tangential"]) == (0.3, 2, False)
    assert choose_parameters((Vn, F), "two_stage", criterion="normals", iterations=4)["iterations"] == 4
    # a given tangential step holds the other off in every run (the two exclude each other)
    kept = choose_parameters((Vn, F), "two_stage", keep_tangential=True)
    assert kept["keep_tangential"] is True and kept["relax_tangential"] is False
    relaxed = choose_parameters((Vn, F), "two_stage", relax_tangential=True)
    assert relaxed["relax_tangential"] is True and relaxed["keep_tangential"] is False
    apply_filter("two_stage", (Vn, F), **kept)  # a valid combination
    perm = np.random.default_rng(5).permutation(len(V))
    inverse = np.argsort(perm)
    assert choose_parameters((Vn[perm], inverse[F]), "two_stage") == choose_parameters((Vn, F), "two_stage")


def test_rule_on_a_mesh_too_small_to_hold_out_keeps_the_defaults_with_a_warning():
    V, F = icosphere(0)
    with pytest.warns(UserWarning, match="defaults are kept"):
        chosen = choose_parameters((V, F), "two_stage", criterion="normals")
    spec = get_filter("two_stage")
    assert all(chosen.get(k, spec.param(k).default) == spec.param(k).default for k in ts.TUNED)


def test_oracle_is_the_least_position_error_of_the_same_sweeps_each_count_run_alone():
    V, Vn, F, _ = noisy_box()
    ops = get_operators(F, len(V))
    best = None
    for sweep in ts.TWO_STAGE_NORMALS.sweeps:
        errors = []
        for X in _one_count_at_a_time(Vn, F, sweep, ops)(Vn):
            errors.append(float(np.sum((X - V) ** 2)))
            if len(errors) - 1 - int(np.argmin(errors)) >= ts.TWO_STAGE_NORMALS.config.patience:
                break
        k = int(np.argmin(errors))
        if best is None or errors[k] < best[0]:
            best = (errors[k], sweep.params(k))
    oracle = choose_parameters((Vn, F), "two_stage", criterion="oracle", reference=V)
    assert oracle == best[1]
