"""Noise models: the paper's (Gaussian along vertex normals) and a range scanner's (correlated, along the view).

Also the measure of a field's correlation length on a mesh (:func:`correlation_length`).
"""

from __future__ import annotations

import warnings
from typing import Any, Sequence

import numpy as np
import scipy.sparse as sp

from .adapters import read_mesh
from .geometry import cotangent_laplacian, lumped_mass, vertex_normals
from .operators import get_operators

__all__ = [
    "add_normal_noise", "add_scanner_noise", "autocorrelation", "correlation_length", "diffusion_length",
    "heat_filtered_noise", "mean_edge_length", "HeatFilter", "HeatKrylov",
]


def add_normal_noise(mesh: Any, rho: float, seed: int | np.random.Generator | None = None) -> Any:
    """Displace every vertex along its normal by Gaussian noise of standard deviation ``rho``.

    .. math:: x_i = x^0_i + \\rho\\, \\varepsilon_i N_i, \\qquad \\varepsilon_i \\sim \\mathcal N(0, 1)

    with :math:`N_i` the normalised sum of the unit normals of the faces around vertex
    ``i`` (:func:`meshdenoise.geometry.vertex_normals`). ``rho`` is absolute (in the
    mesh's units). A vertex with a zero normal (isolated, or normals cancelling) is not
    moved. Returns the same mesh type as the input, like the filters (a MeshSet is
    changed in place).

    Parameters
    ----------
    mesh : (V, F) tuple, pymeshlab.MeshSet or Mesh, or open3d.geometry.TriangleMesh
    rho : float, >= 0
        Noise amplitude.
    seed : int or numpy.random.Generator, optional
        Same seed, same noise.

    Examples
    --------
    >>> import numpy as np
    >>> V = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0]])
    >>> Vn, _ = add_normal_noise((V, np.array([[0, 1, 2]])), rho=0.1, seed=0)
    >>> bool(np.allclose(Vn[:, :2], V[:, :2]))  # a flat triangle moves along z only
    True
    """
    if isinstance(rho, (bool, np.bool_)) or not isinstance(rho, (int, float, np.integer, np.floating)):
        raise TypeError(f"add_normal_noise: rho must be a number, got {rho!r}")
    if not (np.isfinite(rho) and rho >= 0):
        raise ValueError(f"add_normal_noise: parameter 'rho' = {rho!r} is out of range: rho >= 0")
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    data = read_mesh(mesh)
    N = vertex_normals(data.V, data.F)
    eps = rng.standard_normal(data.V.shape[0])
    return data.write(data.V + float(rho) * eps[:, None] * N)


# --- a scanner's noise ----------------------------------------------------------------------------
HEAT_STEPS = 8  # implicit heat steps: (1 + tau lambda / k)^-k, close to exp(-tau lambda) for the kept band

# The discrete filter's correlation is shorter than the continuum's sqrt(8 tau): the correlation
# length (as correlation_length() measures it) of heat_filtered_noise(..., diffusion_length=d),
# computed from exact covariances K D^2 K^T (no sampling) at 25 to 81 interior vertices of a
# 201 x 201 grid and of icosphere(6), averaged (the two agree within 6 %); used inverted, so that
# add_scanner_noise(correlation_length=l) measures l. Above 12 edge lengths the ratio 0.9555 holds.
_DIFFUSION = np.array([0.0, 0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 1.75, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0, 12.0])
_MEASURED = np.array([0.0, 0.4475, 0.5499, 0.6544, 0.7739, 0.9189, 1.1051, 1.3841, 1.6705, 2.1994, 2.7257,
                      3.716, 4.6894, 5.6602, 7.5805, 9.4949, 11.406])


def diffusion_length(correlation_length: float) -> float:
    """The continuum length :math:`\\sqrt{8\\tau}/h` of the heat filter that gives ``correlation_length`` on a mesh.

    Inverts the calibration table above (piecewise linear; linear beyond 12 edge lengths).

    Examples
    --------
    >>> diffusion_length(0.0), round(diffusion_length(2.0), 3)
    (0.0, 2.311)
    """
    if correlation_length <= _MEASURED[-1]:
        return float(np.interp(correlation_length, _MEASURED, _DIFFUSION))
    return float(_DIFFUSION[-1] + (correlation_length - _MEASURED[-1]) / 0.9555)


def _number(name: str, value: Any, *, low: float = 0.0, high: float = np.inf, what: str = "add_scanner_noise") -> float:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TypeError(f"{what}: parameter {name!r} must be a number, got {value!r}")
    value = float(value)
    if not (np.isfinite(value) and low <= value <= high):
        raise ValueError(f"{what}: parameter {name!r} = {value!r} is out of range: {low:g} <= {name} <= {high:g}")
    return value


