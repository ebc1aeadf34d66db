"""``sobolev``'s automatic rule: ``mu`` by SURE over log mu, and the held-out sweep of its normals criterion
(``SOBOLEV_NORMALS``)."""

from __future__ import annotations

from ..tuning.config import SEARCH
from ..tuning.context import TuningContext
from ..tuning.risk import Point
from ..tuning.search import best_shifted
from ..tuning.sweep import HeldOutRule, Sweep, geometric

__all__ = ["choose_sobolev", "SOBOLEV_NORMALS"]


def choose_sobolev(ctx: TuningContext) -> tuple[dict, Point]:
    """``mu`` of :math:`(I + \\mu L) Y = X`: SURE over log mu (grid, then golden section).

    The search starts at :math:`\\mu_0 = k / \\bar d`, with ``k`` the SURE-best number of
    averaging steps: both filters damp the eigenmode of :math:`I - D^{-1}W` with
    eigenvalue :math:`\\lambda` by about half when :math:`k\\lambda \\approx \\mu \\bar d \\lambda \\approx 1`.
    """
    p = best_shifted(ctx.V, ctx.ops, 1, ctx.rho, ctx.criterion, ctx.exact, center=ctx.mu_guess(1), coordinates=False,
                     config=ctx.config_for(SEARCH))
    return {"mu": float(p.value)}, p


# criterion "normals": mu from 0.01 to 10,000 in steps of 2^(1/3), the least held-out face-normal loss: on the
# corpus's tune half 1.28 times the sweep's best error (geometric mean) against 1.48 for SURE's choice moved by the
# estimated normal risk (benchmarks/results/held-out-sweeps.md)
SOBOLEV_NORMALS = HeldOutRule((Sweep("mu", geometric(0.01, 1e4, 2 ** (1 / 3))),))
