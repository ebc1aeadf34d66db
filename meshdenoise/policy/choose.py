"""The default's policy: a few named steps, each returning a small record.

1. :func:`score`: every candidate family's held-out loss along its run
   (:mod:`meshdenoise.tuning.holdout`: vertices hidden with their ring of neighbours, the run on the
   copy, its face normals there compared with the noisy mesh's), on the whole mesh or, above
   :attr:`DefaultConfig.region_vertices`, on a sampled region;
2. :func:`pick`: the family and count of least loss;
3. :func:`guard`: the chosen filter on the whole mesh, the faces it turned over smoothed out
   (:func:`meshdenoise.folds.unfold`) and counted.

The noise reported is what the chosen run removed: the root mean square of the vertices' moves
along the result's vertex normals.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..folds import Folds, unfold_with
from ..geometry import vertex_normals
from ..operators import Operators
from ..tuning.holdout import NoHoldout
from ..tuning.sweep import held_out_losses
from .config import DefaultConfig, Family
from .paths import family_path

NONE = "none"  # the method of a choice that runs nothing

__all__ = ["NONE", "Score", "DefaultChoice", "score", "pick", "choose", "guard"]


@dataclass(frozen=True)
class Score:
    """One family's held-out losses along its run: the mean of ``1 - n_hat . n`` over the scored faces, per step."""

    family: Family
    losses: np.ndarray

    @property
    def step(self) -> int:
        """The count of least loss (1-based)."""
        return int(np.argmin(self.losses)) + 1

    @property
    def loss(self) -> float:
        return float(np.min(self.losses))


@dataclass
class DefaultChoice:
    """What the default decided for one mesh, and why.

    Attributes
    ----------
    method : str
        The filter chosen.
    params : dict
        Its parameters.
    edge_length : float
        Mean edge length (mesh units).
    noise : float
        What the run removed: the rms of the vertices' moves along the result's normals (mesh units;
        set by :func:`guard`).
    scores : list of Score
        Every candidate's losses.
    scored_vertices : int
        Vertices of the mesh (or region) the losses were read on.
    centres : int
        Held-out vertices scored.
    seconds : float
        Time taken to choose.
    flipped : int
        Faces of the result turned over (:func:`flipped_faces`; set by :func:`guard`).
    moved_rms, moved_max : float
        How far the vertices moved, in mean edge lengths (set by :func:`guard`).
    fallback : str
        Why fewer steps than chosen were run ('' when the choice ran as it was).
    reason : str
        Why nothing was run (``method`` is ``"none"``), else ''.
    """

    method: str
    params: dict
    edge_length: float
    noise: float
    scores: list = field(default_factory=list)
    scored_vertices: int = 0
    centres: int = 0
    seconds: float = 0.0
    flipped: int = 0
    moved_rms: float = 0.0
    moved_max: float = 0.0
    fallback: str = ""
    reason: str = ""

    def rescaled(self, k: int) -> "DefaultChoice":
        """The choice with its lengths multiplied by ``2**k`` (read on a mesh divided by it)."""
        self.edge_length = float(np.ldexp(self.edge_length, k))
        self.noise = float(np.ldexp(self.noise, k))
        return self

    @property
    def noise_in_edges(self) -> float:
        return self.noise / self.edge_length if self.edge_length > 0 else 0.0

    def lines(self) -> list[str]:
        """Three lines for a person: the noise, the filter, how far the mesh moved."""
        if self.method == NONE:
            return ["noise removed: none", f"filter: none, the mesh is left as it is ({self.reason})",
                    "moved the vertices 0 mean edge lengths; 0 faces flipped"]
        params = ", ".join(f"{k}={v}" for k, v in self.params.items())
        moved = (f"moved the vertices {self.moved_rms:.2g} mean edge lengths rms, {self.moved_max:.2g} at most; "
                 f"{self.flipped} faces flipped")
        if self.fallback:
            moved += f" ({self.fallback})"
        return [
            f"noise removed: {self.noise_in_edges:.2g} mean edge lengths rms along the normals ({self.noise:.3g})",
            f"filter: {self.method} ({params}), chosen in {self.seconds:.1f} s",
            moved,
        ]

    def explain(self) -> list[str]:
        """Why: each candidate's least held-out error and where along its run."""
        out = [f"{self.centres} vertices hidden with the rings around them; each candidate "
               f"ran on the mesh ({self.scored_vertices} vertices) with them hidden, and its face normals there were "
               "compared with the noisy ones (mean angle, the noise's own included):"]
        for s in sorted(self.scores, key=lambda s: s.loss):
            angle = math.degrees(math.acos(max(-1.0, 1.0 - s.loss))) if np.isfinite(s.loss) else float("nan")
            out.append(f"  {s.family.label}: {angle:.3g} degrees at {s.family.count}={s.step}")
        return out


