"""Feature-preserving two-stage denoising: filter the face normals, then move the vertices to fit them."""

from __future__ import annotations

import warnings
from typing import Callable, Iterator

import numpy as np

from ..normal_filter import GuidanceBuffers, bilateral_passes, fit_scale, power_of_two_scale, two_stage_topology
from ..operators import Operators, gather_rows
from ..registry import MAX_ITERATIONS, AutoRule, Param, ParameterError, get_filter, register
from ..tuning.context import TuningContext
from ..tuning.holdout import NoHoldout
from ..tuning.risk import Point
from ..tuning.sweep import HeldOutRule, HoldoutConfig, Sweep

__all__ = ["two_stage", "outer_iterates"]


# ----------------------------------------------------------------------------- automatic rule
TUNED = ("iterations", "normal_iterations", "vertex_iterations", "sigma_r", "sigma_s", "guidance", "keep_tangential",
         "relax_tangential")


def _along(fixed: dict, values: tuple, F: np.ndarray, ops: Operators) -> Callable[[np.ndarray], Iterator[np.ndarray]]:
    """``path(Y)``: two_stage's positions at each outer-iteration count of ``values``, read along one run."""
    want, last = frozenset(values), max(values)

    def path(Y: np.ndarray) -> Iterator[np.ndarray]:
        runs = outer_iterates(Y, ops, None, last, fixed["normal_iterations"], fixed["vertex_iterations"],
                              fixed["sigma_r"], fixed["sigma_s"], fixed["guidance"], fixed["keep_tangential"],
                              relax_tangential=fixed["relax_tangential"])
        for k, X in enumerate(runs, 1):
            if k in want:
                yield X
    return path


def _sweep(sigma_r: float, keep_tangential: bool, relax_tangential: bool = False) -> Sweep:
    # one bilateral normal pass and five vertex steps per outer iteration: a run reaches every amount of smoothing
    # in small steps, so one count read along it is the only choice left per family (as the default's candidates)
    fixed = (("normal_iterations", 1), ("vertex_iterations", 5), ("sigma_r", sigma_r), ("sigma_s", 1.0),
             ("guidance", "bilateral"), ("keep_tangential", keep_tangential), ("relax_tangential", relax_tangential))
    return Sweep("iterations", tuple(range(1, 41)), fixed, along=_along)


class _TwoStageRule(HeldOutRule):
    """A :class:`HeldOutRule` that reads a given tangential step as excluding the other: a caller's
    ``keep_tangential=True`` holds ``relax_tangential`` off in every run, and the other way round."""

    @staticmethod
    def _exclusive(given: dict) -> dict:
        given = dict(given)
        for name, other in (("keep_tangential", "relax_tangential"), ("relax_tangential", "keep_tangential")):
            if given.get(name) is True:
                given.setdefault(other, False)
        return given

    def choose(self, V, F, ops, run, given):
        return super().choose(V, F, ops, run, self._exclusive(given))

    def oracle(self, V, F, ops, run, given, reference):
        return super().oracle(V, F, ops, run, self._exclusive(given), reference)


# The runs the rule reads, the default's candidates too (meshdenoise.policy.config.FAMILIES is made of them): the
# sharp normal filter (sigma_r 0.35: normals more than about 20 degrees apart hardly average) keeping the input's
# tangential part (noise along the normals) or relaxing it (noise along any direction), and the smooth one (sigma_r
# 2.0: every neighbour's normal counts) relaxing it. The default with them on the corpus's tune half: 1.309 times the
# best oracle-tuned peer's face-normal error (geometric mean), 1.387 with runs that leave the tangential part as the
# fit leaves it instead of relaxing it; without each of the three 1.364 / 1.480 / 1.406; a fourth run leaving it
# 1.304, not worth its time (benchmarks/results/policy-tune.md). Read as the default reads them (it takes this
# config: 4 counts past the least loss, 3 masks; 2 masks read 1.307 but were no faster end to end on the tune half,
# 92 % of its cases within the time budget against 96 %: python benchmarks/corpus_report.py --jobs 1), so that
# denoise(mesh, method="two_stage") chooses what denoise(mesh) does.
TWO_STAGE_NORMALS = _TwoStageRule((_sweep(0.35, True), _sweep(0.35, False, True), _sweep(2.0, False, True)),
                                  HoldoutConfig())


def _run(X: np.ndarray, F: np.ndarray, ops: Operators, params: dict) -> np.ndarray:
    return get_filter("two_stage").public((X, F), **params, operators=ops)[0]


