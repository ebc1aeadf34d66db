"""Each filter's automatic choice against that filter's own normal-error oracle, on the peers benchmark's rows.

Issue 22's target: each filter's automatic choice (``meshdenoise.denoise(mesh, method=M)``, no clean mesh) within
10 % of that filter's oracle error, the error being the mean face-normal angle to the clean mesh (deg, lower is
better). Rows: :data:`benchmarks.peers.MESHES` (the peers table's eight, ``tiny`` for tests) or corpus cases
(``corpus:NAME``, benchmarks/corpus.py); filters: every
registered filter with an automatic rule (:func:`benchmarks.peers.our_methods`).

Per (row, filter) cell: the automatic choice (:func:`benchmarks.peers.run_ours`: normal error, SNR, the time of the
whole call, the parameters) and the oracle: the least normal error over a grid of the parameters the filter's rule
chooses, every other parameter at the value the rule used (so the oracle searches the rule's own space):

- ``filtering``: ``iterations`` (every count along one run up to 100, then about every 1 % of the count
  (:func:`walk_scored`), until ``k >= 2 k_best + 20``).
- ``heat``: ``tau`` in the rule's (0.25, 0.5, 1) x ``time = k tau`` (every k along one Euler run).
- ``taubin``: ``lam`` in ``TAUBIN_LAMBDAS`` (``mu`` from the defaults' pass band, as the rule) x every ``iterations``
  along one run (all three lambdas, also where the rule skips the finer ones on large meshes).
- ``sinkhorn``: ``t`` by :func:`minimize_log` (log grid, golden section to 0.01 decade) of the best over
  ``iterations`` 1..``SINKHORN_MAX_ITERATIONS`` read along one run per ``t`` (the rule's linear configuration).
- ``sobolev``, ``sobolev_bilaplacian``: ``mu`` by :func:`minimize_log`.
- ``sobolev_normal``: ``order`` in (2, 3) x ``mu`` by :func:`minimize_log`; ``tangential`` at the rule's value.
- ``sobolev_axes``: ``mu1, mu2, mu3`` by cyclic coordinate search (:func:`minimize_log` on one axis at a time, from
  the rule's choice, two sweeps, the second narrower); ``frame_steps`` and ``order`` at the rule's values.
- ``sobolev_gls``: ``beta`` in ``SOBOLEV_GLS_BETAS`` x ``mu`` by :func:`minimize_log` with a coarser grid
  (0.5 decade either side of the rule's ``mu``, golden section to 0.02 decade): each candidate is a CG solve.
- ``two_stage``: the whole grid of ``benchmarks/two_stage_auto.py`` (``GRID_SIGMA_R`` x
  ``GRID_NORMAL_ITERATIONS`` x vertex steps 10, 20, 40 x 1..``GRID_MAX_ITERATIONS`` outer iterations,
  ``sigma_s`` 1, ``keep_tangential`` on); ``--two-stage-from JSON`` copies that script's ``grid_ne`` for the rows it
  shares (the same benchmark pairs), which depend on the filter only, not on the rule.

The automatic choice itself is a candidate of every oracle (``oracle = min(grid best, auto)``), so ``auto / oracle``
is at least 1; where the rule's choice lies outside the grid and beats it (two_stage's ``sigma_s`` and fine run are
not in its grid), the table says so. ``edge``: the best lies at an end of a grid axis that could not be extended
(a continuous axis is extended by up to ``EXTEND`` points while its minimum sits at an end).
``auto re-applied``: the normal error of ``apply_filter(M, noisy, **auto parameters)``, a check that the oracle's
evaluator computes what ``denoise`` computed.

One subprocess per (row, filter) (``--one``), at most ``--jobs`` at a time, each killed after ``--timeout`` s and
then recorded as "not measured (> T s)"; cells are stored in ``FILE.json`` as they complete and ``--resume`` measures
only the missing ones.

Run:  PYTHONPATH=. python benchmarks/filter_oracle.py [--rows NAME ...] [--filters NAME ...] [--timeout 1200]
      [--jobs 1] [--two-stage-from benchmarks/results/two-stage-auto.json] [--resume] --out FILE.md
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shlex
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from peers import CORPUS_PREFIX, DEFAULT_MESHES, MESHES, _quality, build_mesh, our_methods, run_ours  # noqa: E402

TARGET = 1.10  # issue 22: the automatic choice within 10 % of the filter's oracle error
SPACING = 0.25  # decades between the points of a continuous axis's coarse grid
HALF_WIDTH = 1.0  # the coarse grid spans this many decades either side of the rule's value
TOL = 0.01  # golden section stops when the bracket is this many decades wide
EXTEND = 8  # a coarse grid is extended by at most this many points while its best sits at an end
WALK_MAX = 20000  # cap of a walk along an iterative run
WALK_DENSE = 100  # a walk scores every step up to this count, then about every 1 % of the count


# ----------------------------------------------------------------------------- pure helpers
def minimize_log(f: Callable[[float], float], center: float, spacing: float = SPACING,
                 half_width: float = HALF_WIDTH, tol: float = TOL, extend: int = EXTEND,
                 memo: dict | None = None) -> tuple[float, float, bool, dict]:
    """Minimise ``f`` over ``t`` (a log10 parameter): a coarse grid, extended at an end, then golden section.

    The coarse grid is ``center + spacing * j`` for ``|j| <= half_width / spacing``; while its least value sits at
    one of its ends the grid grows by one point at that end (at most ``extend`` points). Then golden-section search
    in the bracket ``[t_best - spacing, t_best + spacing]`` until it is narrower than ``tol``. The least value of
    every evaluation is returned (golden section assumes one minimum in the bracket; it never loses the grid's best).

    Parameters
    ----------
    f : callable
        ``f(t)``, a float (NaN counts as infinity).
    center : float
    spacing, half_width, tol : float, > 0
    extend : int, >= 0
    memo : dict, optional
        ``{round(t, 9): value}`` of earlier evaluations, reused and added to.

    Returns
    -------
    t_best : float
    f_best : float
    edge : bool
        Whether the best is at an end of the coarse grid after the extensions (the minimum may lie beyond).
    memo : dict
        Every evaluation.

    Raises
    ------
    ValueError
        On a non-positive ``spacing``, ``half_width`` or ``tol``, or a negative ``extend``.

    Examples
    --------
    >>> t, v, edge, _ = minimize_log(lambda t: (t - 0.37) ** 2, 0.0)
    >>> round(t, 2), edge
    (0.37, False)
    """
    if not (spacing > 0 and half_width > 0 and tol > 0) or extend < 0:
        raise ValueError(f"minimize_log: spacing, half_width, tol must be > 0 and extend >= 0, got "
                         f"{spacing!r}, {half_width!r}, {tol!r}, {extend!r}")
    memo = {} if memo is None else memo

    def at(t: float) -> float:
        key = round(t, 9)
        if key not in memo:
            v = float(f(key))
            memo[key] = math.inf if math.isnan(v) else v
        return memo[key]

    m = max(1, int(round(half_width / spacing)))
    grid = [center + spacing * j for j in range(-m, m + 1)]
    for t in grid:
        at(t)
    added = 0
    while added < extend:
        vals = [at(t) for t in grid]
        j = int(np.argmin(vals))
        if j == 0:
            grid.insert(0, grid[0] - spacing)
        elif j == len(grid) - 1:
            grid.append(grid[-1] + spacing)
        else:
            break
        at(grid[0] if j == 0 else grid[-1])
        added += 1
    vals = [at(t) for t in grid]
    j = int(np.argmin(vals))
    edge = j in (0, len(grid) - 1)
    a, b = grid[j] - spacing, grid[j] + spacing
    g = (math.sqrt(5.0) - 1.0) / 2.0
    c, d = b - g * (b - a), a + g * (b - a)
    while b - a > tol:
        if at(c) <= at(d):
            b, d = d, c
            c = b - g * (b - a)
        else:
            a, c = c, d
            d = a + g * (b - a)
    best = min(memo, key=memo.get)
    return float(best), memo[best], edge, memo


def ratio(auto: float, oracle: float) -> float:
    """``auto / oracle`` of two normal errors (``inf`` for a zero oracle and a non-zero auto)."""
    if oracle < 0 or auto < 0:
        raise ValueError(f"ratio: normal errors are >= 0, got auto={auto!r}, oracle={oracle!r}")
    if oracle == 0:
        return 1.0 if auto == 0 else math.inf
    return auto / oracle


def outside(cells: list[dict], target: float = TARGET) -> list[tuple[str, str, float]]:
    """The measured cells whose ``auto / oracle`` exceeds ``target``: ``(filter, row, ratio)``, worst first."""
    out = [(c["filter"], c["row"], c["ratio"]) for c in cells if "ratio" in c and c["ratio"] > target]
    return sorted(out, key=lambda x: -x[2])


# ----------------------------------------------------------------------------- oracles
class Scorer:
    """Normal error and SNR of candidates against the clean mesh; keeps the best by normal error."""

    def __init__(self, V0: np.ndarray, F: np.ndarray):
        self.V0, self.F, self.best, self.count = V0, F, None, 0

    def __call__(self, X: np.ndarray, params: dict) -> float:
        q = _quality(self.V0, self.F, np.asarray(X, dtype=np.float64))
        self.count += 1
        if self.best is None or q["normal_error_deg"] < self.best["ne"]:
            self.best = {"ne": q["normal_error_deg"], "snr": q["snr_db"], "params": dict(params)}
        return q["normal_error_deg"]


def walk_scored(k: int) -> bool:
    """Whether a walk scores step ``k``: every step up to ``WALK_DENSE``, then every ``k // WALK_DENSE``-th
    (about 1 % of the count apart: long walks of Taubin's fine steps, thousands of steps, stay affordable).

    Examples
    --------
    >>> [k for k in range(195, 215) if walk_scored(k)]
    [195, 196, 197, 198, 199, 200, 202, 204, 206, 208, 210, 212, 214]
    """
    return k <= WALK_DENSE or k % (k // WALK_DENSE) == 0


def _walk_path(scorer: Callable[[np.ndarray, dict], float], X0: np.ndarray, step: Callable,
               params: Callable[[int], dict]) -> dict:
    """Score the states 0, 1, 2, ... of ``X <- step(X)`` (those :func:`walk_scored` picks) until past the minimum
    (:func:`~meshdenoise.tuning.walk.past_minimum`: ``k >= 2 k_best + 20``) or ``WALK_MAX`` steps; the walk's record."""
    from meshdenoise.tuning.walk import past_minimum

    X = np.array(X0, dtype=np.float64)
    k = best_k = 0
    best = scorer(X, params(0))  # no step: the input itself is a candidate (``iterations=0``)
    scored = 1
    while True:
        if past_minimum(k, best_k):
            stop = "past minimum"
            break
        if k >= WALK_MAX:
            stop = "max_steps"
            break
        X = step(X)
        k += 1
        if walk_scored(k):
            v = scorer(X, params(k))
            v = math.inf if math.isnan(v) else v
            scored += 1
            if v < best:
                best, best_k = v, k
    return {"best_k": best_k, "steps": k, "scored": scored, "stop": stop}


def oracle_filtering(V0, F, Vn, auto: dict, scorer: Scorer) -> dict:
    from meshdenoise.operators import get_operators
    from meshdenoise.plugins.filtering import averaging_operator
    from meshdenoise.tuning.search import averaging_step

    ops = get_operators(F, Vn.shape[0])
    w = _walk_path(scorer, Vn, averaging_step(averaging_operator(ops, "uniform", None, True), 1.0),
                   lambda k: {"iterations": k})
    return {"grid": "iterations 0, 1, 2, ... along one run (every step to 100, then every ~1 %; until 2 k_best + 20)",
            "edges": ["iterations"] if w["stop"] != "past minimum" else [], "walks": {"lam=1": w}}


def oracle_heat(V0, F, Vn, auto: dict, scorer: Scorer) -> dict:
    from meshdenoise.operators import get_operators
    from meshdenoise.tuning.search import averaging_step

    ops = get_operators(F, Vn.shape[0])
    walks = {}
    for tau in (0.25, 0.5, 1.0):
        walks[f"tau={tau:g}"] = _walk_path(scorer, Vn, averaging_step(ops.P, tau),
                                           lambda k, tau=tau: {"tau": tau, "time": k * tau})
    edges = ["time"] if any(w["stop"] != "past minimum" for w in walks.values()) else []
    if scorer.best["params"]["tau"] in (0.25,):
        edges.append("tau (smallest of the rule's)")
    return {"grid": "tau in (0.25, 0.5, 1) x time = k tau, k along one Euler run (every step to 100, then every "
                    "~1 %; until 2 k_best + 20)",
            "edges": edges, "walks": walks}


def oracle_taubin(V0, F, Vn, auto: dict, scorer: Scorer) -> dict:
    from meshdenoise.operators import get_operators
    from meshdenoise.plugins.taubin_rule import TAUBIN_LAMBDAS, taubin_mu_for
    from meshdenoise.registry import get_filter
    from meshdenoise.tuning.search import averaging_step

    spec = get_filter("taubin")
    lam0, mu0 = float(spec.param("lam").default), float(spec.param("mu").default)
    band = 1.0 / lam0 + 1.0 / mu0
    ops = get_operators(F, Vn.shape[0])
    walks = {}
    for lam in TAUBIN_LAMBDAS:
        mu = taubin_mu_for(lam, band)
        shrink, inflate = averaging_step(ops.P, lam), averaging_step(ops.P, mu)
        walks[f"lam={lam:g}"] = _walk_path(scorer, Vn, lambda Y, s=shrink, f=inflate: f(s(Y)),
                                           lambda k, lam=lam, mu=mu: {"iterations": k, "lam": lam, "mu": mu})
    edges = ["iterations"] if any(w["stop"] != "past minimum" for w in walks.values()) else []
    if scorer.best["params"]["lam"] == min(TAUBIN_LAMBDAS):
        edges.append("lam (finest of the rule's)")
    return {"grid": f"lam in {TAUBIN_LAMBDAS} (mu for the defaults' pass band) x iterations along one run "
                    "(every step to 100, then every ~1 %; until 2 k_best + 20)", "edges": edges, "walks": walks}


def oracle_sinkhorn(V0, F, Vn, auto: dict, scorer: Scorer) -> dict:
    from meshdenoise.ot import MeshHeatKernel
    from meshdenoise.plugins.sinkhorn_rule import SINKHORN_MAX_ITERATIONS
    from meshdenoise.registry import get_filter

    steps = int(get_filter("sinkhorn").param("steps").default)

    def f(t: float) -> float:
        K = MeshHeatKernel(Vn, F, 10.0**t, laplacian="graph", mass="uniform", steps=steps)
        Y, best = np.array(Vn, dtype=np.float64), math.inf
        for k in range(1, SINKHORN_MAX_ITERATIONS + 1):
            GY = K.solve(Y)
            Y = 2.0 * GY - K.solve(GY)
            best = min(best, scorer(Y, {"t": 10.0**t, "iterations": k}))
        return best

    _, _, edge, memo = minimize_log(f, math.log10(auto["params"]["t"]))
    edges = ["t"] if edge else []
    if scorer.best["params"]["iterations"] == SINKHORN_MAX_ITERATIONS:
        edges.append("iterations")
    return {"grid": f"log10 t: {SPACING} decade grid +-{HALF_WIDTH} around the rule's t (extended), golden to "
                    f"{TOL}; iterations 1..{SINKHORN_MAX_ITERATIONS} along each run", "edges": edges,
            "points": len(memo)}


def _oracle_mu(name: str, extra: dict):
    def oracle(V0, F, Vn, auto: dict, scorer: Scorer) -> dict:
        from meshdenoise.registry import apply_filter

        def f(t: float) -> float:
            p = {"mu": 10.0**t, **{k: auto["params"][k] for k in extra}}
            return scorer(apply_filter(name, (Vn, F), **p)[0], p)

        _, _, edge, memo = minimize_log(f, math.log10(auto["params"]["mu"]))
        return {"grid": f"log10 mu: {SPACING} decade grid +-{HALF_WIDTH} around the rule's mu (extended), golden to "
                        f"{TOL}" + (f"; {', '.join(extra)} at the rule's" if extra else ""),
                "edges": ["mu"] if edge else [], "points": len(memo)}

    return oracle


def oracle_sobolev_normal(V0, F, Vn, auto: dict, scorer: Scorer) -> dict:
    from meshdenoise.plugins.sobolev_normal_rule import SOBOLEV_NORMAL_ORDERS
    from meshdenoise.registry import apply_filter

    tangential = float(auto["params"]["tangential"])
    edges, points = [], 0
    for order in SOBOLEV_NORMAL_ORDERS:
        def f(t: float, order=order) -> float:
            p = {"mu": 10.0**t, "order": order, "tangential": tangential}
            return scorer(apply_filter("sobolev_normal", (Vn, F), **p)[0], p)

        center = math.log10(auto["params"]["mu"]) if order == auto["params"]["order"] else \
            math.log10(auto["params"]["mu"]) + (1.0 if order > auto["params"]["order"] else -1.0)
        _, _, edge, memo = minimize_log(f, center)
        points += len(memo)
        if edge:
            edges.append(f"mu (order {order})")
    return {"grid": f"order in {SOBOLEV_NORMAL_ORDERS} x log10 mu: {SPACING} decade grid +-{HALF_WIDTH} (around the "
                    f"rule's mu for its order, a decade off for the other), golden to {TOL}; tangential at the "
                    "rule's", "edges": edges, "points": points}


def oracle_sobolev_axes(V0, F, Vn, auto: dict, scorer: Scorer) -> dict:
    from meshdenoise.operators import get_operators
    from meshdenoise.plugins.sobolev_axes import normal_frame
    from meshdenoise.solvers import shifted_solver

    p = auto["params"]
    order = int(p.get("order", 3))
    steps = int(p["frame_steps"])
    ops = get_operators(F, Vn.shape[0])
    X = np.array(Vn, dtype=np.float64)
    E, _ = normal_frame(X, F, ops, steps)
    C = X @ E
    cols: dict = {}

    def column(d: int, t: float) -> np.ndarray:
        key = (d, round(t, 9))
        if key not in cols:
            cols[key] = shifted_solver(ops, 10.0**t, order).solve(np.ascontiguousarray(C[:, [d]]))[:, 0]
        return cols[key]

    t = [math.log10(p[f"mu{d + 1}"]) for d in range(3)]
    full: dict = {}

    def score(ts: list[float]) -> float:
        key = tuple(round(x, 9) for x in ts)
        if key not in full:
            Y = np.stack([column(d, ts[d]) for d in range(3)], axis=1) @ E.T
            full[key] = scorer(Y, {f"mu{d + 1}": 10.0 ** ts[d] for d in range(3)} | {"frame_steps": steps})
        return full[key]

    edges = set()
    for sweep, half in enumerate((HALF_WIDTH, 2 * SPACING)):
        for d in range(3):
            def f(x: float, d=d) -> float:
                return score([x if e == d else t[e] for e in range(3)])

            t[d], _, edge, _ = minimize_log(f, t[d], half_width=half)
            if edge:
                edges.add(f"mu{d + 1}")
    return {"grid": f"cyclic search over log10 mu1, mu2, mu3 from the rule's: per axis a {SPACING} decade grid "
                    f"+-{HALF_WIDTH} (second sweep +-{2 * SPACING}), extended, golden to {TOL}; two sweeps; "
                    "frame_steps and order at the rule's", "edges": sorted(edges), "points": len(full)}


def oracle_sobolev_gls(V0, F, Vn, auto: dict, scorer: Scorer) -> dict:
    from meshdenoise.plugins.sobolev_gls_rule import SOBOLEV_GLS_BETAS
    from meshdenoise.registry import apply_filter

    order = int(auto["params"].get("order", 3))
    edges, points = [], 0
    for beta in SOBOLEV_GLS_BETAS:
        def f(t: float, beta=beta) -> float:
            p = {"mu": 10.0**t, "beta": beta, "order": order}
            return scorer(apply_filter("sobolev_gls", (Vn, F), **p)[0], p)

        _, _, edge, memo = minimize_log(f, math.log10(auto["params"]["mu"]), spacing=0.5, half_width=0.5, tol=0.02,
                                        extend=4)
        points += len(memo)
        if edge:
            edges.append(f"mu (beta {beta:g})")
    if scorer.best["params"]["beta"] in (min(SOBOLEV_GLS_BETAS), max(SOBOLEV_GLS_BETAS)):
        edges.append("beta")
    return {"grid": f"beta in {SOBOLEV_GLS_BETAS} x log10 mu: 0.5 decade grid +-0.5 around the rule's mu (extended "
                    "by up to 4 points), golden to 0.02 (bounded: each candidate is a CG solve)", "edges": edges,
            "points": points}


def oracle_two_stage(V0, F, Vn, auto: dict, scorer: Scorer) -> dict:
    from two_stage_auto import grid_oracles

    best_ne, _ = grid_oracles(V0, Vn, F)  # measured by metrics.normal_error_deg, the formula of _quality
    scorer.best = {"ne": best_ne["ne"], "snr": best_ne["snr"], "params": best_ne["params"]}
    return {"grid": TWO_STAGE_GRID, "edges": _two_stage_edges(best_ne["params"]), "points": None}


TWO_STAGE_GRID = ("benchmarks/two_stage_auto.py's grid: sigma_r in GRID_SIGMA_R x normal_iterations in "
                  "GRID_NORMAL_ITERATIONS x vertex_iterations in (10, 20, 40) x iterations 1..8, sigma_s 1, "
                  "keep_tangential on")


def _two_stage_edges(params: dict) -> list[str]:
    import two_stage_auto as grid

    axes = {"sigma_r": grid.GRID_SIGMA_R, "normal_iterations": grid.GRID_NORMAL_ITERATIONS,
            "vertex_iterations": (10, 20, 40), "iterations": tuple(range(1, grid.GRID_MAX_ITERATIONS + 1))}
    return [k for k, axis in axes.items() if k in params and params[k] in (min(axis), max(axis))]


ORACLES: dict[str, Callable] = {
    "filtering": oracle_filtering,
    "heat": oracle_heat,
    "taubin": oracle_taubin,
    "sinkhorn": oracle_sinkhorn,
    "sobolev": _oracle_mu("sobolev", {}),
    "sobolev_bilaplacian": _oracle_mu("sobolev_bilaplacian", {}),
    "sobolev_normal": oracle_sobolev_normal,
    "sobolev_axes": oracle_sobolev_axes,
    "sobolev_gls": oracle_sobolev_gls,
    "two_stage": oracle_two_stage,
}


def measure(row: str, name: str, two_stage_grid: dict | None = None) -> dict:
    """One cell: the automatic choice, the auto parameters re-applied, and the oracle (``two_stage_grid``: a
    stored ``grid_ne`` of benchmarks/two_stage_auto.py for this row, used instead of measuring the grid)."""
    from meshdenoise.registry import apply_filter

    m = build_mesh(row)
    V0, F, Vn = m["V0"], m["F"], m["Vn"]
    out = {"row": row, "filter": name, "n": int(V0.shape[0])}
    a = run_ours(name, V0, F, Vn)
    out["auto"] = {"ne": a["normal_error_deg"], "snr": a["snr_db"], "time": a["time_s"], "params": a["params"]}
    params = {k: v for k, v in a["params"].items()}
    out["auto_reapplied_ne"] = _quality(V0, F, apply_filter(name, (Vn.copy(), F), **params)[0])["normal_error_deg"]
    scorer = Scorer(V0, F)
    t = time.perf_counter()
    if two_stage_grid is not None:
        scorer.best = {k: two_stage_grid[k] for k in ("ne", "snr", "params")}
        info = {"grid": TWO_STAGE_GRID + " (copied from --two-stage-from)", "edges": _two_stage_edges(
            two_stage_grid["params"]), "points": None}
    else:
        info = ORACLES[name](V0, F, Vn, out["auto"], scorer)
    out["oracle_time"] = time.perf_counter() - t
    out["evaluations"] = scorer.count
    out["grid_best"] = scorer.best
    out["grid"], out["edges"] = info["grid"], info["edges"]
    if "walks" in info:
        out["walks"] = info["walks"]
    auto_wins = out["auto"]["ne"] < scorer.best["ne"]
    out["oracle"] = dict(out["auto"] if auto_wins else scorer.best)
    out["oracle"].pop("time", None)
    out["oracle_is_auto"] = bool(auto_wins)
    out["ratio"] = ratio(out["auto"]["ne"], out["oracle"]["ne"])
    return out


# ----------------------------------------------------------------------------- table
def _fmt(p: dict) -> str:
    return ", ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}" for k, v in p.items())


def table(cells: list[dict], rows: list[str], filters: list[str], command: str, note: str) -> str:
    by = {(c["row"], c["filter"]): c for c in cells}
    L = ["# Each filter's automatic choice against its own normal-error oracle (issue 22)", "",
         f"Command: `{command}`  ", note, "",
         "Mean face-normal error to the clean mesh (deg, lower is better). `auto`: `denoise(noisy, method=M)` (no "
         "clean "
         "mesh); `oracle`: the least error over a grid of the parameters the rule chooses (other parameters at the "
         "rule's values; the grids are listed at the end), the automatic choice included as a candidate. Target: "
         f"auto / oracle <= {TARGET:.2f}.", "",
         "## auto / oracle", "",
         "| filter | " + " | ".join(rows) + " |", "|---|" + "---|" * len(rows)]
    for f in filters:
        cellv = []
        for r in rows:
            c = by.get((r, f))
            if c is None:
                cellv.append("not run")
            elif "status" in c:
                cellv.append(c["status"])
            else:
                mark = " **>1.10**" if c["ratio"] > TARGET else ""
                cellv.append(f"{c['ratio']:.3f}{mark}" + (" (e)" if c["edges"] else ""))
        L.append(f"| {f} | " + " | ".join(cellv) + " |")
    measured = [c for c in cells if "ratio" in c and c["row"] in rows and c["filter"] in filters]
    off = outside(measured)
    missing = [(f, r) for f in filters for r in rows if (r, f) not in by or "status" in by[(r, f)]]
    L += ["", f"(e): the oracle's best at an edge of its grid (see the cell). Measured: {len(measured)} of "
              f"{len(rows) * len(filters)} cells.", "",
          f"**Outside 10 % ({len(off)} of {len(measured)} measured cells)**"
          + (": none." if not off else ", worst first:"),
          ""]
    for f in filters:
        mine = [(r, x) for g, r, x in off if g == f]
        n_f = sum(1 for c in measured if c["filter"] == f)
        if mine:
            L.append(f"- {f} ({len(mine)} of {n_f}): " + ", ".join(f"{r} {x:.3f}" for r, x in mine))
        elif n_f:
            L.append(f"- {f} (0 of {n_f}): within 10 % on every measured row")
    L.append("")
    if missing:
        def why(f: str, r: str) -> str:
            return by[(r, f)]["status"].removeprefix("not measured ") if (r, f) in by else "(not run)"

        L.append("Not measured: " + "; ".join(f"{f} on {r} {why(f, r)}" for f, r in missing) + ".")
    L += ["", "## Cells", "",
          "| row | filter | auto ne | auto SNR | auto time (s) | oracle ne | oracle SNR | auto / oracle | auto "
          "re-applied ne | oracle time (s), evaluations | edges | auto parameters | oracle parameters |",
          "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        for f in filters:
            c = by.get((r, f))
            if c is None or "status" in c:
                L.append(f"| {r} | {f} | {'not run' if c is None else c['status']} | | | | | | | | | | |")
                continue
            o = c["oracle"]
            src = " (the auto itself: beats its grid, grid best " + f"{c['grid_best']['ne']:.2f})" \
                if c["oracle_is_auto"] else ""
            L.append(f"| {r} | {f} | {c['auto']['ne']:.2f} | {c['auto']['snr']:.2f} | {c['auto']['time']:.2f} | "
                     f"{o['ne']:.2f}{src} | {o['snr']:.2f} | {c['ratio']:.3f} | {c['auto_reapplied_ne']:.2f} | "
                     f"{c['oracle_time']:.0f}, {c['evaluations']} | {', '.join(c['edges']) or ''} | "
                     f"{_fmt(c['auto']['params'])} | {_fmt(o['params'])} |")
    L += ["", "## Grids", ""]
    seen = {}
    for c in cells:
        if "grid" in c and c["filter"] in filters:
            seen.setdefault(c["filter"], c["grid"].replace(" (copied from --two-stage-from)", ""))
    L += [f"- {f}: {g}" for f, g in sorted(seen.items())]
    return "\n".join(L) + "\n"


# ----------------------------------------------------------------------------- driving
def _load(path: Path) -> list[dict]:
    return json.loads(path.read_text()) if path.is_file() else []


def _run_one(row: str, name: str, timeout: float, ts_grid: dict | None) -> dict:
    cmd = [sys.executable, str(Path(__file__).resolve()), "--one", json.dumps([row, name, ts_grid])]
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        out, err = p.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, 9)
        p.communicate()
        return {"row": row, "filter": name, "status": f"not measured (> {timeout:g} s)"}
    if p.returncode != 0:
        last = [ln for ln in err.strip().splitlines() if ln.strip()]
        return {"row": row, "filter": name, "status": "not measured (failed: " + (last[-1] if last else
                                                                                  f"exit {p.returncode}") + ")"}
    return json.loads(out.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", nargs="+", default=DEFAULT_MESHES)
    ap.add_argument("--filters", nargs="+", default=None)
    ap.add_argument("--timeout", type=float, default=1200.0, help="seconds per cell (default 1200)")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--two-stage-from", metavar="JSON",
                    help="benchmarks/two_stage_auto.py's JSON: its grid_ne for the rows it has (two_stage's grid)")
    ap.add_argument("--resume", action="store_true", help="measure only the cells missing from FILE.json")
    ap.add_argument("--retry", action="store_true", help="with --resume: measure again the 'not measured' cells")
    ap.add_argument("--note", default="", help="a line for the table's header (load, branch)")
    ap.add_argument("--out", type=Path, required=False)
    ap.add_argument("--one", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.one:
        row, name, grid = json.loads(a.one)
        print(json.dumps(measure(row, name, grid), default=float))
        return 0
    filters = a.filters or our_methods()
    bad = [r for r in a.rows if r not in MESHES and not r.startswith(CORPUS_PREFIX)] + [f for f in filters if f not in ORACLES]
    if bad:
        print(f"filter_oracle.py: unknown row or filter {bad[0]!r}; rows: {', '.join(MESHES)}; filters: "
              f"{', '.join(ORACLES)}", file=sys.stderr)
        return 2
    if a.out is None or a.timeout <= 0 or a.jobs < 1:
        print("filter_oracle.py: --out FILE.md is required; --timeout > 0, --jobs >= 1", file=sys.stderr)
        return 2
    js = a.out.with_suffix(".json")
    cells = _load(js) if a.resume else []
    done = {(c["row"], c["filter"]) for c in cells if "status" not in c or not a.retry}
    cells = [c for c in cells if (c["row"], c["filter"]) in done]
    ts_rows = {}
    if a.two_stage_from:
        ts_rows = {r["row"]: r["grid_ne"] for r in json.loads(Path(a.two_stage_from).read_text()) if "grid_ne" in r}
    todo = [(r, f) for r in a.rows for f in filters if (r, f) not in done]
    load = " ".join(open("/proc/loadavg").read().split()[:3]) if os.path.exists("/proc/loadavg") else "?"
    args = list(argv if argv is not None else sys.argv[1:])
    if "--note" in args:  # the note is printed under the command, not inside it
        i = args.index("--note")
        del args[i:i + 2]
    command = "PYTHONPATH=. python benchmarks/filter_oracle.py " + shlex.join(args) + (" --note ..." if a.note else "")
    note = f"Load average when started: {load} (2 cores, shared: times are under load). {a.note}".strip()

    def write() -> None:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        js.write_text(json.dumps(cells, indent=1, default=float))
        a.out.write_text(table(cells, a.rows, filters, command, note))

    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(a.jobs) as pool:
        futures = {pool.submit(_run_one, r, f, a.timeout, ts_rows.get(r) if f == "two_stage" else None): (r, f)
                   for r, f in todo}
        for fut in futures:
            c = fut.result()
            cells.append(c)
            write()
            print(f"{c['row']:20s} {c['filter']:20s} " + (c.get("status") or
                  f"auto {c['auto']['ne']:.2f} oracle {c['oracle']['ne']:.2f} ratio {c['ratio']:.3f} "
                  f"({c['oracle_time']:.0f} s)"), file=sys.stderr, flush=True)
    write()
    return 0


if __name__ == "__main__":
    sys.exit(main())
