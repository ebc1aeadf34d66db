"""Surface detail or correlated noise? The band spectrum of a mesh, fitted with a term for the surface itself.

Generic machinery: nothing here knows a filter.

**Why.** :func:`~meshdenoise.tuning.covariance.estimate_noise_model` fits the energies of
band-pass residuals :math:`B_s X = (I - P)^2 P^s X` (:math:`P = D^{-1} W`) in the fine bands
:math:`s = 0, 1, 2, 4` with noise alone. A clean mesh has energy in these bands too (its
own detail, a few edge lengths wide), and its decay over four fine bands is matched by noise
of a correlation length near 3 edge lengths: clean meshes read 0.24 to 0.6 mean edge lengths of
correlated noise (docs/noise-vs-detail.md).

**Model.** With more bands, :data:`BANDS` = 0, 1, 2, 4, ..., 64, the two differ in shape. Let
:math:`o_s` be the median square of the normal component of :math:`B_s X` (normals of a
smoothed mesh) and :math:`p_s(\\ell)` the same statistic of unit-variance probes of the noise
model (heat-filtered white noise along the normals, :class:`meshdenoise.noise.HeatFilter`). The
surface's own band energy is taken as a power law in :math:`s + 1`,

.. math:: o_s \\approx A\\, (s + 1)^{-\\beta} + \\rho^2 p_s(\\ell), \\qquad A, \\rho^2 \\ge 0,

fitted in relative error, :math:`\\min \\sum_s \\big((A (s+1)^{-\\beta} + \\rho^2 p_s(\\ell)) / o_s - 1\\big)^2`
(:math:`A \\ge 0` in closed form for every :math:`\\rho^2`, :math:`\\beta` in :data:`BETA_GRID`, 1 to 3,
and :math:`\\ell` in :data:`ELL_FINE`, probe spectra computed on :data:`ELL_GRID` and log-interpolated;
the best level is refined between its grid neighbours). Why a power law: the band energy of a smooth surface
sampled finely falls slowly and steadily with the scale (measured: 0.5 to 0.9 decades per octave
of :math:`s` on every clean mesh we have, over all eight bands), while heat-filtered noise of
correlation length :math:`\\ell \\le 5` falls about as :math:`(\\tau + s)^{-5}`, over a decade
per octave past :math:`s \\approx \\ell^2`: its energy is a bump over the fine bands, which the
coarse bands (where the surface alone is left) tell from the surface's continuation.

**Verdict.** The profile of the misfit over :math:`\\rho` (the best misfit with :math:`\\rho`
held) gives the range of noise levels the bands allow: :math:`[\\rho_{lo}, \\rho_{hi}]`, the
levels whose misfit is within :data:`TOLERANCE` (relative) plus :data:`TOLERANCE_ABS` of the
best. The verdict (:class:`DetailVerdict`) is

- ``"noise"``: the lower end :math:`\\rho_{lo}` is at least :data:`NOISE_SHARE` of the fine-band
  fit's level with noise alone (:math:`\\rho_{band}`): the surface's continuation cannot explain
  the fine bands' energy;
- ``"detail"``: the upper end :math:`\\rho_{hi}` is below :data:`NOISE_SHARE` of it: the surface
  explains them, whatever the noise;
- ``"ambiguous"``: both are allowed.

The verdict is about the fine bands' *correlated* reading: a "detail" mesh may still carry
independent noise, which the model then holds (its level is :func:`estimate_noise`'s).

The model returned (:attr:`DetailVerdict.model`) is the best joint fit's level and correlation
length, except that a correlation length below :data:`ELL_MIN` is read as independent noise
with :func:`~meshdenoise.tuning.noise_level.estimate_noise`'s level (as
:func:`~meshdenoise.tuning.covariance.estimate_noise_model` does); with ``conservative=True``
(default) an ambiguous verdict takes :math:`\\rho_{lo}` and its correlation length: a mesh is not
smoothed on evidence the data does not hold. Measurements, limits and the cases it gets wrong:
docs/noise-vs-detail.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..adapters import read_mesh
from ..geometry import vertex_normals  # the compiled kernel from 65,536 vertices (noise_kernels), bit for bit
from ..noise import HeatKrylov, diffusion_length, heat_geometry
from ..operators import get_operators, spmm
from .covariance import NoiseModel
from .noise_level import estimate_noise_and_smooth, mean_edge_length

__all__ = ["DetailVerdict", "separate_detail", "band_spectrum", "probe_spectra", "fit_spectrum", "misfit_profile",
           "interpolate_spectra", "correlation_test", "region_probe_spectra", "BANDS", "ELL_GRID", "ELL_FINE", "BETA_GRID",
           "CORRELATION_SAMPLE"]

BANDS = (0, 1, 2, 4, 8, 16, 32, 64)  # s of (I - P)^2 P^s: the fine bands and the coarse ones the surface dominates
FINE = (0, 1, 2, 4)  # the fine bands (estimate_noise_model's)
ELL_GRID = (0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0, 5.0)  # correlation lengths probed (edge lengths) ...
ELL_FINE = tuple(float(x) for x in np.round(np.arange(0.0, 5.0001, 0.1), 2))  # ... and fitted (log p_s interpolated)
HEAT_TOL = 1e-5  # relative tolerance of the probes' heat solves (a statistic of them is used, not the fields)
# exponents of the surface term: clean meshes measured 1.85 to 2.65 (elephant, both bunnies, Bunny0.2, Block0.4, face000);
# a steeper "surface" mimics noise (Bunny0.2 with noise of 1 h at l = 2 fitted beta 3.6 and read 0.16 h)
BETA_GRID = tuple(float(b) for b in np.round(np.arange(1.0, 3.0001, 0.05), 2))
RHO_STEPS = 121  # levels of the misfit profile, log-spaced over [RHO_SPAN_LOW, RHO_SPAN_HIGH] x rho_band
RHO_SPAN_LOW, RHO_SPAN_HIGH = 1e-3, 4.0
TOLERANCE = 0.25  # a level is allowed while its misfit is within this share of the best ...
TOLERANCE_ABS = 0.02  # ... plus this (a near-perfect fit must not make the range a point)
NOISE_SHARE = 0.5  # "noise" when even the lowest allowed level is this share of the noise-only fine-band fit
ELL_MIN = 0.75  # shorter correlation lengths are read as independent noise (estimate_noise's level)
# the correlation test: the best misfit with independent noise (l < ELL_MIN) is at least this many times ...
CORRELATION_RATIO = 1.4
CORRELATION_GAIN = 0.1  # ... and this much more than the best fit's (l >= ELL_MIN): calibrated, docs/noise-vs-detail.md
CORRELATION_PATCHES = 100  # ... and the mesh holds this many correlation areas pi l^2 (estimate_noise_model's MIN_PATCHES)
PROBES = 4  # probes per correlation length: a median over n * PROBES values
# the correlation test's call (meshdenoise.default.default_noise, where the fine bands read independent noise): its
# probes read on a sampled region above this many vertices (``sample=``). On every cell of
# benchmarks/noise_model_grid.py, the peers/quality rows and the correlated table's rows the same decisions as on
# the noise model's FIT_SAMPLE (30,000): 20 of 20 asked cells the same test answer, verdict and model taken or kept,
# levels taken within 3.3 %; 10,000 moved a level by 16 % (benchmarks/results/noise-model-test-sample.md)
CORRELATION_SAMPLE = 15_000
MIN_VERTICES = 200  # fewer usable vertices than this: too few for eight bands


@dataclass
class DetailVerdict:
    """What the band spectrum says about a mesh: noise, surface detail, or both possible.

    Attributes
    ----------
    verdict : str
        ``"noise"``, ``"detail"`` or ``"ambiguous"`` (module docstring).
    model : NoiseModel
        The noise model to use (module docstring).
    rho_band : float
        The level read from the fine bands :data:`FINE` with noise alone (mesh units), at
        ``ell_band``: what a fit without the surface term reads.
    ell_band : float
    rho_joint : float
        The best joint fit's level (mesh units) and correlation length.
    ell_joint : float
    beta : float
        The best joint fit's exponent of the surface term.
    rho_range : tuple of float
        :math:`(\\rho_{lo}, \\rho_{hi})`, the levels the bands allow (mesh units).
    ell_low : float
        The correlation length at :math:`\\rho_{lo}`.
    rho_white : float
        :func:`~meshdenoise.tuning.noise_level.estimate_noise`'s level (mesh units).
    edge_length : float
        The mean edge length (mesh units).
    reason : str
        One line saying why.
    spectrum : ndarray, shape (len(BANDS),)
        :math:`o_s` (mesh units squared).
    misfit : float
        The best joint fit's relative misfit (NaN when not fitted).
    misfit_white : float
        The best fit's with the noise read as independent (correlation lengths under
        :data:`ELL_MIN`): the null of the correlation test (NaN when not fitted).
    correlated : bool
        The correlation test (:func:`correlation_test`): the fit explains the spectrum
        significantly better with noise correlated over at least :data:`ELL_MIN` than with
        independent noise.
    """

    verdict: str
    model: NoiseModel
    rho_band: float
    ell_band: float
    rho_joint: float
    ell_joint: float
    beta: float
    rho_range: tuple[float, float]
    ell_low: float
    rho_white: float
    edge_length: float
    reason: str
    spectrum: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))
    misfit: float = float("nan")
    misfit_white: float = float("nan")
    correlated: bool = False

    def as_dict(self) -> dict:
        """Plain values (JSON-ready), levels also in mean edge lengths."""
        h = self.edge_length if self.edge_length > 0 else float("nan")
        return {"verdict": self.verdict, "rho": self.model.rho, "correlation_length": self.model.correlation_length,
                "rho_band": self.rho_band, "ell_band": self.ell_band, "rho_joint": self.rho_joint,
                "ell_joint": self.ell_joint, "beta": self.beta, "rho_low": self.rho_range[0],
                "rho_high": self.rho_range[1], "ell_low": self.ell_low, "rho_white": self.rho_white,
                "edge_length": self.edge_length, "rho_in_edges": self.model.rho / h, "misfit": self.misfit,
                "misfit_white": self.misfit_white, "correlated": self.correlated, "reason": self.reason}


def _band_stats(P: Any, X: np.ndarray, N: np.ndarray, ok: np.ndarray, bands: tuple[int, ...]) -> np.ndarray:
    """Median square of :math:`\\langle (B_s X)_i, N_i\\rangle` over usable vertices and all columns pooled, per band.

    ``X`` (n, 3k): k fields of 3 coordinates; returns (len(bands),).
    """
    k = X.shape[1] // 3
    out = np.empty(len(bands))
    Y = np.array(X, dtype=np.float64)
    done = 0
    for j, s in enumerate(bands):
        while done < s:
            Y = spmm(P, Y)
            done += 1
        A = Y - spmm(P, Y)
        R = A - spmm(P, A)
        r = np.einsum("ikj,ij->ik", R.reshape(R.shape[0], k, 3), N, optimize=True)[ok]
        out[j] = np.median(r * r)
    return out


def band_spectrum(V: np.ndarray, F: np.ndarray, N: np.ndarray, bands: tuple[int, ...] = BANDS,
                  ok: np.ndarray | None = None) -> np.ndarray:
    """:math:`o_s`: the median square of the normal component of :math:`(I - P)^2 P^s V`, per band.

    Parameters
    ----------
    V : ndarray, shape (n, 3)
    F : ndarray, shape (m, 3)
    N : ndarray, shape (n, 3)
        Unit normals (of a smoothed mesh).
    bands : tuple of int, increasing
    ok : ndarray of bool, shape (n,), optional
        The vertices counted (default: every vertex on an edge with a non-zero normal).

    Returns
    -------
    ndarray, shape (len(bands),)
    """
    ops = get_operators(F, V.shape[0])
    if ok is None:
        ok = ~ops.isolated & (np.linalg.norm(N, axis=1) > 0)
    return _band_stats(ops.P, V, N, ok, tuple(bands))


def probe_spectra(smooth: np.ndarray, F: np.ndarray, N: np.ndarray, ells: tuple[float, ...] = ELL_GRID,
                  bands: tuple[int, ...] = BANDS, ok: np.ndarray | None = None, probes: int = PROBES,
                  seed: int = 0) -> np.ndarray:
    """:math:`p_s(\\ell)`: :func:`band_spectrum`'s statistic of unit-variance noise of correlation length :math:`\\ell` along ``N``.

    The probes are ``probes`` white fields heat-filtered as :class:`meshdenoise.noise.HeatFilter`
    does (:func:`meshdenoise.noise.diffusion_length` of :math:`\\ell`; all lengths from one Krylov
    space, :class:`meshdenoise.noise.HeatKrylov`, to :data:`HEAT_TOL`) on ``smooth``, rescaled to
    mean square 1 (the noise model's :math:`\\mathrm{tr}\\,\\Sigma = n`); the median is over
    the usable vertices of all probes.

    Returns
    -------
    ndarray, shape (len(ells), len(bands))
    """
    from . import covariance as cov

    n = smooth.shape[0]
    ops = get_operators(F, n)
    if ok is None:
        ok = ~ops.isolated & (np.linalg.norm(N, axis=1) > 0)
    xi = np.random.default_rng(seed).standard_normal((n, probes))
    # every length from one growing Krylov space (HeatKrylov; a HeatFilter per length ran 8 CG solves each), the
    # bands of four lengths at a time from one chain of powers of P (cov._spectrum_medians): the same statistic
    family = HeatKrylov(smooth, F, xi, geometry=heat_geometry(smooth, F), tol=HEAT_TOL)
    Zs = []
    for ell in ells:
        Z = xi if ell == 0 else family(diffusion_length(ell))
        Zs.append(Z * math.sqrt(Z.size / float(np.sum(Z * Z))))
    return cov._spectrum_medians(ops, N, Zs, ok, None, tuple(bands))


def region_probe_spectra(smooth: np.ndarray, F: np.ndarray, N: np.ndarray, ok: np.ndarray, sample: int,
                         ells: tuple[float, ...] = ELL_GRID, bands: tuple[int, ...] = BANDS,
                         seed: int = 0) -> np.ndarray | None:
    """:func:`probe_spectra` read on a sampled region of about ``sample`` vertices, as the noise model reads its own.

    The region, the probes and their weights are
    :func:`~meshdenoise.tuning.covariance.estimate_noise_model`'s with ``sample`` (a
    :class:`~meshdenoise.tuning.region.SampledRegion` of ``FIT_PATCHES`` balls, vertices within
    ``FIT_MARGIN`` rings of a cut left out, ``FIT_SAMPLE_PROBES`` probes coloured on the region
    to ``FIT_TOL``, rescaled to the whole mesh's mean square by ring distance to the mesh's own
    border, medians weighted by that distance so that each counts as in the whole mesh): the
    cost no longer grows with the mesh. None when the mesh has at most ``sample`` vertices (read
    it whole).

    Returns
    -------
    ndarray, shape (len(ells), len(bands)), or None
    """
    from . import covariance as cov
    from .region import SampledRegion

    n = smooth.shape[0]
    ops = get_operators(F, n)
    region = SampledRegion(F, ops, int(sample), cov.FIT_PATCHES, cov.FIT_MARGIN, seed)
    if region.whole:
        return None
    Vr, Fr = smooth[region.vertices], region.F
    opsr = cov.Operators(Fr, region.vertices.size)
    Nr = N[region.vertices]
    inner = region.inner & ~opsr.isolated
    okr = ok[region.vertices] & inner
    strata = cov._border_strata(ops)
    share_all = np.bincount(strata[~ops.isolated], minlength=cov.FIT_BORDER_RINGS + 2) / ops.n
    share_ok = np.bincount(strata[ok], minlength=cov.FIT_BORDER_RINGS + 2) / max(int(ok.sum()), 1)
    sr = strata[region.vertices]
    nearest = cov._nearest_present(np.bincount(sr[okr], minlength=share_ok.size) > 0)
    share_all = np.bincount(nearest, weights=share_all, minlength=share_all.size)
    share_ok = np.bincount(nearest, weights=share_ok, minlength=share_ok.size)
    weights = (share_ok / np.maximum(np.bincount(sr[okr], minlength=share_ok.size), 1))[sr]
    xi = np.random.default_rng(seed).standard_normal((Vr.shape[0], cov.FIT_SAMPLE_PROBES))
    geometry = (cov.noise_mean_edge_length(smooth, F),) + tuple(heat_geometry(Vr, Fr)[1:])
    count = np.maximum(np.bincount(sr[inner], minlength=share_all.size), 1)
    family = HeatKrylov(Vr, Fr, xi, geometry=geometry, tol=cov.FIT_TOL)  # as the noise model colours its own
    Zs = []
    for ell in ells:
        Z = xi if ell == 0 else family(diffusion_length(ell))
        msq = np.bincount(sr[inner], weights=np.mean(Z[inner] ** 2, axis=1), minlength=share_all.size) / count
        Zs.append(Z / math.sqrt(float(np.sum(share_all * msq))))
    return cov._spectrum_medians(opsr, Nr, Zs, okr, weights, tuple(bands))


def interpolate_spectra(p: np.ndarray, ells: tuple[float, ...], fine: tuple[float, ...]) -> np.ndarray:
    """:math:`p_s(\\ell)` on the ``fine`` lengths: :math:`\\log p_s` interpolated linearly in :math:`\\ell` (g, b) -> (f, b)."""
    logp = np.log(np.asarray(p, dtype=np.float64))
    return np.exp(np.stack([np.interp(fine, ells, logp[:, b]) for b in range(logp.shape[1])], axis=1))


def _surface_terms(bands: tuple[int, ...], betas: tuple[float, ...]) -> np.ndarray:
    """(len(betas), len(bands)): :math:`(s + 1)^{-\\beta}`."""
    s = np.asarray(bands, dtype=np.float64) + 1.0
    return s[None, :] ** (-np.asarray(betas)[:, None])


def misfit_profile(o: np.ndarray, p: np.ndarray, rho2: np.ndarray, bands: tuple[int, ...] = BANDS,
                   betas: tuple[float, ...] = BETA_GRID) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The best relative misfit with the noise level held, over the surface term and the correlation length.

    For every :math:`\\rho^2` in ``rho2``, every correlation length (row of ``p``) and every
    :math:`\\beta`, :math:`A \\ge 0` is the least-squares amplitude of the surface term given
    the noise term (closed form, clipped at 0), and the misfit is
    :math:`\\sqrt{\\sum_s ((A (s+1)^{-\\beta} + \\rho^2 p_s) / o_s - 1)^2}`.

    Parameters
    ----------
    o : ndarray, shape (b,)
        Observed band energies, all > 0.
    p : ndarray, shape (g, b)
        Probe band energies per unit :math:`\\rho^2`, one row per correlation length.
    rho2 : ndarray, shape (r,)
        Noise levels squared (mesh units squared), >= 0.

    Returns
    -------
    misfit : ndarray, shape (r,)
        The best misfit per level.
    ell_index : ndarray of int, shape (r,)
        The row of ``p`` attaining it.
    beta_index : ndarray of int, shape (r,)
    """
    o = np.asarray(o, dtype=np.float64)
    f = _surface_terms(bands, betas) / o[None, :]  # (nb, b)
    q = np.asarray(p, dtype=np.float64) / o[None, :]  # (g, b)
    rho2 = np.asarray(rho2, dtype=np.float64)
    target = 1.0 - rho2[:, None, None] * q[None, :, :]  # (r, g, b): what the surface term must supply
    ff = np.sum(f * f, axis=1)  # (nb,)
    A = np.maximum(np.einsum("rgb,kb->rgk", target, f) / ff[None, None, :], 0.0)  # (r, g, nb)
    # misfit^2 = |A f - target|^2 = A^2 ff - 2 A f.target + |target|^2
    ft = np.einsum("rgb,kb->rgk", target, f)
    tt = np.sum(target * target, axis=2)  # (r, g)
    m2 = np.maximum(A * A * ff[None, None, :] - 2.0 * A * ft + tt[:, :, None], 0.0)
    flat = m2.reshape(m2.shape[0], -1)
    best = np.argmin(flat, axis=1)
    g_idx, k_idx = np.unravel_index(best, m2.shape[1:])
    return np.sqrt(flat[np.arange(flat.shape[0]), best]), g_idx, k_idx


