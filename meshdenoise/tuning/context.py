"""What a filter's automatic rule is given: the noisy mesh, its operators, the noise level and the score."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np

from ..operators import Operators
from .risk import Criterion, Point, as_criterion, colour_probes
from .search import mu_guess, sure_smoothed

__all__ = ["TuningContext", "as_configs"]

C = TypeVar("C")


def as_configs(config: Any) -> tuple:
    """``config`` as a tuple of settings objects: ``None`` is none, one frozen dataclass instance is one, a sequence
    of them is itself; two of one type, or anything else, raise a ValueError naming it.

    Examples
    --------
    >>> from meshdenoise.tuning.config import SearchConfig, SpectralConfig
    >>> [type(c).__name__ for c in as_configs((SearchConfig(region_min_vertices=1000), SpectralConfig()))]
    ['SearchConfig', 'SpectralConfig']
    >>> as_configs(None)
    ()
    """
    if config is None:
        return ()
    items = tuple(config) if isinstance(config, (tuple, list)) else (config,)
    seen = set()
    for item in items:
        if not dataclasses.is_dataclass(item) or isinstance(item, type) or not item.__dataclass_params__.frozen:
            raise ValueError(f"config must be a settings object (a frozen dataclass such as SearchConfig) or a "
                             f"sequence of them, got {item!r}")
        if type(item) in seen:
            raise ValueError(f"config holds two {type(item).__name__} objects: give one")
        seen.add(type(item))
    return items


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
    noise : NoiseModel or None
        The noise covariance (:class:`~meshdenoise.tuning.covariance.NoiseModel`): its
        ``rho`` is ``rho``; a correlated one colours the trace probes while the rule runs
        (:func:`~meshdenoise.tuning.risk.noise_colouring`). ``None``: independent noise.
    config : tuple
        Settings objects the caller handed in (``choose_parameters(..., config=...)``): each module's rule reads the
        one of its own type (:meth:`config_for`), its module's default when none is given, e.g.
        ``config=(SearchConfig(region_min_vertices=1000), SinkhornConfig(region=3000))``.
    """

    V: np.ndarray
    F: np.ndarray
    ops: Operators
    rho: float | None
    criterion: Criterion
    exact: bool | None
    given: dict[str, Any] = field(default_factory=dict)
    noise: Any = None
    config: tuple = ()

    def __post_init__(self) -> None:
        self.criterion = as_criterion(self.criterion)
        self.config = as_configs(self.config)

    def config_for(self, default: C) -> C:
        """The settings object of ``default``'s type in :attr:`config`, else ``default`` (the module's own)."""
        for item in self.config:
            if type(item) is type(default):
                return item
        return default

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

    @property
    def correlation_length(self) -> float:
        """The noise's correlation length in mean edge lengths (0: independent)."""
        return float(self.noise.correlation_length) if self.noise is not None else 0.0

    def colour(self, Z: np.ndarray, s: float) -> np.ndarray:
        """Probes ``Z`` (n, m) of scale ``s`` coloured by the noise model (``Z`` itself for independent noise).

        For a rule's own Monte-Carlo SURE probes: with ``b = colour(z) * N`` the divergence
        term estimates :math:`\\mathrm{tr}(\\Sigma J_f)` of the correlated noise.
        """
        return colour_probes(Z, s, self.noise)

    def score(self, p: Point) -> float:
        """``p``'s score under this context's criterion."""
        return self.criterion.score(p, self.ops.n, self.rho)

    def smoothed(self, criterion: Criterion | str | None = None) -> Point:
        """The best point of plain averaging (by ``criterion``, default the context's)."""
        return sure_smoothed(self.V, self.ops, self.rho, criterion or self.criterion, self.exact)

    def mu_guess(self, order: int) -> float:
        """A starting weight for :math:`(I + \\mu L^p)` from the averaging path (:func:`~meshdenoise.tuning.search.mu_guess`)."""
        return mu_guess(self.V, self.ops, self.rho, self.criterion, self.exact, order)
