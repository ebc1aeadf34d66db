"""The noise level of a mesh, estimated without the clean mesh, and the share of it that is tangential.

Generic machinery: nothing here knows a filter (the smoothing used to estimate normals is
plain averaging, :func:`meshdenoise.tuning.search.sure_smoothed`).
"""

from __future__ import annotations

import math
from typing import Any, Callable, NamedTuple

import numpy as np
import scipy.sparse as sp

from ..adapters import read_mesh
from ..arrays import MeshValidationError
from ..geometry import vertex_normals  # the compiled kernel from 65,536 vertices (noise_kernels), bit for bit
from ..operators import Operators, get_operators, spmm
from .noise_kernels import edge_lengths, fourth_difference_csr
from .risk import colour_probes
from .search import averaging_step, best_on_curve, path_curve

__all__ = ["estimate_noise", "estimate_noise_and_smooth", "smoothed_estimate", "SmoothedEstimate", "fourth_difference", "mean_edge_length", "normal_trust", "normal_spread", "WINSOR_K", "MAD"]

MAD = 0.6744897501960817  # median |N(0, 1)|


WINSOR_K = 4.0  # winsorised second moment: residuals clipped at WINSOR_K MAD scales
HEAVY_TAIL_SE = 4.0  # heavy tails declared when the winsorised kurtosis exceeds the Gaussian one by this many standard errors
HEAVY_TAIL_MIN_NOISE = 0.125  # ... and the noise is at least this many edge lengths (below it the tails are the surface's)


def _gauss_winsor_moments(k: float) -> tuple[float, float]:
    """:math:`m_2 = \\mathbb E \\min(Z^2, k^2)` and :math:`m_4 = \\mathbb E \\min(Z^2, k^2)^2` for :math:`Z \\sim N(0, 1)`.

    Closed forms: :math:`m_2 = (2\\Phi(k) - 1) - 2k\\varphi(k) + 2k^2(1 - \\Phi(k))`,
    :math:`m_4 = 3(2\\Phi(k) - 1) - 2\\varphi(k)(k^3 + 3k) + 2k^4(1 - \\Phi(k))`.

    Examples
    --------
    >>> m2, m4 = _gauss_winsor_moments(50.0)  # no clipping: E Z^2 = 1, E Z^4 = 3
    >>> round(m2, 9), round(m4, 9)
    (1.0, 3.0)
    """
    cdf = 0.5 * (1.0 + math.erf(k / math.sqrt(2.0)))
    pdf = math.exp(-0.5 * k * k) / math.sqrt(2.0 * math.pi)
    tail = 0.5 * math.erfc(k / math.sqrt(2.0))
    m2 = (2 * cdf - 1) - 2 * k * pdf + 2 * k * k * tail
    m4 = 3 * (2 * cdf - 1) - 2 * pdf * (k**3 + 3 * k) + 2 * k**4 * tail
    return m2, m4


def fourth_difference(ops: Operators) -> sp.csr_matrix:
    """:math:`B = (I - D^{-1}W)^2` of this topology: a fourth-order difference, blind to the smooth part of
    a surface, whose output on a noisy mesh is almost only noise.

    Made on each call, not stored on ``ops``: it is 220 bytes per vertex (88 MB at 400k vertices) that only
    the noise estimate needs, and :func:`estimate_noise_and_smooth` makes it once. Built by
    :func:`~meshdenoise.tuning.noise_kernels.fourth_difference_csr` on every thread: scipy's
    ``(I - P) @ (I - P)`` entry for entry, in the same order (1.9 s single-threaded at 1.6M vertices).
    """
    return fourth_difference_csr(ops.P)


def _squared(B: sp.csr_matrix) -> sp.csr_matrix:
    """:math:`B \\circ B` (entries squared) sharing ``B``'s index arrays: no copy of the structure."""
    return sp.csr_matrix((B.data * B.data, B.indices, B.indptr), shape=B.shape)