def fit_spectrum(o: np.ndarray, p: np.ndarray, ells: tuple[float, ...] = ELL_GRID, bands: tuple[int, ...] = BANDS,
                 betas: tuple[float, ...] = BETA_GRID, rho2_scale: float | None = None) -> dict:
    """Joint fit of the surface power law and the noise term, with the misfit profile over the level.

    Parameters
    ----------
    o : ndarray, shape (b,)
        Observed band energies (all > 0).
    p : ndarray, shape (g, b)
        :func:`probe_spectra` on ``ells``.
    rho2_scale : float, optional
        The centre of the profile's levels (default: the largest :math:`o_s / p_s(\\ell)`).

    Returns
    -------
    dict
        ``rho2`` (the best level squared), ``ell``, ``beta``, ``misfit``, ``rho2_low``,
        ``rho2_high`` (the allowed range), ``ell_low`` (at ``rho2_low``), ``misfit_white`` (the
        best misfit over the correlation lengths under :data:`ELL_MIN`, read as independent noise;
        NaN if ``ells`` has none), and the profile (``levels``, ``profile``).
    """
    o = np.asarray(o, dtype=np.float64)
    p = np.asarray(p, dtype=np.float64)
    scale = float(np.max(o[None, :] / p)) if rho2_scale is None else float(rho2_scale)
    levels = np.concatenate([[0.0], scale * np.logspace(math.log10(RHO_SPAN_LOW ** 2), math.log10(RHO_SPAN_HIGH ** 2),
                                                        RHO_STEPS)])
    prof, g_idx, k_idx = misfit_profile(o, p, levels, bands, betas)
    j = int(np.argmin(prof))
    allowed = prof <= prof[j] * (1.0 + TOLERANCE) + TOLERANCE_ABS
    idx = np.flatnonzero(allowed)
    lo, hi = int(idx[0]), int(idx[-1])
    # the best level refined between its neighbours on the grid
    near = np.linspace(levels[max(j - 1, 0)], levels[min(j + 1, levels.size - 1)], 41)
    fine, fg, fk = misfit_profile(o, p, near, bands, betas)
    b = int(np.argmin(fine))
    rho2, ell, beta, misfit = ((float(near[b]), float(ells[fg[b]]), float(betas[fk[b]]), float(fine[b]))
                               if fine[b] < prof[j] else
                               (float(levels[j]), float(ells[g_idx[j]]), float(betas[k_idx[j]]), float(prof[j])))
    # the same fit with the noise read as independent (correlation lengths under ELL_MIN, which the model returns as
    # independent noise): the null of the correlation test
    short = [g for g, e in enumerate(ells) if e < ELL_MIN]
    if not short:
        white = float("nan")
    elif ell < ELL_MIN:  # the best fit is among them
        white = misfit
    else:  # its best level refined between its neighbours, as the best fit's is (a coarse grid would favour the test)
        wprof = misfit_profile(o, p[short], levels, bands, betas)[0]
        w = int(np.argmin(wprof))
        near = np.linspace(levels[max(w - 1, 0)], levels[min(w + 1, levels.size - 1)], 41)
        white = max(min(float(wprof[w]), float(np.min(misfit_profile(o, p[short], near, bands, betas)[0]))), misfit)
    return {"rho2": rho2, "ell": ell, "beta": beta, "misfit_white": white,
            "misfit": misfit, "rho2_low": min(float(levels[lo]), rho2), "rho2_high": max(float(levels[hi]), rho2),
            "ell_low": float(ells[g_idx[lo]]) if levels[lo] > 0 else 0.0, "levels": levels, "profile": prof}


