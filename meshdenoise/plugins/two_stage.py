"""Feature-preserving two-stage denoising: filter the face normals, then move the vertices to fit them."""

from __future__ import annotations

import itertools
import logging
from typing import Callable, Iterator

import numpy as np
import scipy.sparse as sp

from ..geometry import face_normals, vertex_normals
from ..normal_filter import bilateral_passes, fit_scale, GuidanceBuffers, power_of_two_scale, two_stage_topology
from ..operators import Operators, gather_rows, get_operators
from ..registry import MAX_ITERATIONS, AutoRule, Param, ParameterError, get_filter, register
from ..tuning.context import TuningContext
from ..tuning.noise_level import MAD
from ..tuning.risk import MC_SURE_STEP_CORRELATED, Point, mc_sure_step, sure
from ..tuning.walk import walk

log = logging.getLogger("meshdenoise.auto")

__all__ = ["two_stage", "outer_iterates"]


# ----------------------------------------------------------------------------- automatic rule
TWO_STAGE_MAX_ITERATIONS = 8  # outer iterations searched, 1..8, along each run ...
TWO_STAGE_MAX_NORMAL_PASSES = 8  # ... or more: up to this many normal-filtering passes in all (runs of few passes each)
TWO_STAGE_PATIENCE_PASSES = 0  # a run also goes on this many normal-filtering passes after its minimum
TWO_STAGE_SIGMA_R = (0.2, 0.25, 0.3, 0.35, 0.45)  # the grid of the automatic rule (docs/filters.md)
TWO_STAGE_NORMAL_ITERATIONS = (5, 10, 20)
TWO_STAGE_VERTEX_ITERATIONS = (40,)  # independent noise: 40 only (offered 20 and 40, the criterion preferred 20 where 40 was better)
TWO_STAGE_VERTEX_ITERATIONS_CORRELATED = (20, 40)  # correlated noise: 10 dropped, 40 added (docs/automatic-parameters.md, docs/peers.md)
TWO_STAGE_DRAWS = 2  # independent noise: synthetic copies (seeds 0..) whose median angles are averaged (one draw's choice is a lottery)
TWO_STAGE_WHITENESS = False  # on: independent, light-tailed noise gets its outer iterations from the residual's whiteness (measured, off: choose_two_stage's docstring)
TWO_STAGE_ORACLE_VERTEX_ITERATIONS = (20, 10, 40)  # the oracle (criterion="oracle") searches these
TWO_STAGE_SAMPLE = 3000  # vertices of the sampled region the rule runs on (the whole mesh below it)
TWO_STAGE_PATCHES = 6  # ... grown from this many seed vertices
TWO_STAGE_PATCHES_LARGE = (100_000, 24)  # from this many vertices, this many seeds: 3000 vertices are under 3 % of the
# surface, and 6 balls of it read its variety by chance (400k: 62.9-65.2 dB over 6 draws, 24 balls 64.6-65.4; docs/scale.md)
TWO_STAGE_PATIENCE = 2  # consistency runs stop this many iterations after their minimum (full runs: same choices on the 6 rows, 30 % slower)
TWO_STAGE_PILOT_ITERATIONS = 3  # outer iterations of the pilot (defaults, keep_tangential on)
TWO_STAGE_PILOT = {}  # the pilot's other parameters (not given ones), over the filter's defaults
TWO_STAGE_GUARD_PROBES = 6  # Rademacher probes of the guard's Monte-Carlo SURE (coloured like the noise) on a full region ...
TWO_STAGE_GUARD_PROBES_MAX = 48  # ... more on a smaller mesh (guard_probes: probes times vertices held), up to this many
TWO_STAGE_GUARD_MARGIN = 0.02  # ... which cuts iterations when SURE drops by this times n rho^2 and 2 standard errors
TWO_STAGE_GUARD_LIGHTER = (  # the guard also tries the chosen run made lighter in these ways ...
    {"normal_iterations": 5, "vertex_iterations": 10},
    {"normal_iterations": 5, "vertex_iterations": 5, "sigma_s": 0.7},  # Bunny0.2: 5.60 -> 5.31 deg, 53.27 -> 54.76 dB
)
TWO_STAGE_GUARD_LIGHTER_GAIN = 0.1  # ... one taken when its SURE is lower again by this share of the chosen one's (0.46 dB)
TWO_STAGE_GUARD_STEP_CORRELATED = MC_SURE_STEP_CORRELATED  # the guard's finite-difference step under correlated noise, in units of rho (docs/automatic-parameters.md)
TWO_STAGE_HEAVY_TAIL = 1.5  # rms / (MAD / 0.6745) of the noise above which SURE's guard is skipped (impulsive noise)
TWO_STAGE_SYNTHETIC_SCALE = 1.3  # the synthetic copy's noise, in units of the estimated rho
TWO_STAGE_FINE = {"normal_iterations": 1, "vertex_iterations": 10}  # the many-light-iterations run (PyGEL's regime) ...
TWO_STAGE_FINE_MAX_ITERATIONS = 48  # ... searched over 1..this many outer iterations ...
TWO_STAGE_FINE_PATIENCE = 4  # ... stopping this many after its minimum (the median angle is noisy at fine steps)
TWO_STAGE_FINE_GAIN = 0.2  # ... taken when its region SURE is below the choice's by this share of it (about 1 dB)
TWO_STAGE_MARGIN = 2  # rings of vertices next to a cut whose faces are left out of the score
TUNED = ("iterations", "normal_iterations", "vertex_iterations", "sigma_r", "sigma_s", "keep_tangential")
STAGES = ("sigma_r", "normal_iterations", "sigma_r", "vertex_iterations",  # the coordinate search ...
          ("normal_iterations", "vertex_iterations"))  # ... and the two counts jointly at the end
TWO_STAGE_REVISIT_SPAN = 1  # the rule's second sigma_r stage tries the grid values within this many steps of the best
# so far (the oracle: all): on 15 rows the same choices, 10-25 % fewer runs where the first stages moved


def synthetic_noise(N: np.ndarray, rho: float, seed: int = 0) -> np.ndarray:
    """The noise the consistency criterion adds to its pilot: :math:`\\rho\\, \\varepsilon_i N_i`, shape (n, 3).

    ``N`` (n, 3) unit vertex normals, :math:`\\varepsilon_i \\sim \\mathcal N(0, 1)` independent
    (the noise model of :func:`meshdenoise.add_normal_noise`), the same for a given ``seed``.
    """
    eps = np.random.default_rng(seed).standard_normal(N.shape[0])
    return rho * eps[:, None] * N


def sure_probe(N: np.ndarray, seed: int = 0) -> np.ndarray:
    """The Monte-Carlo SURE probe :math:`b_i = z_i N_i`, :math:`z_i = \\pm 1` (Rademacher), shape (n, 3), from unit normals ``N`` (n, 3)."""
    z = np.random.default_rng(seed).choice([-1.0, 1.0], size=N.shape[0])
    return z[:, None] * N


TWO_STAGE_COLOUR_RINGS = (4.0, 4)  # correlated_fields colours on the region grown by a * (diffusion length) + b rings ...
TWO_STAGE_COLOUR_SHARE = 0.5  # ... when that is at most this share of the mesh (else on the whole mesh)


