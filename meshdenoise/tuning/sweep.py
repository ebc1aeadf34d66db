"""Held-out losses of candidate runs on a mesh or a sampled region of it, and rules made of them (knows no filter).

:func:`held_out_losses` reads each candidate path's held-out loss
(:func:`meshdenoise.tuning.holdout.path_losses`) on the mesh or, above
:attr:`HoldoutConfig.region_vertices`, on a sampled region: the default for scans
(:mod:`meshdenoise.policy`) scores its candidates with it. A :class:`Sweep` names the parameter a
filter's rule moves and the values it tries, in order of increasing smoothing; :class:`HeldOutRule`
is a filter's automatic rule built from its sweeps: the value of least held-out loss.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Iterator, Sequence

import numpy as np

from ..operators import Operators, get_operators
from .holdout import holdout, path_losses, region

__all__ = ["HoldoutConfig", "HeldOutLosses", "HeldOutRule", "RULE_CONFIG", "Sweep", "geometric", "held_out_losses", "sweep_path"]

Path = Callable[[np.ndarray], Iterator[np.ndarray]]


@dataclass(frozen=True)
class HoldoutConfig:
    """How held-out losses are read (:func:`held_out_losses`); the default's values, chosen on the corpus's
    tune half (benchmarks/results/policy-tune.md, ``python benchmarks/policy_tune.py --split tune``).

    Attributes
    ----------
    radius : int
        Rings hidden around each held-out vertex (:func:`meshdenoise.tuning.holdout.holdout`).
    masks : int
        Masks of held-out vertices (each costs one run per sweep).
    centres : int
        On a small mesh, masks are added until at least this many vertices are held out (up to
        ``4 * masks``).
    patience : int
        A run's scoring stops this many steps after its least loss.
    region_vertices : int
        Above this many vertices the losses are read on a sampled region of about this many vertices.
    region_patches : int
        Balls of the region.
    """

    radius: int = 1
    masks: int = 3
    centres: int = 300
    patience: int = 4
    region_vertices: int = 12_000
    region_patches: int = 24

    def __post_init__(self):
        for name in ("radius", "masks", "centres", "patience", "region_vertices", "region_patches"):
            value = getattr(self, name)
            low = 0 if name in ("radius", "centres") else 1
            if not isinstance(value, int) or isinstance(value, bool) or value < low:
                raise ValueError(f"HoldoutConfig: {name} must be an int >= {low}, got {value!r}")


@dataclass(frozen=True)
class HeldOutLosses:
    """Each path's held-out losses per step, and what they were read on."""

    losses: list
    vertices: int
    centres: int


def held_out_losses(V: np.ndarray, F: np.ndarray, ops: Operators,
                    paths: Sequence[Callable[[np.ndarray, Operators], Path]], steps: Sequence[int],
                    config: HoldoutConfig) -> HeldOutLosses:
    """The held-out loss along each path, on ``(V, F)`` or, above ``config.region_vertices``, a sampled region.

    ``paths[i](F, ops)`` gives the path (``path(Y)`` yields states) on the mesh scored (the
    region's faces and operators when one is sampled); ``steps[i]`` is the most states read along
    it. Raises :class:`~meshdenoise.tuning.holdout.NoHoldout` when no vertex can be held out.
    """
    part = region(V, F, ops, config.region_vertices, config.region_patches, margin=2 * config.radius + 4)
    if part.vertices.size < len(V):
        V, F = V[part.vertices], part.F
        ops = get_operators(F, len(V))
    held = holdout(V, ops, config.radius, config.masks, allowed=part.inner, centres=config.centres)
    losses = [path_losses(make(F, ops), V, F, held, count, config.patience) for make, count in zip(paths, steps)]
    return HeldOutLosses(losses, len(V), held.count)


def geometric(low: float, high: float, ratio: float, integer: bool = False) -> tuple:
    """Values ``low, low r, low r^2, ...`` up to ``high`` (rounded and deduplicated with ``integer``).

    Examples
    --------
    >>> geometric(1, 10, 1.5, integer=True)
    (1, 2, 3, 5, 8, 11)
    >>> len(geometric(0.01, 100.0, 10 ** 0.5))
    9
    """
    if not (0 < low <= high and ratio > 1):
        raise ValueError(f"geometric: need 0 < low <= high and ratio > 1, got {low!r}, {high!r}, {ratio!r}")
    count = int(np.ceil(np.log(high / low) / np.log(ratio) - 1e-9)) + 1
    values = low * ratio ** np.arange(count)
    if integer:
        return tuple(int(v) for v in np.unique(np.round(values).astype(np.int64)))
    return tuple(float(v) for v in values)