def correlation_test(misfit: float, misfit_white: float, ell: float, vertices: int) -> bool:
    """Whether correlated noise explains the band spectrum significantly better than independent noise.

    Parameters
    ----------
    misfit : float
        The best joint fit's relative misfit (:func:`fit_spectrum`), at correlation length ``ell``.
    misfit_white : float
        The best with a correlation length under :data:`ELL_MIN` (read as independent noise).
    ell : float
        The best fit's correlation length (edge lengths).
    vertices : int
        Usable vertices of the mesh.

    Returns
    -------
    bool
        ``ell >= ELL_MIN``, ``misfit_white >= CORRELATION_RATIO * misfit``,
        ``misfit_white - misfit >= CORRELATION_GAIN`` and ``vertices >= CORRELATION_PATCHES * pi * ell**2``.
        Calibrated (docs/noise-vs-detail.md): noise of l = 1 read as independent by the fine
        bands gives ratios 1.5 to 16 and gains 0.29 to 0.74 (icosphere(5), pymeshlab's bunny); the
        benchmark's own independent noise on its CAD meshes (Fandisk0.3, Block0.4), whose best fit is
        at 0.8 to 0.9 edge lengths, ratios 1.1 and gains of 0.02 at most.
    """
    if not (math.isfinite(misfit) and math.isfinite(misfit_white)):
        return False
    return bool(ell >= ELL_MIN and misfit_white >= CORRELATION_RATIO * misfit
                and misfit_white - misfit >= CORRELATION_GAIN and vertices >= CORRELATION_PATCHES * math.pi * ell ** 2)