def _white_fields(n: int, probes: int) -> np.ndarray:
    """The rule's white draws (n, 1 + probes): column 0 standard normal (seed 0), column ``1 + p`` Rademacher (seed ``p``)."""
    white = np.empty((n, 1 + probes))
    white[:, 0] = np.random.default_rng(0).standard_normal(n)
    for p in range(probes):
        white[:, 1 + p] = np.random.default_rng(p).choice([-1.0, 1.0], size=n)
    return white


def correlated_fields(ctx: TuningContext, vertices: np.ndarray, probes: int) -> np.ndarray:
    """The rule's noise fields under correlated noise, coloured in one block and restricted to ``vertices`` (k,): (k, 1 + probes).

    Column 0: the synthetic copy's noise, white :math:`\\mathcal N(0, 1)` (seed 0); columns
    ``1 + p``: the guard's probes, Rademacher (seed ``p``), each drawn on the whole mesh (n
    values) and coloured by the noise model's heat filter :math:`C` (one block solve for all the
    columns), then scaled to mean square 1 per vertex.

    Only ``vertices`` are read, and :math:`C` is local (its kernel, ``HEAT_STEPS`` implicit heat
    steps over the model's diffusion length :math:`L`, falls off faster than exponentially), so the
    block is solved on ``vertices`` grown by :math:`\\lceil a L \\rceil + b` rings
    (``TWO_STAGE_COLOUR_RINGS``): the same system matrix, mass and white-noise scale as the whole
    mesh's filter on those rows, the outside held at 0. At the region's vertices this is the whole
    mesh's colouring to the solver's tolerance (bunny scanner, 14 rings: 1.3e-3 of the unit scale,
    the tolerance's own level; docs/automatic-parameters.md). Each column is scaled to mean
    square 1 over the vertices within half those rings of ``vertices`` (the whole mesh's realised energy
    is not known there: the two scales differ by the sampling of a correlated field's energy, 1-4 %).
    When the grown region exceeds ``TWO_STAGE_COLOUR_SHARE`` of the mesh, the whole mesh is coloured
    (``ctx.colour``) and each column scaled to mean square 1 over the mesh.
    """
    from ..noise import HEAT_STEPS, diffusion_length
    from ..solvers import CGSolver
    from ..tuning.covariance import COLOUR_TOL

    n = ctx.n
    white = _white_fields(n, probes)
    rings = int(np.ceil(TWO_STAGE_COLOUR_RINGS[0] * diffusion_length(ctx.correlation_length))) + TWO_STAGE_COLOUR_RINGS[1]
    inside = np.zeros(n, dtype=bool)
    inside[vertices] = True
    core = None
    for r in range(rings):
        inside = inside | (ctx.ops.W @ inside.astype(np.float64) > 0)
        if r + 1 == rings // 2:
            core = inside.copy()
        if inside.sum() > TWO_STAGE_COLOUR_SHARE * n:
            break
    if inside.sum() > TWO_STAGE_COLOUR_SHARE * n or core is None:  # the whole mesh
        coloured = ctx.colour(white, 1.0 / white.shape[1])
        energy = np.sum(coloured**2, axis=0)
        scale = np.sqrt(n / np.where(energy > 0, energy, 1.0))
        return coloured[vertices] * scale
    rows = np.flatnonzero(inside)
    filt = ctx.noise.filter()  # the model's heat filter on the whole mesh (built once per model)
    solver = CGSolver(filt.solver.A[rows][:, rows])
    mass = filt.mass[rows, None]
    u = white[rows] * filt.scale[rows, None]
    for _ in range(HEAT_STEPS):  # as HeatFilter.__call__, on the grown region's rows
        u = solver.solve(mass * u, tol=COLOUR_TOL, x0=u)
    # the model's mean square per vertex over the core (1 over the whole mesh; it varies with the mesh's density),
    # read off the averaging curve's coloured probes, which the rule's guard colours anyway (ctx.smoothed)
    from ..tuning.risk import probe_block
    from ..tuning.search import probe_count

    Z, s = probe_block(n, ctx.exact, n_probes=probe_count(n), colour=ctx.noise)
    target = s * float(np.sum(Z[core] ** 2)) / int(core.sum())
    kept = core[rows]
    energy = np.sum(u[kept] ** 2, axis=0)
    scale = np.sqrt(target * int(kept.sum()) / np.where(energy > 0, energy, 1.0))
    return u[np.searchsorted(rows, vertices)] * scale


class SampledRegion:
    """A part of a mesh made of ``patches`` vertex balls (rings of neighbours), about ``size`` vertices in all.

    Attributes
    ----------
    vertices : ndarray of int64, shape (k,)
        The region's vertices (indices into the mesh), increasing.
    F : ndarray of int64, shape (l, 3)
        The faces with all three corners in the region, on the region's numbering.
    scored : ndarray of bool, shape (l,)
        Faces with no corner within ``margin`` rings of a cut (a vertex with a neighbour
        outside the region): the ones a score counts. The mesh's own boundary is no cut.

    A mesh of at most ``size`` vertices is its own region (nothing cut).
    """

    def __init__(self, F: np.ndarray, ops: Operators, size: int, patches: int, margin: int, seed: int = 0):
        n = ops.n
        if n <= size:
            self.vertices = np.arange(n, dtype=np.int64)
            self.F = np.asarray(F, dtype=np.int64)
            self.scored = np.ones(self.F.shape[0], dtype=bool)
            self.inner = np.ones(n, dtype=bool)
            return
        W = ops.W
        rng = np.random.default_rng(seed)
        used = np.zeros(n, dtype=bool)
        used[np.asarray(F).ravel()] = True  # the same mask as np.unique(F), without its sort (0.4 s at 1.6M)
        inside = np.zeros(n, dtype=bool)
        inside[rng.choice(np.flatnonzero(used), size=min(patches, int(used.sum())), replace=False)] = True
        while inside.sum() < size:  # one ring per pass; a new seed when every ball has filled its component
            grown = inside | (W @ inside.astype(np.float64) > 0)
            if grown.sum() == inside.sum():
                grown[rng.choice(np.flatnonzero(used & ~inside))] = True
            inside = grown
        keep = inside[F].all(axis=1)
        self.vertices = np.flatnonzero(inside)
        number = np.full(n, -1, dtype=np.int64)
        number[self.vertices] = np.arange(self.vertices.size)
        self.F = number[F[keep]]
        near = inside & (W @ (~inside).astype(np.float64) > 0)  # the cut
        for _ in range(margin):
            near = inside & (near | (W @ near.astype(np.float64) > 0))
        self.inner = ~near[self.vertices]
        self.scored = self.inner[self.F].all(axis=1)


