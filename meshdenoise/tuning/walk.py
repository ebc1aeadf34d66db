"""The walk along an iterative run until its score is past the minimum, with any score.

Generic machinery: a walk knows a sequence of states (the state after 0, 1, 2, ... steps of
any iterative filter) and one or more scores of a state, never a filter. It serves the oracle
searches that know the clean mesh (the error against it scores each step): the paper's tables
(:mod:`meshdenoise.reproduce`: the SNR averaged over noise seeds), the quality benchmark's
MeshLab and Open3D filters (SNR and face-normal error, one library call per step) and the
feature benchmark. The automatic rules walk their risk estimate by the same rule
(:func:`~meshdenoise.tuning.search.best_on_path`; ``tests/test_tuning_walk.py`` checks that
both choose the same step, with SURE and with the oracle score).

The stopping rule is :func:`past_minimum` (``k >= 2 k_best + 20``),
or, for a caller whose steps are costly, ``patience``: stop ``patience`` steps after the best.

Examples
--------
>>> w = walk([5.0, 3.0, 2.0, 4.0, 6.0] + [7.0] * 30, lambda s: s)
>>> w.best[0].step, w.best[0].score, w.steps, w.stop
(2, 2.0, 24, 'past minimum')
>>> walk([5.0, 3.0, 2.0, 4.0, 6.0], lambda s: s, patience=2).steps
4
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["Best", "Walk", "walk", "past", "past_minimum", "WALK_STOPS"]

WALK_STOPS = ("past minimum", "max_steps", "end")

PAST_MINIMUM_FACTOR, PAST_MINIMUM_MARGIN = 2, 20


def past_minimum(k: int, k_best: int) -> bool:
    """The one stopping rule of every walk along an iterative run: ``k >= 2 k_best + 20``.

    The score curves of the smoothers here are unimodal in practice (bias grows, variance
    falls, both monotone), so a walk twice as long as the best step count, and 20 past
    it, has passed the minimum. Used by :func:`walk` (so by :func:`~meshdenoise.tuning.search.best_on_path`) and by the paper's
    SNR-along-a-run searches (:mod:`meshdenoise.reproduce`).

    Examples
    --------
    >>> past_minimum(20, 0), past_minimum(29, 5), past_minimum(30, 5)
    (True, False, True)
    """
    return k >= PAST_MINIMUM_FACTOR * k_best + PAST_MINIMUM_MARGIN


@dataclass
class Best:
    """The lowest score seen by a walk: its step (0 = the state before any step), score and state."""

    step: int
    score: float
    item: Any


@dataclass
class Walk:
    """The outcome of :func:`walk`.

    Attributes
    ----------
    best : tuple of Best
        One per score, in the order the score function returns them.
    steps : int
        The last step scored (``steps + 1`` states were scored).
    stop : str
        ``"past minimum"`` (every score passed its minimum), ``"max_steps"`` (the cap came
        first: a score may still be falling) or ``"end"`` (the states ran out first).
    """

    best: tuple[Best, ...]
    steps: int
    stop: str

    @property
    def complete(self) -> bool:
        """Whether every score was seen past its minimum (not cut by the cap or the end of the states)."""
        return self.stop == "past minimum"


def past(k: int, k_best: int, patience: int | None = None) -> bool:
    """Whether step ``k`` is past the minimum found at ``k_best``: :func:`past_minimum`,
    or ``k >= k_best + patience`` when ``patience`` is given.

    Examples
    --------
    >>> past(29, 5), past(30, 5), past(7, 5, patience=2)
    (False, True, True)
    """
    if patience is None:
        return past_minimum(k, k_best)
    return k >= k_best + patience


def walk(
    items: Iterable[Any],
    score: Callable[[Any], float | Sequence[float]],
    *,
    patience: int | None = None,
    max_steps: int = 20000,
) -> Walk:
    """Score the states of a run in order until every score has passed its minimum; keep each minimum.

    Parameters
    ----------
    items : iterable
        The states after 0, 1, 2, ... steps (for a filter: coordinates (n, 3), or any object
        the score reads). Only the best state of each score is kept, so the states may be
        large and the iterable endless.
    score : callable
        ``score(item)``: a float, or a sequence of floats (several scores along one run, for
        instance SNR and normal error of a library filter called once per step). Smaller is
        better; NaN counts as infinity. A score that must see every state (to record a curve) may do so here: it is
        called once per state, in order.
    patience : int, optional
        Stop ``patience`` steps after the best of every score instead of the default rule
        :func:`past_minimum` (``k >= 2 k_best + 20``). For runs whose
        steps are costly and whose score curves are known to be unimodal.
    max_steps : int
        Score at most the states 0 .. ``max_steps``.

    Returns
    -------
    Walk
        The best state of each score, the last step scored and why the walk stopped. Ties
        keep the earlier state.

    Raises
    ------
    ValueError
        On a negative ``patience`` or ``max_steps``, or when ``items`` is empty.
    """
    if patience is not None and (isinstance(patience, bool) or not isinstance(patience, int) or patience < 1):
        raise ValueError(f"walk: patience must be a positive int or None, got {patience!r}")
    if isinstance(max_steps, bool) or not isinstance(max_steps, int) or max_steps < 0:
        raise ValueError(f"walk: max_steps must be an int >= 0, got {max_steps!r}")
    best: list[Best] = []
    k = -1
    for k, item in enumerate(items):
        raw = score(item)
        values = tuple(math.inf if math.isnan(v) else v for v in map(float, np.atleast_1d(raw)))  # NaN: never the best
        if not best:
            best = [Best(k, v, item) for v in values]
        elif len(values) != len(best):
            raise ValueError(f"walk: the score returned {len(values)} values at step {k}, {len(best)} before")
        else:
            for b, v in zip(best, values):
                if v < b.score:
                    b.step, b.score, b.item = k, v, item
        if all(past(k, b.step, patience) for b in best):
            return Walk(tuple(best), k, "past minimum")
        if k >= max_steps:
            return Walk(tuple(best), k, "max_steps")
    if not best:
        raise ValueError("walk: no state to score (the run is empty)")
    return Walk(tuple(best), k, "end")