@dataclass(frozen=True)
class Sweep:
    """One parameter of a filter tried at ``values`` (least smoothing first), the others ``fixed``.

    Attributes
    ----------
    parameter : str
        The parameter swept.
    values : tuple
        Its values, in order of increasing smoothing.
    fixed : tuple of (name, value)
        The filter's other parameters held.
    additive : bool
        Running the filter at ``a`` then at ``b`` is running it at ``a + b`` (counts of one run): the
        states are read along one run instead of one run per value.
    along : callable, optional
        The filter's own reading of one run: ``along(fixed, values, F, ops)`` gives ``path(Y)``, the
        states at each of ``values`` (counts of one run whose later states depend on its input, as
        ``two_stage`` restoring its input's tangential parts); used instead of ``additive``.
    """

    parameter: str
    values: tuple
    fixed: tuple = ()
    additive: bool = False
    along: Callable[..., Path] | None = None

    def __post_init__(self):
        if not self.values:
            raise ValueError(f"Sweep: values of {self.parameter!r} must not be empty")

    def params(self, k: int) -> dict[str, Any]:
        """The filter's parameters at the ``k``-th value (0-based)."""
        return {**dict(self.fixed), self.parameter: self.values[k]}

    def with_given(self, given: dict) -> "Sweep":
        """The sweep with the caller's parameters held instead of its own fixed ones.

        A fixed value the caller changes may be what made the values additive (``heat``'s times are whole
        steps of its fixed ``tau``): the sweep then runs each value from the input.
        """
        own = dict(self.fixed)
        fixed = {**own, **{k: v for k, v in given.items() if k != self.parameter}}
        additive = self.additive and all(fixed[k] == v for k, v in own.items())
        return Sweep(self.parameter, self.values, tuple(fixed.items()), additive, self.along)


# run(Y, F, ops, params) -> the filter's positions (n, 3) on the mesh (Y, F) with its operators
Runner = Callable[[np.ndarray, np.ndarray, Operators, dict], np.ndarray]


def sweep_path(sweep: Sweep, run: Runner, F: np.ndarray, ops: Operators) -> Path:
    """``path(Y)``: the filter's positions at each of the sweep's values, from ``Y`` (n, 3)."""
    fixed = dict(sweep.fixed)
    if sweep.along is not None:
        return sweep.along(fixed, sweep.values, F, ops)

    def path(Y: np.ndarray) -> Iterator[np.ndarray]:
        if sweep.additive:  # one run, read at each count: the step from the previous count only
            X, done = Y, 0
            for v in sweep.values:
                X = run(X, F, ops, {**fixed, sweep.parameter: v - done})
                done = v
                yield X
        else:
            for v in sweep.values:
                yield run(Y, F, ops, {**fixed, sweep.parameter: v})
    return path


# A filter's own rule reads its sweep 8 values past the least loss (the default, 4 steps of its runs): on the corpus's
# tune half the same choices or better (taubin 1.185 against 1.198 times the sweep's best, filtering, sobolev and heat
# alike: benchmarks/results/held-out-sweeps.md), and on a noisy sphere taubin's loss has a shallow dip at 5 iterations
# that 4 values past it do not leave (3.8 degrees where the sweep's best, 133 iterations, is 1.2: tests/test_held_out_rules.py)
RULE_CONFIG = HoldoutConfig(patience=8)


@dataclass(frozen=True)
class HeldOutRule:
    """A filter's automatic rule: the value of least held-out face-normal loss over its sweeps.

    Attributes
    ----------
    sweeps : tuple of Sweep
        The candidates; a parameter the caller gives is held (:meth:`Sweep.with_given`), and a sweep
        whose own parameter is given is not run.
    config : HoldoutConfig
        How the losses are read (:data:`RULE_CONFIG`).
    """

    sweeps: tuple
    config: HoldoutConfig = RULE_CONFIG

    def choose(self, V: np.ndarray, F: np.ndarray, ops: Operators, run: Runner, given: dict) -> tuple[dict, float]:
        """``(parameters, least loss)`` for the mesh ``(V, F)``; ``run(Y, F, ops, params)`` runs the filter."""
        sweeps = [s.with_given(given) for s in self.sweeps if s.parameter not in given]
        if not sweeps:
            return dict(given), float("nan")
        paths = [lambda F, ops, s=s: sweep_path(s, run, F, ops) for s in sweeps]
        losses = held_out_losses(V, F, ops, paths, [len(s.values) for s in sweeps], self.config).losses
        best = min(range(len(sweeps)), key=lambda i: float(np.min(losses[i])))
        k = int(np.argmin(losses[best]))
        return {**sweeps[best].params(k), **given}, float(losses[best][k])

    def oracle(self, V: np.ndarray, F: np.ndarray, ops: Operators, run: Runner, given: dict,
               reference: np.ndarray) -> tuple[dict, float]:
        """``(parameters, least squared error)``: the value of the sweeps closest to the clean ``reference`` (n, 3)
        (the sum of the squared distances of the vertices), each sweep read on the whole mesh up to
        ``config.patience`` values past its least error. For benchmarks: the best this rule could choose."""
        sweeps = [s.with_given(given) for s in self.sweeps if s.parameter not in given]
        if not sweeps:
            return dict(given), float("nan")
        best, at = float("inf"), dict(given)
        for s in sweeps:
            least, since = float("inf"), 0
            for k, X in enumerate(sweep_path(s, run, F, ops)(V)):
                err = float(np.sum((X - reference) ** 2))
                if err < least:
                    least, since = err, 0
                    if err < best:
                        best, at = err, {**s.params(k), **given}
                else:
                    since += 1
                    if since >= self.config.patience:
                        break
        return at, best
