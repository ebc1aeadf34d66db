"""The noise covariance of a mesh, estimated from the noisy mesh alone: a level and a correlation length.

Generic machinery: nothing here knows a filter.

**Model** (:func:`meshdenoise.noise.add_scanner_noise` without outliers or depth): vertex *i*
moves along its unit normal :math:`N_i` by :math:`\\rho z_i`, with :math:`z = c\\, C_\\ell \\xi`,
:math:`\\xi` white, :math:`C_\\ell` the mesh heat filter of correlation length :math:`\\ell`
mean edge lengths (:class:`meshdenoise.noise.HeatFilter` over
:func:`meshdenoise.noise.diffusion_length` of :math:`\\ell`) and :math:`c` such that
:math:`\\mathrm{tr}\\, \\Sigma_\\ell = n`, :math:`\\Sigma_\\ell = c^2 C_\\ell C_\\ell^T`.
:math:`\\ell = 0` is the paper's independent noise (:math:`\\Sigma = I`).

**Estimate** (:func:`estimate_noise_model`). Band-pass operators
:math:`B_s = (I - P)^2 P^s`, :math:`P = D^{-1} W`, :math:`s \\in` :data:`BANDS`, see the
surface little (a fourth difference kills its smooth part) and the noise a lot, each a
different share of it depending on :math:`\\ell`: the finest band sees almost nothing of a
smooth (long-correlated) noise, the coarser ones more. The normal components
:math:`r_{s,i} = \\langle (B_s X)_i, N_i\\rangle` (normals of a smoothed mesh) are read
robustly by their median square :math:`o_s`; the same statistic of probes of the model,
:math:`b = (C_\\ell \\xi) \\odot N` through the same operators, gives :math:`p_s(\\ell)`
(per unit :math:`\\rho^2`; the probes of every length :math:`\\ell` the fit and the band spectrum ask for
are filtered from one growing Krylov space, :class:`meshdenoise.noise.HeatKrylov`, not by a heat
filter each). When the surface is negligible in these bands,
:math:`\\hat\\rho_s(\\ell) = \\sqrt{o_s / p_s(\\ell)}` is the same for every band at the true
:math:`\\ell`; :math:`\\hat\\ell` minimises the spread (variance of
:math:`\\log \\hat\\rho_s(\\ell)` over the bands), and :math:`\\hat\\rho` is the geometric mean of
:math:`\\hat\\rho_s(\\hat\\ell)`. The noise is taken as independent (:math:`\\hat\\ell = 0`, and
:math:`\\hat\\rho` is :func:`~meshdenoise.tuning.noise_level.estimate_noise`'s, unchanged) unless the
fit is significant: :data:`ELL_MIN` :math:`\\le \\hat\\ell \\le` :data:`ELL_MAX`, the spread falls from
its white-noise value by at least :data:`SPREAD_GAIN` and by a factor :data:`SPREAD_RATIO`, and the
mesh holds at least :data:`MIN_PATCHES` correlation areas :math:`\\pi \\hat\\ell^2`. The surface's
own detail in the coarser bands reads as a little correlation (0.5 to 1.1 edge lengths on
the benchmark's CAD meshes with independent noise), which these thresholds reject. Why
these bands and numbers: docs/automatic-parameters.md.

**Risk.** For a linear smoother :math:`H` (on the three coordinate columns),
:math:`\\mathbb E \\|HX - X^0\\|^2 = \\mathbb E \\|HX - X\\|^2 - \\rho^2 n + 2\\rho^2\\, \\mathrm{tr}(H \\Sigma_\\ell)`
(normals taken as locally parallel over a correlation length: :math:`\\langle N_i, N_j\\rangle \\approx 1`
where :math:`\\Sigma_{ij} \\neq 0`). :math:`\\mathrm{tr}(H\\Sigma)` is Hutchinson's estimate
with coloured probes :math:`z = \\Sigma^{1/2} \\xi` (:meth:`NoiseModel.colour`), which
:func:`~meshdenoise.tuning.risk.probe_block` returns while a model is active
(:func:`~meshdenoise.tuning.risk.noise_colouring`), so every rule using the shared probes
gets it.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field
from typing import Any, Iterator

import numpy as np
import scipy.sparse as sp

from ..adapters import read_mesh
from ..kernels import every_thread
from ..noise import HeatFilter, HeatKrylov, diffusion_length, heat_geometry
from ..noise import mean_edge_length as noise_mean_edge_length
from ..operators import Operators, get_operators, spmm
from .memo import MEMO, digest
from .noise_level import smoothed_estimate
from .region import SampledRegion, ring_distance

__all__ = ["NoiseModel", "estimate_noise_model", "band_residuals", "BANDS", "ELL_MIN", "ELL_MAX", "ELL_GRID", "FIT_PROBES",
           "FIT_SAMPLE"]

BANDS = (0, 1, 2, 4)  # s of the band-pass operators (I - P)^2 P^s
ELL_GRID = (0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0)  # correlation lengths the fit evaluates
ELL_MIN = 0.75  # fitted correlation lengths below this (mean edge lengths) are read as independent noise
ELL_MAX = 5.0  # ... and above this: so smooth a "noise" is not told from the shape (pymeshlab's raw bunny reads 6.8)
SPREAD_GAIN = 0.0015  # ... and so are fits that lower the spread (variance of log rho_s) by less than this
SPREAD_RATIO = 2.0  # ... or by less than this factor
MIN_PATCHES = 100  # ... or that leave fewer than this many correlation areas pi ell^2 on the mesh
COLOUR_CACHE_BYTES = 128 << 20  # coloured probes a NoiseModel keeps (by content of the white ones)
FIT_PROBES = 4  # probes per model of the fit: a median over n * 4 values
FIT_SAMPLE = 30_000  # above this many vertices the probes' statistic is read on a sampled region of about this size
FIT_PATCHES = 8  # ... made of this many balls of vertices
FIT_MARGIN = 8  # ... counting only vertices more than this many rings from a cut
FIT_SAMPLE_PROBES = 4  # ... with this many probes (the whole mesh: FIT_PROBES)
FIT_TOL = 1e-5  # relative accuracy of the fit's probe colourings (HeatKrylov; a median of squares needs no 8 digits)
COLOUR_TOL = 1e-5  # ... and of NoiseModel.colour's random probes: rescaled to the model's energy, they only feed
# Monte-Carlo traces, whose sampling error (~1/sqrt(probes)) is far above this (the exact identity probes: 1e-8)
FIT_BORDER_RINGS = 12  # ... weighting its vertices by their ring distance to the mesh's own border (0 .. this, farther)


@dataclass
class NoiseModel:
    """Noise of level ``rho`` along the normals, correlated over ``correlation_length`` mean edge lengths.

    Attributes
    ----------
    rho : float
        Standard deviation of the displacement along the normal (mesh units), root mean
        square over the vertices.
    correlation_length : float
        :math:`\\ell` in mean edge lengths (:func:`meshdenoise.noise.correlation_length`'s
        definition); 0 for independent noise.
    V : ndarray, shape (n, 3), optional
        The geometry the heat filter is built on (a smoothed mesh); needed when ``correlation_length > 0``.
    F : ndarray, shape (m, 3), optional
    """

    rho: float
    correlation_length: float = 0.0
    V: np.ndarray | None = field(default=None, repr=False, compare=False)
    F: np.ndarray | None = field(default=None, repr=False, compare=False)
    _filter: Any = field(default=None, init=False, repr=False, compare=False)
    _coloured: dict = field(default_factory=dict, init=False, repr=False, compare=False)
    # colour() may be called from threads at once (rules run side by side): the lock guards the filter's
    # build and the cache; a colouring under way is waited for, not computed twice
    _lock: Any = field(default_factory=threading.Lock, init=False, repr=False, compare=False)
    _pending: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        for name in ("rho", "correlation_length"):
            value = getattr(self, name)
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
                raise TypeError(f"NoiseModel: {name} must be a number, got {value!r}")
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"NoiseModel: parameter {name!r} = {value!r} is out of range: {name} >= 0")
        self.rho = float(self.rho)
        self.correlation_length = float(self.correlation_length)
        if self.correlated and (self.V is None or self.F is None):
            raise ValueError("NoiseModel: a correlated model (correlation_length > 0) needs the mesh V, F "
                             "its heat filter is built on")

    def __getstate__(self) -> dict:  # pickled (a process pool, Dask) without its lock and caches
        state = dict(self.__dict__)
        state.update(_filter=None, _coloured={}, _lock=None, _pending={})
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._lock = threading.Lock()

    @property
    def correlated(self) -> bool:
        return self.correlation_length > 0

    def filter(self) -> HeatFilter:
        """The heat filter :math:`C_\\ell` (built once, also when asked from several threads)."""
        with self._lock:
            if self._filter is None:
                self._filter = HeatFilter(self.V, self.F, diffusion_length(self.correlation_length))
            return self._filter

    def colour(self, Z: np.ndarray, s: float) -> np.ndarray:
        """Probes ``Z`` (n, m) coloured by :math:`\\Sigma^{1/2}`: ``Z`` itself (same object) when independent.

        ``s`` is the probes' scale (``tr(A) ~ s * sum(Z * (A Z))``, :func:`~meshdenoise.tuning.risk.probe_block`).
        The result :math:`Y = c\\, C_\\ell Z` has ``s * sum(Y * Y) = n`` (the model's
        :math:`\\mathrm{tr}\\,\\Sigma = n`, taken by the probes themselves, so that
        :math:`\\mathrm{tr}(H\\Sigma)` is exact for :math:`H = I` and its error is a ratio's).
        With ``Z = I`` (exact traces) :math:`\\mathrm{tr}(Y^T H Y) = \\mathrm{tr}(H\\Sigma)` exactly.
        The result is kept (by the content of ``Z`` and ``s``, at most :data:`COLOUR_CACHE_BYTES`,
        :meth:`clear`): the rules of one choice colour the same probes several times, each
        colouring :data:`~meshdenoise.noise.HEAT_STEPS` CG solves on the whole mesh. Safe to call
        from several threads: a colouring asked for while another thread computes it is waited
        for (one computation); different probes are coloured at the same time.
        """
        if not self.correlated:
            return Z
        Z = np.asarray(Z, dtype=np.float64)
        key = (digest(Z), float(s))
        with self._lock:
            if key in self._coloured:  # the rules of one choice colour the same probes several times
                return self._coloured[key].copy()
            gate = self._pending.get(key)
            mine = gate is None
            if mine:
                gate = self._pending[key] = threading.Event()
        if not mine:
            gate.wait()
            with self._lock:
                if key in self._coloured:
                    return self._coloured[key].copy()
            return self._coloured_probes(Z, s)  # the other thread failed, or its result was too large to keep
        try:
            with every_thread():  # other threads may be waiting for it: not held to a worker's one thread
                Y = self._coloured_probes(Z, s)
            if Y.nbytes <= COLOUR_CACHE_BYTES:
                with self._lock:
                    while self._coloured and sum(v.nbytes for v in self._coloured.values()) + Y.nbytes > COLOUR_CACHE_BYTES:
                        self._coloured.pop(next(iter(self._coloured)))  # oldest first
                    self._coloured[key] = Y.copy()
            return Y
        finally:
            with self._lock:
                del self._pending[key]
            gate.set()

    def _coloured_probes(self, Z: np.ndarray, s: float) -> np.ndarray:
        """:meth:`colour`'s computation, uncached."""
        # exact traces (Z = I, as many columns as rows: small meshes) keep 8 digits; probes need no more than 5
        Y = self.filter()(Z, tol=1e-8 if Z.shape[1] >= Z.shape[0] else COLOUR_TOL)
        energy = s * float(np.sum(Y * Y))
        n = Y.shape[0]
        return Y * math.sqrt(n / energy) if energy > 0 else Y

    def clear(self) -> None:
        """Forget the coloured probes kept by :meth:`colour` (at most :data:`COLOUR_CACHE_BYTES`)."""
        with self._lock:
            self._coloured.clear()


def band_residuals(ops: Operators, X: np.ndarray, bands: tuple[int, ...] = BANDS) -> dict[int, np.ndarray]:
    """:math:`B_s X = (I - P)^2 P^s X` for every ``s`` in ``bands``, ``X`` (n, k) -> dict of (n, k).

    Differences taken before each product (:math:`(I - P)((I - P) P^s X)`): for coordinates, whose
    offset from the origin may be far above the residual, this cancels the offset first. Zero-mean
    probes take :func:`_band_chain` (fewer products).
    """
    out = {}
    Y = np.array(X, dtype=np.float64)
    done = 0
    for s in sorted(bands):
        while done < s:
            Y = spmm(ops.P, Y)
            done += 1
        A = Y - spmm(ops.P, Y)
        out[s] = A - spmm(ops.P, A)
    return out


def _band_chain(ops: Operators, X: np.ndarray, bands: tuple[int, ...]) -> Iterator[tuple[int, np.ndarray]]:
    """``(s, B_s X)`` for the increasing ``bands``, :math:`B_s X = P^s X - 2 P^{s+1} X + P^{s+2} X`.

    One chain of powers :math:`P^j X`, ``j`` = 0 .. max(bands) + 2 (three kept at a time): 66
    sparse products for the bands 0 .. 64 of the detail spectrum, where
    :math:`(I - P)((I - P) P^s X)` took two more per band (80). For zero-mean probes (no offset to
    cancel: the rounding is that of the powers themselves).
    """
    bands = sorted(set(int(b) for b in bands))
    window: dict[int, np.ndarray] = {}
    Y = np.array(X, dtype=np.float64)
    j = 0
    for s in bands:
        while j < s + 2:
            if j >= s:
                window[j] = Y
            Y = spmm(ops.P, Y)
            j += 1
        window[j] = Y
        B = window[s] - 2.0 * window[s + 1]
        B += window[s + 2]
        yield s, B
        window = {k: v for k, v in window.items() if k > s}  # the next band may start at s + 1 or s + 2


def _normal_component(R: np.ndarray, N: np.ndarray) -> np.ndarray:
    """Row-wise :math:`\\langle R_i, N_i\\rangle` of (n, 3k) blocks -> (n, k) (optimize: a batched product, 4x faster)."""
    k = R.shape[1] // 3
    return np.einsum("ikj,ij->ik", R.reshape(R.shape[0], k, 3), N, optimize=True)


def _probe_medians(ops: Operators, N: np.ndarray, Z: np.ndarray, ok: np.ndarray,
                   weights: np.ndarray | None = None) -> np.ndarray:
    """Median square of the normal component of :math:`B_s (z \\odot N)` over usable vertices and probes, per band
    (weighted by ``weights`` (n,) per vertex when given)."""
    m = Z.shape[1]
    B = (Z[:, :, None] * N[:, None, :]).reshape(Z.shape[0], 3 * m)
    R = dict(_band_chain(ops, B, BANDS))
    if weights is None:
        return np.array([np.median(_normal_component(R[s], N)[ok] ** 2) for s in BANDS])
    w = np.repeat(weights[ok], m)
    return np.array([_weighted_median(_normal_component(R[s], N)[ok].ravel() ** 2, w) for s in BANDS])


def _weighted_median(x: np.ndarray, w: np.ndarray) -> float:
    """The smallest ``x`` at which the cumulative weight of the sorted values reaches half the total; ``x``, ``w`` (k,)."""
    order = np.argsort(x)  # the value is returned, not an index: ties need no stable order (quicksort: 6x faster)
    c = np.cumsum(w[order])
    return float(x[order][np.searchsorted(c, 0.5 * c[-1])])


def _border_strata(ops: Operators) -> np.ndarray:
    """Ring distance of every vertex to the mesh's own border, capped: 0 .. FIT_BORDER_RINGS, FIT_BORDER_RINGS + 1 farther (n,)."""
    border = np.flatnonzero(ops.boundary_vertices)
    d = ring_distance(ops.W, border, float(FIT_BORDER_RINGS))
    return np.where(np.isfinite(d), d, FIT_BORDER_RINGS + 1).astype(np.int64)


def _nearest_present(present: np.ndarray) -> np.ndarray:
    """For each stratum, the nearest one (the lower on ties) where ``present`` (k,) bool is True; itself if present."""
    idx = np.flatnonzero(present)
    k = np.arange(present.size)
    if idx.size == 0:
        return k
    pos = np.clip(np.searchsorted(idx, k), 1, max(idx.size - 1, 1)) if idx.size > 1 else np.zeros(k.size, dtype=np.int64)
    if idx.size == 1:
        return np.full(k.size, idx[0])
    lo, hi = idx[pos - 1], idx[pos]
    return np.where(np.abs(k - lo) <= np.abs(hi - k), lo, hi)


def _fit(logr: np.ndarray, grid: np.ndarray) -> tuple[float, int]:
    """The correlation length minimising the spread of :math:`\\log\\hat\\rho_s` over the bands.

    ``logr`` (g, b): :math:`\\log \\hat\\rho_s(\\ell_j)` on the grid. The spread is evaluated on
    the grid, then on a fine grid between the best point's neighbours with
    :math:`\\log \\hat\\rho_s` interpolated linearly in :math:`\\ell`.
    """
    spread = np.var(logr, axis=1)
    j = int(np.argmin(spread))
    lo, hi = max(j - 1, 0), min(j + 1, len(grid) - 1)
    fine = np.linspace(grid[lo], grid[hi], 81)
    curves = np.stack([np.interp(fine, grid[lo:hi + 1], logr[lo:hi + 1, b]) for b in range(logr.shape[1])], axis=1)
    k = int(np.argmin(np.var(curves, axis=1)))
    return float(fine[k]), j


def _spectrum_medians(ops: Operators, N: np.ndarray, Zs: list[np.ndarray], ok: np.ndarray,
                      weights: np.ndarray | None, bands: tuple[int, ...], group: int = 2) -> np.ndarray:
    """Median square of the normal component of :math:`B_s (z \\odot N)`, per probe block of ``Zs`` and band.

    ``Zs``: blocks (n, m) of probes (one per correlation length), read as :func:`_probe_medians`
    reads one (weighted by ``weights`` (n,) when given), with ``bands`` any increasing band list.
    The blocks are pushed through the band-pass operators ``group`` at a time (one wider sparse
    product instead of one per block; 2 blocks of 4 probes, 24 columns, keep the chain's three
    powers in cache: 0.46 s against 0.54 s for 4 and 0.59 s for 1 on a 28k-vertex scan, the
    same medians bit for bit). Returns (len(Zs), len(bands)).
    """
    out = np.empty((len(Zs), len(bands)))
    for start in range(0, len(Zs), group):
        chunk = Zs[start:start + group]
        m = chunk[0].shape[1]
        Z = np.concatenate(chunk, axis=1)
        Y = (Z[:, :, None] * N[:, None, :]).reshape(Z.shape[0], 3 * Z.shape[1])
        w = None if weights is None else np.repeat(weights[ok], m)
        for j, (s, B) in enumerate(_band_chain(ops, Y, bands)):
            r = _normal_component(B, N)[ok]  # (k, m * len(chunk))
            del B
            for g in range(len(chunk)):
                x = r[:, g * m:(g + 1) * m] ** 2
                out[start + g, j] = np.median(x) if w is None else _weighted_median(x.ravel(), w)
    return out


def estimate_noise_model(mesh: Any, *, refine: int = 2, seed: int = 0, details: bool = False,
                         sample: int | None = None, spectrum: tuple[tuple[int, ...], tuple[float, ...]] | None = None,
                         release: bool = True) -> NoiseModel:
    """Estimate the noise level and correlation length of a noisy mesh, without the clean mesh.

    See the module docstring for the model and the estimate.

    Parameters
    ----------
    mesh : (V, F) tuple, pymeshlab.MeshSet or Mesh, or open3d.geometry.TriangleMesh
    refine : int, >= 1
        Passed to :func:`~meshdenoise.tuning.noise_level.estimate_noise`.
    seed : int
        Seed of the model's probes (the same seed, the same estimate).
    details : bool
        Also return a dict: ``rho_white`` (:func:`estimate_noise`), ``ell_fit`` (before the
        significance test), ``grid`` and ``log_rho`` (:math:`\\log\\hat\\rho_s(\\ell)` on it),
        ``spread_white``, ``spread_fit``, ``fit_vertices`` (vertices the probes' medians were read
        on), and ``reason``: one line saying why the noise was read as correlated or independent.
    sample : int, optional
        Above this many vertices (default :data:`FIT_SAMPLE`) the fit is made on a
        :class:`~meshdenoise.tuning.region.SampledRegion` (:data:`FIT_PATCHES` balls, vertices
        within :data:`FIT_MARGIN` rings of a cut left out, :data:`FIT_SAMPLE_PROBES` probes
        coloured on the region to a relative accuracy :data:`FIT_TOL`): both medians, the
        observed :math:`o_s` (band residuals of the whole mesh read at the region's vertices)
        and the probes' :math:`p_s(\\ell)`, are taken over the same vertices, weighted by their
        ring distance to the mesh's own border (:data:`FIT_BORDER_RINGS`) so that each distance
        counts as in the whole mesh; lengths are in the whole mesh's mean edge length. The fit
        then costs the same at any size. The white-noise level (the estimate when the noise
        reads independent) is always the whole mesh's. A mesh of at most ``sample`` vertices is
        fitted whole, its probes also coloured to :data:`FIT_TOL` (1e-8 before: the level moved by
        5e-6 relative on the bunny with scanner noise). Against the whole-mesh fit, docs/scale.md.
    spectrum : (bands, lengths), optional
        When the noise reads as correlated (the fit is significant), also read a band spectrum
        with the same probes, coloured once (those the fit did not colour are coloured alike, to
        a relative accuracy :data:`FIT_TOL`), read at the same vertices with the same weights
        (the mesh's own residuals over all its usable vertices): ``info["spectrum"]`` (with
        ``details``; absent when the noise reads independent) holds ``bands``, ``lengths``,
        ``observed`` (len(bands),: the median square of the normal component of the mesh's own
        :math:`B_s X`) and ``probes`` (len(lengths), len(bands): the same of unit-variance probes of
        each correlation length), for the caller to fit; asked for with the noise model, the
        probes are coloured once. ``info["smooth"]`` is
        always the smoothed mesh (n, 3) the normals come from.
    release : bool
        When the noise reads correlated, forget the averaging runs this call added to the tuning
        memo (:data:`meshdenoise.tuning.memo.MEMO`): :func:`estimate_noise`'s SURE smoothing with
        white probes, which no rule under a correlated model reads (their probes are coloured, so
        their runs are others). Each holds an ``(n, 7)`` state, the ``(n, 4)`` probes, a copy of
        ``V`` and the averaging matrix ``P`` it steps with: about 75 MB at 400k vertices. With
        independent noise they are kept: the rules that follow (``filtering``, the Sobolev start
        guess, ``two_stage``'s guard) read the same runs. What stays by design: the vertex
        matrices on the cached topology (:func:`~meshdenoise.operators.get_operators`; the rules
        need them, :meth:`~meshdenoise.operators.Operators.drop_matrices` frees them) and a
        correlated model's smoothed mesh.

    Returns
    -------
    NoiseModel
        ``correlation_length`` 0 (and ``rho`` exactly :func:`estimate_noise`'s) unless the fit
        is significant (module docstring); a correlated model carries the smoothed mesh its
        heat filter is built on.

    Examples
    --------
    >>> from meshdenoise.shapes import icosphere
    >>> from meshdenoise import add_normal_noise
    >>> V, F = icosphere(4)
    >>> Vn, _ = add_normal_noise((V, F), rho=0.01, seed=0)
    >>> model = estimate_noise_model((Vn, F))
    >>> model.correlation_length, round(model.rho / 0.01, 1)
    (0.0, 1.0)
    """
    if isinstance(refine, (bool, np.bool_)) or not isinstance(refine, (int, np.integer)) or refine < 1:
        raise ValueError(f"estimate_noise_model: parameter 'refine' must be an int >= 1, got {refine!r}")
    if not isinstance(release, (bool, np.bool_)):
        raise TypeError(f"estimate_noise_model: parameter 'release' must be True or False, got {release!r}")
    if sample is None:
        sample = FIT_SAMPLE
    if isinstance(sample, (bool, np.bool_)) or not isinstance(sample, (int, np.integer)) or sample < 1:
        raise ValueError(f"estimate_noise_model: parameter 'sample' must be an int >= 1, got {sample!r}")
    data = read_mesh(mesh)
    V, F = data.V, data.F
    if spectrum is not None:
        bands_s, ells_s = (tuple(int(b) for b in spectrum[0]), tuple(float(x) for x in spectrum[1]))
        if not bands_s or list(bands_s) != sorted(set(bands_s)) or bands_s[0] < 0 or not ells_s or min(ells_s) < 0:
            raise ValueError(f"estimate_noise_model: parameter 'spectrum' = {spectrum!r} must be (increasing bands >= 0, "
                             "correlation lengths >= 0)")
    ops = get_operators(F, V.shape[0])
    before = set(MEMO)
    out = _estimate(V, F, ops, int(refine), int(seed), details, int(sample), None if spectrum is None else (bands_s, ells_s))
    model = out[0] if details else out
    if release and model.correlated:
        # the averaging runs of estimate_noise (white probes, in the tuning memo): the rules under a correlated model
        # colour their probes, so they read other runs; these would stay until evicted (at 400k vertices about 75 MB:
        # an (n, 7) state, the (n, 4) probes, a copy of V, and the averaging matrix P they step with)
        for key in set(MEMO) - before:
            if isinstance(key, tuple) and key[:1] == ("path",):
                MEMO.discard(key)
    return out


def _estimate(V: np.ndarray, F: np.ndarray, ops: Operators, refine: int, seed: int, details: bool, sample: int,
              spectrum: tuple[tuple[int, ...], tuple[float, ...]] | None) -> Any:
    """:func:`estimate_noise_model` on checked arguments (``ops`` the cached topology of ``F``)."""
    if spectrum is not None:
        bands_s, ells_s = spectrum
    found = smoothed_estimate(V, F, int(refine), ops)  # the level, the smoothed mesh, its normals and mean edge length
    rho0, smooth = found.rho, found.smooth
    info: dict[str, Any] = {"rho_white": rho0, "smooth": smooth}
    if rho0 == 0:
        model = NoiseModel(0.0)
        info["reason"] = "independent: no noise found (estimate_noise reads 0)"
        return (model, info) if details else model
    N = found.normals  # vertex_normals(smooth, F), computed by the estimate
    ok = ~ops.isolated & (np.linalg.norm(N, axis=1) > 0)
    R = band_residuals(ops, V)
    residual = {s: _normal_component(R[s], N) for s in BANDS}
    del R
    observed = np.array([np.median(residual[s][ok] ** 2) for s in BANDS])
    observed_fit = observed
    if not np.all(observed > 0):  # a band without residual (a plane, a tiny mesh): nothing to fit
        model = NoiseModel(rho0)
        info["reason"] = "independent: a band-pass residual is zero"
        return (model, info) if details else model
    region = SampledRegion(F, ops, int(sample), FIT_PATCHES, FIT_MARGIN, seed)
    if not region.whole and not np.any(ok[region.vertices] & region.inner):
        # a region too small for its margin (every vertex near a cut): the whole mesh, which this small sample allows
        region = SampledRegion(F, ops, ops.n, FIT_PATCHES, FIT_MARGIN, seed)
    if region.whole:  # the whole mesh, as before
        Vr, Fr, Nr, okr, opsr, probes = smooth, F, N, ok, ops, FIT_PROBES
        inner = None
    else:
        Vr, Fr = smooth[region.vertices], region.F
        opsr = Operators(Fr, region.vertices.size)
        Nr = N[region.vertices]
        inner = region.inner & ~opsr.isolated
        okr = ok[region.vertices] & inner
        probes = FIT_SAMPLE_PROBES
        strata = _border_strata(ops)
        # the whole mesh's share of each stratum: of its vertices on a face (the mean square of the model's noise,
        # zero elsewhere) and of its usable vertices (the medians)
        share_all = np.bincount(strata[~ops.isolated], minlength=FIT_BORDER_RINGS + 2) / ops.n
        share_ok = np.bincount(strata[ok], minlength=FIT_BORDER_RINGS + 2) / max(int(ok.sum()), 1)
        sr = strata[region.vertices]
        present = np.bincount(sr[okr], minlength=share_ok.size) > 0
        nearest = _nearest_present(present)
        share_all = np.bincount(nearest, weights=share_all, minlength=share_all.size)  # empty strata: into the nearest
        share_ok = np.bincount(nearest, weights=share_ok, minlength=share_ok.size)
        count_ok = np.bincount(sr[okr], minlength=share_ok.size)
        weights = (share_ok / np.maximum(count_ok, 1))[sr]  # per region vertex: a weighted median is the whole mesh's
        # the region's own observed residuals, on the same vertices as the probes: the local shape weighs on both
        # alike (with the whole mesh's instead, the level read on the 400k elephant ranged over 0.79-1.18 of the
        # whole-mesh fit's from one region to another)
        sel = region.vertices[okr]
        observed_fit = np.array([_weighted_median(residual[b][sel, 0] ** 2, weights[okr]) for b in BANDS])
    info["fit_vertices"] = int(okr.sum())
    xi = np.random.default_rng(seed).standard_normal((Vr.shape[0], probes))
    scale = None
    geometry = heat_geometry(Vr, Fr)
    if not region.whole:  # lengths in the whole mesh's mean edge length (a scan's sampling varies over it)
        geometry = (found.edge_length,) + tuple(geometry[1:])  # noise.mean_edge_length(smooth, F), same sum
    full = np.array(ELL_GRID)
    logr = np.empty((full.size, len(BANDS)))
    used = 0
    coloured: dict[float, np.ndarray] = {}
    # every length the fit and the spectrum ask for, filtered from one growing Krylov space (a HeatFilter per length
    # ran 8 CG solves each: on the bunny with scanner noise about 800 sparse products against 56 Lanczos steps)
    family = HeatKrylov(Vr, Fr, xi, geometry=geometry, tol=FIT_TOL)

    def probes_of(ell: float) -> np.ndarray:  # unit-variance probes of correlation length ell
        if ell == 0:
            Z = xi
        else:
            Z = family(diffusion_length(ell))
        if region.whole:
            return Z * math.sqrt(Z.size / float(np.sum(Z * Z)))  # mean square 1: tr(Sigma) = n
        # the whole mesh's mean square, from the inner vertices' by stratum (the noise is stronger near a border)
        msq = np.bincount(sr[inner], weights=np.mean(Z[inner] ** 2, axis=1), minlength=share_all.size)
        msq = msq / np.maximum(np.bincount(sr[inner], minlength=share_all.size), 1)
        return Z / math.sqrt(float(np.sum(share_all * msq)))

    for j, ell in enumerate(full):  # up the grid until the spread has risen well past its minimum
        Z = probes_of(float(ell))
        if spectrum is not None:
            coloured[float(ell)] = Z
        medians = _probe_medians(opsr, Nr, Z, okr, None if region.whole else weights)
        logr[j] = 0.5 * (np.log(observed_fit) - np.log(medians))
        used = j + 1
        spread = np.var(logr[:used], axis=1)
        best = int(np.argmin(spread))
        if j >= best + 2 and spread[j] > 4.0 * spread[best] + SPREAD_GAIN:
            break
    grid, logr = full[:used], logr[:used]
    ell, _ = _fit(logr, grid)
    curves = np.array([np.interp(ell, grid, logr[:, b]) for b in range(len(BANDS))])
    spread0, spread_fit = float(np.var(logr[0])), float(np.var(curves))
    info.update(grid=grid, log_rho=logr, ell_fit=ell, observed=observed, spread_white=spread0, spread_fit=spread_fit)
    significant = (ELL_MIN <= ell <= ELL_MAX and spread0 - spread_fit >= SPREAD_GAIN and spread0 >= SPREAD_RATIO * spread_fit
                   and int(ok.sum()) >= MIN_PATCHES * math.pi * ell**2)
    if spectrum is not None and significant:  # the surface-or-noise question arises only then
        Zs = [coloured[e] if e in coloured else probes_of(e) for e in ells_s]
        w = None if region.whole else weights
        # the whole mesh's own residuals, over all its usable vertices: the surface's spectrum varies over a scan,
        # and the region's balls read it with a sampling error the probes do not have (face000: up to 0.2 decades
        # at s = 8 to 16, which moved the allowed upper level from 0.109 to 0.061 h); the probes' statistic is
        # the whole mesh's already (weighted by border distance), within 0.07 decades of it on face000
        residuals = band_residuals(ops, V, bands_s)
        obs = np.array([np.median(_normal_component(residuals.pop(b), N)[ok] ** 2) for b in bands_s])
        info["spectrum"] = {"bands": bands_s, "lengths": ells_s, "observed": obs,
                            "probes": _spectrum_medians(opsr, Nr, Zs, okr, w, bands_s)}
        del coloured, Zs
    family = None  # the Krylov basis (up to HEAT_KRYLOV_MAX_STEPS blocks of the region's probes): not kept
    if significant:
        model = NoiseModel(float(np.exp(curves.mean())), ell, smooth, F)
        info["reason"] = (f"correlated: the bands agree at {ell:.2f} edge lengths (spread of log rho "
                          f"{spread0:.2g} for independent noise, {spread_fit:.2g} at the fit)")
    else:
        model = NoiseModel(rho0)
        why = []
        if not ELL_MIN <= ell <= ELL_MAX:
            why.append(f"the fitted length {ell:.2f} is outside [{ELL_MIN:g}, {ELL_MAX:g}] edge lengths")
        if spread0 - spread_fit < SPREAD_GAIN or spread0 < SPREAD_RATIO * spread_fit:
            why.append(f"the fit hardly improves on independent noise (spread {spread0:.2g} -> {spread_fit:.2g})")
        if int(ok.sum()) < MIN_PATCHES * math.pi * ell**2:
            why.append(f"too few vertices for a correlation length of {ell:.2f}")
        info["reason"] = "independent: " + "; ".join(why)
    return (model, info) if details else model