def choose_two_stage(ctx: TuningContext) -> tuple[dict, Point]:
    """The rule for the criteria other than ``"normals"``: ``"oracle"`` (benchmarks) reads the sweeps of
    :data:`TWO_STAGE_NORMALS` against the clean mesh; two_stage has no rule by SURE or GCV (a nonlinear filter's
    risk has no closed form), so ``"sure"`` and ``"gcv"`` choose by held-out vertices as ``"normals"`` does."""
    given = {k: v for k, v in ctx.given.items() if k in TUNED}
    if ctx.criterion.oracle:
        chosen, score = TWO_STAGE_NORMALS.oracle(ctx.V, ctx.F, ctx.ops, _run, given, ctx.criterion.reference)
    else:
        try:
            chosen, score = TWO_STAGE_NORMALS.choose(ctx.V, ctx.F, ctx.ops, _run, given)
        except NoHoldout as exc:
            warnings.warn(f"choose_parameters(two_stage): {exc}; the filter's defaults are kept", UserWarning,
                          stacklevel=4)
            chosen, score = dict(given), float("nan")
    X = _run(ctx.V, ctx.F, ctx.ops, chosen)
    point = Point(chosen.get("iterations", 0), float(np.sum((X - ctx.V) ** 2)), 0.0, X, score)
    return {k: v for k, v in chosen.items() if k not in ctx.given}, point


@register(
    "two_stage",
    scale_free=True,
    auto=AutoRule(TUNED, choose_two_stage, normals="iterations", held_out=TWO_STAGE_NORMALS),
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
        Param(
            "relax_tangential",
            bool,
            False,
            help="after each vertex update, move each vertex in its tangent plane to its neighbours' mean (noise along any direction)",
        ),
    ],
    linear=False,
)
def two_stage(
    V, F, *, ops, pinned, iterations, normal_iterations, vertex_iterations, sigma_r, sigma_s, guidance, keep_tangential,
    relax_tangential
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
    5. with ``relax_tangential`` instead: each vertex moves to its neighbours' mean less the move's
       part along its vertex normal :math:`u_i`,
       :math:`x_i \\leftarrow x_i + (I - u_i u_i^T)(\\bar x_{\\mathcal N(i)} - x_i)`: noise along any
       direction moves vertices along the surface too, which the face normals' fit does not undo
       (pinned and open-border vertices stay).

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
    (``denoise(method="two_stage")``) chooses it, ``sigma_r`` and ``keep_tangential`` by held-out vertices along
    runs of one normal pass and five vertex steps per outer iteration (:data:`TWO_STAGE_NORMALS`).

    Parameters
    ----------
    mesh : (V, F) tuple, pymeshlab.MeshSet or Mesh, or open3d.geometry.TriangleMesh
    iterations, normal_iterations, vertex_iterations : int, >= 0
    sigma_r : float, > 0
    sigma_s : float, > 0
        In mean centroid distances.
    guidance : {"guided", "bilateral"}
    keep_tangential : bool
        Step 4 above (off by default; the automatic rule chooses it).
    relax_tangential : bool
        Step 5 above (off by default; not with ``keep_tangential``).
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
    if keep_tangential and relax_tangential:
        raise ParameterError("parameters 'keep_tangential' and 'relax_tangential' are both True: one keeps the input's "
                             "tangential positions, the other moves them to the neighbours' mean; choose one")
    if F.shape[0] == 0 or iterations == 0:
        return np.array(V, dtype=np.float64, order="C")
    X = None  # outer_iterates reads V (no copy of it here: it relabels the vertices into a new array)
    for X in outer_iterates(V, ops, pinned, iterations, normal_iterations, vertex_iterations, sigma_r, sigma_s,
                            guidance, keep_tangential, every=False, relax_tangential=relax_tangential):
        pass
    return X


class _Relaxation:
    """Step 5 of :func:`two_stage` (``relax_tangential``) on the run's relabelled vertices.

    Each vertex moves to its neighbours' mean, less the move's part along its vertex normal (the
    normalised sum of its faces' unit normals), so the surface keeps its shape to first order while
    the noise along it (any direction but the normal) is averaged out. Pinned, isolated and open-border
    vertices stay (moving a border vertex to its neighbours' mean would pull the border in). The mean is
    read from the faces: the other corners of a vertex's faces, each neighbour of an interior manifold
    vertex twice, so no adjacency matrix is kept beside the run's arrays.
    """

    def __init__(self, ops: Operators, topo, scale: np.ndarray):
        self.F, self.ptr, self.corners = topo.F, topo.corner_ptr, topo.corners
        self.still = (scale == 0) | ops.boundary_vertices[topo.vertex_order]
        self.mean = None

    def step(self, X: np.ndarray, N: np.ndarray) -> None:
        """Move ``X`` (n, 3, relabelled) in place; ``N`` (m, 3) its unit face normals."""
        from .. import kernels

        self.mean = np.empty_like(X) if self.mean is None else self.mean
        kernels.face_corner_mean(X, self.F, self.ptr, self.corners, self.mean)
        self.mean[self.still] = X[self.still]
        kernels.restore_tangential(X, self.mean, N, self.ptr, self.corners)


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
    relax_tangential: bool = False,
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

    done, relax = 0, None
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
        if relax_tangential:
            relax = _Relaxation(ops, topo, scale) if relax is None else relax
            kernels.face_geometry(X, F, N, areas, C)
            relax.step(X, N)
        if every and it < iterations - 1:
            yield caller_order()
    if not every or done in (0, iterations):  # else the last state was yielded in the loop
        # the run's buffers are dead: free them before the result is made (they were the peak's largest part)
        N = areas = C = out = S = buffers = sums = Y = relax = None
        yield caller_order()