def guard_probes(vertices: int) -> int:
    """Probes of the guard's Monte-Carlo SURE on a region of ``vertices`` vertices.

    ``TWO_STAGE_GUARD_PROBES`` on a region of ``TWO_STAGE_SAMPLE`` vertices, and on a smaller
    mesh (the whole mesh is then the region) as many more as keep probes times vertices, up to
    ``TWO_STAGE_GUARD_PROBES_MAX``. Why: the guard compares SURE differences with a margin
    proportional to the vertex count and with two standard errors of the probes' differences,
    which grow as the square root of the vertex count over the probes; on a small mesh with 6
    probes the guard could never cut (the Nefertiti, 299 vertices: a drop of 1.2 against 2 standard
    errors of 1.4; with 24 or more probes it cut 3 outer iterations to 1, 21.95 -> 18.66 degrees,
    the oracle's 17.75; docs/automatic-parameters.md).

    >>> guard_probes(3000), guard_probes(1500), guard_probes(299)
    (6, 12, 48)
    """
    if vertices < 1:
        raise ValueError(f"guard_probes: vertices must be at least 1, got {vertices!r}")
    wanted = -(-TWO_STAGE_GUARD_PROBES * TWO_STAGE_SAMPLE // int(vertices))  # ceil
    return int(min(TWO_STAGE_GUARD_PROBES_MAX, max(TWO_STAGE_GUARD_PROBES, wanted)))


def guard_drops(per_probe: np.ndarray, last: np.ndarray, margin: float) -> bool:
    """Whether a shorter run's SURE is below the chosen run's by more than ``margin`` and two standard errors.

    ``per_probe`` and ``last`` (P,): Monte-Carlo SURE with the same P probes for the two runs;
    the paired differences :math:`d_p` must have :math:`\\bar d + 2\\, s_d / \\sqrt P < -\\mathrm{margin}`
    (:math:`s_d` their sample standard deviation; 0 with one probe).
    """
    d = np.asarray(per_probe, dtype=np.float64) - np.asarray(last, dtype=np.float64)
    se = float(np.std(d, ddof=1)) / np.sqrt(d.size) if d.size > 1 else 0.0
    return bool(float(d.mean()) + 2.0 * se < -margin)


def fine_run_wins(fine: float, along: list[float], gain: float) -> bool:
    """Whether the fine run's SURE ``fine`` is below the least of ``along`` (SURE at each outer iteration of the
    chosen run, (k,)) by ``gain`` times that least's magnitude.

    The least, not the chosen count's: SURE is a position risk, whose best count comes before the normals'
    (docs/automatic-parameters.md).
    """
    least = min(along)
    return bool(fine < least - gain * abs(least))


def face_angles(A: np.ndarray, B: np.ndarray | None, F: np.ndarray, faces: np.ndarray,
                normals_b: np.ndarray | None = None) -> np.ndarray:
    """Angles (radians) between the unit normals of faces ``F[faces]`` under ``A`` and ``B`` (n, 3), shape (k,).

    ``faces`` (m,) bool. ``normals_b`` (k, 3): ``face_normals(B, F)[faces]`` when known (``B``
    is then not read). Faces of zero area in either are left out.
    """
    a = face_normals(A, F)[faces]
    b = face_normals(B, F)[faces] if normals_b is None else normals_b
    ok = (np.abs(a).sum(axis=1) > 0) & (np.abs(b).sum(axis=1) > 0)
    a, b = a[ok], b[ok]
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.einsum("ij,ij->i", a, b))


def median_angle(A: np.ndarray, B: np.ndarray | None, F: np.ndarray, faces: np.ndarray,
                 normals_b: np.ndarray | None = None) -> float:
    """Median over ``faces`` (bool (m,)) of the angle between the unit normals of faces ``F`` under ``A`` and ``B`` (n, 3), radians.

    Faces of zero area in either are left out; ``inf`` when none is left (:func:`face_angles`).
    """
    t = face_angles(A, B, F, faces, normals_b)
    return float(np.median(t)) if t.size else float("inf")


def mean_angle(A: np.ndarray, B: np.ndarray | None, F: np.ndarray, faces: np.ndarray,
               normals_b: np.ndarray | None = None) -> float:
    """Mean over ``faces`` of the angle between the unit normals of faces ``F`` under ``A`` and ``B``, radians (as :func:`median_angle`)."""
    t = face_angles(A, B, F, faces, normals_b)
    return float(np.mean(t)) if t.size else float("inf")


def residual_correlation(Y: np.ndarray, X: np.ndarray, F: np.ndarray, W: sp.spmatrix,
                         rows: np.ndarray | None = None) -> float:
    """Lag-one autocorrelation of the method noise along the result's normals: :math:`\\sum_{ij} W_{ij} r_i r_j / (\\sum_{ij} W_{ij}\\, \\overline{r^2})`.

    ``Y``, ``X`` (n, 3): the noisy and filtered positions; ``F`` (m, 3) faces; ``W`` (n, n) the
    0/1 vertex adjacency; :math:`r_i = (Y_i - X_i) \\cdot N_i(X)` with :math:`N(X)` the
    result's unit vertex normals. ``rows`` (n,) bool: only these vertices (and the pairs
    between them) are counted (all when None). Independent noise and a filter that removes
    exactly the noise leave :math:`r` white (0); too little smoothing leaves the noise's
    high-pass part (negative: a vertex above its neighbours keeps part of its offset, they do
    not), too much moves the surface's own low frequencies into :math:`r` (positive).
    0 when the residual is 0.
    """
    r = np.einsum("ij,ij->i", np.asarray(Y, dtype=np.float64) - X, vertex_normals(X, F))
    if rows is not None:
        W = W[rows][:, rows]
        r = r[rows]
    energy = float(np.mean(r**2)) * float(W.sum())
    return float(r @ (W @ r)) / energy if energy > 0 else 0.0


def _search_grid(given: dict, oracle: bool = False, correlated: bool = False) -> dict[str, tuple]:
    """The values the rule (or the oracle, a superset) tries for each tuned parameter (one value for a given one).

    ``correlated``: the rule's grid under correlated noise (``TWO_STAGE_VERTEX_ITERATIONS_CORRELATED``).
    """
    vertex = TWO_STAGE_VERTEX_ITERATIONS_CORRELATED if correlated else TWO_STAGE_VERTEX_ITERATIONS
    grid = {"sigma_r": TWO_STAGE_SIGMA_R, "normal_iterations": TWO_STAGE_NORMAL_ITERATIONS,
            "vertex_iterations": TWO_STAGE_ORACLE_VERTEX_ITERATIONS if oracle else vertex,
            "keep_tangential": (True,)}
    return {k: (given[k],) if k in given else v for k, v in grid.items()}