def _normal_weight_sums(B: sp.csr_matrix, N: np.ndarray, squared: bool = False) -> np.ndarray:
    """:math:`c_i^2 = \\sum_j B_{ij}^2 \\langle N_i, N_j\\rangle^2` for every row, ``N`` (n, 3) -> (n,), no per-entry gathers.

    :math:`\\langle N_i, N_j\\rangle^2 = \\langle U_i, U_j\\rangle` with the six columns
    :math:`U = (N_x^2, N_y^2, N_z^2, \\sqrt2 N_xN_y, \\sqrt2 N_xN_z, \\sqrt2 N_yN_z)`, so
    :math:`c^2 = \\sum_{\\text{columns}} U \\odot ((B \\circ B)\\, U)`: one sparse product of six
    columns instead of gathering two ``(nnz, 3)`` arrays of normals (800 MB at 400k vertices).
    ``squared``: ``B`` is already :math:`B \\circ B` (the estimate squares it once for all its normals).
    """
    N = np.asarray(N, dtype=np.float64)
    r2 = math.sqrt(2.0)
    U = np.column_stack([N[:, 0] ** 2, N[:, 1] ** 2, N[:, 2] ** 2,
                         r2 * N[:, 0] * N[:, 1], r2 * N[:, 0] * N[:, 2], r2 * N[:, 1] * N[:, 2]])
    c2 = np.einsum("ij,ij->i", U, spmm(B if squared else _squared(B), U))
    return np.maximum(c2, 0.0)  # a sum of squares; rounding of the expansion cannot make it negative


def _normal_residual_scale(V: np.ndarray, ops: Operators, N: np.ndarray, B: sp.csr_matrix) -> tuple[float, float, float]:
    """Robust estimates of rho from the normal component of :math:`B X`, :math:`B = (I - P)^2`.

    The noise part of :math:`r_i = \\langle (BX)_i, N_i\\rangle` is
    :math:`\\rho \\sum_j B_{ij} \\varepsilon_j \\langle N_j, N_i\\rangle`, of standard deviation
    :math:`\\rho c_i`, :math:`c_i^2 = \\sum_j B_{ij}^2 \\langle N_i, N_j\\rangle^2`
    (about :math:`1 + 4/d + ...`: computed exactly from the sparse ``B``) whatever the
    distribution of :math:`\\varepsilon`. ``B`` is a fourth-order difference, so the clean
    surface's smooth curvature term is much smaller than with one Laplacian.

    Returns ``(mad, winsor, excess)`` for the normalised residuals :math:`t_i = r_i / c_i`:

    - ``mad`` :math:`= \\operatorname{median}|t_i| / 0.6745`: ignores features (edges,
      corners), but reads only the core of a heavy-tailed noise (half the vertices hit by
      a Gaussian impulse: 0.76 of the rms);
    - ``winsor`` :math:`= \\sqrt{\\operatorname{mean}_i \\min(t_i^2, k^2 s^2) / m_2(k)}`,
      ``s = mad``, ``k = WINSOR_K``: the second moment, which is what SURE needs
      (:math:`\\mathbb E\\langle E, HE\\rangle = \\sum_i H_{ii}\\sigma_i^2` for any independent noise),
      clipped so that a few feature vertices weigh at most :math:`k^2 s^2` each;
    - ``excess``: the winsorised kurtosis :math:`\\overline{w^2} / \\bar w^2`, :math:`w_i = \\min(t_i^2, k^2 s^2)`,
      minus its Gaussian value :math:`m_4/m_2^2`,
      in standard errors :math:`\\sqrt{24/m}` (``m`` usable vertices).
    """
    return _normal_scale(spmm(B, np.asarray(V, dtype=np.float64)), _squared(B), N, ops)


def _normal_scale(BV: np.ndarray, B2: sp.csr_matrix, N: np.ndarray, ops: Operators) -> tuple[float, float, float]:
    """:func:`_normal_residual_scale` from ``BV`` :math:`= B X` (n, 3) and ``B2`` :math:`= B \\circ B` (the estimate
    computes both once for its ``refine`` rounds of normals)."""
    c = np.sqrt(_normal_weight_sums(B2, N, squared=True))
    r = np.einsum("ij,ij->i", BV, N)
    ok = (c > 1e-12) & ~ops.isolated & (np.linalg.norm(N, axis=1) > 0)
    if ok.sum() < 3:
        raise MeshValidationError(
            f"estimate_noise: too small to estimate the noise: {int(ok.sum())} of its {ops.n} vertices have the "
            "neighbourhood the estimate needs (at least 3); choose a filter and its parameters instead (--method and --param on the command line)")
    t = r[ok] / c[ok]
    mad = float(np.median(np.abs(t)) / MAD)
    if mad == 0:
        return 0.0, 0.0, 0.0
    m2, m4 = _gauss_winsor_moments(WINSOR_K)
    w = np.minimum(t**2, (WINSOR_K * mad) ** 2)
    winsor = float(np.sqrt(np.mean(w) / m2))
    excess = (float(np.mean(w**2) / np.mean(w) ** 2) - m4 / m2**2) / math.sqrt(24.0 / t.size)
    return mad, winsor, excess


