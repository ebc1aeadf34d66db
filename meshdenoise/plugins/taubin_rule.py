"""``taubin``'s automatic rule: ``iterations`` by SURE along one run for each shrinking step ``lam`` at the pass band of the
given (or default) pair, its settings (:class:`TaubinConfig`) and the held-out sweep of its normals criterion
(``TAUBIN_NORMALS``)."""

from __future__ import annotations

from dataclasses import dataclass

from ..registry import get_filter
from ..tuning.config import check_fields
from ..tuning.context import TuningContext
from ..tuning.risk import Point
from ..tuning.search import averaging_step, best_on_curve, best_on_path, iterative_path, path_curve
from ..tuning.sweep import HeldOutRule, Sweep, geometric
from ._averaging import meshlab_taubin_operator

__all__ = ["choose_taubin", "taubin_mu_for", "TaubinConfig", "TAUBIN_LAMBDAS", "TAUBIN_NORMALS"]

TAUBIN_LAMBDAS = (0.5, 0.25, 0.125)  # candidate shrinking steps of the automatic taubin rule


@dataclass(frozen=True)
class TaubinConfig:
    """The taubin rule's pruning (``choose_parameters(..., config=TaubinConfig(...))``).

    Attributes
    ----------
    fine_min_vertices : int
        From this size a finer lambda is tried only while ...
    fine_max_iterations : int
        ... the coarser one's best count is below this (a count past it is already a fine step's).
    """

    fine_min_vertices: int = 10_000
    fine_max_iterations: int = 8

    def __post_init__(self) -> None:
        check_fields(self, nonnegative=("fine_min_vertices", "fine_max_iterations"))


DEFAULT = TaubinConfig()


def taubin_mu_for(lam: float, pass_band: float) -> float:
    """The inflating step ``mu`` that gives Taubin's filter the pass-band frequency ``pass_band``.

    .. math:: k_{PB} = \\frac1\\lambda + \\frac1\\mu \\quad\\Rightarrow\\quad \\mu = \\frac{1}{k_{PB} - 1/\\lambda}

    Parameters
    ----------
    lam : float in (0, 1]
        Shrinking step.
    pass_band : float
        :math:`k_{PB}`, with :math:`0 < k_{PB} < 1/\\lambda - 1` so that :math:`-1 \\le \\mu < 0`.

    Examples
    --------
    >>> round(taubin_mu_for(0.5, 1 / 0.5 + 1 / -0.53), 6)  # the defaults' own pass band
    -0.53
    """
    if not (0 < lam <= 1):
        raise ValueError(f"taubin_mu_for: parameter 'lam' = {lam!r} is out of range: 0 < lam <= 1")
    if not (0 < pass_band < 1 / lam - 1):
        raise ValueError(f"taubin_mu_for: parameter 'pass_band' = {pass_band!r} is out of range: 0 < pass_band < 1/lam - 1")
    return 1.0 / (pass_band - 1.0 / lam)


def choose_taubin(ctx: TuningContext) -> tuple[dict, Point]:
    """``iterations`` (and ``lam``, ``mu`` unless given) of Taubin lambda/mu smoothing.

    With ``weights`` "uniform" or "meshlab" one iteration is the linear map
    :math:`H_1 = (I + \\mu(A - I))(I + \\lambda(A - I))`, so SURE is read along one run
    exactly as for ``filtering``. Unless ``lam`` or ``mu`` is given, the run is repeated for
    :math:`\\lambda \\in` ``TAUBIN_LAMBDAS`` (0.5, 0.25, 0.125) with :math:`\\mu` from
    :func:`taubin_mu_for` keeping the pass band :math:`k_{PB} = 1/\\lambda + 1/\\mu` of the
    defaults (0.5, -0.53): the same low-pass shape, finer steps (one default iteration
    can already be too much on weak noise: Nefertiti at rho = 0.015), and the smallest
    SURE wins, as ``tau`` for ``heat``. From ``TaubinConfig.fine_min_vertices`` (10,000) vertices a
    finer lambda is tried only while the best count so far is below ``TaubinConfig.fine_max_iterations``
    (8): the finer steps are there for weak noise, where one default iteration is already too
    much; with more iterations the count itself resolves the time, and each halving of lambda
    doubles a walk that is already long (the 400k scale mesh: 80 iterations at lambda 0.5,
    docs/scale.md). Open3D's weights depend on the coordinates: not
    linear, not supported here.
    """
    weights = ctx.given.get("weights", "uniform")
    if weights == "open3d":
        raise ValueError(
            "choose_parameters: taubin with weights='open3d' (inverse-distance, recomputed each pass) is not a "
            "linear smoother; automatic parameters need weights 'uniform' or 'meshlab'"
        )
    spec = get_filter("taubin")
    lam0, mu0 = float(spec.param("lam").default), float(spec.param("mu").default)
    if "lam" in ctx.given or "mu" in ctx.given:
        pairs = [(float(ctx.given.get("lam", lam0)), float(ctx.given.get("mu", mu0)))]
    else:
        pass_band = 1.0 / lam0 + 1.0 / mu0
        pairs = [(lam, taubin_mu_for(lam, pass_band)) for lam in TAUBIN_LAMBDAS]
    A = ctx.ops.P if weights == "uniform" else meshlab_taubin_operator(ctx.ops)
    config = ctx.config_for(DEFAULT)
    best, best_pair = None, None
    for lam, mu in pairs:
        if best is not None and ctx.n >= config.fine_min_vertices and best.value >= config.fine_max_iterations:
            break  # the run's own count already resolves the time; a finer step costs twice the walk
        shrink, inflate = averaging_step(A, lam), averaging_step(A, mu)
        step = lambda Y, s=shrink, f=inflate: f(s(Y))  # noqa: E731
        if ctx.oracle:
            p = best_on_path(iterative_path(ctx.V, ctx.ops, step, ctx.exact), ctx.ops.n, ctx.rho, ctx.criterion)
        else:
            curve = path_curve(ctx.V, ctx.ops, step, ("taubin", weights, lam, mu), ctx.exact)
            p = best_on_curve(curve, ctx.ops.n, ctx.rho, ctx.criterion, coordinates=False)
        if best is None or p.score < best.score:
            best, best_pair = p, (lam, mu)
    out = {"iterations": int(best.value)}
    if len(pairs) > 1:
        out.update(lam=best_pair[0], mu=best_pair[1])
    return out, best


# criterion "normals": iterations from 1 to 2,000 in steps of 15 % along one run, lam and mu the defaults, the least
# held-out face-normal loss: on the corpus's tune half 1.19 times the sweep's best error (geometric mean) against 1.39
# for SURE over three lambdas moved by the estimated normal risk (benchmarks/results/held-out-sweeps.md)
TAUBIN_NORMALS = HeldOutRule((Sweep("iterations", geometric(1, 2000, 1.15, integer=True), (("lam", 0.5), ("mu", -0.53)),
                                    additive=True),))