def _fine_band_fit(o: np.ndarray, p: np.ndarray, ells: tuple[float, ...], bands: tuple[int, ...]) -> tuple[float, float]:
    """Noise alone on the fine bands (estimate_noise_model's fit, on the grid): the correlation length whose
    :math:`\\log \\hat\\rho_s` spread least, and the geometric mean level squared there."""
    cols = [bands.index(s) for s in FINE if s in bands]
    logr = 0.5 * (np.log(o[cols])[None, :] - np.log(p[:, cols]))
    j = int(np.argmin(np.var(logr, axis=1)))
    return float(np.exp(2.0 * logr[j].mean())), float(ells[j])


def separate_detail(mesh: Any, *, refine: int = 2, seed: int = 0, conservative: bool = True,
                    smooth: np.ndarray | None = None, rho_white: float | None = None,
                    spectrum: dict | None = None, sample: int | None = None) -> DetailVerdict:
    """Tell the surface's own detail from correlated noise by the band spectrum, and give the noise model to use.

    See the module docstring for the model, the fit and the verdict.

    Parameters
    ----------
    mesh : (V, F) tuple, pymeshlab.MeshSet or Mesh, or open3d.geometry.TriangleMesh
    refine : int, >= 1
        Passed to :func:`~meshdenoise.tuning.noise_level.estimate_noise` (unless ``smooth`` and
        ``rho_white`` are given).
    seed : int
        Seed of the probes.
    conservative : bool
        With an ambiguous verdict, the lowest level the bands allow (default) instead of the best fit's.
    smooth : ndarray, shape (n, 3), optional
        The smoothed mesh whose normals are used, if the caller has it
        (:func:`~meshdenoise.tuning.noise_level.estimate_noise_and_smooth`), with ``rho_white``.
    rho_white : float, optional
        :func:`~meshdenoise.tuning.noise_level.estimate_noise`'s level, if the caller has it.
    spectrum : dict, optional
        The observed and probe spectra already read, with ``smooth`` and ``rho_white``:
        ``info["spectrum"]`` of :func:`~meshdenoise.tuning.covariance.estimate_noise_model` called
        with ``spectrum=(BANDS, ELL_GRID)`` (on a sampled region above its ``sample`` vertices,
        with the probes its own fit coloured). Otherwise both are read here on the whole mesh
        (the probes on a sampled region with ``sample``).
    sample : int, optional
        Without ``spectrum``: above this many vertices the probes' spectra are read on a sampled
        region of about this size (:func:`region_probe_spectra`; the observed spectrum is still the
        whole mesh's). Default: the whole mesh.

    Returns
    -------
    DetailVerdict

    Examples
    --------
    >>> from meshdenoise.shapes import icosphere
    >>> from meshdenoise import add_normal_noise
    >>> V, F = icosphere(4)
    >>> Vn, _ = add_normal_noise((V, F), rho=0.01, seed=0)
    >>> v = separate_detail((Vn, F))
    >>> v.verdict, v.model.correlation_length, round(v.model.rho / 0.01, 1)
    ('noise', 0.0, 1.0)
    """
    if isinstance(refine, (bool, np.bool_)) or not isinstance(refine, (int, np.integer)) or refine < 1:
        raise ValueError(f"separate_detail: parameter 'refine' must be an int >= 1, got {refine!r}")
    if sample is not None and (isinstance(sample, (bool, np.bool_)) or not isinstance(sample, (int, np.integer))
                               or sample < 1):
        raise ValueError(f"separate_detail: parameter 'sample' must be an int >= 1, got {sample!r}")
    data = read_mesh(mesh)
    V, F = data.V, data.F
    ops = get_operators(F, V.shape[0])
    h = mean_edge_length(V, ops) if ops.edges.shape[0] else 0.0
    if smooth is None or rho_white is None:
        rho_white, smooth = estimate_noise_and_smooth(V, F, int(refine))
    rho_white = float(rho_white)

    def plain(reason: str, verdict: str = "detail") -> DetailVerdict:
        return DetailVerdict(verdict, NoiseModel(rho_white), rho_white, 0.0, rho_white, 0.0, float("nan"),
                             (rho_white, rho_white), 0.0, rho_white, h, reason)

    if rho_white == 0:
        return plain("no noise found (estimate_noise reads 0)")
    N = vertex_normals(smooth, F)
    ok = ~ops.isolated & (np.linalg.norm(N, axis=1) > 0)
    if int(ok.sum()) < MIN_VERTICES:
        return plain(f"only {int(ok.sum())} usable vertices (fewer than {MIN_VERTICES}): no band fit, "
                     "independent noise assumed", "ambiguous")
    if spectrum is not None:
        if tuple(spectrum["bands"]) != BANDS or tuple(spectrum["lengths"]) != ELL_GRID:
            raise ValueError(f"separate_detail: parameter 'spectrum' has bands {tuple(spectrum['bands'])} and lengths "
                             f"{tuple(spectrum['lengths'])}; the fit needs bands {BANDS} and lengths {ELL_GRID}")
        o = np.asarray(spectrum["observed"], dtype=np.float64)
    else:
        o = band_spectrum(V, F, N, BANDS, ok)
    if not np.all(o > 0):
        return plain("a band-pass residual is zero (no energy to call noise): no band fit, independent noise assumed")
    if spectrum is not None:
        p = np.asarray(spectrum["probes"], dtype=np.float64)
    else:
        p = None if sample is None else region_probe_spectra(smooth, F, N, ok, sample, ELL_GRID, BANDS, seed)
        if p is None:
            p = probe_spectra(smooth, F, N, ELL_GRID, BANDS, ok, PROBES, seed)
    if not np.all(p > 0):
        return plain("a probe's band-pass residual is zero: no band fit, independent noise assumed", "ambiguous")
    rho2_band, ell_band = _fine_band_fit(o, p, ELL_GRID, BANDS)
    fit = fit_spectrum(o, interpolate_spectra(p, ELL_GRID, ELL_FINE), ELL_FINE, BANDS, BETA_GRID, rho2_scale=rho2_band)
    rho_band, rho_joint = math.sqrt(rho2_band), math.sqrt(fit["rho2"])
    lo, hi = math.sqrt(fit["rho2_low"]), math.sqrt(fit["rho2_high"])
    if lo >= NOISE_SHARE * rho_band:
        verdict = "noise"
    elif hi < NOISE_SHARE * rho_band:
        verdict = "detail"
    else:
        verdict = "ambiguous"
    use_rho, use_ell = (lo, fit["ell_low"]) if verdict == "ambiguous" and conservative else (rho_joint, fit["ell"])
    if use_ell < ELL_MIN or use_rho == 0:
        model = NoiseModel(rho_white)
        what = f"independent noise ({rho_white / h:.3g} edge lengths, estimate_noise's level)"
    else:
        model = NoiseModel(use_rho, use_ell, smooth, F)
        what = f"noise of {use_rho / h:.3g} edge lengths correlated over {use_ell:.3g}"
    said = {"noise": "the surface's own band spectrum, continued from the coarse bands, cannot explain the fine bands",
            "detail": "the surface's own band spectrum, continued from the coarse bands, explains the fine bands",
            "ambiguous": "the bands allow both surface detail and noise"}[verdict]
    reason = (f"{verdict}: the fine bands alone read {rho_band / h:.3g} edge lengths correlated over {ell_band:.3g}; "
              f"{said} (noise from {lo / h:.3g} to {hi / h:.3g} edge lengths allowed, best {rho_joint / h:.3g} over "
              f"{fit['ell']:.3g}) -> {what}")
    return DetailVerdict(verdict, model, rho_band, ell_band, rho_joint, fit["ell"], fit["beta"], (lo, hi),
                         fit["ell_low"], rho_white, h, reason, o, fit["misfit"], fit["misfit_white"],
                         correlation_test(fit["misfit"], fit["misfit_white"], fit["ell"], int(ok.sum())))