def _staged_search(path: Callable[[dict], Point], grid: dict[str, tuple],
                   revisit_span: int | None = None,
                   evaluate: Callable[[Callable[[dict], Point], list[dict]], list[Point]] | None = None) -> tuple[dict, Point]:
    """Coordinate search over ``grid``: ``sigma_r``, ``normal_iterations``, ``sigma_r``, ``vertex_iterations``, then both counts jointly.

    ``path(params)`` returns the best :class:`Point` (its ``value`` the outer iteration
    count) of one run. The first stage holds the counts at 10 (or their one given value);
    each later stage varies one parameter (the last one the pair of counts, over their whole
    product) around the best so far. Ties keep the earlier (cheaper) candidate. About 12 to 15
    runs instead of the grid's 30. The joint stage: one count at a time stalls where the
    criterion wants both changed (the bunny with scanner noise of 0.5 edge lengths at
    correlation length 4: 10 passes and 20 steps, 9.59 degrees; with (5, 40) 9.33).

    ``revisit_span``: a parameter's second stage (``sigma_r``'s, after the normal-filtering count
    moved) tries only the grid values within this many grid steps of its best so far (all when
    None). The rule uses :data:`TWO_STAGE_REVISIT_SPAN` = 1: replayed on 15 rows (the 6 of
    ``benchmarks/two_stage_auto.py``, the default's bunny scanner, face000 and face000 scanner, the
    bunny and elephant with scanner noise 0.3 h at correlation lengths 1, 2 and 4), every search
    ends at the same point as with the full stage, with 10 to 25 % fewer normal-filtering passes
    where the count had moved (docs/automatic-parameters.md).

    ``evaluate(path, candidates)``: the points of a stage's new candidates, in order (a loop
    when None; the rule runs them side by side, :func:`~meshdenoise.kernels.run_concurrently`).
    A stage's candidates differ from the best so far in the stage's own parameters only, so
    they are known before any of them is run, and the choice is the loop's.
    """
    evaluate = evaluate or (lambda f, xs: [f(x) for x in xs])
    done: dict[tuple, Point] = {}
    visited: set[str] = set()
    middle = lambda values: 10 if 10 in values else values[0]  # noqa: E731
    best = {"sigma_r": grid["sigma_r"][0], "normal_iterations": middle(grid["normal_iterations"]),
            "vertex_iterations": grid["vertex_iterations"][0], "keep_tangential": grid["keep_tangential"][0]}
    best_point = None
    for stage in STAGES:
        names = stage if isinstance(stage, tuple) else (stage,)
        values_of = []
        for name in names:
            values = tuple(grid[name])
            if revisit_span is not None and not isinstance(stage, tuple) and name in visited and best[name] in values:
                j = values.index(best[name])
                values = values[max(0, j - revisit_span):j + revisit_span + 1]
            values_of.append(values)
        visited.update(names)
        stage_params = [{**best, **dict(zip(names, values))} for values in itertools.product(*values_of)]
        todo = {tuple(sorted(p.items())): p for p in stage_params}
        todo = {key: p for key, p in todo.items() if key not in done}
        done.update(zip(todo, evaluate(path, list(todo.values()))))
        for params in stage_params:
            key = tuple(sorted(params.items()))
            if best_point is None or done[key].score < best_point.score:
                best, best_point = params, done[key]
    return best, best_point