def _residual_energy_scale(V: np.ndarray, ops: Operators, B: sp.csr_matrix) -> float:
    """Root-mean-square estimate of rho from the whole 3-D residual :math:`B X`, no normals needed.

    The noise part of :math:`(BX)_i` is :math:`\\rho \\sum_j B_{ij} \\varepsilon_j N_j` with
    unit :math:`N_j`, so :math:`\\mathbb E \\|(BX)_i\\|^2 = \\rho^2 \\sum_j B_{ij}^2` whatever the
    normals are: exact under strong noise, where no normal can be trusted. The clean
    surface adds its own (small, positive) energy, so this errs upward on weak noise.
    """
    return _energy_scale(spmm(B, np.asarray(V, dtype=np.float64)), np.asarray(_squared(B).sum(axis=1)).ravel(), ops)


def _energy_scale(R: np.ndarray, c2: np.ndarray, ops: Operators) -> float:
    """:func:`_residual_energy_scale` from ``R`` :math:`= B X` (n, 3) and the row sums ``c2`` (n,) of :math:`B \\circ B`."""
    ok = (c2 > 1e-24) & ~ops.isolated
    if ok.sum() < 3:
        raise MeshValidationError(
            f"estimate_noise: too small to estimate the noise: {int(ok.sum())} of its {ops.n} vertices have the "
            "neighbourhood the estimate needs (at least 3); choose a filter and its parameters instead (--method and --param on the command line)")
    return float(np.sqrt(np.mean(np.sum(R[ok] ** 2, axis=1) / c2[ok])))


def mean_edge_length(X: np.ndarray, ops: Operators) -> float:
    """Mean length of the mesh's edges at coordinates ``X`` (0 with no edge)."""
    e = ops.edges
    return float(edge_lengths(X, e).mean()) if e.size else 0.0


def estimate_noise(mesh: Any, *, refine: int = 2) -> float:
    """Estimate the noise level ``rho`` of a noisy mesh, without the clean mesh.

    The paper's noise moves vertex ``i`` by :math:`\\rho\\, \\varepsilon_i N_i`. The
    high-frequency part of the coordinates, :math:`B X` with :math:`B = (I - D^{-1}W)^2`
    (a fourth-order difference, blind to the smooth part of the surface), is almost
    only noise. Two estimates are read from it:

    - along the normals, robustly: the noise part of :math:`r_i = \\langle (BX)_i, N_i\\rangle`
      has standard deviation :math:`\\rho c_i`, :math:`c_i^2 = \\sum_j B_{ij}^2 \\langle N_i, N_j\\rangle^2`
      (exact, from the sparse ``B``), so :math:`\\hat\\rho_{N} = \\operatorname{median}_i |r_i| / c_i / 0.6745`
      (MAD: ignores sharp edges and corners; the projection ignores the tangential
      irregularity of the sampling). It needs normals of the *clean* surface: they are
      taken from the mesh smoothed by SURE-chosen ``filtering``, refined ``refine`` times;
    - in 3-D, by energy: :math:`\\hat\\rho_{E}^2 = \\operatorname{mean}_i \\|(BX)_i\\|^2 / \\sum_j B_{ij}^2`,
      exact for any normals, but it also counts the clean surface's detail.

    Which one to trust depends on the noise relative to the mesh resolution ``h`` (mean
    edge length of the smoothed mesh): when :math:`\\hat\\rho_E > h` no normal survives
    the noise (and the surface detail is negligible next to it), so :math:`\\hat\\rho_E`
    is used; below :math:`h/2`, :math:`\\hat\\rho_N`; in between a geometric blend.

    Parameters
    ----------
    mesh : (V, F) tuple, pymeshlab.MeshSet or Mesh, or open3d.geometry.TriangleMesh
    refine : int, >= 1
        Rounds of smoothing the normals are taken from.

    Returns
    -------
    float
        :math:`\\hat\\rho` in the mesh's units: within about 5 % on smooth and CAD meshes
        from 0.2 to 25 edge lengths of noise (README, "Automatic parameters"); a coarse, curved mesh
        with noise far below its edge length (Nefertiti at rho = 0.015) is overestimated.

    Examples
    --------
    >>> from meshdenoise.shapes import icosphere
    >>> from meshdenoise import add_normal_noise
    >>> V, F = icosphere(4)
    >>> Vn, _ = add_normal_noise((V, F), rho=0.01, seed=0)
    >>> round(estimate_noise((Vn, F)) / 0.01, 1)
    1.0
    """
    if isinstance(refine, (bool, np.bool_)) or not isinstance(refine, (int, np.integer)) or refine < 1:
        raise ValueError(f"estimate_noise: parameter 'refine' must be an int >= 1, got {refine!r}")
    data = read_mesh(mesh)
    return estimate_noise_and_smooth(data.V, data.F, refine)[0]


