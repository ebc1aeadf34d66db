"""The one walk along a run (meshdenoise.tuning.walk) against a brute-force reading of its rule."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from meshdenoise.noise import add_normal_noise
from meshdenoise.operators import get_operators
from meshdenoise.shapes import icosphere
from meshdenoise.tuning.risk import Criterion
from meshdenoise.tuning.search import averaging_step, best_on_path, iterative_path
from meshdenoise.tuning.walk import walk


def brute_force(scores: np.ndarray, patience: int | None, max_steps: int) -> tuple[list[int], int, str]:
    """The rule read literally on the whole score table (rows = steps, columns = scores): the first step k
    at which every column's first minimum over steps 0..k lies at b with k >= 2 b + 20 (or k >= b + patience)."""
    for k in range(scores.shape[0]):
        bests = [int(np.argmin(scores[: k + 1, c])) for c in range(scores.shape[1])]
        if all(k >= (2 * b + 20 if patience is None else b + patience) for b in bests):
            return bests, k, "past minimum"
        if k >= max_steps:
            return bests, k, "max_steps"
    return [int(np.argmin(scores[:, c])) for c in range(scores.shape[1])], scores.shape[0] - 1, "end"


@pytest.mark.parametrize("seed", range(40))
def test_walk_follows_its_rule_on_random_runs(seed):
    rng = np.random.default_rng(seed)
    n_steps, n_scores = int(rng.integers(1, 250)), int(rng.integers(1, 4))
    # bumpy curves with a minimum somewhere, some plateaus (ties) and a few local minima
    t = np.arange(n_steps)[:, None]
    scores = (t - rng.integers(0, max(1, n_steps // 3), n_scores)) ** 2 + rng.integers(0, 3, (n_steps, n_scores)) * rng.integers(0, 40)
    scores = scores.astype(float)
    patience = None if seed % 2 else int(rng.integers(1, 10))
    max_steps = int(rng.integers(0, 300))
    bests, steps, stop = brute_force(scores, patience, max_steps)
    seen = []

    def score(k):
        seen.append(k)
        return scores[k]

    w = walk(range(n_steps), score, patience=patience, max_steps=max_steps)
    assert [b.step for b in w.best] == bests
    assert [b.item for b in w.best] == bests  # the state kept is the best step's own
    assert [b.score for b in w.best] == [scores[b, c] for c, b in enumerate(bests)]
    assert (w.steps, w.stop) == (steps, stop) and w.complete == (stop == "past minimum")
    assert seen == list(range(steps + 1))  # every state scored once, in order, none after the stop


def test_walk_on_an_endless_run_and_its_arguments():
    w = walk(itertools.count(), lambda k: (k - 7) ** 2)
    assert (w.best[0].step, w.steps, w.stop) == (7, 34, "past minimum")
    w = walk(itertools.count(), lambda k: -k, max_steps=50)  # still falling at the cap
    assert (w.best[0].step, w.steps, w.stop) == (50, 50, "max_steps")
    w = walk([0, 1, 2], lambda k: [math.nan, 3.0, 1.0][k])  # NaN is never the best
    assert (w.best[0].step, w.stop) == (2, "end")
    with pytest.raises(ValueError, match="no state"):
        walk([], float)
    with pytest.raises(ValueError, match="patience"):
        walk(range(3), float, patience=0)
    with pytest.raises(ValueError, match="max_steps"):
        walk(range(3), float, max_steps=-1)
    with pytest.raises(ValueError, match="returned 2 values at step 1"):
        walk(range(3), lambda k: [1.0] * (k + 1))


@pytest.mark.parametrize("criterion", ["sure", "oracle"])
def test_walk_chooses_what_the_automatic_search_chooses(criterion):
    """The same search with another score: along the SURE path of averaging, and with the oracle score,
    the walk and :func:`best_on_path` (the automatic rules' walk) pick the same step."""
    V, F = icosphere(3)
    Vn = add_normal_noise((V, F), 0.02, seed=0)[0]
    ops = get_operators(F, V.shape[0])
    crit = Criterion("oracle", V) if criterion == "oracle" else Criterion("sure")
    step = averaging_step(ops.P, 1.0)
    expected = best_on_path(iterative_path(Vn, ops, step), ops.n, 0.02, crit)
    w = walk(iterative_path(Vn, ops, step), lambda p: crit.score(p, ops.n, 0.02))
    assert w.best[0].step == expected.value >= 1
    np.testing.assert_array_equal(w.best[0].item.X, expected.X)
    if criterion == "oracle":  # and it is the true best count: brute force over the dense powers
        P = ops.P.toarray()
        errors, X = [], Vn.copy()
        for _ in range(w.steps + 1):
            errors.append(float(np.sum((X - V) ** 2)))
            X = P @ X
        assert w.best[0].step == int(np.argmin(errors))
