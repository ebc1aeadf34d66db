"""Held-out losses of candidate runs on a mesh or a sampled region of it (knows no filter).

:func:`held_out_losses` reads each candidate path's held-out loss
(:func:`meshdenoise.tuning.holdout.path_losses`) on the mesh or, above
:attr:`HoldoutConfig.region_vertices`, on a sampled region: the default for scans
(:mod:`meshdenoise.policy`) scores its candidates with it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterator, Sequence

import numpy as np

from ..operators import Operators, get_operators
from .holdout import holdout, path_losses, region

__all__ = ["HoldoutConfig", "HeldOutLosses", "held_out_losses"]

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
