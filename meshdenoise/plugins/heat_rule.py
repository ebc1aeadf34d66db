"""``heat``'s automatic rule: ``time`` (and ``tau`` unless given) by SURE along one run of explicit-Euler steps, and
the held-out sweep of its normals criterion (``HEAT_NORMALS``)."""

from __future__ import annotations

from ..tuning.context import TuningContext
from ..tuning.risk import Point
from ..tuning.search import averaging_step, best_on_curve, best_on_path, iterative_path, path_curve
from ..tuning.sweep import HeldOutRule, Sweep, geometric

__all__ = ["choose_heat", "HEAT_NORMALS"]


def choose_heat(ctx: TuningContext) -> tuple[dict, Point]:
    """``time`` (and ``tau`` unless given) of explicit-Euler heat diffusion.

    For each candidate ``tau`` in (0.25, 0.5, 1) the SURE curve over ``time = k tau`` is
    read along one run; the (tau, time) of the smallest SURE wins. Smaller steps follow
    :math:`e^{-T(I - P)}` more closely; tau = 1 is plain averaging, whose high-frequency
    gain :math:`(1 - \\lambda)^k` alternates in sign on bipartite-like meshes.
    """
    taus = [float(ctx.given["tau"])] if "tau" in ctx.given else [0.25, 0.5, 1.0]
    best, best_tau = None, None
    for tau in taus:
        if ctx.oracle:
            p = best_on_path(iterative_path(ctx.V, ctx.ops, averaging_step(ctx.ops.P, tau), ctx.exact), ctx.ops.n, ctx.rho, ctx.criterion)
        else:  # memoised: tau = 1 is the averaging run estimate_noise already made
            curve = path_curve(ctx.V, ctx.ops, averaging_step(ctx.ops.P, tau), ("P", tau), ctx.exact)
            p = best_on_curve(curve, ctx.ops.n, ctx.rho, ctx.criterion, coordinates=False)
        if best is None or p.score < best.score:
            best, best_tau = p, tau
    return {"tau": best_tau, "time": float(best.value * best_tau)}, best


# criterion "normals": steps of tau = 0.1, from 1 to 5,000 of them in steps of 15 % along one run, the least held-out
# face-normal loss: on the corpus's tune half 1.22 times the sweep's best error (geometric mean; 1.13 on the 13 cases
# where the normal-risk search it replaced read 1.66) (benchmarks/results/held-out-sweeps.md)
HEAT_NORMALS = HeldOutRule((Sweep("time", tuple(round(0.1 * k, 6) for k in geometric(1, 5000, 1.15, integer=True)),
                                  (("tau", 0.1),), additive=True),))