def estimate_noise_and_smooth(V: np.ndarray, F: np.ndarray, refine: int = 2) -> tuple[float, np.ndarray]:
    """:func:`estimate_noise` on arrays, and the smoothed coordinates (n, 3) its last normals came from
    (``V`` itself when the estimate is 0)."""
    found = smoothed_estimate(V, F, refine)
    return found.rho, found.smooth


class SmoothedEstimate(NamedTuple):
    """:func:`estimate_noise`'s level and what it computed on the way, for the callers that need them too.

    Attributes
    ----------
    rho : float
        The level (:func:`estimate_noise`).
    smooth : ndarray, shape (n, 3)
        The smoothed coordinates its last normals came from (``V`` itself when ``rho`` is 0).
    normals : ndarray, shape (n, 3) or None
        Their vertex normals (:func:`meshdenoise.geometry.vertex_normals` of ``smooth``); None when ``rho`` is 0.
    edge_length : float
        The mean edge length of ``smooth`` (NaN when ``rho`` is 0).
    """

    rho: float
    smooth: np.ndarray
    normals: np.ndarray | None
    edge_length: float


def smoothed_estimate(V: np.ndarray, F: np.ndarray, refine: int = 2, ops: Operators | None = None) -> SmoothedEstimate:
    """:func:`estimate_noise_and_smooth` with the last normals and mean edge length (:class:`SmoothedEstimate`).

    The fourth difference ``B`` is made once and used once: its product with the coordinates
    :math:`BX` (the same in every round, and in both estimates) and its squared entries
    (:math:`B \\circ B`, squared in place: the estimate needs no more of ``B``) are kept for the
    ``refine`` rounds of normals. The same numbers as computing each from ``B`` anew. ``ops``: the
    operators of ``F`` if the caller has them (:func:`~meshdenoise.operators.get_operators` hashes the faces).
    """
    ops = get_operators(F, V.shape[0]) if ops is None else ops
    B = fourth_difference(ops)  # made once here, dropped on return (fourth_difference)
    BV = spmm(B, np.asarray(V, dtype=np.float64))
    B.data *= B.data  # B o B from here on (the same numbers as _squared(B)); B itself is not needed again
    rho_e = _energy_scale(BV, np.asarray(B.sum(axis=1)).ravel(), ops)
    rho = rho_e
    smooth, N, h = V, None, float("nan")
    smoother = None
    for _ in range(int(refine)):
        if rho == 0:
            return SmoothedEstimate(0.0, V, None, float("nan"))
        smoother = smoother or _AveragingSmoother(V, ops)
        smooth = smoother(rho)
        N = vertex_normals(smooth, F)
        rho_n, rho_w, excess = _normal_scale(BV, B, N, ops)
        h = mean_edge_length(smooth, ops)
        if excess > HEAVY_TAIL_SE and rho_n >= HEAVY_TAIL_MIN_NOISE * h:
            rho_n = rho_w  # heavy-tailed noise: its second moment, not its Gaussian core
        w = normal_trust(rho_e, h)
        rho = float(np.exp((1 - w) * np.log(max(rho_n, 1e-300)) + w * np.log(rho_e)))
    return SmoothedEstimate(rho, smooth, N, h)