def score(V: np.ndarray, F: np.ndarray, ops: Operators, config: DefaultConfig) -> tuple[list[Score], int, int]:
    """Step 1: the held-out losses of every family; also the vertices scored on and the centres."""
    paths = [lambda F, ops, f=f: family_path(f, F, ops, config.steps) for f in config.families]
    found = held_out_losses(V, F, ops, paths, [config.steps] * len(paths), config.holdout)
    return [Score(f, losses) for f, losses in zip(config.families, found.losses)], found.vertices, found.centres


def pick(scores: list[Score]) -> Score:
    """Step 2: the family of least held-out loss (the first listed on a tie)."""
    return min(scores, key=lambda s: s.loss)


def choose(V: np.ndarray, F: np.ndarray, ops: Operators, config: DefaultConfig) -> DefaultChoice:
    """Steps 1 and 2: the filter and its parameters for the mesh ``(V, F)``."""
    t0 = time.perf_counter()
    edges = ops.edges
    h = float(np.mean(np.linalg.norm(V[edges[:, 0]] - V[edges[:, 1]], axis=1))) if edges.size else 0.0
    try:
        scores, scored, centres = score(V, F, ops, config)
    except NoHoldout as exc:
        return DefaultChoice(method=NONE, params={}, edge_length=h, noise=0.0, reason=str(exc),
                             seconds=time.perf_counter() - t0)
    best = pick(scores)
    return DefaultChoice(method=best.family.method, params=best.family.params(best.step), edge_length=h,
                         noise=0.0, scores=scores,
                         scored_vertices=scored, centres=centres, seconds=time.perf_counter() - t0)


def guard(choice: DefaultChoice, V: np.ndarray, F: np.ndarray, ops: Operators, run: Any,
          rounds: int = 10) -> np.ndarray:
    """Step 3: run the choice on the whole mesh and smooth out any fold it made (:func:`meshdenoise.folds.unfold`).

    ``run(params)`` returns the filter's positions (n, 3) with ``params``. Sets ``choice.flipped``
    (folds left), ``noise``, ``moved_rms``, ``moved_max`` and ``fallback`` (what was unfolded);
    returns the positions.
    """
    X = run(choice.params)
    state = Folds(V, X, F)
    folds = state.count
    if folds and rounds > 0:
        X, left = unfold_with(V, np.array(X, dtype=np.float64), F, ops, rounds, state)
        choice.fallback = f"{folds} faces turned over by the filter, {folds - left} of them smoothed out"
        folds = left
    del state
    choice.flipped = folds
    h = choice.edge_length if choice.edge_length > 0 else 1.0
    move = np.linalg.norm(X - V, axis=1)
    along = np.einsum("ij,ij->i", X - V, vertex_normals(X, F))
    choice.noise = float(np.sqrt(np.mean(along ** 2))) if along.size else 0.0
    choice.moved_rms = float(np.sqrt(np.mean(move ** 2))) / h if move.size else 0.0
    choice.moved_max = float(move.max()) / h if move.size else 0.0
    return X
