"""The face-normal risk of a linear smoother, estimated from the noisy mesh alone (Stein's identity).

Generic machinery: it knows a linear map applied to blocks of coordinates (``apply(value,
block)``), never a filter. A filter's rule chooses its parameter by the position risk (SURE);
:func:`refine_for_normals` moves that parameter to the least estimated error of the *face
normals*, which is what a rendering shows and what the peers benchmark measures. The two
disagree because the uniform Laplacian also moves vertices along the surface: that drift costs
position error but hardly turns a face, so position SURE stops smoothing 2 to 10 times too
early for the normals (docs/automatic-parameters.md, "Each filter's automatic choice against
its own oracle").
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, NamedTuple, Sequence

import numpy as np

from .. import kernels
from ..geometry import cross_rows, vertex_normals
from .risk import EXACT_TRACE_MAX
from .config import SPECTRAL, SpectralConfig, resolve
from .spectral import Spectral, SpectralFailed, SpectralSearch, StartDual

__all__ = ["NormalJacobian", "NormalChoice", "normal_risk", "dirichlet_sure", "refine_for_normals", "normal_probe_count",
           "NORMAL_PROBES", "NORMAL_ITERATIONS", "NORMAL_SCALES", "NORMAL_WIDE_SCALES", "NORMAL_WIDE_BELOW", "NORMAL_FIRST",
           "NORMAL_LINEAR_MAX"]

# Rademacher vector probes: NORMAL_PROBE_BUDGET / n, from NORMAL_PROBES to NORMAL_MAX_PROBES (the estimate averages
# over the faces, so its spread falls like 1 / sqrt(n P): a constant n P keeps it; 8 probes at 50k vertices chose the
# oracle's weight on the benchmark rows)
NORMAL_PROBES = 8
NORMAL_MAX_PROBES = 64
NORMAL_PROBE_BUDGET = 8 * 50_000
NORMAL_LINEAR_MAX = 1.0  # noise (rho) from this many mean edge lengths of a smoothed mesh: the linearised risk
# does not hold and the candidates are ranked by the Dirichlet energy's SURE (elephant rho = 0.2, 29 edge lengths:
# filtering, heat, sinkhorn, sobolev 1.07, 1.07, 1.03, 1.10 times their normal oracles' error, against 1.21, 1.28,
# 1.15, 1.00; every other benchmark row is below 0.7)
# the first pass linearises at this multiple of position SURE's choice, the middle of NORMAL_SCALES: at SURE's own
# choice a rough mesh's J overstates the turns of further smoothing (filtering on Fandisk0.3 stayed at 1 step, its
# normal oracle 2; from the middle it found 2)
NORMAL_FIRST = 10.0 ** 0.5
NORMAL_MIN_HEIGHT = 0.2  # faces lower than this fraction of the median height are left out of the risk: a scan's
# slivers (face000: 0.17 % of its faces held 98 % of the first-order turn, its risk 3e21 rad^2 and its choice swinging
# between the candidates' ends; cut, the 0.1 % largest terms hold 14 %)
NORMAL_ITERATIONS = 6  # fixed-point passes at most (a bisection over the 14 candidates needed 4 once bracketed)
# the weight's multiples searched, 10^t for t = -0.3 .. 1.0 by tenths: the normal oracles measured were 1 to 10 times
# position SURE's weight (docs/automatic-parameters.md); beyond 10, at a much shrunk mesh, the estimate asked for ever
# more smoothing on the Nefertiti (hence guard_above past here)
NORMAL_SCALES = tuple(float(10.0 ** (t / 10.0)) for t in range(-3, 11))
# ... and on to 10^2 where the noise is below NORMAL_WIDE_BELOW mean edge lengths, where the linearisation holds:
# face000's oracles were 12, 20 and 28 times SURE's weight (sobolev, sobolev_bilaplacian, sobolev_axes), the
# elephant's, at 26 edge lengths of noise, 2 times (and the estimate there asked for the grid's end)
NORMAL_WIDE_SCALES = tuple(float(10.0 ** (t / 10.0)) for t in range(-3, 21))
NORMAL_WIDE_BELOW = 1.0


def normal_probe_count(n: int) -> int:
    """Vector probes of :func:`refine_for_normals` on ``n`` vertices.

    Examples
    --------
    >>> normal_probe_count(2_562), normal_probe_count(35_000), normal_probe_count(1_000_000)
    (64, 12, 8)
    """
    return int(min(NORMAL_MAX_PROBES, max(NORMAL_PROBES, math.ceil(NORMAL_PROBE_BUDGET / max(int(n), 1)))))


class NormalJacobian:
    """The derivative of the unit face normals with respect to the vertex positions, at fixed vertices ``R``.

    For a face :math:`(p_0, p_1, p_2)` with :math:`c = (p_1 - p_0) \\times (p_2 - p_0)` and
    :math:`n = c / \\|c\\|`, a displacement :math:`d` of its vertices turns the normal by

    .. math:: J d = \\frac{(I - n n^T)\\,\\big((d_1 - d_0) \\times (p_2 - p_0) + (p_1 - p_0) \\times (d_2 - d_0)\\big)}{\\|c\\|},

    so that :math:`\\|J d\\|^2` is, to first order, the sum over faces of the squared angles
    (radians) by which ``d`` turns them. Zero-area faces count 0.

    Parameters
    ----------
    R : ndarray, shape (n, 3)
        The vertices where the derivative is taken.
    F : ndarray, shape (m, 3)
    min_height : float
        Faces whose height (twice the area over the longest edge) is below this fraction of
        the median height count 0 (``counted`` says which count): a sliver's first-order turn
        grows like one over its height while the true angle stays below pi.

    Examples
    --------
    >>> import numpy as np
    >>> J = NormalJacobian(np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]))
    >>> np.round(J(np.array([[0.0, 0, 0], [0, 0, 0], [0, 0, 0.01]])), 6)  # lift one corner by 0.01: 0.01 rad
    array([[ 0.  , -0.01,  0.  ]])
    """

    def __init__(self, R: np.ndarray, F: np.ndarray, min_height: float = 0.0):
        P = np.asarray(R, dtype=np.float64)[F]
        self.F = np.ascontiguousarray(F, dtype=np.int64)
        self.e1, self.e2 = np.ascontiguousarray(P[:, 1] - P[:, 0]), np.ascontiguousarray(P[:, 2] - P[:, 0])
        c = cross_rows(self.e1, self.e2)
        area2 = np.linalg.norm(c, axis=1)
        self.counted = area2 > 0
        if min_height > 0 and area2.size:
            e3 = np.ascontiguousarray(P[:, 2] - P[:, 1])
            longest = np.sqrt(np.max([np.einsum("ij,ij->i", e, e) for e in (self.e1, self.e2, e3)], axis=0))
            height = np.divide(area2, longest, out=np.zeros_like(area2), where=longest > 0)
            self.counted &= height > float(min_height) * float(np.median(height))
        self.inv = np.divide(1.0, area2, out=np.zeros_like(area2), where=self.counted)
        self.n = c * self.inv[:, None]

    def __call__(self, D: np.ndarray) -> np.ndarray:
        """:math:`J d` for ``D`` of shape (n, 3): the turn of each unit face normal, shape (m, 3)."""
        out = np.empty((self.F.shape[0], 3))
        kernels.normal_turns(np.ascontiguousarray(D, dtype=np.float64), self.F, self.e1, self.e2, self.n, self.inv, out)
        return out

    def many(self, D: np.ndarray) -> np.ndarray:
        """:math:`J d_k` for ``D`` of shape (n, P, 3), ``P`` displacements at once: shape (m, P, 3)."""
        D = np.ascontiguousarray(D, dtype=np.float64)
        out = np.empty((self.F.shape[0], D.shape[1], 3))
        kernels.normal_turns_many(D, self.F, self.e1, self.e2, self.n, self.inv, out)
        return out

    def adjoint(self, W: np.ndarray, n: int) -> np.ndarray:
        """:math:`J^T w` for ``W`` of shape (m, 3), on ``n`` vertices: shape (n, 3), so that
        :math:`(J d) \\cdot w = d \\cdot (J^T w)` for every ``d``."""
        W = np.asarray(W, dtype=np.float64)
        W = (W - self.n * np.einsum("ij,ij->i", self.n, W)[:, None]) * self.inv[:, None]
        g1, g2 = cross_rows(self.e2, W), cross_rows(W, self.e1)  # (a x e2) . w = a . (e2 x w); (e1 x a) . w = a . (w x e1)
        out = np.zeros((n, 3))
        for corner, g in ((0, -g1 - g2), (1, g1), (2, g2)):
            for axis in range(3):
                out[:, axis] += np.bincount(self.F[:, corner], weights=g[:, axis], minlength=n)
        return out

    def adjoint_many(self, W: np.ndarray, n: int) -> np.ndarray:
        """:meth:`adjoint` of ``P`` turn fields at once: ``W`` (m, P, 3) into shape (n, P, 3), one compiled pass over
        the faces per field (the normals search's duals: 15 to 31 fields a pass, 9 ``bincount`` each before)."""
        W = np.ascontiguousarray(W, dtype=np.float64)
        out = np.zeros((n, W.shape[1], 3))
        kernels.normal_turns_adjoint_many(W, self.F, self.e1, self.e2, self.n, self.inv, out)
        return out


def normal_risk(J: NormalJacobian, X: np.ndarray, Y: np.ndarray, JB: Sequence[np.ndarray], HB: Sequence[np.ndarray],
                rho: float, faces: np.ndarray | None = None) -> float:
    """Stein's estimate of the mean squared turn of the face normals of a linear smoother's result from the clean ones.

    For noise :math:`X = X^0 + \\rho\\, \\varepsilon`, :math:`\\varepsilon = \\mathrm{diag}(N)\\, z`
    along unit directions ``N`` (:math:`z` standard, or coloured like correlated noise), a
    linear smoother ``H`` (the same on each coordinate) and the face normals' derivative ``J``
    at a fixed mesh, with probes :math:`b_p = \\mathrm{diag}(N)\\, z_p` (:math:`\\mathbb E\\, z_p z_p^T`
    the noise's correlation):

    .. math:: G = \\frac1m\\Big(\\|J(HX - X)\\|^2 + \\frac{\\rho^2}{P}\\sum_p \\big(2\\,(J b_p)^T (J H b_p) - \\|J b_p\\|^2\\big)\\Big),

    unbiased for :math:`\\frac1m \\mathbb E\\|J(HX - X^0)\\|^2`, to first order the mean squared
    angle (rad^2) between the result's face normals and the clean ones.

    Parameters
    ----------
    J : NormalJacobian
    X : ndarray, shape (n, 3)
        The noisy vertices.
    Y : ndarray, shape (n, 3)
        :math:`HX`.
    JB : ndarray, shape (m, P, 3), or sequence of ndarray, shape (m, 3)
        :math:`J b_p`.
    HB : ndarray, shape (n, P, 3), or sequence of ndarray, shape (n, 3)
        :math:`H b_p`.
    rho : float
    faces : ndarray of bool, shape (m,), optional
        The faces counted (default all; ``JB`` holds the turns of every face).

    Returns
    -------
    float
    """
    faces = J.counted if faces is None else faces & J.counted
    JB = (JB if isinstance(JB, np.ndarray) else np.stack(list(JB), axis=1))[faces]
    JHB = J.many(HB if isinstance(HB, np.ndarray) else np.stack(list(HB), axis=1))[faces]
    return _normal_risk_sum(J, X, Y, np.einsum("fpc,fpc->p", JB, JHB), np.einsum("fpc,fpc->p", JB, JB), rho, faces)


def _normal_risk_sum(J: NormalJacobian, X: np.ndarray, Y: np.ndarray, cross: np.ndarray, own: np.ndarray, rho: float,
                     faces: np.ndarray) -> float:
    """:func:`normal_risk` from its probe terms: ``cross[p]`` :math:`= (J b_p)^T (J H b_p)`, ``own[p]`` :math:`= \\|J b_p\\|^2`
    over the counted ``faces``."""
    JR = J(Y - X)[faces]
    terms = 2.0 * cross - own
    m = max(int(np.count_nonzero(faces)), 1)
    return (float(np.sum(JR * JR)) + rho**2 * float(np.mean(terms))) / m


@dataclass(frozen=True)
class NormalChoice:
    r"""What :func:`refine_for_normals` chose.

    Attributes
    ----------
    value : float
        The parameter of least estimated normal risk at the last pass.
    risk : float
        Its estimate (mean squared turn, rad^2 per face).
    path : tuple of float
        The value chosen by each fixed-point pass (the first pass linearises at ``first``).
    values, risks : tuple of float
        The last pass's candidates and estimates.
    position_risk : float
        SURE of the chosen value's positions, :math:`\|HX - X\|^2 - n\rho^2 + 2\rho^2\,\mathrm{tr}\,H`
        (the trace from the same probes: :math:`\mathbb E\, b_p^T H b_p = \mathrm{tr}\,H` for
        a smoother acting alike on each coordinate), over the scored vertices.
    noise_energy : float
        :math:`n\rho^2` over the same vertices: the input's expected squared error.
    criterion : str
        ``"normals"``; ``"dirichlet"`` where the noise is too large for the linearised estimate
        (:data:`NORMAL_LINEAR_MAX`) and the candidates were ranked by SURE of the error's Dirichlet
        energy (:func:`dirichlet_sure`): ``risk`` and ``risks`` are then that estimate per scored
        vertex (squared mesh units), ``path`` holds its one choice.
    """

    value: float
    risk: float
    path: tuple
    values: tuple
    risks: tuple
    position_risk: float = math.nan
    noise_energy: float = math.nan
    criterion: str = "normals"

    @property
    def position_gain_db(self) -> float:
        """The estimated SNR gain of the positions over the input (dB; negative: worse than the input)."""
        if not (self.position_risk > 0 and self.noise_energy > 0):
            return math.inf if self.position_risk <= 0 else math.nan
        return 10.0 * math.log10(self.noise_energy / self.position_risk)

    @property
    def rms_degrees(self) -> float:
        """The estimate as an rms angle in degrees (0 when it came out negative; NaN for the Dirichlet ranking)."""
        if self.criterion != "normals":
            return math.nan
        return math.degrees(math.sqrt(max(self.risk, 0.0)))


def dirichlet_sure(L: Any, V: np.ndarray, out: np.ndarray, B: np.ndarray, LB: np.ndarray, rho: float,
                   rows: np.ndarray | None = None) -> float:
    r"""Stein's estimate of the Dirichlet energy of a linear smoother's error,
    :math:`\mathbb E\,(HX - X^0)^T L (HX - X^0)`.

    With noise :math:`X = X^0 + E`, :math:`\mathbb E\, E E^T = \Sigma` (per coordinate), probes
    :math:`b_p` with :math:`\rho^2\, \mathbb E\, b_p b_p^T = \Sigma` and :math:`L = D - W` symmetric:

    .. math:: D = (HX - X)^T L (HX - X) - \frac{\rho^2}{P} \sum_p b_p^T L b_p
              + \frac{2 \rho^2}{P} \sum_p (L b_p)^T (H b_p)

    (:math:`\mathbb E\,(H E - E)^T L (H E - E) = \mathrm{tr}(H^T L H \Sigma) - 2\,\mathrm{tr}(L H \Sigma)
    + \mathrm{tr}(L \Sigma)`, and :math:`\mathrm{tr}(H^T L \Sigma) = \mathrm{tr}(L H \Sigma)` for symmetric
    :math:`L`, :math:`\Sigma`, whether or not ``H`` is). The energy sums the error's squared differences across
    the edges, which turn the faces, with no linearisation at a mesh: what
    :func:`refine_for_normals` ranks by where the noise is too large for :func:`normal_risk`'s first order.

    Parameters
    ----------
    L : scipy.sparse matrix, shape (n, n)
    V : ndarray, shape (n, 3)
        The noisy vertices :math:`X`.
    out : ndarray, shape (n, 3 + 3P)
        :math:`HX` then :math:`H b_p` (probe ``p`` in columns ``3 + 3p .. 5 + 3p``).
    B, LB : ndarray, shape (n, 3P)
        The probes and :math:`L` times them.
    rho : float
    rows : ndarray of bool, shape (n,), optional
        The vertices summed over (default all).

    Examples
    --------
    >>> import numpy as np, scipy.sparse as sp
    >>> L = sp.csr_matrix(np.array([[1.0, -1.0], [-1.0, 1.0]]))
    >>> V = np.array([[0.0, 0, 0], [1.0, 0, 0]]); B = np.zeros((2, 3))
    >>> float(dirichlet_sure(L, V, np.hstack([V, B]), B, L @ B, 0.1))  # H = I, no probes: the error's energy is 0
    0.0
    """
    P = B.shape[1] // 3
    keep = (lambda A: A) if rows is None else (lambda A: A[rows])  # noqa: E731
    noise = float(np.sum(keep(B) * keep(LB))) / P
    cross = float(np.sum(keep(LB) * keep(out[:, 3:]))) / P
    return _dirichlet_sum(L, V, out[:, :3], noise, cross, rho, rows)


def _dirichlet_sum(L: Any, V: np.ndarray, Y: np.ndarray, noise: float, cross: float, rho: float,
                   rows: np.ndarray | None) -> float:
    """:func:`dirichlet_sure` from its probe terms (``noise``, ``cross``: the means over the probes)."""
    R = Y - V
    keep = (lambda A: A) if rows is None else (lambda A: A[rows])  # noqa: E731
    energy = float(np.sum(keep(R) * keep(np.asarray(L @ R))))
    return energy - rho**2 * noise + 2.0 * rho**2 * cross


def _mean_edge(X: np.ndarray, F: np.ndarray) -> float:
    """Mean length of the faces' sides (an interior edge counted twice)."""
    F = np.asarray(F)
    if F.size == 0:
        return math.inf  # no face: nothing to linearise, nothing to compare the noise with
    return float(np.linalg.norm(X[F[:, [1, 2, 0]]] - X[F], axis=2).mean())


class FixedPointBracket:
    """The passes' walk to a fixed point of a map ``f`` on grid indices ``0 .. size - 1``, told each pass's
    ``f(at)``: on to ``f(at)`` until a value above and one below have been seen, then regula falsi on the gap
    :math:`f(i) - i` between the two ends, each point strictly inside the bracket; midpoints from the first regula
    falsi point that left more than half of its bracket (the gap far from linear: a choice clipped at the grid's end).
    On maps of slope 0 to -1 clipped to the grid (6,888 walks: every start, 41 crossings) never more passes than
    bisection and 19 % fewer in all; on steeper ones, whose fixed point repels, 10 % fewer in all, up to four more in
    a few. A choice within one index of ``at`` ends the walk.

    :meth:`next` returns the next index, ``None`` to stop at ``f(at)``, or the pair of adjacent ends ``(lo, hi)`` to
    choose between. Bisection took face000's ``sobolev_axes`` search 3.2 -> 79, 79 -> 50, then 16, 35 and 50 (five
    passes); regula falsi goes from the first two passes to 50 (three).

    Examples
    --------
    >>> walk, at, seen = FixedPointBracket(24), 8, []
    >>> while isinstance(at, int):  # f(i) = 22 for i < 20, else 20 (its fixed point 20)
    ...     seen.append(at)
    ...     at = walk.next(at, 22 if at < 20 else 20)
    >>> seen, at
    ([8, 22, 20], None)
    """

    def __init__(self, size: int):
        self.size = int(size)
        self.lo, self.hi = -1, self.size  # the ends seen (-1, size: none on that side yet)
        self.gap: dict[int, float] = {}  # an end -> f(end) - end (> 0 at lo, < 0 at hi)
        self._falsi_width: int | None = None  # the bracket's width when the last point came by regula falsi
        self._bisect = False  # a regula falsi point left more than half of its bracket: midpoints from then on

    def next(self, at: int, best: int) -> int | tuple[int, int] | None:
        if abs(best - at) <= 1:  # the fixed point, or a candidate one grid step (26 %) from it: a further pass,
            return None  # a run of every candidate, would choose between the two on a curve that is flat there
        if best > at:
            self.lo = at
        else:
            self.hi = at
        self.gap[at] = float(best - at)
        lo, hi = self.lo, self.hi
        if lo < 0 or hi >= self.size:  # one side only seen: on to the choice
            return best
        if hi - lo <= 1:
            return (lo, hi)
        if self._bisect or (self._falsi_width is not None and 2 * (hi - lo) > self._falsi_width):
            self._bisect = True
            return (lo + hi) // 2
        self._falsi_width = hi - lo
        at = lo + int(round(self.gap[lo] * (hi - lo) / (self.gap[lo] - self.gap[hi])))
        return min(max(at, lo + 1), hi - 1)


class _Result(NamedTuple):
    """A candidate's result: ``Y`` :math:`= HX`, with the whole block ``out`` (:math:`[HX, HB]`, the filter run) or
    the probes' terms ``terms`` (duals, 3P) :math:`u^T H b` per probe column (:class:`~.spectral.SpectralSearch`)."""

    Y: np.ndarray
    out: np.ndarray | None = None
    terms: np.ndarray | None = None


def _dirichlet_choice(V: np.ndarray, F: np.ndarray, values: list[float], start: float, rho: float, count: int,
                      rows: np.ndarray | None, probes_at: Callable, position_sure: Callable, guarded: Callable,
                      search: Callable, results: Callable, at_value: Callable, path: tuple) -> NormalChoice:
    """:func:`refine_for_normals`' ranking where the noise is too large for its linearised estimate:
    :func:`dirichlet_sure`, the probes along the vertex normals of the result at ``start`` (position SURE's choice),
    searched from there."""
    from ..operators import get_operators

    L = get_operators(np.asarray(F), V.shape[0]).L
    i0 = int(np.argmin(np.abs(np.log(values) - math.log(float(start)))))
    B = probes_at(at_value(values[i0]))
    LB = np.asarray(L @ B)
    P = B.shape[1] // 3
    keep = (lambda A: A) if rows is None else (lambda A: np.where(rows[:, None], A, 0.0))  # noqa: E731
    noise = None
    scores: dict[int, float] = {}
    sures: dict[int, float] = {}

    def score(i: int, r: _Result) -> None:
        nonlocal noise
        if r.out is not None:
            scores[i] = dirichlet_sure(L, V, r.out, B, LB, rho, rows) / max(count, 1)
        else:
            if noise is None:
                noise = float(np.sum(keep(B) * LB)) / P
            cross = float(np.sum(r.terms[0])) / P
            scores[i] = _dirichlet_sum(L, V, r.Y, noise, cross, rho, rows) / max(count, 1)
        sures[i] = position_sure(B, r)
        if guarded(i, sures[i]):
            scores[i] = math.inf

    # on the whole mesh both duals are the probes times a power of L: Gauss rules of the probes' own run, where the
    # map is a function of L (SpectralSearch, StartDual), else recorded
    duals = [StartDual(1, L), StartDual()] if rows is None else [keep(LB), keep(B)]
    search(i0, results(B, duals), score, scores)
    best = min(scores, key=scores.get)
    order = sorted(scores)
    return NormalChoice(values[best], float(scores[best]), path + (values[best],), tuple(values[i] for i in order),
                        tuple(float(scores[i]) for i in order), float(sures[best]), float(count * rho**2),
                        criterion="dirichlet")


def refine_for_normals(V: np.ndarray, F: np.ndarray, apply: Callable[[float, np.ndarray], np.ndarray],
                       start: float, candidates: Sequence[float], rho: float, *,
                       colour: Callable[[np.ndarray, float], np.ndarray] | None = None,
                       probes: int | None = None, iterations: int = NORMAL_ITERATIONS,
                       first: float | None = None, rows: np.ndarray | None = None,
                       exact: bool | None = None, guard_above: float | None = None, seed: int = 0,
                       edge_length: float | None = None,
                       spectral: Callable[[float], Spectral] | None = None,
                       config: SpectralConfig | None = None) -> NormalChoice:
    """The parameter of a linear smoother with the least estimated face-normal risk (:func:`normal_risk`).

    The risk is linearised at a mesh ``R`` (``J`` and the noise directions ``N``, the unit
    vertex normals of ``R``). The value sought is a fixed point: the candidate whose own result,
    linearised at, chooses it. ``R`` is first the result at the candidate nearest ``first``
    (:func:`~meshdenoise.tuning.choose.choose_parameters` passes :data:`NORMAL_FIRST` times its
    position-SURE choice); each pass then moves to the pass's choice, until the choice is the
    candidate linearised at. Linearised at a rougher mesh the estimate asks for more smoothing,
    at a smoother one for less, so once a choice above and one below have been seen the fixed
    point is bracketed and the passes close in on it by regula falsi on the choice's distance from the
    candidate linearised at (:class:`FixedPointBracket`: midpoints once a regula falsi point leaves more than
    half of its bracket; adjacent ends: the better as the last pass sees them); a choice one candidate from the point linearised at ends the passes; at most
    ``iterations`` passes. Linearising at the position-SURE result alone overshoots
    on meshes with sharp features (the chosen weight at the search's end on Fandisk0.3 and
    Block0.4 for :math:`(I + \\mu L)^{-1}`); the fixed point is within 1 % of the normal oracle
    there (docs/automatic-parameters.md, "The normals criterion").
    From :data:`NORMAL_LINEAR_MAX` mean edge lengths of noise (``edge_length``) the first
    order does not hold and the candidates are ranked instead by :func:`dirichlet_sure`, searched
    from ``start`` (``NormalChoice.criterion`` "dirichlet").

    Parameters
    ----------
    V : ndarray, shape (n, 3)
        The noisy vertices.
    F : ndarray, shape (m, 3)
    apply : callable
        ``apply(value, block)``: the smoother at ``value`` on ``block`` (n, 3k), coordinate
        triples side by side; linear in ``block``.
    start : float
        The value to linearise at first.
    candidates : sequence of float
        The values compared, ascending.
    rho : float
        The noise level, > 0.
    colour : callable, optional
        ``colour(Z, s)``: probes ``Z`` (n, P) coloured like correlated noise
        (:meth:`~meshdenoise.tuning.context.TuningContext.colour`); none for independent noise.
    probes : int, optional
        Default :func:`normal_probe_count`.
    iterations : int
        Most passes; each descends from the candidate nearest the value it linearised at to a local
        minimum (a few solves).
    first : float, optional
        The value whose result the first pass linearises at (default ``start``).
    edge_length : float, optional
        The mean edge length ``rho`` is compared with (:data:`NORMAL_LINEAR_MAX`); default the
        first pass's mesh's (a smoothed mesh: the noisy one's edges grow with the noise).
    spectral : callable, optional
        ``spectral(value)``: the map at ``value`` as :math:`S^{-1} g(M) S`
        (:class:`~meshdenoise.tuning.spectral.Spectral`, every value on the same ``M``). From
        ``config.min_vertices`` vertices (Rademacher probes) the candidates are then scored
        without running ``apply`` on the probes: their terms :math:`u_p^T H b_p` (the normal
        risk's :math:`(J b_p)^T (J H b_p)` with :math:`u_p = J^T J b_p`, position SURE's and the
        Dirichlet estimate's) from one Lanczos run per pass that records the duals' projections,
        the coordinates :math:`HX` from one run for the whole search
        (:class:`~meshdenoise.tuning.spectral.SpectralSearch`): the same estimates to about 1e-10,
        no factorisation or filter run per candidate. ``apply`` is used where a run does not
        converge.
    config : SpectralConfig, optional
        The Lanczos runs' settings (:class:`~meshdenoise.tuning.config.SpectralConfig`; ``None``: its default).
    rows : ndarray of bool, shape (n,), optional
        The vertices scored (a sampled region's inner part): only faces with three scored
        corners count. Default: all.
    exact : bool, optional
        Exact traces (probes :math:`\\sqrt n\\, e_i`, ``3n`` columns) instead of Rademacher ones;
        by default up to :data:`~meshdenoise.tuning.risk.EXACT_TRACE_MAX` vertices.
    guard_above : float, optional
        Candidates above this value are chosen only where the positions' SURE
        (``NormalChoice.position_risk``) is below the input's expected error :math:`n\\rho^2`:
        past there the filter shrinks the mesh faster than it removes noise, and the
        linearisation at so shrunk a mesh asked for ever more smoothing (Nefertiti at
        rho = 0.2, ``sobolev``: 24 times SURE's weight, 25.4 degrees against the oracle's 17.8).
    seed : int

    Returns
    -------
    NormalChoice

    Examples
    --------
    >>> import numpy as np, scipy.sparse as sp, scipy.sparse.linalg as sla
    >>> from meshdenoise.shapes import icosphere
    >>> from meshdenoise.operators import get_operators
    >>> V, F = icosphere(3)
    >>> X = V + 0.02 * np.random.default_rng(0).standard_normal(len(V))[:, None] * V
    >>> L = get_operators(F, len(V)).L
    >>> smooth = lambda mu, B: sla.spsolve((sp.identity(len(V)) + mu * L).tocsc(), B)  # (I + mu L)^-1
    >>> choice = refine_for_normals(X, F, smooth, 0.1, [0.1, 0.2, 0.4, 0.8, 1.6, 3.2], rho=0.02)
    >>> bool(choice.value > 0.1), choice.path[-1] == choice.value
    (True, True)
    """
    V = np.asarray(V, dtype=np.float64)
    values = sorted(float(c) for c in candidates)
    if not values:
        raise ValueError("refine_for_normals: candidates is empty")
    if not (math.isfinite(rho) and rho > 0):
        raise ValueError(f"refine_for_normals: rho must be finite and > 0, got {rho!r}")
    if probes is None:
        probes = normal_probe_count(V.shape[0])
    if int(probes) < 1 or int(iterations) < 1:
        raise ValueError(f"refine_for_normals: probes and iterations must be >= 1, got {probes!r}, {iterations!r}")
    n = V.shape[0]
    exact_probes = exact if exact is not None else n <= EXACT_TRACE_MAX
    if exact_probes:  # probes sqrt(n) e_i: the mean over them is the trace
        Z = math.sqrt(n) * np.eye(n)
    else:
        Z = np.random.default_rng(seed).choice([-1.0, 1.0], size=(n, int(probes)))
    if colour is not None:
        Z = colour(Z, 1.0 / int(probes))
    logs = np.log(values)
    faces = None
    if rows is not None:
        rows = np.asarray(rows, dtype=bool)
        if rows.shape != (n,):
            raise ValueError(f"refine_for_normals: rows must be a bool mask of shape ({n},), got shape {rows.shape}")
        faces = rows[np.asarray(F)].all(axis=1)
    count = n if rows is None else int(np.count_nonzero(rows))
    part = (lambda A: A) if rows is None else (lambda A: A[rows])  # noqa: E731  the scored vertices
    P = Z.shape[1]

    def probes_at(R: np.ndarray) -> np.ndarray:  # (n, 3P): probe p in columns 3p .. 3p + 2, along R's vertex normals
        N = vertex_normals(R, F)
        return (Z[:, :, None] * N[:, None, :]).reshape(n, 3 * P)

    def position_sure(B: np.ndarray, r: _Result) -> float:
        if r.out is not None:
            trace = float(np.sum(part(B) * part(r.out[:, 3:]))) / P
        else:  # the terms of dual 1, the probes on the scored vertices
            trace = float(np.sum(r.terms[1])) / P
        return float(np.sum(part(r.Y - V) ** 2)) - count * rho**2 + 2.0 * rho**2 * trace

    def guarded(i: int, sure: float) -> bool:  # past guard_above, positions worse than the input's: not a candidate
        return guard_above is not None and values[i] > guard_above and not sure < count * rho**2

    def search(at: int, result: Callable[[int], _Result], score: Callable[[int, _Result], None],
               risks: dict[int, float]) -> None:
        """Score candidates into ``risks``: a descent from ``at`` to a local minimum."""
        cur = at  # descend from the candidate linearised at (the risk is smooth in log value)
        while True:
            for j in (cur, cur - 1, cur + 1):  # cur first: its result was just computed for R (a cached factor)
                if 0 <= j < len(values) and j not in risks:
                    score(j, result(j))
            nxt = min((j for j in (cur - 1, cur, cur + 1) if j in risks), key=risks.get)
            if nxt == cur:
                break
            cur = nxt

    def run_results(B: np.ndarray, duals: list[np.ndarray]) -> Callable[[int], _Result]:
        """Each candidate's result by the filter on ``[V, B]``, one run per candidate."""
        VB = np.hstack([V, B])

        def result(j: int) -> _Result:
            out = apply(values[j], VB)
            return _Result(out[:, :3], out=out)

        return result

    def passes(spectral_search: SpectralSearch | None) -> NormalChoice:
        at_value = (lambda value: apply(value, V)) if spectral_search is None else spectral_search.coordinates

        def results(B: np.ndarray, duals: list[np.ndarray | StartDual]) -> Callable[[int], _Result]:
            if spectral_search is None:
                return run_results(B, duals)
            terms = spectral_search.probes(B, duals)
            return lambda j: _Result(spectral_search.coordinates(values[j]), terms=terms(values[j]))

        # the fixed point, bracketed: linearised at a smoother mesh the estimate asks for less smoothing, at a
        # rougher one for more (face000: 2 and 20 steps asked for each other); once both sides are seen, regula falsi
        at = int(np.argmin(np.abs(logs - math.log(float(first) if first is not None else float(start)))))
        bracket = FixedPointBracket(len(values))
        path: list[float] = []
        for _ in range(int(iterations)):
            R = at_value(values[at])
            if not path and rho >= NORMAL_LINEAR_MAX * (_mean_edge(R, F) if edge_length is None else float(edge_length)):
                # the noise turns a face by about rho / h radians: past one the first order does not hold (the
                # elephant at 26 edge lengths of noise: every candidate's estimate -3,900 rad^2, the choice at the
                # search's end)
                return _dirichlet_choice(V, F, values, start, rho, count, rows, probes_at, position_sure, guarded,
                                         search, results, at_value, ())
            J = NormalJacobian(R, F, NORMAL_MIN_HEIGHT)
            B = probes_at(R)
            JB = J.many(B.reshape(n, P, 3))
            counted = J.counted if faces is None else faces & J.counted
            duals: list[np.ndarray] = []
            own = None
            if spectral_search is not None:  # u_p = J^T (J b_p on the counted faces): (J b_p).(J H b_p) = u_p . H b_p
                masked = np.where(counted[:, None, None], JB, 0.0)
                duals = [J.adjoint_many(masked, n).reshape(n, 3 * P),
                         StartDual() if rows is None else np.where(rows[:, None], B, 0.0)]
                own = np.einsum("fpc,fpc->p", masked, masked)  # the counted faces' (zero elsewhere): no copies
            risks: dict[int, float] = {}
            sures: dict[int, float] = {}

            def score(i: int, r: _Result) -> None:
                if r.out is not None:
                    risks[i] = normal_risk(J, V, r.Y, JB, r.out[:, 3:].reshape(n, P, 3), rho, faces)
                else:
                    risks[i] = _normal_risk_sum(J, V, r.Y, r.terms[0].reshape(P, 3).sum(axis=1), own, rho, counted)
                sures[i] = position_sure(B, r)
                if guarded(i, sures[i]):
                    risks[i] = math.inf

            search(at, results(B, duals), score, risks)
            best = min(risks, key=risks.get)
            path.append(values[best])
            nxt = bracket.next(at, best)
            if nxt is None:
                break
            if isinstance(nxt, tuple):  # adjacent ends: the better of the two as this pass sees them
                best = min((i for i in nxt if i in risks), key=risks.get, default=best)
                break
            at = nxt
        order = sorted(risks)
        return NormalChoice(values[best], float(risks[best]), tuple(path), tuple(values[i] for i in order),
                            tuple(float(risks[i]) for i in order), float(sures[best]), float(count * rho**2))

    config = resolve(config, SPECTRAL)
    if spectral is not None and not exact_probes and n >= config.min_vertices:
        try:
            return passes(SpectralSearch(V, spectral, candidates=values, config=config))
        except SpectralFailed:  # a run past config.max_steps: the filter's own runs
            pass
    return passes(None)
