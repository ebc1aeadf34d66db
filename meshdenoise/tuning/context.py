"""What a filter's automatic rule is given: the noisy mesh, its operators, the noise level and the score."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..operators import Operators
from .risk import Criterion, Point, as_criterion
from .search import mu_guess, sure_smoothed

__all__ = ["TuningContext"]


@dataclass
class TuningContext:
    """The inputs of an automatic rule (``rule(ctx) -> (chosen parameters, best Point)``).

    Attributes
    ----------
    V : ndarray, shape (n, 3)
        The noisy coordinates.
    F : ndarray, shape (m, 3)
    ops : Operators
        The topology's operators (factorisations are stored there).
    rho : float or None
        The noise level (``None`` with ``criterion="gcv"``, which needs none).
    criterion : Criterion
        How candidates are scored (a name is converted).
    exact : bool or None
        Exact traces (identity probes), Hutchinson ones, or by size (``None``).
    given : dict
        The filter's parameters the caller holds fixed.
    """

    V: np.ndarray
    F: np.ndarray
    ops: Operators
    rho: float | None
    criterion: Criterion
    exact: bool | None
    given: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.criterion = as_criterion(self.criterion)

    @property
    def n(self) -> int:
        return self.ops.n

    @property
    def reference(self) -> np.ndarray | None:
        """The clean coordinates in oracle mode, else ``None``."""
        return self.criterion.reference

    @property
    def oracle(self) -> bool:
        return self.criterion.oracle

    def score(self, p: Point) -> float:
        """``p``'s score under this context's criterion."""
        return self.criterion.score(p, self.ops.n, self.rho)

    def smoothed(self, criterion: Criterion | str | None = None) -> Point:
        """The best point of plain averaging (by ``criterion``, default the context's)."""
        return sure_smoothed(self.V, self.ops, self.rho, criterion or self.criterion, self.exact)

    def mu_guess(self, order: int) -> float:
        """A starting weight for :math:`(I + \\mu L^p)` from the averaging path (:func:`~meshdenoise.tuning.search.mu_guess`)."""
        return mu_guess(self.V, self.ops, self.rho, self.criterion, self.exact, order)