def mean_edge_length(V: np.ndarray, F: np.ndarray) -> float:
    """Mean length of the unique undirected edges of ``(V, F)``; the unit of correlation lengths.

    Examples
    --------
    >>> import numpy as np
    >>> float(mean_edge_length(np.array([[0., 0, 0], [2, 0, 0], [0, 2, 0]]), np.array([[0, 1, 2]])).__round__(4))
    2.2761
    """
    e = get_operators(F, V.shape[0]).edges
    if e.shape[0] == 0:
        raise ValueError("the mesh has no edges, so no mean edge length")
    from .tuning.noise_kernels import edge_lengths  # np.linalg.norm(V[e[:, 0]] - V[e[:, 1]], axis=1), no gathers

    return float(edge_lengths(V, e).mean())


def heat_filtered_noise(
    V: np.ndarray, F: np.ndarray, length: float, rng: np.random.Generator, columns: int = 1
) -> np.ndarray:
    """White noise smoothed by the mesh heat kernel over the length ``length`` (in mean edge lengths).

    White noise :math:`w` (variance :math:`\\bar m / m_i` at vertex *i*, the discrete
    white noise of the lumped mass :math:`m`) is diffused for the time
    :math:`\\tau = (\\ell h)^2 / 8` with :data:`HEAT_STEPS` implicit steps of the cotangent
    Laplacian :math:`L` (:math:`(M + \\tfrac{\\tau}{k} L) u_{s+1} = M u_s`). In the plane
    the covariance of the result is the heat kernel at time :math:`2\\tau`, so the
    correlation of two points at distance :math:`r` is :math:`\\exp(-r^2 / (8 \\tau))
    = \\exp(-(r / (\\ell h))^2)`: it falls to :math:`1/e` at :math:`r = \\ell h`, with
    :math:`h` the mean edge length. On a mesh the measured correlation length is a little
    shorter (0.77 edge lengths for ``length=1``, 3.7 for 4): :func:`diffusion_length` gives the
    ``length`` for a wanted correlation length. Not rescaled.

    Parameters
    ----------
    V : ndarray, shape (n, 3)
    F : ndarray, shape (m, 3)
    length : float
        :math:`\\ell` in mean edge lengths; 0 gives the white noise itself (one independent
        standard normal per vertex).
    rng : numpy.random.Generator
    columns : int
        Independent fields to draw.

    Returns
    -------
    ndarray, shape (n, columns)
    """
    n = V.shape[0]
    w = rng.standard_normal((n, columns))
    if length == 0.0:
        return w
    return HeatFilter(V, F, length)(w)


HEAT_MASS_FLOOR = 1e-9  # mass of a vertex on no face of positive area, relative to the mean positive mass


def heat_geometry(V: np.ndarray, F: np.ndarray) -> tuple[float, np.ndarray, sp.csr_matrix]:
    """What every :class:`HeatFilter` of one mesh shares: mean edge length, lumped mass (floored), cotangent Laplacian."""
    h = mean_edge_length(V, F)
    mass = lumped_mass(V, F)
    floor = HEAT_MASS_FLOOR * _positive_mean(mass)
    mass = np.maximum(mass, floor)  # vertices on no face of positive area: kept apart, not singular
    return h, mass, cotangent_laplacian(V, F)


def _positive_mean(mass: np.ndarray) -> float:
    positive = mass > 0
    return float(mass[positive].mean()) if positive.any() else 1.0