def choose_two_stage(ctx: TuningContext) -> tuple[dict, Point]:
    """``sigma_r``, ``normal_iterations``, ``vertex_iterations``, ``iterations`` and ``keep_tangential`` of ``two_stage``.

    **Criterion (no clean mesh): consistency on a synthetic copy.** The target is the mean
    face-normal error, which squared position errors (SURE) do not follow without
    ``keep_tangential``: the position optimum stops after 1 or 2 iterations, leaving 4 to
    85 % more normal error than the best (docs/filters.md). The rule denoises a pilot
    :math:`P` (``two_stage`` with the filter's defaults, ``keep_tangential`` on,
    ``TWO_STAGE_PILOT_ITERATIONS`` outer iterations), adds noise of the estimated level along
    its normals, :math:`\\tilde Y = P + \\rho\\, \\varepsilon N(P)` (:func:`synthetic_noise`),
    and scores each candidate :math:`\\theta` by the median angle between the face normals of
    :math:`f_\\theta(\\tilde Y)` and of :math:`P` (:func:`median_angle`), averaged over
    ``TWO_STAGE_DRAWS`` (2) copies drawn with seeds 0, 1 (independent noise; one coloured copy under
    correlated noise): with one draw the choice was a lottery (over 8 seeds 1.04-1.18 times the grid's best
    normal error on Fandisk0.3 before the fine run, 1.00-1.46 on Twelve0.5Impulsive; docs/automatic-parameters.md).
    The median, not the
    mean: :math:`P`'s own errors sit at its sharp edges, where a candidate like the pilot's
    reproduces them, so a mean prefers the pilot's parameters; the median is decided by the
    faces the pilot got right. ``keep_tangential`` is on (the noise model moves vertices
    along the normals only; the criterion, on normals, cannot see tangential positions).

    **Guard (smooth meshes).** The synthetic copy is as smooth as the pilot, so on a mesh
    with fine detail the criterion over-smooths. Along the chosen run, Monte-Carlo SURE on
    positions (Ramani et al. 2008, ``TWO_STAGE_GUARD_PROBES`` probes coloured like the noise, more on a
    mesh smaller than the region (:func:`guard_probes`),
    along the normals of the SURE-smoothed mesh) may cut the outer iterations: to the count of
    least SURE among those whose SURE is below the chosen count's by ``TWO_STAGE_GUARD_MARGIN``
    :math:`n\\rho^2` and two standard errors of the paired differences (:func:`guard_drops`).
    Then the same run made lighter in each of the ways of ``TWO_STAGE_GUARD_LIGHTER`` (5
    normal-filtering passes and 10 vertex steps; 5, 5 and the narrower spatial kernel
    ``sigma_s=0.7``; parameters not given) replaces it with the point of least SURE among those
    whose SURE is lower again by ``TWO_STAGE_GUARD_LIGHTER_GAIN`` of the chosen point's (the bunny
    with independent noise of 0.3 edge lengths: 56.57 -> 58.27 dB and 5.40 -> 4.93 degrees, the first;
    Bunny0.2: 53.27 -> 54.76 dB and 5.60 -> 5.31 degrees, the second). ``sigma_s`` is chosen by these
    runs only (the filter's 1.0 otherwise). Skipped for heavy-tailed (impulsive) noise, which SURE's Gaussian
    model does not fit. Under correlated noise the divergence's finite-difference step is
    ``TWO_STAGE_GUARD_STEP_CORRELATED`` (one rho): at ``MC_SURE_STEP`` (0.1 rho) the filter's response missed
    10-12 % of the realised covariance of the noise, more after fewer iterations, and the guard cut the bunny
    with scanner noise at correlation length 2 from 5 iterations to 2 (8.58 -> 9.33 degrees; one rho: 3, 8.63).

    **Many light iterations (feature meshes).** When the guard keeps the criterion's choice (it
    neither cut nor lightened it: the mesh is not one the synthetic copy over-smooths) and the
    noise is not heavy-tailed, the rule also runs the chosen ``sigma_r`` with one normal-filtering
    pass and 10 vertex steps per outer iteration (``TWO_STAGE_FINE``, PyGEL's
    ``anisotropic_smooth`` regime) on the synthetic copy, over 1 to ``TWO_STAGE_FINE_MAX_ITERATIONS``
    outer iterations (stopping ``TWO_STAGE_FINE_PATIENCE`` after the least median angle), and takes
    that run's best point when (a) its *mean* face-normal angle to the pilot is below the choice's
    and (b) its region SURE is below the least SURE along the chosen run by ``TWO_STAGE_FINE_GAIN``
    (0.2, about 1 dB) of it (the least, not the chosen count's: SURE is a position risk, whose best count
    comes before the normals'; Block0.4 at (0.3, 5, 40, 8): 8.84 at the chosen count, 3.86 at 2, the fine
    run 5.54 and 3.03 degrees against the choice's 2.68). The
    median decides the run length (it is not dominated by the pilot's own feature errors) but does
    not compare regimes: the pilot is made in the heavy regime (10 passes), which reproduces its
    own flat sides better on the copy, so the median preferred it (Fandisk0.3: 0.0363 against
    0.0380) where the light run is better against the clean mesh (2.18 against 2.39 degrees); the
    mean, which counts the faces at the features, where the light run is better, orders them right
    (0.0622 against 0.0637), and SURE (0.194 against 0.287) confirms it on positions. On Block0.4
    the mean also preferred the light run (0.0563 against 0.0596) but SURE only by 2 % (truth: 0.8 dB
    worse), so (b) keeps the choice; with another synthetic draw SURE said 10.5 % where the truth
    was again 0.8 dB worse, hence 0.2 and not the lighter runs' 0.1 (Fandisk0.3: 32 and 41 % on the
    two draws that took it, truth 1.2 and 1.0 dB better; docs/automatic-parameters.md).

    **Synthetic noise level.** ``TWO_STAGE_SYNTHETIC_SCALE`` (1.3) times the estimated rho
    (independent noise; correlated noise is already read 1.2-1.5 times too high, and 1.3 there
    lost 0.6 dB on the elephant at correlation length 1): the
    pilot is a near-fixed point of the filter (its features already as the filter makes them),
    so the synthetic copy is easier than the real mesh and, at 1.0 times rho, asked for too few
    iterations (Twelve0.5Impulsive: 4 against 7 or 8, 1.29 times the grid's best normal
    error; at 1.3: 1.00; docs/automatic-parameters.md).

    **Vertex steps.** ``TWO_STAGE_VERTEX_ITERATIONS`` is 40 (independent noise): with 20 and 40
    the criterion preferred 20 where 40 was better (Block0.4, on the rule's two draws: (0.3, 10, 20), 3.04
    degrees, against (0.3, 5, 40), 2.78; the grid's truth prefers 40 at every sigma_r there with 5 or 10
    passes), and the search
    is shorter by its vertex-step stage. Under correlated noise (``TWO_STAGE_VERTEX_ITERATIONS_CORRELATED``,
    not measured again) 20 and 40: the criterion preferred 10
    (the pilot's own count) on Fandisk0.3 and Block0.4, where 20 was better (Block0.4: 3.10
    against 2.94 degrees, the grid's best 2.74), so 10 is left to the guard's lighter runs; 40
    lowered Twelve0.5Impulsive from 2.37 to 2.06 degrees and changed no other benchmark row for the
    worse (docs/peers.md). The oracle searches 10, 20 and 40.

    **Search.** Outer iterations along each run (1 to ``TWO_STAGE_MAX_ITERATIONS``, stopping
    two after the minimum), the rest by :func:`_staged_search` (ending with the two counts
    jointly) over ``TWO_STAGE_SIGMA_R``,
    ``TWO_STAGE_NORMAL_ITERATIONS`` and ``TWO_STAGE_VERTEX_ITERATIONS``, its second ``sigma_r``
    stage within ``TWO_STAGE_REVISIT_SPAN`` grid steps of the best so far (the oracle: the whole
    grid); parameters in ``ctx.given`` are held. ``TWO_STAGE_WHITENESS`` (off) would set the outer
    iterations afterwards to the count of the whitest method noise on the noisy region
    (:func:`residual_correlation`; Block0.4 2.68 degrees against 2.78, but 33 % more choice time in
    a default's choice that runs two_stage, from the longer run, and the elephant 1.5 % worse).

    **Cost.** Everything runs on a :class:`SampledRegion` of ``TWO_STAGE_SAMPLE`` vertices in
    ``TWO_STAGE_PATCHES`` patches (24 from 100,000 vertices, ``TWO_STAGE_PATCHES_LARGE``: smaller
    balls spread over more of a large surface, a steadier choice; faces and vertices within
    ``TWO_STAGE_MARGIN`` rings of a cut not scored), so the choice costs about the same at 50k and at 1M vertices apart from
    the region's growth (a sparse product per ring). A stage's candidates and the guard's
    runs (the chosen run and its probes) run side by side, one kernel thread each
    (:func:`~meshdenoise.kernels.run_concurrently`; the same bits as one after another).

    ``criterion="oracle"`` runs the same staged search on the whole noisy mesh, scored by the
    squared position error against the reference (the generic oracle). The returned point's
    score estimates the whole mesh's squared error :math:`\\|f(X) - X^0\\|_F^2` (the region's
    Monte-Carlo SURE on its inner vertices, scaled by ``n`` over their count: comparable with the
    other filters' SURE); its ``X`` is the result on the sampled region (oracle: on the mesh).
    """
    from .. import kernels

    spec = get_filter("two_stage")
    full = spec.resolve(ctx.given, where="choose_parameters(method='two_stage')")
    n = ctx.ops.n
    if ctx.criterion.name == "gcv":
        raise ValueError("choose_parameters: two_stage is not a linear smoother; use criterion 'sure' or 'oracle'")
    if (ctx.rho is not None and ctx.rho == 0) or ctx.given.get("iterations") == 0:
        return ({} if "iterations" in ctx.given else {"iterations": 0}), Point(0, 0.0, float(n), np.array(ctx.V, dtype=np.float64), 0.0)
    fixed_k = "iterations" in ctx.given

    def run_length(params: dict) -> int:
        """Outer iterations searched along a run of ``params``: the given count, else 1..max(8, passes / ni)."""
        if fixed_k:
            return int(ctx.given["iterations"])
        ni = {**full, **params}["normal_iterations"]
        return max(TWO_STAGE_MAX_ITERATIONS, TWO_STAGE_MAX_NORMAL_PASSES // max(ni, 1))

    def patience(params: dict) -> int:
        ni = {**full, **params}["normal_iterations"]
        return max(TWO_STAGE_PATIENCE, TWO_STAGE_PATIENCE_PASSES // max(ni, 1))

    def runs(start: np.ndarray, F: np.ndarray, ops: Operators, params: dict,
             length: int | None = None) -> Iterator[tuple[int, np.ndarray]]:
        """(k, positions after k outer iterations), k = 1.. ``length`` or :func:`run_length` (the given count only, when held)."""
        step = {**full, **params}
        per_iteration = max(1, step["normal_iterations"] + step["vertex_iterations"])
        step["iterations"] = max(1, min(run_length(params) if length is None else length, MAX_ITERATIONS // per_iteration))  # the filter's bound on passes
        for k, X in enumerate(outer_iterates(start, ops, None, **step, every=not fixed_k), start=1):
            yield (step["iterations"] if fixed_k else k), X

    def best_on_run(points: Iterator[Point], patience: int = 2) -> Point:
        """The best point of a run, which stops ``patience`` iterations after the minimum (the tuning walk)."""
        return walk(points, lambda p: p.score, patience=patience).best[0].item

    if ctx.oracle:
        def path(params: dict) -> Point:
            def scored():
                for k, X in runs(ctx.V, ctx.F, ctx.ops, params):
                    p = Point(k, float(np.sum((X - ctx.V) ** 2)), 0.0, X)
                    p.score = ctx.score(p)
                    yield p
            return best_on_run(scored())

        chosen, best = _staged_search(path, _search_grid(ctx.given, oracle=True))
        chosen["iterations"] = int(best.value)
        chosen.setdefault("sigma_s", full["sigma_s"])
        return {k: v for k, v in chosen.items() if k not in ctx.given}, best

    patches = TWO_STAGE_PATCHES_LARGE[1] if ctx.n >= TWO_STAGE_PATCHES_LARGE[0] else TWO_STAGE_PATCHES
    region = SampledRegion(ctx.F, ctx.ops, TWO_STAGE_SAMPLE, patches, TWO_STAGE_MARGIN)
    F = region.F
    ops = get_operators(F, region.vertices.size)
    Y = np.ascontiguousarray(ctx.V[region.vertices], dtype=np.float64)
    pilot_params = {**full, **{k: v for k, v in TWO_STAGE_PILOT.items() if k not in ctx.given},
                    "iterations": TWO_STAGE_PILOT_ITERATIONS, "keep_tangential": True}
    pilot = spec.core(Y, F, ops=ops, pinned=None, **pilot_params)
    Np = vertex_normals(pilot, F)
    pilot_normals = face_normals(pilot, F)[region.scored]  # the candidates' angles are to these

    correlated = bool(ctx.correlation_length)
    n_probes = guard_probes(region.vertices.size)
    if correlated:  # no extra scale: the estimate already reads correlated noise 1.2-1.5 times too high
        fields = correlated_fields(ctx, region.vertices, n_probes)
        eps = fields[:, 0]
        synthetics = [pilot + ctx.rho * eps[:, None] * Np]
    else:  # TWO_STAGE_DRAWS copies: one draw's choice is a lottery (over 8 seeds 1.04-1.18 times the grid's best on Fandisk0.3)
        synthetics = [pilot + synthetic_noise(Np, TWO_STAGE_SYNTHETIC_SCALE * ctx.rho, seed=d)
                      for d in range(max(1, TWO_STAGE_DRAWS))]
    synthetic = synthetics[0]  # the fine run's copy
    inner = region.inner
    r = np.einsum("ij,ij->i", Y - pilot, Np)[inner]  # the noise as the pilot sees it, along its normals
    mad = float(np.median(np.abs(r))) / MAD
    heavy = bool(mad > 0 and np.sqrt(np.mean(r**2)) > TWO_STAGE_HEAVY_TAIL * mad)

    def path(params: dict) -> Point:
        def scored():  # the copies' runs in step; the score is their mean median angle, the point's X the first copy's
            for steps in zip(*(runs(s, F, ops, params) for s in synthetics)):
                p = Point(steps[0][0], 0.0, 0.0, steps[0][1])
                p.score = float(np.mean([median_angle(X, None, F, region.scored, pilot_normals) for _, X in steps]))
                yield p
        return best_on_run(scored(), patience(params))

    # the candidates run side by side, one thread each: on the region a parallel loop costs about as much
    # in joining threads as in work (the same choice, bit for bit)
    chosen, best = _staged_search(path, _search_grid(ctx.given, correlated=correlated), TWO_STAGE_REVISIT_SPAN,
                                  evaluate=lambda f, xs: kernels.run_concurrently(f, xs, region.vertices.size))
    chosen["iterations"] = int(best.value)
    clean_run = None  # the chosen run on the noisy region, when the whiteness step ran it
    if TWO_STAGE_WHITENESS and not fixed_k and not heavy and not correlated:
        # the outer iterations: the count whose method noise along the result's normals is whitest (least |lag-one
        # autocorrelation|, residual_correlation); the synthetic copy, as smooth as the pilot, stops runs early
        # (Block0.4: 6 iterations at (0.3, 5, 20), the truth 8; docs/automatic-parameters.md)
        clean_run = list(runs(Y, F, ops, chosen))
        lag = [abs(residual_correlation(Y, X, F, ops.W, inner)) for _, X in clean_run]
        chosen["iterations"] = int(clean_run[int(np.argmin(lag))][0])
        log.debug("two_stage rule: whiteness %s -> %d iterations", np.round(lag, 4).tolist(), chosen["iterations"])
    consistent = (dict(chosen), best)  # the criterion's choice, before the guard

    # the guard: Monte-Carlo SURE on positions along the chosen run (probes coloured like the noise)
    # probes along the normals of the SURE-smoothed mesh, not the pilot's: with keep_tangential a vertex keeps
    # the noise's part tangential to the result's normal, which probes along normals sharing the result's
    # errors (the pilot's) do not see (docs/automatic-parameters.md)
    Ng = vertex_normals(ctx.smoothed().X, ctx.F)[region.vertices]
    if ctx.correlation_length:
        probes = [fields[:, 1 + seed, None] * Ng for seed in range(n_probes)]
    else:
        probes = [sure_probe(Ng, seed) for seed in range(n_probes)]
    # under correlated noise the filter's response to a probe of 0.1 rho misses 10 % of its divergence (the
    # realised covariance e^T f of the noise), more after fewer iterations, so the guard cut too many: a step
    # of one rho measures it (bunny scanner l=2: 0.5265 against 0.5263 at k=2; docs/automatic-parameters.md)
    delta = mc_sure_step(ctx.rho, bool(ctx.correlation_length))

    def sure_per_probe(params: dict, clean: list | None = None) -> list[tuple[Point, np.ndarray]]:
        """Along a run of ``params["iterations"]``: (point scored by SURE with the mean divergence, SURE per probe (P,)).

        ``clean``: the run's iterates on ``Y`` when known (at least ``params["iterations"]`` of them).
        """
        def along(start: np.ndarray) -> list[tuple[int, np.ndarray]]:
            return list(itertools.islice(runs(start, F, ops, params), params["iterations"]))

        starts = ([] if clean is not None else [Y]) + [Y + delta * b for b in probes]
        perturbed = kernels.run_concurrently(along, starts, Y.shape[0])
        if clean is None:
            clean, *perturbed = perturbed
        clean = clean[:params["iterations"]]
        out = []
        for (k, X), *others in zip(clean, *perturbed):
            res = float(np.sum((X - Y)[inner] ** 2))
            divs = np.array([np.sum((b * (Xp - X))[inner]) for b, (_, Xp) in zip(probes, others)]) / delta
            p = Point(k, res, float(divs.mean()), X)
            p.score = sure(res, p.trace, int(inner.sum()), ctx.rho)
            out.append((p, np.array([sure(res, d, int(inner.sum()), ctx.rho) for d in divs])))
        return out

    log.debug("two_stage rule: consistency chose %s; noise rms/MAD %.2f", chosen, np.sqrt(np.mean(r**2)) / mad if mad else 0)
    chosen.setdefault("sigma_s", full["sigma_s"])  # searched by the guard's lighter runs only
    path_sure = sure_per_probe(chosen, clean_run)  # SURE along the chosen run (its last point: the chosen count)
    final = path_sure[-1][0]
    lighters = [TWO_STAGE_GUARD_LIGHTER] if isinstance(TWO_STAGE_GUARD_LIGHTER, dict) else list(TWO_STAGE_GUARD_LIGHTER)
    lights = []
    for change in lighters:
        light = {**chosen, **{k: v for k, v in change.items() if k not in ctx.given}}
        if light != chosen and light not in lights:
            lights.append(light)
    if not fixed_k and not heavy:
        # the guard: fewer outer iterations when SURE says so by more than TWO_STAGE_GUARD_MARGIN of the
        # noise energy and two standard errors of the paired probes (a smooth mesh, where the synthetic copy
        # of a smooth pilot asks for too much smoothing); then, along a second run with the fewest
        # normal-filtering passes, a point whose SURE is lower again by TWO_STAGE_GUARD_LIGHTER_GAIN of it
        last = path_sure[-1][1]
        margin = TWO_STAGE_GUARD_MARGIN * int(inner.sum()) * ctx.rho**2
        agreed = [(p, per_probe) for p, per_probe in path_sure[:-1] if guard_drops(per_probe, last, margin)]
        if agreed:
            final, last = min(agreed, key=lambda c: c[0].score)
            chosen["iterations"] = int(final.value)
        gain = max(margin, TWO_STAGE_GUARD_LIGHTER_GAIN * max(float(np.mean(last)), 0.0))
        agreed = []  # (point, its lighter parameters) over every lighter run
        for light in lights:
            light["iterations"] = chosen["iterations"]
            agreed += [(p, light) for p, per_probe in sure_per_probe(light) if guard_drops(per_probe, last, gain)]
        if agreed:
            final, light = min(agreed, key=lambda c: c[0].score)  # ties: the earlier lighter run, the fewer iterations
            chosen = {**light, "iterations": int(final.value)}
    fine_ok = not fixed_k and not heavy and not any(k in ctx.given for k in TWO_STAGE_FINE)
    if fine_ok and TWO_STAGE_FINE and chosen == {**consistent[0], "sigma_s": chosen["sigma_s"]}:
        # the guard kept the criterion's choice (a feature mesh): the same sigma_r in many light iterations
        fine = {**chosen, **TWO_STAGE_FINE}
        def fine_points():
            for k, X in runs(synthetic, F, ops, fine, length=TWO_STAGE_FINE_MAX_ITERATIONS):
                p = Point(k, 0.0, 0.0, X)
                p.score = median_angle(X, None, F, region.scored, pilot_normals)
                yield p
        fp = best_on_run(fine_points(), TWO_STAGE_FINE_PATIENCE)
        mean_fine = mean_angle(fp.X, None, F, region.scored, pilot_normals)
        mean_chosen = mean_angle(consistent[1].X, None, F, region.scored, pilot_normals)
        log.debug("two_stage rule: fine run %s k=%d median %.5f mean %.5f; chosen median %.5f mean %.5f", fine,
                  int(fp.value), fp.score, mean_fine, consistent[1].score, mean_chosen)
        if mean_fine < mean_chosen:
            fine["iterations"] = int(fp.value)
            fine_sure = sure_per_probe(fine)
            log.debug("two_stage rule: fine SURE %.6g, chosen %.6g (n rho^2 %.6g); along the chosen run %s", fine_sure[-1][0].score,
                      final.score, int(inner.sum()) * ctx.rho**2, [round(p.score, 4) for p, _ in path_sure])
            # against the least SURE along the chosen run, not its last point: SURE is a position risk, whose best
            # count comes before the normals' (Block0.4 at (0.3, 5, 40): least at 2 iterations, 3.86, the chosen 8
            # 8.84; the fine run's 5.54 is 37 % below the latter and 3.03 degrees against 2.68)
            if fine_run_wins(fine_sure[-1][0].score, [p.score for p, _ in path_sure], TWO_STAGE_FINE_GAIN):
                chosen, final = fine, fine_sure[-1][0]
    # the returned score estimates the whole mesh's squared error ||f(X) - X0||^2 (comparable with
    # other filters' SURE, as choose_parameters(return_risk=True) reports it): the region's SURE on its
    # inner vertices, scaled to the mesh's vertex count
    scale = n / max(int(inner.sum()), 1)
    best = Point(final.value, final.residual_sq * scale, final.trace * scale, final.X, final.score * scale)
    return {k: v for k, v in chosen.items() if k not in ctx.given}, best


@register(
    "two_stage",
    scale_free=True,
    auto=AutoRule(TUNED, choose_two_stage),
    along_normals=lambda values: bool(values["keep_tangential"]),  # every vertex moves along its normal only
    summary="Feature-preserving: guided/bilateral filtering of face normals, then vertex update (Zheng 2011, Zhang 2015)",
    params=[
        Param("iterations", int, 3, low=0, high=MAX_ITERATIONS, help="outer iterations (normal filtering + vertex update)"),
        Param("normal_iterations", int, 10, low=0, high=MAX_ITERATIONS, help="normal-filtering passes per outer iteration"),
        Param("vertex_iterations", int, 10, low=0, high=MAX_ITERATIONS, help="vertex-update steps per outer iteration"),
        Param("sigma_r", float, 0.35, low=0.0, low_open=True, help="range width on normal differences (0.2-0.6)"),
        Param(
            "sigma_s",
            float,
            1.0,
            low=0.0,
            low_open=True,
            help="spatial width, in units of the mean distance between neighbouring face centroids",
        ),
        Param("guidance", str, "guided", choices=("guided", "bilateral"), help="range kernel on guidance or own normals"),
        Param(
            "keep_tangential",
            bool,
            False,
            help="after each vertex update, give each vertex back its input position's tangential part (noise along normals)",
        ),
    ],
    linear=False,
)
def two_stage(
    V, F, *, ops, pinned, iterations, normal_iterations, vertex_iterations, sigma_r, sigma_s, guidance, keep_tangential
):
    """Two-stage feature-preserving denoising: filter the face normals, then fit the vertices to them.

    Each outer iteration (``iterations`` of them):

    1. face normals :math:`n`, centroids :math:`c` and areas :math:`A` of the current mesh;
    2. ``normal_iterations`` passes of bilateral filtering over the faces sharing a vertex:

       .. math:: n_i \\leftarrow \\mathrm{unit}\\Big(\\sum_{j \\in \\mathcal N(i)} A_j\\,
                 W_s(\\|c_i - c_j\\|)\\, W_r(\\|g_i - g_j\\|)\\, n_j\\Big), \\quad
                 W_\\sigma(x) = e^{-x^2 / 2\\sigma^2}

       with :math:`g = n` (``guidance="bilateral"``, Zheng et al. 2011) or the mean
       normal of the most consistent neighbouring patch (``guidance="guided"``,
       Zhang et al. 2015), which keeps sharp edges at high noise;
    3. ``vertex_iterations`` steps of the vertex update

       .. math:: x_i \\leftarrow x_i + \\frac{1}{|F_i|} \\sum_{f \\ni i} n_f\\, (n_f \\cdot (c_f - x_i)).

    4. with ``keep_tangential``: each vertex takes back the tangential part of its move,
       :math:`x_i \\leftarrow x_i + (I - u_i u_i^T)(y_i - x_i)` with :math:`y_i` the input
       position and :math:`u_i` the vertex normal of the updated mesh
       (:func:`meshdenoise.kernels.restore_tangential`). The noise model moves vertices along
       the normals only, so the tangential drift of step 3 (which the face normals hardly
       see) is error: on the benchmark pairs it was 57 to 78 % of the squared position error,
       and taking it back gains 0.7 to 4.7 dB of SNR and lowers the normal error
       (docs/filters.md).

    ``sigma_s`` is relative to the mean distance between neighbouring face centroids,
    recomputed each outer iteration, so the defaults do not depend on the mesh's scale
    or resolution. ``sigma_r`` acts on unit-normal differences (dimensionless).
    Each normal-filtering pass is three compiled, threaded loops over the face pairs and
    each vertex step one loop over the corners (:mod:`meshdenoise.kernels`), on
    preallocated buffers; the neighbourhoods are cached per topology (about 300 bytes
    per vertex). The work is done on the coordinates divided by a power of two near the
    mesh's extent (exact), so the result scales with the mesh: a mesh scaled by 1e80 or
    1e-80 gives the same result, scaled. Defaults reach 3.0 degrees of mean face-normal error on the
    Fandisk0.3 benchmark (noisy: 28.4) and 3.6 on Block0.4 (noisy: 33.7).

    Choosing ``iterations`` for a scan: ``sigma_r`` and ``sigma_s`` have no length unit; the outer
    count grows with the noise in mean edge lengths: with noise of 0.1, 0.3 and 1 edge lengths
    along the normals (other parameters at their defaults) the oracle chose 1-2, 1-8 and 2-8 on a
    sphere, a torus and the bunny (``benchmarks/results/parameter-scale.md``). The automatic rule
    (``denoise(method="two_stage")``) chooses it with ``sigma_r`` and the inner counts.

    Parameters
    ----------
    mesh : (V, F) tuple, pymeshlab.MeshSet or Mesh, or open3d.geometry.TriangleMesh
    iterations, normal_iterations, vertex_iterations : int, >= 0
    sigma_r : float, > 0
    sigma_s : float, > 0
        In mean centroid distances.
    guidance : {"guided", "bilateral"}
    keep_tangential : bool
        Step 4 above (off by default; the automatic rule turns it on).
    pinned, region, preserve_volume, operators
        Options shared by every filter; see the README.

    Returns
    -------
    Same type as ``mesh``

    References
    ----------
    X. Sun, P. Rosin, R. Martin, F. Langbein, "Fast and effective feature-preserving
    mesh denoising", IEEE TVCG 13(5), 2007.
    Y. Zheng, H. Fu, O. Au, C.-L. Tai, "Bilateral normal filtering for mesh denoising",
    IEEE TVCG 17(10), 2011.
    W. Zhang, B. Deng, J. Zhang, S. Bouaziz, L. Liu, "Guided mesh normal filtering",
    Computer Graphics Forum 34(7), 2015.

    Examples
    --------
    >>> import numpy as np
    >>> from meshdenoise.shapes import grid
    >>> V, F = grid(8, 8)
    >>> Vn = V + [0, 0, 0.01] * np.random.default_rng(0).standard_normal((len(V), 1))
    >>> V1, _ = two_stage((Vn, F))
    >>> bool(V1[:, 2].std() < 0.3 * Vn[:, 2].std())  # much flatter
    True
    """
    passes = iterations * (normal_iterations + vertex_iterations)
    if passes > MAX_ITERATIONS:  # each count is bounded, their product too
        raise ParameterError(
            f"parameters 'iterations' = {iterations} x ('normal_iterations' = {normal_iterations} + 'vertex_iterations' = "
            f"{vertex_iterations}) = {passes} passes, more than the limit {MAX_ITERATIONS}"
        )
    if F.shape[0] == 0 or iterations == 0:
        return np.array(V, dtype=np.float64, order="C")
    X = None  # outer_iterates reads V (no copy of it here: it relabels the vertices into a new array)
    for X in outer_iterates(V, ops, pinned, iterations, normal_iterations, vertex_iterations, sigma_r, sigma_s,
                            guidance, keep_tangential, every=False):
        pass
    return X


def outer_iterates(
    V: np.ndarray,
    ops: Operators,
    pinned: np.ndarray | None,
    iterations: int,
    normal_iterations: int,
    vertex_iterations: int,
    sigma_r: float,
    sigma_s: float,
    guidance: str,
    keep_tangential: bool,
    every: bool = True,
) -> Iterator[np.ndarray]:
    """The positions (n, 3) after each of ``two_stage``'s outer iterations (``every=False``: after the last only).

    One run: the outer iterations share the input ``V`` (``keep_tangential`` restores its
    tangential parts at every one), so the k-th yielded array is ``two_stage`` with
    ``iterations=k``. Stops early when the faces collapse to a point. Parameters as
    :func:`two_stage` (checked there); ``ops`` the topology's operators, ``pinned`` a
    boolean mask (n,) or ``None``.
    """
    from .. import kernels

    kernels.set_threads()
    X = np.asarray(V, dtype=np.float64, order="C")  # only read: the relabelled copy below is the one worked on
    # Work on X / 2^k with 2^k ~ the extent: exact (powers of two), so the result is the same
    # as on X, but nothing overflows or underflows at 1e80 or 1e-80 (squared lengths, areas).
    k = power_of_two_scale(X)
    topo = two_stage_topology(ops)
    nb, F = topo.nb, topo.F
    X = gather_rows(X, topo.vertex_order)  # relabelled vertices, a new array ...
    np.ldexp(X, -k, out=X)  # ... scaled in place
    Y = X.copy() if keep_tangential else None
    m = F.shape[0]
    guided = guidance == "guided"
    # one normal-filtering pass of the bilateral filter: the spatial weights are made inside it, never stored
    fused = normal_iterations == 1 and not guided
    # per run, reused by every outer iteration: three (m, 3) arrays in all. C holds the centroids,
    # then (dead once S is made) the guidance normals of the passes, then fit_vertices' centroids;
    # out holds each pass's output and, before it, the guided filter's patch means
    N, areas, C, out = np.empty((m, 3)), np.empty(m), np.empty((m, 3)), np.empty((m, 3))
    S = None if fused else np.empty(nb.indices.size)  # spatial weights of the face pairs, per outer iteration
    buffers = GuidanceBuffers(nb, g=out) if guided and normal_iterations > 0 else None
    sums = buffers.H if buffers is not None else np.empty(m)  # H is written by the passes, after the sums are used
    scale = fit_scale(topo.corner_ptr, None if pinned is None else pinned[topo.vertex_order])

    def caller_order() -> np.ndarray:
        out = np.empty_like(X)
        out[topo.vertex_order] = X
        return np.ldexp(out, k, out=out)

    done = 0
    for it in range(iterations):
        kernels.face_geometry(X, F, N, areas, C)
        count = kernels.centroid_spacing_sums(C, nb.indptr, nb.indices, sums)
        spacing = float(sums.sum()) / count if count else 0.0
        if spacing == 0.0:
            break
        done += 1
        denom_s = 2.0 * (sigma_s * spacing) ** 2
        if fused:
            kernels.bilateral_spatial_pass(N, N, C, areas, nb.indptr, nb.indices, denom_s, 2.0 * sigma_r**2, out)
            Nf = out
        else:
            kernels.spatial_weights(C, areas, nb.indptr, nb.indices, denom_s, S)
            Nf = bilateral_passes(N, areas, nb, S, sigma_r, normal_iterations, guided, out=out, G=C, buffers=buffers)
        spare = out if Nf is N else N
        kernels.fit_vertices(X, F, Nf, topo.corner_ptr, topo.corners, scale, int(vertex_iterations), C)
        N, out = Nf, spare  # the next iteration's face normals overwrite the filtered ones (used up)
        if keep_tangential:  # pinned vertices sit at Y: they get back nothing and stay bit for bit
            kernels.face_geometry(X, F, N, areas, C)
            kernels.restore_tangential(X, Y, N, topo.corner_ptr, topo.corners)
        if every and it < iterations - 1:
            yield caller_order()
    if not every or done in (0, iterations):  # else the last state was yielded in the loop
        # the run's buffers are dead: free them before the result is made (they were the peak's largest part)
        N = areas = C = out = S = buffers = sums = Y = None
        yield caller_order()
