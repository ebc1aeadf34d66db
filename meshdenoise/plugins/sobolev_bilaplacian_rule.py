"""``sobolev_bilaplacian``'s automatic rule: ``mu`` by SURE over log mu."""

from __future__ import annotations

from ..tuning.config import SEARCH
from ..tuning.context import TuningContext
from ..tuning.risk import Point
from ..tuning.search import best_shifted

__all__ = ["choose_sobolev_bilaplacian"]


def choose_sobolev_bilaplacian(ctx: TuningContext) -> tuple[dict, Point]:
    """``mu`` of :math:`(I + \\mu L^2) Y = X`: SURE over log mu, starting at :math:`(k/\\bar d)^2`."""
    p = best_shifted(ctx.V, ctx.ops, 2, ctx.rho, ctx.criterion, ctx.exact, center=ctx.mu_guess(2), coordinates=False,
                     config=ctx.config_for(SEARCH))
    return {"mu": float(p.value)}, p
