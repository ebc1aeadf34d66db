"""Recorrupted pairs (meshdenoise.tuning.recorrupted) against closed forms written here with dense matrices."""

from __future__ import annotations

import numpy as np
import pytest

from meshdenoise.geometry import vertex_normals
from meshdenoise.shapes import icosphere
from meshdenoise.tuning.recorrupted import (cross_normals, normal_score, position_risk, position_score, recorrupt,
                                            recorrupted_scores)


def _setup(rho=0.05):
    V, F = icosphere(1)  # 42 vertices
    n = V.shape[0]
    N = vertex_normals(V, F)
    # a dense linear smoother: two explicit uniform-Laplacian steps, H = (I - 0.5 L)^2, L = I - D^-1 A
    A = np.zeros((n, n))
    for i, j in ((0, 1), (1, 2), (2, 0)):
        A[F[:, i], F[:, j]] = 1.0
        A[F[:, j], F[:, i]] = 1.0
    L = np.eye(n) - A / A.sum(axis=1, keepdims=True)
    H = np.linalg.matrix_power(np.eye(n) - 0.5 * L, 2)
    return V, F, N, H, rho


def _normal_noise(N, rho, rng):
    return rho * rng.standard_normal(N.shape[0])[:, None] * N


def test_recorrupted_position_score_has_the_closed_form_expectation_of_a_linear_filter():
    V, F, N, H, rho = _setup()
    n = V.shape[0]
    a = 0.7
    # closed form on the 3n coordinates: x = vec(X) (vertex-major), H3 = H (x) I3, Sigma = blockdiag(rho^2 N_i N_i^T)
    H3 = np.kron(H, np.eye(3))
    I = np.eye(3 * n)
    S = np.zeros((3 * n, 3 * n))
    for i in range(n):
        S[3 * i:3 * i + 3, 3 * i:3 * i + 3] = rho**2 * np.outer(N[i], N[i])
    x0 = V.reshape(-1)
    bias = float(np.sum(((H3 - I) @ x0) ** 2))
    expected = bias + np.trace((H3 - I) @ S @ (H3 - I).T) + np.trace((a * H3 + I / a) @ S @ (a * H3 + I / a).T)
    risk_inflated = bias + (1 + a**2) * np.trace(H3 @ S @ H3.T)  # E ||H(Y + aZ) - X0||^2
    rng = np.random.default_rng(1)
    scores = []
    for m in range(3000):  # the real noise E drawn afresh each time, Z by the function (its own seed)
        Y = V + _normal_noise(N, rho, rng)
        s = recorrupted_scores(lambda Yp: [H @ Yp], Y, lambda r: _normal_noise(N, rho, r),
                               lambda X, T: position_score(X, T), a=a, draws=1, seed=m)
        scores.append(s[0, 0])
    scores = np.array(scores)
    se = scores.std(ddof=1) / np.sqrt(scores.size)
    assert abs(scores.mean() - expected) < 4 * se
    risk = position_risk(scores, n * rho**2, a)
    assert abs(risk.mean() - risk_inflated) < 4 * se
    assert 4 * se < 0.1 * (expected - risk_inflated)  # the test resolves the noise-energy constant


def test_cross_normals_of_the_target_are_unbiased_and_the_normal_score_ranks_by_the_clean_cosines():
    V, F, N, H, rho = _setup(rho=0.08)
    a = 0.5
    rng = np.random.default_rng(2)
    C0 = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])  # written here
    X = V + 0.03 * rng.standard_normal(V.shape)  # a fixed output (independent of the target's noise)
    U = np.cross(X[F[:, 1]] - X[F[:, 0]], X[F[:, 2]] - X[F[:, 0]])
    U /= np.linalg.norm(U, axis=1, keepdims=True)
    w = 1.0 / np.linalg.norm(C0, axis=1)
    expected = -float(np.sum(w * np.einsum("ij,ij->i", U, C0)))  # minus the sum of the clean cosines
    crosses, scores = [], []
    for m in range(4000):
        Y = V + _normal_noise(N, rho, rng)
        _, minus = recorrupt(Y, _normal_noise(N, rho, rng), a)
        C = cross_normals(minus, F)
        crosses.append(C)
        scores.append(normal_score(X, F, C, weights=w))
    crosses, scores = np.array(crosses), np.array(scores)
    se = crosses.std(axis=0, ddof=1) / np.sqrt(crosses.shape[0])
    assert np.all(np.abs(crosses.mean(axis=0) - C0) < 4.5 * se + 1e-15)
    assert abs(scores.mean() - expected) < 4 * scores.std(ddof=1) / np.sqrt(scores.size)
    # the unit normals of the same noisy target are biased (shrunk): what the cross products avoid
    Cu = crosses / np.linalg.norm(crosses, axis=2, keepdims=True)
    shrink = np.einsum("ij,ij->i", Cu.mean(axis=0), C0 * w[:, None])
    assert np.all(shrink < 0.99)


def test_recorrupt_and_scores_reject_bad_values():
    Y = np.zeros((4, 3))
    with pytest.raises(ValueError, match="a must be positive"):
        recorrupt(Y, Y, 0.0)
    with pytest.raises(ValueError, match="differ in shape"):
        recorrupt(Y, np.zeros((3, 3)), 1.0)
    with pytest.raises(ValueError, match="draws must be at least 1"):
        recorrupted_scores(lambda Yp: [Yp], Y, lambda r: Y, lambda X, T: 0.0, draws=0)
    with pytest.raises(ValueError, match="yielded no output"):
        recorrupted_scores(lambda Yp: [], Y, lambda r: Y, lambda X, T: 0.0)


def test_recorrupted_scores_read_every_output_of_every_draw_in_order():
    V, F, N, H, rho = _setup()
    Y = V + _normal_noise(N, rho, np.random.default_rng(4))
    run = lambda Yp: (np.linalg.matrix_power(H, k) @ Yp for k in (1, 2, 3))  # noqa: E731
    sampler = lambda r: _normal_noise(N, rho, r)  # noqa: E731
    got = recorrupted_scores(run, Y, sampler, lambda X, T: (position_score(X, T), float(np.sum(X))), a=0.5, draws=2,
                             seed=7, length=2)
    assert got.shape == (2, 2, 2)
    rng = np.random.default_rng(7)
    for d in range(2):
        Z = rho * rng.standard_normal(V.shape[0])[:, None] * N
        plus, minus = Y + 0.5 * Z, Y - Z / 0.5
        for k in (1, 2):
            X = np.linalg.matrix_power(H, k) @ plus
            assert got[d, k - 1, 0] == pytest.approx(np.sum((X - minus) ** 2), rel=1e-12)
            assert got[d, k - 1, 1] == pytest.approx(np.sum(X), rel=1e-12)