def _white_scale(mass: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The vertices on a face of positive area (n,) bool, and the discrete white noise's scale :math:`\\sqrt{\\bar m / m_i}` (n,).

    A vertex on no face of positive area (unreferenced, as range scans have) gets no noise (scale 0): its
    floored mass would otherwise amplify it 30,000 times and, once rescaled, leave the surface almost noiseless.
    """
    surface = mass > 2.0 * HEAT_MASS_FLOOR * _positive_mean(mass)  # floored masses sit at the floor
    scale = np.where(surface, np.sqrt(mass[surface].mean() / mass) if surface.any() else 0.0, 0.0)
    return surface, scale


class HeatFilter:
    """The linear map of :func:`heat_filtered_noise`: white noise in, heat-filtered noise out.

    :math:`C = K\\, \\mathrm{diag}(\\sqrt{\\bar m / m})` with :math:`K = (M + \\tfrac{\\tau}{k} L)^{-k} M^k`
    (:data:`HEAT_STEPS` implicit steps, :math:`\\tau = (\\ell h)^2 / 8`), so that
    ``heat_filtered_noise(V, F, length, rng)`` is ``HeatFilter(V, F, length)(rng.standard_normal((n, 1)))``.
    Its covariance :math:`C C^T` is the noise model's (before rescaling); applied to probes
    it colours them (:class:`meshdenoise.tuning.covariance.NoiseModel`).

    Parameters
    ----------
    V : ndarray, shape (n, 3)
    F : ndarray, shape (m, 3)
    length : float, > 0
        The diffusion length in mean edge lengths (:func:`diffusion_length` of a correlation length).
    geometry : tuple, optional
        :func:`heat_geometry` of ``(V, F)``, when several filters of one mesh are built.
    """

    def __init__(self, V: np.ndarray, F: np.ndarray, length: float,
                 geometry: tuple[float, np.ndarray, sp.csr_matrix] | None = None):
        from .solvers import CGSolver

        h, mass, L = heat_geometry(V, F) if geometry is None else geometry
        self.length = float(length)
        self.mass = mass
        self.surface, self.scale = _white_scale(mass)
        tau = (length * h) ** 2 / 8.0
        # M + (tau / k) L is well conditioned (tau / k is about (l h)^2 / 64): Jacobi-preconditioned CG takes
        # tens of iterations, where a Cholesky factorisation of an unordered 655k-vertex mesh took 90 s
        self.solver = CGSolver(sp.csr_matrix(sp.diags(mass) + (tau / HEAT_STEPS) * L))

    def __call__(self, Z: np.ndarray, tol: float = 1e-8) -> np.ndarray:
        """:math:`C Z` for ``Z`` (n, k) (``Z`` is not changed)."""
        u = Z * self.scale[:, None]
        for _ in range(HEAT_STEPS):
            u = self.solver.solve(self.mass[:, None] * u, tol=tol, x0=u)
        return u


HEAT_KRYLOV_CHECK = 4  # HeatKrylov: a length's coefficients must settle over this many Lanczos steps ...
HEAT_KRYLOV_MAX_STEPS = 128  # ... within this many steps; lengths not settled by then are filtered by CG (HeatFilter)
HEAT_KRYLOV_CHUNK = 16  # ... and the result is summed over this many basis vectors at a time


class HeatKrylov:
    """:class:`HeatFilter` ``(V, F, length, geometry)(Z)`` for any number of lengths, from one growing Krylov space.

    With :math:`A = M^{-1} L` (lumped mass, cotangent Laplacian) the heat filter is
    :math:`C_\\ell Z = (I + t_\\ell A)^{-k} \\mathrm{diag}(s) Z`, :math:`k` = :data:`HEAT_STEPS`,
    :math:`t_\\ell = (\\ell h)^2 / (8k)`, :math:`s` the white noise's scale. With the symmetric
    :math:`S = M^{-1/2} L M^{-1/2}`, :math:`(I + tA)^{-k} = M^{-1/2} f_t(S) M^{1/2}` with
    :math:`f_t(x) = (1 + t x)^{-k}`, so per column :math:`w` of :math:`W = M^{1/2} \\mathrm{diag}(s) Z`
    Lanczos on :math:`S` from :math:`w` (orthonormal basis :math:`Q_j`, tridiagonal :math:`T_j`) gives
    :math:`f_t(S) w \\approx \\|w\\|\\, Q_j f_t(T_j) e_1` for **every** length: one Krylov space serves all
    lengths and all :math:`k` implicit steps, where :class:`HeatFilter` runs :math:`k` CG solves per
    length (the noise model's fit on the bunny with scanner noise: 10 lengths, 8 solves of 2 to 19
    iterations each, about 800 sparse products, against 56 Lanczos steps).

    :math:`f_t` is analytic on the spectrum :math:`[0, \\lambda_{max}]` with its pole at :math:`-1/t`,
    so the error falls geometrically, slower for longer lengths and for a wider spectrum. A length
    is taken when its coefficients :math:`\\|w\\| f_t(T_j) e_1` moved by at most ``tol`` of their norm
    over the last :data:`HEAT_KRYLOV_CHECK` steps, for every column (against a tightly solved
    :class:`HeatFilter` the result's relative error is then far below ``tol``: tests/test_fast_noise.py).
    The space grows as longer lengths ask for it, up to ``max_steps``; a length not settled by then
    (badly shaped triangles spread the spectrum: the strongly smoothed elephant at noise 0.2 needs
    more than 128 steps beyond 1 edge length) is filtered by :class:`HeatFilter` instead, whose
    Jacobi-preconditioned CG does not mind. No reorthogonalisation: Lanczos for :math:`f(S) b` stays
    accurate in floating point (Greenbaum 1989; Musco, Musco and Sidford 2018); loss of
    orthogonality only delays it a little. The basis is kept (float32 when ``tol >= 1e-6``: its
    rounding, 6e-8 relative, is far below ``tol``) until the object is dropped: at most
    ``max_steps`` blocks of ``(n, m)``.

    Parameters
    ----------
    V : ndarray, shape (n, 3)
    F : ndarray, shape (f, 3)
    Z : ndarray, shape (n, m)
        White fields (columns filtered independently).
    geometry : tuple, optional
        :func:`heat_geometry` of ``(V, F)`` (its mean edge length is the unit of the lengths).
    tol : float in (0, 1)
    max_steps : int, >= 1

    Examples
    --------
    >>> from meshdenoise.shapes import icosphere
    >>> V, F = icosphere(3)
    >>> Z = np.random.default_rng(0).standard_normal((len(V), 2))
    >>> family = HeatKrylov(V, F, Z, tol=1e-9)
    >>> Y = family(2.0)  # a diffusion length, as HeatFilter's
    >>> bool(np.allclose(Y, HeatFilter(V, F, 2.0)(Z, tol=1e-12), rtol=0, atol=1e-7 * np.abs(Y).max()))
    True
    """

    def __init__(self, V: np.ndarray, F: np.ndarray, Z: np.ndarray, *,
                 geometry: tuple[float, np.ndarray, sp.csr_matrix] | None = None, tol: float = 1e-5,
                 max_steps: int = HEAT_KRYLOV_MAX_STEPS):
        if isinstance(tol, bool) or not isinstance(tol, (float, int)) or not 0 < tol < 1:
            raise ValueError(f"HeatKrylov: parameter 'tol' = {tol!r} is out of range: 0 < tol < 1")
        if isinstance(max_steps, bool) or not isinstance(max_steps, (int, np.integer)) or max_steps < 1:
            raise ValueError(f"HeatKrylov: parameter 'max_steps' = {max_steps!r} must be an int >= 1")
        Z = np.asarray(Z, dtype=np.float64)
        if Z.ndim != 2 or Z.shape[0] != V.shape[0]:
            raise ValueError(f"HeatKrylov: Z must have shape ({V.shape[0]}, m), got {Z.shape}")
        self.V, self.F, self.Z = V, F, Z
        self.geometry = heat_geometry(V, F) if geometry is None else geometry
        self.tol, self.max_steps = float(tol), int(max_steps)
        h, mass, L = self.geometry
        _, scale = _white_scale(mass)
        root = np.sqrt(mass)
        self._inv = 1.0 / root
        self._S = sp.csr_matrix(sp.diags(self._inv) @ L @ sp.diags(self._inv))
        W = (root * scale)[:, None] * Z
        self._beta0 = np.sqrt(np.einsum("ij,ij->j", W, W))
        self._q = W / np.where(self._beta0 > 0, self._beta0, 1.0)
        del W
        self._q_prev = np.zeros_like(self._q)
        self._b_prev = np.zeros(Z.shape[1])
        self._alpha: list[np.ndarray] = []
        self._beta: list[np.ndarray] = []
        self._dtype = np.float32 if tol >= 1e-6 else np.float64
        self._basis = np.empty((0,) + Z.shape, dtype=self._dtype)
        self.exhausted = False  # every column's Krylov space is invariant: the coefficients are exact
        self.fallbacks = 0  # lengths filtered by HeatFilter (not settled within max_steps)

    @property
    def steps(self) -> int:
        """Lanczos steps taken (basis vectors kept)."""
        return len(self._alpha)

    def _extend(self, steps: int) -> None:
        """Grow the basis to ``steps`` vectors (fewer when the space is exhausted)."""
        from .operators import spmm

        tiny = np.finfo(np.float64).eps
        if steps > self._basis.shape[0]:  # room for the new vectors (capacity doubles)
            grown = np.empty((min(max(steps, 2 * self._basis.shape[0]), self.max_steps),) + self.Z.shape, dtype=self._dtype)
            grown[: self.steps] = self._basis[: self.steps]
            self._basis = grown
        while self.steps < steps and not self.exhausted:
            q = self._q
            self._basis[self.steps] = q
            z = spmm(self._S, q)
            a = np.einsum("ij,ij->j", q, z)
            z -= a * q
            z -= self._b_prev * self._q_prev
            b = np.sqrt(np.einsum("ij,ij->j", z, z))
            b = np.where(b > 64.0 * tiny * np.maximum(np.abs(a) + self._b_prev + b, tiny), b, 0.0)  # breakdown
            self._alpha.append(a)
            self._beta.append(b)
            self._q_prev, self._q, self._b_prev = q, z / np.where(b > 0, b, 1.0) * (b > 0), b
            self.exhausted = not np.any(b > 0)

    def _coefficients(self, t: float, k: int) -> np.ndarray:
        """``||w|| f_t(T_k) e_1`` per column, (k, m)."""
        from scipy.linalg import eigh_tridiagonal

        alpha, beta = np.array(self._alpha[:k]), np.array(self._beta[:k])
        out = np.zeros((k, alpha.shape[1]))
        for c in np.flatnonzero(self._beta0 > 0):
            if k > 1:
                theta, U = eigh_tridiagonal(alpha[:, c], beta[: k - 1, c])
            else:
                theta, U = alpha[:, c], np.ones((1, 1))
            f = (1.0 + t * np.maximum(theta, 0.0)) ** (-float(HEAT_STEPS))  # S is positive semi-definite: rounding only
            out[:, c] = self._beta0[c] * (U @ (f * U[0]))
        return out

    def __call__(self, length: float) -> np.ndarray:
        """``HeatFilter(V, F, length, geometry)(Z)`` to relative accuracy ``tol``, shape (n, m)."""
        length = float(length)
        if not (np.isfinite(length) and length >= 0):
            raise ValueError(f"HeatKrylov: parameter 'length' = {length!r} is out of range: a finite length >= 0")
        h = self.geometry[0]
        t = (length * h) ** 2 / (8.0 * HEAT_STEPS)
        self._extend(min(max(self.steps, 2 * HEAT_KRYLOV_CHECK), self.max_steps))
        while True:
            k = self.steps
            coef = self._coefficients(t, k)
            if self.exhausted:
                break
            if k > HEAT_KRYLOV_CHECK:
                j = k - HEAT_KRYLOV_CHECK
                before = self._coefficients(t, j)
                change = np.sqrt(np.sum((coef[:j] - before) ** 2, axis=0) + np.sum(coef[j:] ** 2, axis=0))
                size = np.sqrt(np.sum(coef**2, axis=0))
                if np.all(change <= self.tol * np.where(size > 0, size, 1.0)):
                    break
            if k >= self.max_steps:  # a spectrum too wide for the budget: CG per length
                self.fallbacks += 1
                return HeatFilter(self.V, self.F, length, self.geometry)(self.Z, tol=self.tol)
            self._extend(min(k + HEAT_KRYLOV_CHECK, self.max_steps))
        Y = np.zeros(self.Z.shape)
        for j0 in range(0, k, HEAT_KRYLOV_CHUNK):  # a chunk of the basis at a time in float64
            j1 = min(j0 + HEAT_KRYLOV_CHUNK, k)
            Y += np.einsum("km,knm->nm", coef[j0:j1], self._basis[j0:j1].astype(np.float64, copy=False))
        Y *= self._inv[:, None]
        return Y


def add_scanner_noise(
    mesh: Any,
    sigma: float,
    *,
    correlation_length: float = 0.0,
    direction: str | Sequence[float] | np.ndarray = "normals",
    depth_sigma: float | None = None,
    outlier_fraction: float = 0.0,
    outlier_scale: float = 10.0,
    seed: int | np.random.Generator | None = None,
) -> Any:
    """Displace the vertices as a range scanner's noise does: along the view, correlated, depth dependent, outliers.

    Every vertex *i* moves along a unit direction :math:`d_i` (the view direction, or its
    normal) by

    .. math:: x_i = x^0_i + \\big(\\sigma_i z_i + o_i\\big)\\, d_i

    - :math:`z` is white noise filtered by the mesh heat kernel
      (:func:`heat_filtered_noise` over :func:`diffusion_length` of ``correlation_length``)
      and divided by its root mean square, so
      :math:`\\sqrt{\\overline{z^2}} = 1` exactly; its **correlation length** is
      ``correlation_length`` mean edge lengths: the distance at which the correlation of
      :math:`z` between two vertices falls to :math:`1/e` (see :func:`correlation_length`,
      which measures it). 0 gives independent noise, as :func:`add_normal_noise`.
    - :math:`\\sigma_i` is ``sigma``, or with ``depth_sigma`` it grows linearly with the
      depth :math:`t_i = x_i \\cdot d` along the view direction, from ``sigma`` at the
      nearest vertex to ``depth_sigma`` at the farthest.
    - :math:`o_i` is 0 except on ``round(outlier_fraction * n)`` vertices drawn without
      replacement, where it is :math:`\\pm u\\,` ``outlier_scale`` :math:`\\sigma_i` with a
      random sign and :math:`u` uniform in [0.5, 1]: flying pixels, at least
      ``outlier_scale / 2`` local sigmas off.

    Vertices on no edge, and with ``direction="normals"`` vertices whose normal is zero,
    do not move. Near an open boundary the filtered noise is a little stronger (fewer
    neighbours average it). Returns the same mesh type as the input (a MeshSet is changed
    in place).

    Parameters
    ----------
    mesh : (V, F) tuple, pymeshlab.MeshSet or Mesh, or open3d.geometry.TriangleMesh
    sigma : float, >= 0
        Noise standard deviation in mesh units (at the nearest depth with ``depth_sigma``).
    correlation_length : float, >= 0
        In mean edge lengths. Structured light and time-of-flight scans are typically 1 to 4.
    direction : 'normals' or array-like, shape (3,)
        The scanner's viewing direction (from the scanner towards the scene; orthographic,
        one direction for all vertices), or ``'normals'`` for the vertex normals.
    depth_sigma : float, optional
        Sigma at the farthest vertex along ``direction`` (needs a direction vector).
    outlier_fraction : float in [0, 1]
    outlier_scale : float, > 0
        Largest outlier offset in local sigmas.
    seed : int or numpy.random.Generator, optional
        Same seed, same noise.

    Examples
    --------
    >>> from meshdenoise.shapes import grid
    >>> V, F = grid(30, 30)
    >>> Vn, _ = add_scanner_noise((V, F), 0.01, correlation_length=2, direction=(0, 0, -1), seed=0)
    >>> bool(np.allclose(Vn[:, :2], V[:, :2])), round(float(np.sqrt(np.mean((Vn - V)[:, 2] ** 2))), 6)
    (True, 0.01)
    """
    sigma = _number("sigma", sigma)
    ell = _number("correlation_length", correlation_length, high=1e6)
    fraction = _number("outlier_fraction", outlier_fraction, high=1.0)
    scale = _number("outlier_scale", outlier_scale, low=np.nextafter(0.0, 1.0))
    data = read_mesh(mesh)
    V, F = data.V, data.F
    n = V.shape[0]
    if isinstance(direction, str):
        if direction != "normals":
            raise ValueError(f"add_scanner_noise: direction must be 'normals' or a vector (3,), got {direction!r}")
        D = vertex_normals(V, F)
        view = None
    else:
        try:
            view = np.asarray(direction, dtype=np.float64)
        except (TypeError, ValueError):
            raise TypeError(f"add_scanner_noise: direction must be 'normals' or a vector (3,), got {direction!r}") from None
        norm = float(np.linalg.norm(view)) if view.shape == (3,) else 0.0
        if view.shape != (3,) or not np.isfinite(norm) or norm == 0:
            raise ValueError(f"add_scanner_noise: direction must be 'normals' or a non-zero finite vector (3,), "
                             f"got {direction!r}")
        view = view / norm
        D = np.broadcast_to(view, V.shape)
    if depth_sigma is not None:
        depth_sigma = _number("depth_sigma", depth_sigma)
        if view is None:
            raise ValueError("add_scanner_noise: depth_sigma needs a view direction vector (direction=(x, y, z)): "
                             "depth is measured along it")
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    moving = ~get_operators(F, n).isolated
    z = heat_filtered_noise(V, F, diffusion_length(ell), rng)[:, 0]
    z[~moving] = 0.0
    rms = float(np.sqrt(np.mean(z[moving] ** 2))) if moving.any() else 0.0
    if rms > 0:
        z /= rms
    if depth_sigma is None:
        sig = np.full(n, sigma)
    else:
        depth = V @ view
        lo, hi = (float(depth[moving].min()), float(depth[moving].max())) if moving.any() else (0.0, 0.0)
        t = (depth - lo) / (hi - lo) if hi > lo else np.zeros(n)
        sig = sigma + (depth_sigma - sigma) * t
    offset = sig * z
    count = int(round(fraction * int(moving.sum())))
    if count:
        idx = rng.choice(np.flatnonzero(moving), size=count, replace=False)
        sign = rng.choice(np.array([-1.0, 1.0]), size=count)
        offset[idx] += sign * rng.uniform(0.5, 1.0, size=count) * scale * sig[idx]
    return data.write(V + offset[:, None] * D)


# --- measuring a correlation length ---------------------------------------------------------------
def autocorrelation(
    values: np.ndarray,
    mesh: Any,
    *,
    max_distance: float = 12.0,
    bin_width: float = 0.25,
    samples: int = 1000,
    seed: int | np.random.Generator | None = 0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Empirical autocorrelation of a per-vertex field over distance on the surface, in mean edge lengths.

    For a sample of ``samples`` vertices *s* and every vertex *j* within
    :math:`K = \\lceil 2\\, \\mathrm{max\\_distance} \\rceil` edges of *s* (BFS rings, as
    sparse matrix products), the pair's distance :math:`r_{sj} = \\|x_s - x_j\\| / h`
    (:math:`h` the mean edge length; pairs are taken from graph neighbourhoods, so across a
    thin part the other side is not counted) falls in a bin of width ``bin_width``. Per bin

    .. math:: \\rho(r) = \\frac{\\sum_{(s, j) \\in \\text{bin}} \\langle u_s, u_j\\rangle}
                              {\\sqrt{\\sum_{(s, j) \\in \\text{bin}} \\|u_s\\|^2 \\sum_{(s, j) \\in \\text{bin}} \\|u_j\\|^2}},
              \\qquad u_i = v_i - \\bar v

    (normalised by the bin's own sums rather than the global variance: the sampled centres'
    variance then cancels, which halves the scatter of the estimate).

    Parameters
    ----------
    values : ndarray, shape (n,) or (n, k)
        One value (or vector) per vertex, e.g. a displacement along the normal or a
        residual; a mean is removed per column.
    mesh : (V, F) tuple or any mesh type of :func:`meshdenoise.adapters.read_mesh`
        Gives the neighbourhoods and the distances.
    max_distance : float
        Largest distance looked at, in mean edge lengths.
    bin_width : float
        In mean edge lengths.
    samples : int
        Centre vertices (all of them when the mesh has fewer).
    seed : int or Generator
        Which centre vertices; the default 0 makes the result repeatable.

    Returns
    -------
    distance : ndarray, shape (b,)
        Mean pair distance of each non-empty bin (``0`` first: :math:`\\rho(0) = 1`).
    rho : ndarray, shape (b,)
    pairs : ndarray, shape (b,)
        Pairs per bin.
    """
    data = read_mesh(mesh)
    V, F = data.V, data.F
    n = V.shape[0]
    vals = np.asarray(values, dtype=np.float64)
    if vals.ndim == 1:
        vals = vals[:, None]
    if vals.ndim != 2 or vals.shape[0] != n:
        raise ValueError(f"correlation_length: values must have shape ({n},) or ({n}, k), one per vertex; "
                         f"got {np.shape(values)}")
    if not np.isfinite(vals).all():
        raise ValueError("correlation_length: values must be finite")
    max_distance = _number("max_distance", max_distance, low=bin_width, high=1e4, what="correlation_length")
    bin_width = _number("bin_width", bin_width, low=1e-3, high=max_distance, what="correlation_length")
    if isinstance(samples, (bool, np.bool_)) or not isinstance(samples, (int, np.integer)) or samples < 1:
        raise ValueError(f"correlation_length: samples must be a positive integer, got {samples!r}")
    ops = get_operators(F, n)
    h = mean_edge_length(V, F)
    vals = vals - vals.mean(axis=0)
    var = float(np.mean(np.sum(vals**2, axis=1)))
    if var == 0:
        raise ValueError("correlation_length: values are constant, so they have no correlation")
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    candidates = np.flatnonzero(~ops.isolated)
    centres = rng.choice(candidates, size=min(samples, candidates.size), replace=False)
    k = centres.size
    step = sp.csr_matrix(ops.W + sp.identity(n, format="csr"))
    reach = sp.csr_matrix((np.ones(k), (np.arange(k), centres)), shape=(k, n))
    for _ in range(int(np.ceil(2 * max_distance))):  # a vertex r edge lengths away is rarely more than 2r edges away
        grown = reach @ step
        grown.data[:] = 1.0
        if grown.nnz == reach.nnz:
            break
        reach = grown
    pairs = reach.tocoo()
    s, j = centres[pairs.row], pairs.col
    r = np.linalg.norm(V[s] - V[j], axis=1) / h
    keep = (r <= max_distance) & (s != j)
    r, s, j = r[keep], s[keep], j[keep]
    prod = np.einsum("ij,ij->i", vals[s], vals[j])
    b = np.floor(r / bin_width).astype(np.int64)
    counts = np.bincount(b)
    used = counts > 0
    dist = np.bincount(b, weights=r)[used] / counts[used]
    square = np.sum(vals**2, axis=1)
    norm = np.sqrt(np.bincount(b, weights=square[s]) * np.bincount(b, weights=square[j]))[used]
    rho = np.bincount(b, weights=prod)[used] / np.where(norm > 0, norm, 1.0)
    return np.concatenate([[0.0], dist]), np.concatenate([[1.0], rho]), np.concatenate([[n], counts[used]])


QUICK_DISTANCE = 4.0  # correlation_length's first look, in mean edge lengths


def correlation_length(
    values: np.ndarray,
    mesh: Any,
    *,
    max_distance: float = 12.0,
    bin_width: float = 0.25,
    samples: int = 1000,
    min_pairs: int = 30,
    seed: int | np.random.Generator | None = 0,
) -> float:
    """The distance, in mean edge lengths, at which a field's autocorrelation on the mesh falls to 1/e.

    **Definition.** With :math:`\\rho(r)` the autocorrelation of the field between two
    vertices at distance :math:`r` (in mean edge lengths, measured between vertices of one
    graph neighbourhood; see :func:`autocorrelation`), the correlation length is the
    smallest :math:`\\ell` with :math:`\\rho(\\ell) = 1/e`. For noise made by
    :func:`add_scanner_noise` with ``correlation_length=l``, :math:`\\rho(r) \\approx
    \\exp(-(r/l)^2)`, so this returns about ``l``.

    **Estimate.** :math:`\\rho` is measured in bins (bins with fewer than ``min_pairs``
    pairs are dropped); between the last bin above :math:`1/e` and the first below it,
    :math:`\\ln \\rho` is interpolated linearly in :math:`r^2` (exact for a Gaussian
    correlation), starting from :math:`\\rho(0) = 1`. When already the nearest bin (about
    one edge length) is not significantly above zero (:math:`\\rho < 3/\\sqrt{\\text{pairs}}`,
    three standard errors of independent noise), the field has no correlation this mesh
    can resolve and the result is ``0.0``. When :math:`\\rho` stays above :math:`1/e` up to
    ``max_distance``, the result is ``inf`` with a ``UserWarning``.

    Parameters
    ----------
    values : ndarray, shape (n,) or (n, k)
        One value or vector per vertex (e.g. displacements or residuals along the normals).
    mesh : (V, F) tuple or any mesh type
    max_distance, bin_width, samples, seed
        See :func:`autocorrelation`.
    min_pairs : int
        Bins with fewer pairs are too noisy to use.

    Returns
    -------
    float
        In mean edge lengths (multiply by :func:`mean_edge_length` for mesh units).

    Examples
    --------
    >>> from meshdenoise.shapes import grid
    >>> V, F = grid(60, 60)
    >>> z = np.random.default_rng(0).standard_normal(len(V))
    >>> correlation_length(z, (V, F))
    0.0
    >>> Vn, _ = add_scanner_noise((V, F), 1.0, correlation_length=3, direction=(0, 0, 1), seed=0)
    >>> 2.5 < correlation_length(Vn[:, 2], (V, F)) < 3.5
    True
    """
    if isinstance(seed, np.random.Generator):
        seed = int(seed.integers(2**62))  # the same centres in both passes
    target = np.exp(-1.0)
    # a short look first (8 BFS rings instead of 24): most fields cross 1/e within 4 edge lengths
    for reach in ([QUICK_DISTANCE] if max_distance > QUICK_DISTANCE else []) + [max_distance]:
        dist, rho, pairs = autocorrelation(values, mesh, max_distance=reach, bin_width=bin_width,
                                           samples=samples, seed=seed)
        ok = pairs >= min_pairs
        dist, rho, pairs = dist[ok], rho[ok], pairs[ok]
        if dist.size < 2 or rho[1] < 3.0 / np.sqrt(pairs[1]):
            return 0.0
        below = np.flatnonzero(rho < target)
        if below.size:
            break
    if below.size == 0:
        warnings.warn(
            f"correlation_length: the autocorrelation stays above 1/e up to {max_distance:g} mean edge lengths; "
            "returning inf (raise max_distance to measure longer correlations)", UserWarning, stacklevel=2)
        return float("inf")
    b = int(below[0])
    a = b - 1
    la = np.log(rho[a])
    if rho[b] <= 0:  # no logarithm: interpolate rho itself
        r = dist[a] + (rho[a] - target) / (rho[a] - rho[b]) * (dist[b] - dist[a])
        return float(r)
    lb = np.log(rho[b])
    r2 = dist[a] ** 2 + (-1.0 - la) / (lb - la) * (dist[b] ** 2 - dist[a] ** 2)
    return float(np.sqrt(r2))