class _AveragingSmoother:
    """``sure_smoothed(V, ops, rho).X`` for the estimate's rounds: one curve, coordinates carried from round to round.

    :func:`~meshdenoise.tuning.search.sure_smoothed` looks its memoised averaging curve up for
    every call (a digest of the faces, coordinates and probes, 170 MB at 1.6M vertices) and
    recomputes the best step's coordinates from ``V``; here the curve is looked up once (the same
    memo entry, which the rules after the estimate read) and a later round whose best step ``k``
    is at or past the last one's continues from its coordinates (the same steps on the same
    numbers: the same coordinates, tests/test_noise_kernels.py).
    """

    def __init__(self, V: np.ndarray, ops: Operators):
        self.ops = ops
        self.curve = path_curve(V, ops, averaging_step(ops.P, 1.0), ("P", 1.0))  # sure_smoothed's curve and key
        self.k, self.X = -1, None

    def __call__(self, rho: float) -> np.ndarray:
        k = int(best_on_curve(self.curve, self.ops.n, rho, "sure", coordinates=False).value)
        if self.X is None or k < self.k:
            X = self.curve.coordinates(k)
        else:
            X = self.X
            for _ in range(k - self.k):
                X = self.curve.step(X)
            X = np.array(X, dtype=np.float64)  # a copy, as PathCurve.coordinates returns
        self.k, self.X = k, X
        return X


def normal_trust(rho: float, h: float) -> float:
    """How far normals of a smoothed mesh are NOT to be trusted at noise ``rho``, mesh resolution ``h``: 0 to 1.

    0 below half an edge length of noise (normals trusted), 1 above one edge length (no
    normal survives the noise), linear in between. :func:`estimate_noise` blends its two
    estimates by it; normal-based rules use it as the share of their tangential update.

    Examples
    --------
    >>> normal_trust(0.1, 1.0), normal_trust(0.75, 1.0), normal_trust(3.0, 1.0)
    (0.0, 0.5, 1.0)
    """
    return 1.0 if h == 0 else min(max((rho / h - 0.5) / 0.5, 0.0), 1.0)


def normal_spread(
    Xs: np.ndarray, F: np.ndarray, smooth: Callable[[np.ndarray], np.ndarray], rho: float, samples: int, seed: int = 0
) -> float:
    """Parametric bootstrap of the spread of a smoother's normals around the clean ones.

    ``Xs`` (n, 3) is a smoothed estimate of the clean mesh and ``smooth`` the linear
    smoother that made it (``smooth(Y)`` for ``Y`` (n, k), columns independent). ``Xs``
    stands in for the clean mesh: noise of the model is drawn on it,
    :math:`X^{(k)} = X_s + \\rho\\, \\varepsilon^{(k)} \\odot N(X_s)`, :math:`\\varepsilon^{(k)}_i \\sim N(0, 1)`
    (coloured by the active correlated noise model, :func:`~meshdenoise.tuning.risk.noise_colouring`),
    smoothed again, and the spread is the mean squared sine of the angle between the
    normals of the result and those of ``Xs``:

    .. math:: \\tau = \\frac{1}{K |I|} \\sum_{k=1}^{K} \\sum_{i \\in I}
              \\Big(1 - \\big\\langle N_i(H X^{(k)}), N_i(X_s)\\big\\rangle^2\\Big)

    (``I``: vertices with a normal, ``K = samples``; :math:`H X^{(k)} = H X_s + \\rho H(\\varepsilon^{(k)} \\odot N)`,
    one solve for all draws). It counts both the normals' noise (the spread of
    :math:`H \\varepsilon`) and their smoothing bias (:math:`H X_s` against :math:`X_s`), but not
    the tangential irregularity of the sampling, which the tangential residual
    :math:`X - X_s` also holds (on the benchmark Bunny0.2, the shape's own tangential
    residual is most of it).

    Returns
    -------
    float
        :math:`\\tau \\in [0, 1]`.
    """
    N = vertex_normals(Xs, F)
    ok = np.linalg.norm(N, axis=1) > 0
    if not ok.any():
        return 1.0
    eps = colour_probes(np.random.default_rng(seed).standard_normal((Xs.shape[0], samples)), 1.0 / samples)
    rhs = np.hstack([Xs] + [rho * eps[:, [k]] * N for k in range(samples)])
    out = smooth(rhs)
    total = 0.0
    for k in range(samples):  # over draws, not vertices
        Nk = vertex_normals(out[:, :3] + out[:, 3 + 3 * k:6 + 3 * k], F)
        total += float(np.mean(1.0 - np.sum(Nk[ok] * N[ok], axis=1) ** 2))
    return min(max(total / samples, 0.0), 1.0)
