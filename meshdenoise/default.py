"""What :func:`denoise` does with no method: the default for scans, which chooses the filter and its parameters.

The policy, from measurements of the noisy mesh alone:

1. the noise: its level and correlation length
   (:func:`~meshdenoise.tuning.covariance.estimate_noise_model`; a scanner's noise is
   correlated over a few samples), printed absolute and in mean edge lengths; where it reads
   correlated noise, whether the surface's own detail explains it
   (:func:`~meshdenoise.tuning.detail.separate_detail`, :func:`noise_policy`: its verdict and
   the levels allowed are printed); every risk estimate below accounts for the model;
2. a short feature-preserving pre-smoothing (:func:`detect_features`), after which CAD parts
   have almost all their creased edges sharp, scans and organic shapes have gradual creases,
   and a mesh whose noise is too strong for normals to be filtered still has a large share of
   all its edges sharp;
3. open borders (vertices on a boundary edge), which then move only along their normals
   (``boundary_motion="normal"``, :func:`meshdenoise.registry.boundary_along_normals`).

Where the noise is too strong for normals to be filtered, ``sobolev_bilaplacian`` (a smooth
prior) is chosen; elsewhere both it and ``two_stage`` (feature-preserving normal filtering) get
their automatic parameters and the one with the smaller estimated error is kept (SURE of
``sobolev_bilaplacian``'s choice, and :func:`feature_risk` for ``two_stage``'s: Monte-Carlo SURE on
the whole mesh with probes along the smooth prior's result's normals; from :data:`REGION_FROM`
vertices the feature test, both candidates' Monte-Carlo SURE and the post-step below run on a
sampled region, :class:`RiskRegion`, in time independent of the mesh's size). Measured
(``benchmarks/results/default-candidates.md``): the normal filter on the CAD parts (2.5-3.1 against
10.5-12.0 degrees of normal error), on the benchmark's scanned Bunny0.2 and on the range scan with
scanner noise (5.6-8.0 against 9.4-11.7), the smooth prior on the bunny with independent scanner
noise, on the 299-vertex Nefertiti and at noise near one edge length (the paper's elephant: 11.5
against 28.6); no wrong pick in 10 rows (docs/scans.md). The sharp-feature verdict is reported.
On meshes of at most :data:`SMALL_MESH` vertices ``sobolev_normal`` is a third candidate (its search
costs under a second there; on the 299-vertex Nefertiti at rho 0.2 it gives 16.7 degrees and 25.9 dB
against 19.3 and 24.8 for ``sobolev_bilaplacian``), scored like ``two_stage``.
Parameters are those of the filter's own automatic rule; after a smooth prior,
:func:`choose_post_step` then scales its ``mu`` by 1, 1.5 or 2 and adds 0, 2 or 5 Taubin steps, by a
normal-domain risk estimate guarded by SURE on positions (the paper's elephant at rho 0.2: 19.74 ->
18.88 degrees, 27.42 -> 27.14 dB; docs/peers.md, "Smooth-prior post-step"). On meshes of at most
:data:`SMALL_MESH` vertices whose probe normals are far off the noise's direction (read on synthetic
copies), the guard's probes are tilted by that error and the candidates ranked by recorrupted pairs
(:func:`small_post_estimates`; the Nefertiti at rho 0.2: 16.35 -> 15.41 degrees, 25.70 -> 25.95 dB).
After ``two_stage`` on a mesh with no sharp features, :func:`feature_post_step` adds 0 to 16 Taubin
steps by the same two estimates, read on the probes' runs that scored ``two_stage`` (pymeshlab's bunny
with scanner noise of 0.5 mean edge lengths correlated over 2: 8.63 -> 8.23 degrees, 48.93 -> 48.81 dB;
docs/peers.md, "Taubin steps after two_stage").
This module names filters: it is policy, above the
generic tuning machinery.
"""

from __future__ import annotations

import logging
import math
import time
import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .adapters import read_mesh
from . import kernels
from .geometry import face_normals, vertex_face_incidence, vertex_normals
from .locality import relabelling
from .operators import Operators, get_operators, spmm
from .progress import stage
from .registry import COMMON_OPTIONS, FilterSpec, ParameterError, apply_filter, get_filter, run_core
from .tuning.choose import choose_parameters, relabelled_model, rule_criterion
from .tuning.covariance import NoiseModel, estimate_noise_model
from .tuning.memo import release_before_filter
from .tuning.detail import BANDS as DETAIL_BANDS
from .tuning.detail import ELL_GRID as DETAIL_LENGTHS
from .tuning.detail import DetailVerdict, separate_detail
from .tuning.noise_level import mean_edge_length
from .tuning.region import SampledRegion
from .tuning.recorrupted import cross_normals, normal_score, recorrupt
from .tuning.risk import mc_sure_step
from .tuning.normal_risk import NormalJacobian
from .tuning.search import shifted_reach

__all__ = ["DefaultChoice", "FeatureTest", "choose_default", "denoise", "detect_features", "feature_risk",
           "feature_runs", "ProbeRuns", "feature_post_step", "FEATURE_POST_STEPS",
           "noise_policy", "default_noise", "SMOOTH_METHOD", "FEATURE_METHOD", "NormalJacobian", "PostCandidate",
           "PostStep", "post_step_estimates", "choose_post_step", "run_post_step", "normal_error_share",
           "tilted_directions", "small_post_estimates", "taubin_passes"]

log = logging.getLogger("meshdenoise.auto")

SMOOTH_METHOD = "sobolev_bilaplacian"  # the smooth prior (alone where the noise is too strong for normal filtering)
FEATURE_METHOD = "two_stage"  # feature-preserving normal filtering
# The pre-smoothing of the feature test, written out so that a change of two_stage's defaults does not move it.
PRESMOOTH = {"iterations": 2, "normal_iterations": 10, "vertex_iterations": 10, "sigma_r": 0.35, "sigma_s": 1.0,
             "guidance": "guided"}
CREASE_DEG = 20.0  # an edge is creased above this dihedral angle ...
SHARP_DEG = 45.0  # ... and sharp above this one
SHARP_SHARE = 0.70  # sharp features when at least this share of the creased edges is sharp
TOO_NOISY = 0.10  # above this fraction of sharp edges the pre-smoothing has not removed the noise: no decision on features
MIN_SHARP_EDGES = 12  # fewer sharp edges than this are no feature lines
NOT_SMOOTHING = 0.01  # a run that moves vertices by less than this many mean edge lengths (rms) is said not to smooth
SMALL_MESH = 2000  # up to this many vertices the default also tries ...
SMALL_MESH_METHOD = "sobolev_normal"  # ... this smooth prior with a normal-aware update (its search costs under a second there)
RISK_PROBE_RUNS = 30_000  # the feature filter's risk: Monte-Carlo SURE probes x vertices, about (see feature_risk) ...
RISK_PROBES = (2, 16)  # ... within these bounds on the probe count
SMOOTH_PRIORS = (SMOOTH_METHOD, SMALL_MESH_METHOD)  # the picks after which the post-step is chosen (choose_post_step)
POST_SCALES = (1.0, 1.5, 2.0)  # the post-step: multiples of the smooth prior's SURE-chosen mu ...
POST_STEPS = (0, 2, 5)  # ... times Taubin steps after it ...
POST_TAUBIN = {"lam": 0.5, "mu": -0.53}  # ... with these (uniform weights: the filter's default)
FEATURE_POST_STEPS = (0, 2, 5, 8, 12, 16)  # Taubin step counts tried after two_stage where there are no sharp features
NOISE_LEVEL_SLACK = 0.02  # ... whose SURE guard takes the noise level as known to within this fraction
POST_MAX_LOSS_DB = 0.3  # a candidate is allowed if its SURE on positions loses less than this (dB), 2 s.e. included
POST_PROBE_RUNS = 60_000  # probes x vertices of the post-step's estimates, about ...
POST_PROBES = (4, 16)  # ... within these bounds on the probe count
# On meshes of at most SMALL_MESH vertices (choose_default passes smooth_params) the post-step corrects its probes for the
# error of their normals where that error is large (docs/peers.md, "Small meshes: tilted probes and recorrupted pairs"):
SMALL_TILT_FROM = 0.03  # from this mean sin^2 of the probe normals' error (about 10 degrees; read on synthetic copies) ...
SMALL_COPIES = 16  # ... read on this many synthetic copies of the prior's result ...
SMALL_PROBES = 32  # ... the guard's tilted Monte-Carlo SURE probes ...
SMALL_DRAWS = 32  # ... and the criterion's recorrupted pairs ...
SMALL_RECORRUPTION = 0.5  # ... Y + aZ, Y - Z/a with this a (the estimate's level: sqrt(1 + a^2) = 1.12 times the noise's)
SMALL_POST_STEPS = (0, 2, 5, 8)  # ... over these Taubin step counts (after each of POST_SCALES), run as denoise runs them
# Above this many vertices the candidates' risks, the probes' normals and the post-step are estimated on a sampled
# region (:class:`RiskRegion`) instead of the whole mesh: on the 1.6M elephant their whole-mesh runs took 160 s
# (feature_risk) and 548 s (the post-step's 17 runs of the prior) of an 813 s choice (session 9). The measured rows of
# the benchmark tables have at most 35k vertices, so none of them changes.
REGION_FROM = 50_000
# up to this many vertices the smooth prior's rule runs beside two_stage's (_candidate_rules; idle, same choices: bunny
# scanner 28k 3.20 -> 2.98 s, face000 scanner 85k 4.99 -> 4.70 s); larger meshes are not measured: one after another
RULES_BESIDE_UP_TO = 100_000
# the smooth prior's run for the probes' normals on the whole mesh: two Lanczos passes, no factor (the bunny scanner at
# mu 3: 0.14 s against 0.43 s for the factor, the normals within 2e-12; the region's runs below share one factor)
PRIOR_NORMALS_SOLVER = "lanczos"
RISK_REGION = 40_000  # the region: about this many vertices ...
RISK_PATCHES = 12  # ... in this many balls (the 400k elephant: 8, 12 and 24 chose the post-step as the whole mesh did) ...
RISK_MARGIN = 10  # ... scored from this many rings from a cut on (more where the smooth prior reaches farther):
# measured on the 100k elephant (a 32k region cut in 24 balls), two_stage at the default's 400k choice moves region
# vertices 10 rings from a cut by 0.003 rho rms from the whole mesh's result (0.018 at 4 outer iterations), the
# smooth prior at mu 1.1 by 0.01 rho at 8 rings
RISK_MAX_MARGIN = 16  # ... and at most this many
FEATURE_REGION = 60_000  # the feature test's region from REGION_FROM vertices: about this many vertices ...
FEATURE_PATCHES = 48  # ... in this many balls (it reads shares of edges: many small balls sample the mesh wider) ...
FEATURE_MARGIN = 8  # ... its edges counted from this many rings from a cut on (two outer iterations of PRESMOOTH: 0.02
# rho rms from the whole mesh's result there, measured as for RISK_MARGIN)


@dataclass(frozen=True)
class FeatureTest:
    """The outcome of :func:`detect_features`.

    Attributes
    ----------
    sharp : bool
        Whether the mesh has sharp features.
    too_noisy : bool
        Whether the noise hides the surface's creases (then ``sharp`` is False).
    share : float
        Sharp edges / creased edges after the pre-smoothing (NaN with no creased edge).
    sharp_fraction : float
        Sharp edges / interior edges after the pre-smoothing.
    reason : str
        One sentence saying why.
    """

    sharp: bool
    too_noisy: bool
    share: float
    sharp_fraction: float
    reason: str


def _dihedral_angles(V: np.ndarray, F: np.ndarray, ops: Operators, faces: np.ndarray | None = None) -> np.ndarray:
    """Dihedral angles (degrees, 0 for a flat pair) of the edges shared by exactly two faces (both in ``faces``,
    a boolean mask (m,), when given)."""
    N = face_normals(V, F)
    n = ops.n
    # side 3 f + k of face f is (F[f, k], F[f, k + 1 mod 3]); its key min * (n + 1) + max names the edge.
    # Lean on memory (issue 17: this was the default's peak at 400k vertices): no (3m, 2) edge array,
    # no np.unique (a second sort), the face of a side is its index // 3; the same angles as before
    Fi = np.asarray(F, dtype=np.int64)
    key = np.minimum(Fi.ravel(), Fi[:, [1, 2, 0]].ravel())
    key *= n + 1
    key += np.maximum(Fi.ravel(), Fi[:, [1, 2, 0]].ravel())
    order = np.argsort(key, kind="stable")
    key = key[order]  # sorted
    start = np.flatnonzero(np.concatenate(([True], key[1:] != key[:-1]))) if key.size else np.zeros(0, dtype=np.int64)
    counts = np.diff(np.append(start, key.size))
    del key
    first = start[counts == 2]  # manifold edges: a key seen exactly twice, adjacent once sorted
    del start, counts
    a, b = order[first] // 3, order[first + 1] // 3
    del order, first
    if faces is not None:
        both = faces[a] & faces[b]
        a, b = a[both], b[both]
    c = np.clip(np.einsum("ij,ij->i", N[a], N[b]), -1.0, 1.0)
    return np.degrees(np.arccos(c))


def detect_features(mesh: Any, *, ops: Operators | None = None) -> FeatureTest:
    """Whether a (noisy) mesh has sharp features, from its dihedral angles after a feature-preserving pre-smoothing.

    Two outer iterations of ``two_stage`` (fixed parameters, :data:`PRESMOOTH`) remove most
    of the noise while keeping creases sharp. Then, among the edges creased by more than
    :data:`CREASE_DEG` degrees, the share sharper than :data:`SHARP_DEG`:

    .. math:: s = \\frac{\\#\\{e : \\theta_e > 45^\\circ\\}}{\\#\\{e : \\theta_e > 20^\\circ\\}}

    is near 1 on CAD parts (flat faces meeting at sharp edges) and well below on scans and
    organic shapes, whose creases are gradual. Measured (``python benchmarks/feature_test.py``,
    ``benchmarks/results/feature-test.md``): CAD parts with noise 0.74 to 0.98, scans and smooth
    meshes with or without noise 0.28 to 0.64; the threshold is :data:`SHARP_SHARE`. When more
    than :data:`TOO_NOISY` of all edges stay sharp the noise (several edge lengths) was not
    removed and no sharp feature is reported: a smooth prior is the safe choice there.
    Above :data:`REGION_FROM` vertices the pre-smoothing runs on a :class:`RiskRegion` of about
    :data:`FEATURE_REGION` vertices in :data:`FEATURE_PATCHES` balls and the shares count its
    edges :data:`FEATURE_MARGIN` rings or more from a cut: both are shares, which a sample
    estimates (the edge count said is the region's).

    Parameters
    ----------
    mesh : (V, F) tuple, pymeshlab.MeshSet or Mesh, or open3d.geometry.TriangleMesh
    ops : Operators, optional
        The topology's operators, if the caller holds them.

    Returns
    -------
    FeatureTest

    Examples
    --------
    >>> from meshdenoise.shapes import icosphere
    >>> detect_features(icosphere(3)).sharp
    False
    """
    data = read_mesh(mesh)
    V, F = data.V, data.F
    ops = ops if ops is not None else get_operators(F, V.shape[0])
    return _feature_test(V, F, ops)


def _feature_test(V: np.ndarray, F: np.ndarray, ops: Operators) -> FeatureTest:
    """:func:`detect_features` on arrays ``V`` (n, 3), ``F`` (m, 3) and their operators (no copy of them)."""
    if F.shape[0] < 2:
        return FeatureTest(False, False, float("nan"), 0.0, "fewer than two faces: no dihedral angle")
    spec = get_filter(FEATURE_METHOD)
    on = ""
    if V.shape[0] > REGION_FROM:  # shares of edges: read on a region of fixed size, away from its cuts
        region = RiskRegion.cut(V, F, ops, FEATURE_MARGIN, size=FEATURE_REGION, patches=FEATURE_PATCHES)
        smooth = core_run(spec, region.V, region.ops, spec.resolve(dict(PRESMOOTH)))
        theta = _dihedral_angles(smooth, region.F, region.ops, faces=region.rows[region.F].all(axis=1))
        on = f" (on {theta.size:,} edges of a sampled region)"
    else:
        smooth = core_run(spec, V, ops, spec.resolve(dict(PRESMOOTH)))  # the public filter's result, bit for bit
        theta = _dihedral_angles(smooth, F, ops)
    del smooth
    creased = int(np.count_nonzero(theta > CREASE_DEG))
    sharp = int(np.count_nonzero(theta > SHARP_DEG))
    share = sharp / creased if creased else float("nan")
    fraction = sharp / theta.size if theta.size else 0.0
    where = (f"after a feature-preserving pre-smoothing {sharp:,} edges are sharp (> {SHARP_DEG:g} deg), "
             f"{share:.0%} of the {creased:,} creased ones (> {CREASE_DEG:g} deg)" if creased else
             f"after a feature-preserving pre-smoothing no edge is creased (> {CREASE_DEG:g} deg)") + on
    if fraction > TOO_NOISY:
        return FeatureTest(False, True, share, fraction, f"{where}, but that is {fraction:.0%} of all edges (over "
                           f"{TOO_NOISY:.0%}): the noise is too strong for normals to be filtered")
    if not creased:
        return FeatureTest(False, False, share, fraction, f"{where}: no sharp features")
    if sharp < MIN_SHARP_EDGES or not share >= SHARP_SHARE:
        return FeatureTest(False, False, share, fraction, f"{where}: gradual creases, no sharp features "
                           f"(sharp features from {SHARP_SHARE:.0%})")
    return FeatureTest(True, False, share, fraction, f"{where}: sharp features (from {SHARP_SHARE:.0%})")


@dataclass
class DefaultChoice:
    """What the default decided for one mesh, and why (:func:`choose_default`).

    Attributes
    ----------
    method : str
        The filter chosen.
    params : dict
        Its parameters (chosen by its automatic rule).
    noise : float
        The estimated noise level rho (mesh units).
    edge_length : float
        The mean edge length (mesh units).
    correlation_length : float
        The noise's estimated correlation length in mean edge lengths (0: independent).
    features : FeatureTest
    boundary_vertices : int
        Vertices on open borders (they move along their normals only).
    reasons : list of str
        Sentences saying why.
    seconds : float
        Time taken to decide.
    caveats : list of str
        What the estimate cannot tell (printed as ``note:`` lines).
    verdict : str
        Surface detail or noise (:func:`~meshdenoise.tuning.detail.separate_detail`, asked when the
        fine bands read correlated noise): ``"noise"``, ``"detail"`` or ``"ambiguous"``;
        ``"independent"`` when they read independent noise (not asked), ``"given"`` when the noise
        was given.
    rho_range : tuple of float
        The noise levels (mesh units) the band spectrum allows, (low, high); NaN when not read.
    post_steps : int
        Taubin steps (:data:`POST_TAUBIN`) run after the filter: after a smooth prior
        (:func:`choose_post_step`; its ``mu`` in ``params`` is already scaled) or after
        ``two_stage`` on a mesh with no sharp features (:func:`feature_post_step`); 0: none.
    post : PostStep or None
        The post-step's choice and its candidates (None when none was considered).
    region : tuple of int
        ``(vertices, scored)`` of the :class:`RiskRegion` the candidates' risks were estimated on
        (above :data:`REGION_FROM` vertices); ``(0, 0)`` when they were estimated on the whole mesh.
    """

    method: str
    params: dict
    noise: float
    edge_length: float
    correlation_length: float
    features: FeatureTest
    boundary_vertices: int
    reasons: list[str] = field(default_factory=list)
    seconds: float = 0.0
    caveats: list[str] = field(default_factory=list)
    verdict: str = ""
    rho_range: tuple[float, float] = (float("nan"), float("nan"))
    post_steps: int = 0
    post: PostStep | None = None
    region: tuple[int, int] = (0, 0)

    @property
    def noise_in_edges(self) -> float:
        """The noise level in mean edge lengths."""
        return self.noise / self.edge_length if self.edge_length > 0 else float("nan")

    def lines(self) -> list[str]:
        """The decision as short lines for a terminal or a log."""
        settings = ", ".join(f"{k}={_short(v)}" for k, v in self.params.items()) or "its defaults"
        spread = (f"correlated over {self.correlation_length:.3g} edge lengths" if self.correlation_length > 0
                  else "independent")
        return [
            f"noise: {self.noise:.4g} ({self.noise_in_edges:.3g} mean edge lengths; mean edge {self.edge_length:.4g}; "
            f"{spread})",
            *([f"surface detail or noise: {self.verdict} (the band spectrum allows noise from "
               f"{self.rho_range[0] / self.edge_length:.3g} to {self.rho_range[1] / self.edge_length:.3g} "
               "mean edge lengths)"] if self.edge_length > 0 and np.all(np.isfinite(self.rho_range)) else []),
            f"method: {self.method} ({settings})" + (
                f", then {self.post_steps} Taubin steps (taubin: iterations={self.post_steps}, "
                f"lam={POST_TAUBIN['lam']:g}, mu={POST_TAUBIN['mu']:g})" if self.post_steps else ""),
            *(f"  because {r}" for r in self.reasons),
            *(f"  note: {c}" for c in self.caveats),
        ]

    def as_dict(self) -> dict:
        """Plain values (JSON-ready)."""
        return {
            "method": self.method, "params": dict(self.params), "noise": self.noise, "edge_length": self.edge_length,
            "noise_in_edges": self.noise_in_edges, "correlation_length": self.correlation_length,
            "sharp_features": self.features.sharp,
            "too_noisy": self.features.too_noisy,
            "sharp_share": self.features.share, "boundary_vertices": self.boundary_vertices,
            "reasons": list(self.reasons), "caveats": list(self.caveats), "seconds": self.seconds,
            "verdict": self.verdict, "rho_range": [float(r) for r in self.rho_range],
            "post_steps": self.post_steps, "post_taubin": dict(POST_TAUBIN) if self.post_steps else None,
            "post_scale": self.post.scale if self.post is not None else None,
            "region_vertices": self.region[0], "region_scored": self.region[1],
            "rho_range_in_edges": [float(r) / self.edge_length if self.edge_length > 0 else float("nan")
                                   for r in self.rho_range],
        }


def risk_margin(mu: float) -> int:
    """Rings of a :class:`RiskRegion`'s margin for a smooth prior of weight ``mu``: the reach of ``mu`` times the
    post-step's largest scale (:func:`~meshdenoise.tuning.search.shifted_reach`, order 2) plus its Taubin steps, at
    least :data:`RISK_MARGIN` (``two_stage``'s), at most :data:`RISK_MAX_MARGIN`."""
    reach = shifted_reach(float(mu) * max(POST_SCALES), 2) + max(POST_STEPS) if mu > 0 else 0
    return int(min(RISK_MAX_MARGIN, max(RISK_MARGIN, reach)))


@dataclass(frozen=True)
class RiskRegion:
    """A sampled part of a large mesh, cut out as a mesh of its own, on which the default's estimates run.

    From :data:`REGION_FROM` vertices :func:`choose_default` scores its candidates
    (:func:`feature_risk`) and chooses the post-step (:func:`choose_post_step`) on such a region:
    :data:`RISK_PATCHES` balls of rings of vertices
    (:class:`~meshdenoise.tuning.region.SampledRegion`), about :data:`RISK_REGION` vertices or
    more with a wide margin, in time independent of the mesh's size. Near a cut the region has a
    free border the mesh has not: only vertices ``margin`` rings or more from every cut are
    scored (``rows``). Both candidates are scored on the same rows with the same probes, so the
    comparison is paired.

    Attributes
    ----------
    vertices : ndarray of int64, shape (k,)
        The region's vertices (indices into the mesh).
    V : ndarray, shape (k, 3)
        Their coordinates.
    F : ndarray of int64, shape (l, 3)
        The region's faces, on its numbering.
    ops : Operators
        The region's operators.
    rows : ndarray of bool, shape (k,)
        The scored vertices.
    n : int
        The whole mesh's vertex count.

    Examples
    --------
    >>> import numpy as np
    >>> from meshdenoise.shapes import icosphere
    >>> from meshdenoise.operators import get_operators
    >>> V, F = icosphere(5)
    >>> r = RiskRegion.cut(V, F, get_operators(F, len(V)), 3, size=2000, patches=4)
    >>> 2000 <= r.V.shape[0] < len(V), bool(np.allclose(r.V, V[r.vertices])), bool(0 < r.rows.sum() < r.V.shape[0])
    (True, True, True)
    """

    vertices: np.ndarray
    V: np.ndarray
    F: np.ndarray
    ops: Operators
    rows: np.ndarray
    n: int

    @classmethod
    def cut(cls, V: np.ndarray, F: np.ndarray, ops: Operators, margin: int, *, size: int | None = None,
            patches: int | None = None, seed: int = 0) -> "RiskRegion":
        """Cut a region with ``margin`` rings unscored next to its cuts: at least ``size`` vertices (default
        :data:`RISK_REGION`) in ``patches`` balls (default :data:`RISK_PATCHES`), and balls of at least twice the
        margin's radius (``patches x 12 x margin^2`` vertices) so that some of each is scored."""
        size = RISK_REGION if size is None else size
        patches = RISK_PATCHES if patches is None else patches
        size = int(max(size, patches * 12 * margin * margin))
        region = SampledRegion(F, ops, size, patches, int(margin), seed)
        # its own operators, not the shared cache's: freed with the region (its factorisations too)
        sub_ops = ops if region.whole else Operators(region.F, region.vertices.size)
        return cls(region.vertices, np.ascontiguousarray(V[region.vertices]), region.F, sub_ops, region.inner,
                   int(V.shape[0]))

    @property
    def scale(self) -> float:
        """The whole mesh's vertices per scored vertex: a sum over ``rows`` times this estimates the mesh's sum."""
        return self.n / max(int(np.count_nonzero(self.rows)), 1)

    def noise_model(self, model: NoiseModel) -> NoiseModel:
        """``model`` on the region (a correlated model's heat filter built on the region's part of its geometry)."""
        if not model.correlated:
            return model
        return NoiseModel(model.rho, model.correlation_length, V=np.asarray(model.V)[self.vertices], F=self.F)


def feature_risk(V: np.ndarray, F: np.ndarray, params: dict, model: NoiseModel, normals: np.ndarray, *,
                 ops: Operators | None = None, probes: int | None = None, seed: int = 0,
                 method: str = FEATURE_METHOD, rows: np.ndarray | None = None) -> tuple[float, np.ndarray]:
    """Monte-Carlo SURE of ``two_stage`` (or ``method``) with ``params`` on the whole mesh, probes along ``normals``.

    .. math:: \\widehat R = \\|f(X) - X\\|_F^2 - n\\rho^2 + \\frac{2\\rho^2}{P}\\sum_{k=1}^P
              \\frac{b_k^T (f(X + \\delta b_k) - f(X))}{\\delta}, \\quad b_{k,i} = z_{k,i} N_i,\\ \\delta = 0.1\\rho

    with :math:`z_k` Rademacher (coloured by the noise model when it is correlated, as every
    rule's probes are: all probes at once, scaled so that :math:`\\sum_k \\|z_k\\|^2 = P n`). An unbiased estimate of :math:`\\|f(X) - X^0\\|_F^2` when ``N`` is the
    direction of the noise (Stein's lemma). Why not the estimate ``two_stage``'s rule returns: it
    is on a sampled region of 3000 vertices, scaled to the mesh (0.4 to 1.6 times the true error
    on the default's rows), and its probes follow the normals of a ``two_stage`` pilot. With
    ``keep_tangential`` each vertex keeps the part of the noise tangential to the *result's*
    normal, an error of :math:`\\rho^2 \\sum_i \\sin^2\\theta_i` (:math:`\\theta_i` the angle between
    the result's and the clean normal); probes along normals that share the result's own errors
    (the pilot's) do not see it: Nefertiti rho 0.2, 30 probes: 2.7 against a true 4.55, 4.8 along
    the clean normals. The caller passes the normals of an independent estimate (the smooth prior's
    result), which see it. With ``rows`` the sums run over those vertices only (each term of
    Stein's identity is a vertex's own: the estimate is unbiased for their squared error); the
    default passes a :class:`RiskRegion`'s scored vertices.

    Parameters
    ----------
    V : ndarray, shape (n, 3)
        The noisy vertices.
    F : ndarray, shape (m, 3)
    params : dict
        ``two_stage``'s parameters (the rest at its defaults).
    model : NoiseModel
        The noise level and correlation.
    normals : ndarray, shape (n, 3)
        Unit noise directions.
    ops : Operators, optional
    probes : int, optional
        Probe count; by default ``RISK_PROBE_RUNS`` divided by the vertices scored, within
        ``RISK_PROBES`` (16 on a 300-vertex mesh, 2 from 15,000 vertices).
    seed : int
    method : str
        The filter (``two_stage`` by default; the default also scores ``sobolev_normal`` and, on a
        region, ``sobolev_bilaplacian`` with it).
    rows : ndarray of bool, shape (n,), optional
        The vertices scored (default: all).

    Returns
    -------
    (float, ndarray of shape (n, 3))
        The estimate and ``f(X)``.
    """
    runs = feature_runs(V, F, params, model, normals, ops=ops, probes=probes, seed=seed, method=method, rows=rows)
    return float(np.mean(runs.sure())), runs.out


@dataclass
class ProbeRuns:
    """A filter's result and its runs on probed inputs (:func:`feature_runs`), kept for the estimates read on them.

    Attributes
    ----------
    V : ndarray, shape (n, 3)
        The noisy vertices :math:`X`.
    out : ndarray, shape (n, 3)
        :math:`f(X)`.
    runs : list of ndarray, shape (n, 3)
        :math:`f(X + \\delta b_p)`, one per probe (empty when rho is 0).
    probes : list of ndarray, shape (n, 3)
        The probes :math:`b_p = z_p N`.
    normals : ndarray, shape (n, 3)
        The unit directions :math:`N` of the probes (the noise's, as estimated).
    delta : float
        The step :math:`\\delta`.
    rho : float
        The noise level.
    rows : ndarray of bool, shape (n,), or None
        The vertices scored (None: all).
    """

    V: np.ndarray
    out: np.ndarray
    runs: list
    probes: list
    normals: np.ndarray
    delta: float
    rho: float
    rows: np.ndarray | None = None

    def part(self, A: np.ndarray) -> np.ndarray:
        """``A``'s scored rows."""
        return A if self.rows is None else A[self.rows]

    @property
    def count(self) -> int:
        """The vertices scored."""
        return self.V.shape[0] if self.rows is None else int(np.count_nonzero(self.rows))

    def sure(self, out: np.ndarray | None = None, runs: list | None = None) -> np.ndarray:
        """Monte-Carlo SURE per probe, shape (P,) (one value when rho is 0), of ``out`` and ``runs`` (by default
        the filter's own; given: the same probes through a filter run after it, such as Taubin steps)."""
        out = self.out if out is None else out
        runs = self.runs if runs is None else runs
        residual = float(np.sum((self.part(out) - self.part(self.V)) ** 2))
        if self.rho == 0:
            return np.array([residual])
        rho2 = self.rho**2
        return np.array([residual - self.count * rho2
                         + 2 * rho2 * float(np.sum(self.part(b) * self.part(X - out))) / self.delta
                         for b, X in zip(self.probes, runs)])


def feature_runs(V: np.ndarray, F: np.ndarray, params: dict, model: NoiseModel, normals: np.ndarray, *,
                 ops: Operators | None = None, probes: int | None = None, seed: int = 0,
                 method: str = FEATURE_METHOD, rows: np.ndarray | None = None) -> ProbeRuns:
    """The runs of :func:`feature_risk` (same arguments), kept: its SURE is ``feature_runs(...).sure().mean()``.

    Returns
    -------
    ProbeRuns
    """
    n = V.shape[0]
    ops = ops if ops is not None else get_operators(F, n)
    keep = _rows(rows, n, "feature_risk")
    count = n if keep is None else int(np.count_nonzero(keep))
    if probes is None:
        probes = int(np.clip(math.ceil(RISK_PROBE_RUNS / max(count, 1)), *RISK_PROBES))
    spec = get_filter(method)
    values = spec.resolve(dict(params))
    run = lambda X: core_run(spec, X, ops, values)  # noqa: E731
    rho = float(model.rho)
    if rho == 0:
        return ProbeRuns(V, run(V), [], [], normals, 0.0, 0.0, keep)
    # 0.1 rho, also under correlated noise: measured (docs/peers.md, smooth-prior post-step), the 1 rho of
    # two_stage's guard (mc_sure_step(rho, True)) read two_stage 0.328 h rms against 0.300 on bunny scanner l=2 and
    # flipped the pick to sobolev_bilaplacian (8.63 / 48.93 -> 8.76 / 48.40); no other row of four changed
    delta = mc_sure_step(rho, False)
    Z = np.random.default_rng(seed).choice([-1.0, 1.0], size=(probes, n)).T  # the draws of one probe at a time
    if model.correlated:  # all probes in one colouring (a block solve); mean square 1 per vertex over the probes
        Z = model.colour(Z, 1.0 / probes)
    B = [Z[:, k, None] * normals for k in range(probes)]
    del Z

    def result(k: int) -> np.ndarray:  # the filter is not linear: one run per probe (k = -1: the input itself)
        return run(V if k < 0 else V + delta * B[k])

    # two_stage's runs are compiled kernels: on a small mesh (under kernels.CONCURRENT_BELOW vertices) side by side,
    # one thread each, they share the cores better than each run's parallel loops do (the same bits); the other
    # filters' solves run one after another
    if spec.name == "two_stage":
        out, *runs = kernels.run_concurrently(result, range(-1, probes), n)
    else:
        out, runs = result(-1), [result(k) for k in range(probes)]
    return ProbeRuns(V, out, list(runs), B, normals, delta, rho, keep)


def feature_post_step(runs: ProbeRuns, F: np.ndarray, *, ops: Operators | None = None,
                      steps: tuple = FEATURE_POST_STEPS, max_loss_db: float = POST_MAX_LOSS_DB) -> PostStep:
    """Taubin steps after ``two_stage`` on a mesh with no sharp features: a count by a normal-domain risk, guarded by SURE.

    The probes' runs that scored ``two_stage`` (:func:`feature_runs`) are run on through ``k``
    Taubin steps :data:`POST_TAUBIN` (:math:`T^k`, linear) for each ``k`` of ``steps``: the
    candidate :math:`f_k = T^k \\circ f` costs no other run of ``two_stage``. For each probe
    :math:`b_p` (with :math:`\\Delta_p = (f_k(X + \\delta b_p) - f_k(X)) / \\delta`) the same two
    estimates as :func:`post_step_estimates`' are read:

    - on normals, with :math:`J` the derivative of the unit face normals at ``two_stage``'s
      result (:class:`NormalJacobian`),

      .. math:: G_p = \\frac1m\\Big(\\|J(f_k(X) - X)\\|^2 - \\rho^2 \\|J b_p\\|^2
                + 2\\rho^2 (J b_p)^T (J \\Delta_p)\\Big),

      Stein's estimate of the mean squared turn of the face normals from the clean ones;
    - on positions, Monte-Carlo SURE :math:`S_p` (:meth:`ProbeRuns.sure`).

    The count kept has the least mean :math:`G` among those whose gain over no step is
    significant (the paired difference plus two standard errors below 0) and whose SURE loses
    less than ``max_loss_db`` (the paired difference plus two standard errors, as
    :func:`choose_post_step`'s guard); 0 when none is. Why: ``two_stage`` fits the vertices to
    filtered normals and leaves the noise's long waves where the surface is smooth; under
    correlated noise they are most of it (pymeshlab's bunny with scanner noise of 0.5 mean edge
    lengths correlated over 2: 12 steps take its normal error from 8.63 to 8.23 degrees for 0.12
    dB, and this estimate reads -0.0034 rad^2 per face against a true -0.0050; docs/peers.md,
    "Taubin steps after two_stage"). Where the surface has sharp features the steps round them;
    :func:`choose_default` does not ask then.

    Parameters
    ----------
    runs : ProbeRuns
        ``two_stage``'s result and its probes' runs (with ``rows``: a :class:`RiskRegion`'s scored
        vertices, and the faces whose three corners are among them).
    F : ndarray, shape (m, 3)
        The faces of ``runs``' mesh.
    ops : Operators, optional
        Its operators.
    steps : tuple of int
        The counts tried (0 among them: no step).
    max_loss_db : float
        The SNR loss allowed (dB).

    Returns
    -------
    PostStep
        ``scale`` 1 (``two_stage`` has no ``mu``) and the count; its candidates' ``normal_risk``
        and ``sure`` are means over the probes.

    Examples
    --------
    >>> from meshdenoise.shapes import icosphere
    >>> from meshdenoise import add_normal_noise
    >>> from meshdenoise.geometry import vertex_normals
    >>> from meshdenoise.tuning.covariance import NoiseModel
    >>> V, F = icosphere(3)
    >>> Vn, _ = add_normal_noise((V, F), rho=0.02, seed=0)
    >>> params = {"sigma_r": 0.35, "iterations": 1}
    >>> post = feature_post_step(feature_runs(Vn, F, params, NoiseModel(0.02), vertex_normals(V, F), probes=4), F)
    >>> post.scale, post.steps in FEATURE_POST_STEPS
    (1.0, True)
    """
    steps = tuple(sorted({int(k) for k in steps}))
    if not steps or steps[0] < 0:
        raise ValueError(f"feature_post_step: parameter 'steps' = {steps!r} must be counts >= 0")
    if runs.rho == 0 or len(runs.runs) < 2:
        return PostStep(1.0, 0, (), "Taubin steps after two_stage: none (no noise, or too few probes to compare)")
    F = np.asarray(F)
    ops = ops if ops is not None else get_operators(F, runs.V.shape[0])
    n, P = runs.V.shape[0], len(runs.runs)
    faces = None if runs.rows is None else runs.rows[F].all(axis=1)
    J = NormalJacobian(runs.out, F)
    turn = (lambda D: J(D)) if faces is None else (lambda D: J(D)[faces])  # noqa: E731
    m = max(F.shape[0] if faces is None else int(np.count_nonzero(faces)), 1)
    rho2, delta = runs.rho**2, runs.delta
    JB = [turn(b) for b in runs.probes]
    noise_term = [rho2 * float(np.sum(jb * jb)) for jb in JB]
    # (J b)^T J d = (J^T J b)^T d: each probe's term becomes a product in vertex space, no turn per run
    lifted = [J.adjoint(J(b) if faces is None else J(b) * faces[:, None], n) for b in runs.probes]
    JV = turn(runs.V)
    # the result and every probe's run side by side as columns: each Taubin pass is one product for all of them
    block = np.hstack([runs.out] + list(runs.runs))
    spare = np.empty_like(block)
    passes = taubin_passes(ops)
    done, est, ends, turned = 0, {}, {}, {}
    for k in sorted(set(steps) | {0}):
        for _ in range(k - done):  # Taubin run on from the previous count, as the filter runs it
            for M in passes:
                spmm(M, block, out=spare)
                block, spare = spare, block
        done = k
        Y, probed = block[:, :3].copy(), [block[:, 3 * (p + 1):3 * (p + 2)] for p in range(P)]
        turned[k] = J(Y)  # J is linear: the turns of differences are differences of turns
        JY = turned[k] if faces is None else turned[k][faces]
        JR = JY - JV
        normal_residual = float(np.sum(JR * JR))
        G = np.array([normal_residual - t + 2 * rho2 * float(np.sum(a * (X - Y))) / delta
                      for a, t, X in zip(lifted, noise_term, probed)]) / m
        est[k] = (G, runs.sure(Y, probed))
        ends[k] = Y
    del block, spare
    G0, S0 = est[0]
    # SURE's n rho^2 with rho off by NOISE_LEVEL_SLACK: where two_stage leaves a small part of the noise (a sphere at
    # 0.5 edge lengths: SURE 0.0995 for a true 0.0383, rho estimated 0.6 % low), a ratio to SURE reads losses too small
    slack = 2 * NOISE_LEVEL_SLACK * runs.count * runs.rho**2
    # the noise's direction, as the probes take it (b_p = z_p N): the realization's spread below is along it
    normals = runs.normals
    cands = []
    for k, (G, S) in est.items():
        d = G - G0
        # each paired difference is off by the noise realization's own term, which the probes do not see: for S,
        # -2 (f_k - f_0)^T E, for G, -2 (J^T J (f_k - f_0))^T E / m; their standard deviations for noise along the
        # normals (independent: under correlated noise the steps' change is high-pass, where the noise is weaker)
        along = runs.part(np.einsum("ij,ij->i", ends[k] - ends[0], normals))
        spread_s = 2 * runs.rho * math.sqrt(float(np.sum(along * along)))
        turn_change = turned[k] - turned[0]
        adj = J.adjoint(turn_change if faces is None else turn_change * faces[:, None], n)
        along = runs.part(np.einsum("ij,ij->i", adj, normals))
        spread_g = 2 * runs.rho * math.sqrt(float(np.sum(along * along))) / m
        se = math.hypot(float(np.std(d, ddof=1)) / math.sqrt(d.size), spread_g)
        gain = float(d.mean()) + 2 * se  # an upper bound on the change
        loss = 0.0 if k == 0 else _loss_db(S, S0, realization=spread_s, slack=slack)
        cands.append(PostCandidate(1.0, k, float(np.mean(G)), float(np.mean(S)), loss,
                                   k == 0 or (loss < max_loss_db and gain < 0)))
    best = min((p for p in cands if p.allowed), key=lambda p: (p.normal_risk, p.steps))
    if best.steps == 0:
        why = ("Taubin steps after two_stage: none (no count has a significantly smaller normal-domain risk with SURE "
               f"on positions losing less than {max_loss_db:g} dB)")
    else:
        why = (f"{best.steps} Taubin steps after two_stage: the least normal-domain risk allowed (Stein, face normals' "
               f"squared turn: {best.normal_risk - float(np.mean(G0)):+.3g} rad^2 per face against none, two standard "
               f"errors below 0; SURE on positions loses at most {max(best.loss_db, 0):.2g} dB, under {max_loss_db:g}); "
               "no sharp features to round")
    return PostStep(1.0, best.steps, tuple(cands), why)


def _rows(rows: np.ndarray | None, n: int, who: str) -> np.ndarray | None:
    """``rows`` checked as a boolean mask of ``n`` vertices (None: all)."""
    if rows is None:
        return None
    rows = np.asarray(rows)
    if rows.dtype != bool or rows.shape != (n,):
        raise ValueError(f"{who}: rows must be a boolean mask of shape ({n},), got {rows.dtype} {rows.shape}")
    return rows


def core_run(spec: FilterSpec, V: np.ndarray, ops: Operators, values: dict) -> np.ndarray:
    """``spec.public((V, ops.F), operators=ops, **values)[0]`` (no pinned vertices, region or volume), without its copies.

    The public adapter copies ``V`` (n, 3) and ``F`` (m, 3) on every call (``read_mesh``) and
    checks ``ops`` against ``F``; :func:`feature_risk` runs a filter ``1 + probes`` times on one
    topology, so it calls the array core the same way here: the same scaling by a power of two
    for scale-free filters, the same result bit for bit (tests/test_memory_default.py), 30 to 40
    bytes per vertex less at the peak.

    Parameters
    ----------
    spec : FilterSpec
    V : ndarray, shape (n, 3), float64
    ops : Operators
        The topology's operators (``ops.F`` is the faces).
    values : dict
        The filter's parameters, resolved (``spec.resolve``).

    Returns
    -------
    ndarray, shape (n, 3)
    """
    out = run_core(spec, V, ops, values)
    if not np.isfinite(out).all():
        raise ParameterError(f"filter '{spec.name}' produced non-finite coordinates (overflow: a parameter is too "
                             "large or too small for this mesh)")
    return out


@dataclass(frozen=True)
class PostCandidate:
    """One candidate of :func:`choose_post_step` and its estimates (means over the probes).

    Attributes
    ----------
    scale : float
        The multiple of the smooth prior's ``mu``.
    steps : int
        Taubin steps after it.
    normal_risk : float
        Estimated mean squared turn of the face normals from the clean ones (rad^2, per face).
    sure : float
        Monte-Carlo SURE on positions (squared error, mesh units^2, summed over vertices).
    loss_db : float
        Estimated SNR loss against the smooth prior as chosen (``scale`` 1, no step), dB, from
        the paired difference plus two standard errors (positive: a loss).
    allowed : bool
        Whether ``loss_db`` is below :data:`POST_MAX_LOSS_DB`.
    """

    scale: float
    steps: int
    normal_risk: float
    sure: float
    loss_db: float
    allowed: bool


@dataclass(frozen=True)
class PostStep:
    """What :func:`choose_post_step` chose: ``mu`` times ``scale``, then ``steps`` Taubin steps.

    Attributes
    ----------
    scale : float
    steps : int
    candidates : tuple of PostCandidate
    reason : str
        One sentence saying why.
    """

    scale: float
    steps: int
    candidates: tuple
    reason: str


def post_step_estimates(V: np.ndarray, F: np.ndarray, method: str, params: dict, model: NoiseModel, *,
                        ops: Operators | None = None, normals: np.ndarray | None = None, scales: tuple = POST_SCALES,
                        steps: tuple = POST_STEPS, probes: int | None = None, seed: int = 0,
                        rows: np.ndarray | None = None) -> dict[tuple[float, int], tuple[np.ndarray, np.ndarray]]:
    """Per-probe normal-domain risk and position SURE of the smooth prior with ``mu`` scaled, then Taubin steps.

    For each candidate :math:`f` (``method`` with ``mu`` times a scale, then ``k`` Taubin steps
    :data:`POST_TAUBIN`) and each probe :math:`b_p = z_p N` (Rademacher :math:`z_p`, coloured like
    the noise when it is correlated, as in :func:`feature_risk`; :math:`N` the unit vertex normals of
    the prior's own result :math:`R`), with :math:`\\Delta_p = (f(X + \\delta b_p) - f(X)) / \\delta`
    (:math:`\\delta` = :func:`~meshdenoise.tuning.risk.mc_sure_step`):

    - on positions, Monte-Carlo SURE
      :math:`S_p = \\|f(X) - X\\|^2 - n\\rho^2 + 2\\rho^2\\, b_p^T \\Delta_p`;
    - on normals, the same Stein identity for the quadratic form :math:`W = J^T J` of the
      face normals' derivative at :math:`R` (:class:`NormalJacobian`),

      .. math:: G_p = \\frac1m\\Big(\\|J(f(X) - X)\\|^2 - \\rho^2 \\|J b_p\\|^2 + 2\\rho^2 (J b_p)^T (J \\Delta_p)\\Big),

      unbiased for :math:`\\frac1m \\mathbb E\\|J(f(X) - X^0)\\|^2`, to first order the mean
      squared angle between the result's and the clean face normals (the benchmark's target
      is their mean angle). Its noise term :math:`\\rho^2\\|J b_p\\|^2` is the same for every
      candidate: paired differences do not see it.

    Every candidate uses the same probes (paired differences). Cost: ``len(scales)`` x
    (probes + 1) runs of ``method`` (one factorisation per scale for ``sobolev_bilaplacian``)
    and cheap Taubin steps. With ``rows`` the sums run over those vertices and the faces whose
    three corners are among them (a :class:`RiskRegion`'s scored part); :math:`n` and :math:`m`
    are then their counts.

    Parameters
    ----------
    V : ndarray, shape (n, 3)
        The noisy vertices.
    F : ndarray, shape (m, 3)
    method : str
        The smooth prior (a filter with a ``mu`` parameter).
    params : dict
        Its parameters as chosen by its rule.
    model : NoiseModel
        The noise level and correlation (rho > 0).
    ops : Operators, optional
    normals : ndarray, shape (n, 3), optional
        Unit probe directions: the noise's direction. Default: the vertex normals of the
        prior's result; the default passes those of ``sobolev_bilaplacian``'s result, an
        estimate independent of ``sobolev_normal``'s own errors (see :func:`feature_risk`).
    scales : tuple of float
    steps : tuple of int
    probes : int, optional
        By default ``POST_PROBE_RUNS`` divided by the vertices scored, within :data:`POST_PROBES`.
    seed : int
    rows : ndarray of bool, shape (n,), optional
        The vertices scored (default: all).

    Returns
    -------
    dict
        ``(scale, steps)`` -> (``G`` (P,), ``S`` (P,)).
    """
    n = V.shape[0]
    ops = ops if ops is not None else get_operators(F, n)
    keep = _rows(rows, n, "post_step_estimates")
    count = n if keep is None else int(np.count_nonzero(keep))
    if probes is None:
        probes = int(np.clip(math.ceil(POST_PROBE_RUNS / max(count, 1)), *POST_PROBES))
    part = (lambda A: A) if keep is None else (lambda A: A[keep])  # noqa: E731
    faces = None if keep is None else keep[np.asarray(F)].all(axis=1)
    turn = (lambda D: J(D)) if faces is None else (lambda D: J(D)[faces])  # noqa: E731
    spec, taubin = get_filter(method), get_filter("taubin")
    prior = lambda X, c: np.asarray(spec.public((X, F), operators=ops, **{**params, "mu": params["mu"] * c})[0])  # noqa: E731
    rho = float(model.rho)
    delta = mc_sure_step(rho, model.correlated)
    base = prior(V, 1.0)
    normals = vertex_normals(base, F) if normals is None else normals
    J = NormalJacobian(base, F)
    m = max(F.shape[0] if faces is None else int(np.count_nonzero(faces)), 1)
    Z = np.random.default_rng(seed).choice([-1.0, 1.0], size=(probes, n)).T
    if model.correlated:
        Z = model.colour(Z, 1.0 / probes)
    B = [Z[:, p, None] * normals for p in range(probes)]
    JB = [turn(b) for b in B]
    noise_term = np.array([rho**2 * float(np.sum(jb * jb)) for jb in JB])
    out = {}
    for c in scales:
        runs = [base if c == 1.0 else prior(V, c)] + [prior(V + delta * b, c) for b in B]
        done = 0
        for k in sorted(steps):
            if k > done:  # Taubin is run on from the previous count
                runs = [np.asarray(taubin.public((X, F), operators=ops, iterations=k - done, **POST_TAUBIN)[0]) for X in runs]
                done = k
            Y, D = runs[0], [(X - runs[0]) / delta for X in runs[1:]]
            residual = float(np.sum(part(Y - V) ** 2))
            JR = turn(Y - V)
            normal_residual = float(np.sum(JR * JR))
            S = np.array([residual - count * rho**2 + 2 * rho**2 * float(np.sum(part(b) * part(d))) for b, d in zip(B, D)])
            G = np.array([normal_residual - t + 2 * rho**2 * float(np.sum(jb * turn(d))) for jb, t, d in zip(JB, noise_term, D)]) / m
            out[(float(c), int(k))] = (G, S)
    return out


def normal_error_share(R: np.ndarray, F: np.ndarray, smooth_params: dict, rho: float, *, ops: Operators | None = None,
                       copies: int = SMALL_COPIES, seed: int = 0) -> np.ndarray:
    """Per vertex, the mean :math:`\\sin^2` of the angle between :data:`SMOOTH_METHOD`'s vertex normals and the noise's direction, read on synthetic copies.

    The probes of the post-step's Monte-Carlo SURE follow the vertex normals of
    :data:`SMOOTH_METHOD`'s result, an estimate of the noise's direction (the clean normals).
    How far off it is, is read where the truth is known: on ``copies`` synthetic copies
    :math:`Y_s = R + \\rho\\, \\varepsilon_s N(R)` of a smooth result ``R`` (Gaussian
    :math:`\\varepsilon_s` per vertex, :math:`N(R)` its unit vertex normals), each smoothed by
    :data:`SMOOTH_METHOD` with ``smooth_params``:

    .. math:: \\beta_i = \\frac1S \\sum_s \\big(1 - (N_i(f(Y_s)) \\cdot N_i(R))^2\\big).

    Measured on 47 small noisy meshes (docs/peers.md, "Small meshes"): the mean of
    :math:`\\beta` within 25 % of the same mean against the clean normals (the Nefertiti at
    rho 0.2: 0.062-0.076 against 0.055-0.085).

    Parameters
    ----------
    R : ndarray, shape (n, 3)
        The copies' clean surface (the smooth prior's result).
    F : ndarray, shape (m, 3)
    smooth_params : dict
        :data:`SMOOTH_METHOD`'s parameters (as chosen on the noisy mesh).
    rho : float
        The noise level.
    ops : Operators, optional
    copies : int
    seed : int

    Returns
    -------
    ndarray, shape (n,)
        In [0, 1].
    """
    R = np.asarray(R, dtype=np.float64)
    n = R.shape[0]
    if int(copies) < 1:
        raise ValueError(f"normal_error_share: copies must be at least 1, got {copies!r}")
    ops = ops if ops is not None else get_operators(F, n)
    spec = get_filter(SMOOTH_METHOD)
    NR = vertex_normals(R, F)
    rng = np.random.default_rng(seed)
    share = np.zeros(n)
    for _ in range(int(copies)):
        Ys = R + float(rho) * rng.standard_normal(n)[:, None] * NR
        N = vertex_normals(np.asarray(spec.public((Ys, F), operators=ops, **smooth_params)[0]), F)
        share += 1.0 - np.einsum("ij,ij->i", N, NR) ** 2
    return np.clip(share / int(copies), 0.0, 1.0)


def tilted_directions(N: np.ndarray, share: np.ndarray | float, rng: np.random.Generator) -> np.ndarray:
    """Unit directions :math:`\\sqrt{1 - \\beta_i}\\, N_i + \\sqrt{\\beta_i}\\, T_i`, with :math:`T_i \\perp N_i` uniform on the tangent circle.

    A probe :math:`b_i = z_i D_i` (Rademacher :math:`z_i`) has covariance
    :math:`(1 - \\beta_i) N_i N_i^T + \\tfrac{\\beta_i}{2}(I - N_i N_i^T)`: that of noise along a
    unit normal at angle :math:`\\arcsin\\sqrt{\\beta_i}` from :math:`N_i` in a random direction.

    Parameters
    ----------
    N : ndarray, shape (n, 3)
        Unit normals.
    share : float or ndarray, shape (n,)
        :math:`\\beta_i` in [0, 1].
    rng : numpy.random.Generator

    Returns
    -------
    ndarray, shape (n, 3)
    """
    N = np.asarray(N, dtype=np.float64)
    beta = np.broadcast_to(np.asarray(share, dtype=np.float64), N.shape[:1])
    if not np.all((beta >= 0) & (beta <= 1)):
        raise ValueError(f"tilted_directions: share must be within [0, 1], got {beta.min():g} to {beta.max():g}")
    T = rng.standard_normal(N.shape)
    T -= N * np.einsum("ij,ij->i", T, N)[:, None]
    length = np.linalg.norm(T, axis=1)
    T = np.divide(T, length[:, None], out=np.zeros_like(T), where=length[:, None] > 0)
    return np.sqrt(1.0 - beta)[:, None] * N + np.sqrt(beta)[:, None] * T


def taubin_passes(ops: Operators, pinned: np.ndarray | None = None) -> tuple:
    """The two passes of a :data:`POST_TAUBIN` step as matrices, ``(1 - f) I + f D^{-1} W`` (n, n) CSR for f = lam, mu.

    The filter's own matrices (:func:`meshdenoise.plugins.taubin.pass_matrix`): ``taubin`` with
    uniform weights applies them in turn per iteration; here they apply to many columns at once.
    ``pinned`` (bool, shape (n,)): identity rows there, as the filter with those vertices pinned.
    """
    from .plugins.taubin import pass_matrix

    return tuple(pass_matrix(ops.P, f, pinned) for f in (POST_TAUBIN["lam"], POST_TAUBIN["mu"]))


def small_post_runs(inputs: list, F: np.ndarray, method: str, params: dict, *, ops: Operators,
                    steps: tuple = SMALL_POST_STEPS, boundary_motion: str = "free") -> list[dict[tuple[float, int], np.ndarray]]:
    """Every candidate of the small-mesh post-step run on each input, as ``denoise`` runs it.

    A candidate is ``method`` with ``mu`` times a scale of :data:`POST_SCALES`, then a count of
    ``steps`` Taubin steps :data:`POST_TAUBIN`. With ``boundary_motion="normal"`` both the prior and
    the steps move open borders along their normals only, as ``denoise`` and
    :func:`run_post_step` do (:func:`meshdenoise.registry.boundary_along_normals`: the free run,
    each border vertex moved along the free result's vertex normal by its move's normal part, then
    the run again with the border held there); ``"free"``: the filters as they are. The prior
    runs scale by scale over all inputs, so that one factorisation of each scale's system (and of
    its border-held system) serves them all; the Taubin steps (:func:`taubin_passes`) and the
    border's vertex normals of all inputs and scales run at once, as blocks of columns.

    Parameters
    ----------
    inputs : list of ndarray, shape (n, 3)
        Noisy vertex positions (the mesh, its probes, its recorrupted copies).
    F : ndarray, shape (m, 3)
    method : str
        The smooth prior (a filter with a ``mu`` parameter).
    params : dict
        Its parameters as chosen (``mu`` is scaled).
    ops : Operators
    steps : tuple of int
    boundary_motion : {"free", "normal"}

    Returns
    -------
    list of dict
        One per input: ``(scale, steps)`` -> ndarray (n, 3).
    """
    if boundary_motion not in ("free", "normal"):
        raise ValueError(f"small_post_runs: boundary_motion must be 'free' or 'normal', got {boundary_motion!r}")
    spec = get_filter(method)
    # the prior's array core with resolved parameters (the public filter's result bit for bit, without its copies)
    priors = {float(c): spec.resolve({**params, "mu": params["mu"] * c}) for c in POST_SCALES}
    counts = sorted(set(int(k) for k in steps))
    border = ops.boundary_vertices if boundary_motion == "normal" else None
    if border is not None and not border.any():
        border = None
    passes = taubin_passes(ops)
    held_passes = taubin_passes(ops, border) if border is not None else None
    n = ops.n
    if border is not None:  # the faces around the border and their incidence: the border's vertex normals
        rim = np.asarray(F)[border[np.asarray(F)].any(axis=1)]
        around = vertex_face_incidence(rim, n)[border]

    def prior_run(X: np.ndarray, values: dict) -> np.ndarray:
        if border is None:
            return core_run(spec, X, ops, values)
        out = run_core(spec, X, ops, values, boundary_motion="normal")
        if not np.isfinite(out).all():
            raise ParameterError(f"filter '{spec.name}' produced non-finite coordinates (overflow: a parameter is too "
                                 "large or too small for this mesh)")
        return out

    def border_normals(block: np.ndarray) -> np.ndarray:
        """:func:`vertex_normals` at the border of each vertex triple (columns 3j..3j+2) of ``block`` (n, 3K): (nb, K, 3)."""
        X = block.reshape(n, -1, 3)
        P0 = X[rim[:, 0]]
        c = np.cross(X[rim[:, 1]] - P0, X[rim[:, 2]] - P0)
        length = np.linalg.norm(c, axis=2, keepdims=True)
        u = np.divide(c, length, out=np.zeros_like(c), where=length > 0)
        total = (around @ u.reshape(len(rim), -1)).reshape(int(np.count_nonzero(border)), -1, 3)
        length = np.linalg.norm(total, axis=2, keepdims=True)
        return np.divide(total, length, out=np.zeros_like(total), where=length > 0)

    # scale by scale over all inputs: one factorisation of each scale's systems serves them all (the border's held
    # system is a second one: cycling through six would miss the solver cache's four every time)
    Ys = [[prior_run(np.asarray(X, dtype=np.float64), values) for X in inputs] for values in priors.values()]
    scales, count = list(priors), len(inputs)
    # then the Taubin steps of every input and scale at once: triple q * len(scales) + i is input q at scale i
    start = np.hstack([Ys[i][q] for q in range(count) for i in range(len(scales))])
    block, done, out = start, 0, [{} for _ in range(count)]
    for k in counts:
        for _ in range(k - done):  # run on from the previous count
            for M in passes:
                block = M @ block
        done = max(done, k)
        result = block
        if k and border is not None:  # as denoise runs them: borders along the free run's normals, then held
            N = border_normals(block)
            at = start[border].reshape(N.shape)
            result = start.copy()
            result[border] = (at + np.einsum("ijk,ijk->ij", block[border].reshape(N.shape) - at, N)[..., None]
                              * N).reshape(N.shape[0], -1)
            for _ in range(k):
                for M in held_passes:
                    result = M @ result
        for q in range(count):
            for i, c in enumerate(scales):
                j = q * len(scales) + i
                out[q][(c, k)] = Ys[i][q] if k == 0 else result[:, 3 * j:3 * j + 3]
    return out


def small_post_estimates(V: np.ndarray, F: np.ndarray, method: str, params: dict, model: NoiseModel, *,
                         ops: Operators | None = None, normals: np.ndarray, share: np.ndarray,
                         probes: int = SMALL_PROBES, draws: int = SMALL_DRAWS, a: float = SMALL_RECORRUPTION,
                         seed: int = 0, steps: tuple = SMALL_POST_STEPS,
                         boundary_motion: str = "free") -> dict[tuple[float, int], tuple[np.ndarray, float, np.ndarray]]:
    """The post-step's estimates on a small mesh: tilted Monte-Carlo SURE, its realization spread, recorrupted normal scores.

    For each candidate :math:`f` (``method`` with ``mu`` times a scale of :data:`POST_SCALES`,
    then a count of ``steps`` Taubin steps :data:`POST_TAUBIN`, run by :func:`small_post_runs`
    with ``boundary_motion``; :math:`f_0` the prior as chosen):

    - **positions**: Monte-Carlo SURE :math:`S_p = \\|f(X) - X\\|^2 - n\\rho^2 + 2\\rho^2 b_p^T
      (f(X + \\delta b_p) - f(X)) / \\delta` with probes :math:`b_p = z_p D_p` along
      :func:`tilted_directions` of ``normals`` by ``share`` (the probes' covariance is the
      noise's if the clean normals lie at that angle from ``normals`` in a random direction:
      probes along ``normals`` alone miss the noise ``sobolev_normal`` keeps tangential to its
      own normals, and read the Taubin steps' gain on the Nefertiti as a loss of 1.6 dB);
    - **the realization's spread** of a paired difference :math:`S(f) - S(f_0)`: its error
      :math:`-2 (f(X) - f_0(X))^T E` has standard deviation
      :math:`2\\rho \\|((f(X) - f_0(X)) \\cdot N_i)_i\\|` for noise :math:`E` along the normals
      (the probes' standard error does not see it: on the 800-vertex torus at 0.7 edge lengths it
      is 10 times larger);
    - **face normals**: recorrupted pairs :math:`Y^\\pm` (:mod:`~meshdenoise.tuning.recorrupted`,
      :math:`Z = \\rho\\, \\varepsilon N` along ``normals``), the score
      :math:`-\\frac{1}{m \\bar c} \\sum_f u_f(f(Y^+)) \\cdot c_f(Y^-)`, :math:`\\bar c` the mean
      cross-normal length of :math:`f_0(X)`: an estimate, unbiased when the recorruption follows the
      noise, of the area-weighted mean of :math:`-\\cos\\theta_f` (:math:`\\theta_f` the angle to the
      clean face normal) at the level :math:`\\sqrt{1 + a^2}\\, \\rho`.

    All candidates use the same probes and pairs (paired differences). Cost: ``len(POST_SCALES)``
    x (1 + ``probes`` + ``draws``) runs of ``method`` and their Taubin steps.

    Parameters
    ----------
    V : ndarray, shape (n, 3)
        The noisy vertices.
    F : ndarray, shape (m, 3)
    method : str
        The smooth prior (a filter with a ``mu`` parameter).
    params : dict
        Its parameters as chosen by its rule.
    model : NoiseModel
        Independent noise, rho > 0.
    ops : Operators, optional
    normals : ndarray, shape (n, 3)
        Unit vertex normals of :data:`SMOOTH_METHOD`'s result.
    share : ndarray, shape (n,)
        :func:`normal_error_share`.
    probes, draws : int
    a : float
        The recorruption's strength.
    seed : int
    steps : tuple of int
        The Taubin step counts (0 among them).
    boundary_motion : {"free", "normal"}
        How the candidates move open borders: as ``denoise`` will (:func:`choose_default` passes
        its own). With free borders, Taubin steps pull open borders inward, a loss ``denoise``
        does not have: on the Nefertiti at rho 0.2 (seed 0) 8 steps after ``mu`` as chosen lose
        0.55 dB with free borders and gain 0.13 dB with borders along their normals.

    Returns
    -------
    dict
        ``(scale, steps)`` -> (``S`` (probes,), realization standard deviation of ``S - S(f_0)``,
        normal scores (draws,)).
    """
    V = np.asarray(V, dtype=np.float64)
    n, m = V.shape[0], F.shape[0]
    ops = ops if ops is not None else get_operators(F, n)
    if boundary_motion not in ("free", "normal"):
        raise ValueError(f"small_post_estimates: boundary_motion must be 'free' or 'normal', got {boundary_motion!r}")
    if 0 not in steps:
        raise ValueError(f"small_post_estimates: steps must include 0 (the prior as chosen, f_0), got {steps!r}")
    run = lambda inputs: small_post_runs(inputs, F, method, params, ops=ops, steps=steps,  # noqa: E731
                                         boundary_motion=boundary_motion)
    rho = float(model.rho)
    delta = mc_sure_step(rho, False)
    rng = np.random.default_rng(seed)
    B = []
    for _ in range(int(probes)):
        B.append(rng.choice([-1.0, 1.0], size=n)[:, None] * tilted_directions(normals, share, rng))
    # the recorrupted pairs as recorrupted_scores draws them (tuning/recorrupted.py), run in the same batch
    pair_rng = np.random.default_rng(seed + 1)
    pairs = [recorrupt(V, rho * pair_rng.standard_normal(n)[:, None] * normals, a) for _ in range(int(draws))]
    done = run([V] + [V + delta * b for b in B] + [plus for plus, _ in pairs])
    base, moved_all, paired = done[0], done[1:1 + len(B)], done[1 + len(B):]
    keys = list(base)
    residual = {key: float(np.sum((X - V) ** 2)) for key, X in base.items()}
    S = np.empty((int(probes), len(keys)))
    for p, (b, moved) in enumerate(zip(B, moved_all)):
        for j, key in enumerate(keys):
            S[p, j] = residual[key] - n * rho**2 + 2 * rho**2 * float(np.sum(b * (moved[key] - base[key]))) / delta
    f0 = base[(1.0, 0)]
    spread = {key: 2 * rho * float(np.linalg.norm(np.einsum("ij,ij->i", X - f0, normals))) for key, X in base.items()}
    c_mean = float(np.mean(np.linalg.norm(cross_normals(f0, F), axis=1)))
    w = np.full(m, 1.0 / (m * c_mean)) if c_mean > 0 else np.zeros(m)
    scores = np.empty((len(pairs), len(keys)))
    for d, ((_, minus), out) in enumerate(zip(pairs, paired)):
        target = cross_normals(minus, F)
        for j, key in enumerate(keys):
            scores[d, j] = normal_score(out[key], F, target, weights=w)
    return {key: (S[:, j], spread[key], scores[:, j]) for j, key in enumerate(keys)}


def _small_post_step(V: np.ndarray, F: np.ndarray, method: str, params: dict, model: NoiseModel, *, ops: Operators,
                     normals: np.ndarray, smooth_params: dict, base: np.ndarray, seed: int,
                     max_loss_db: float, boundary_motion: str = "free") -> PostStep | None:
    """:func:`choose_post_step` on a small mesh whose probe normals are far off (None below :data:`SMALL_TILT_FROM`)."""
    share = normal_error_share(base, F, smooth_params, float(model.rho), ops=ops, seed=seed)
    mean_share = float(np.mean(share))
    if mean_share < SMALL_TILT_FROM:
        return None
    est = small_post_estimates(V, F, method, params, model, ops=ops, normals=normals, share=share, seed=seed,
                               steps=SMALL_POST_STEPS, boundary_motion=boundary_motion)
    S0 = est[(1.0, 0)][0]
    R0 = 2.0 * (1.0 + float(np.mean(est[(1.0, 0)][2])))
    cands = []
    for (c, k), (S, spread, scores) in est.items():
        loss = 0.0 if (c, k) == (1.0, 0) else _loss_db(S, S0, spread)
        cands.append(PostCandidate(c, k, 2.0 * (1.0 + float(np.mean(scores))), float(np.mean(S)), loss,
                                   loss < max_loss_db))
    best = min((p for p in cands if p.allowed), key=lambda p: (p.normal_risk, p.scale, p.steps))
    said = lambda p: f"mu x {p.scale:g}, {p.steps} Taubin steps"  # noqa: E731
    held = " run with open borders along their normals" if boundary_motion == "normal" and ops.boundary_vertices.any() else ""
    where = (f"smooth-prior post-step (small mesh: the probe normals' error is large, mean sin^2 {mean_share:.3f} on "
             f"synthetic copies, from {SMALL_TILT_FROM:g}: tilted probes, recorrupted pairs{held})")
    if (best.scale, best.steps) == (1.0, 0):
        why = f"{where}: none (mu as SURE chose it): no candidate allowed has a smaller recorrupted normal risk"
    else:
        why = (f"{where}: {said(best)}: the least recorrupted normal risk allowed ({best.normal_risk - R0:+.3g} "
               f"against mu as chosen, 2(1 - cos) per face; SURE on positions with tilted probes loses at most "
               f"{max(best.loss_db, 0):.2g} dB, two standard errors with the realization's, under {max_loss_db:g})")
    return PostStep(best.scale, best.steps, tuple(cands), why)


def _loss_db(S: np.ndarray, S0: np.ndarray, realization: float = 0.0, slack: float = 0.0) -> float:
    """The SNR loss (dB) of SURE ``S`` against ``S0`` (paired probes): 10 log10 of their ratio, two standard errors up.

    ``realization``: a standard deviation of the paired difference over noise realizations (mesh
    units^2), combined with the probes' standard error (:func:`small_post_estimates`); 0 (the
    default): the probes' only. ``slack``: taken off ``S0``'s mean before the ratio, the part of it
    that is not known (mesh units^2; :func:`feature_post_step`: what the noise level's own error
    makes of SURE's :math:`n\\rho^2`), so that a small error is not read larger than it may be.
    """
    d = np.asarray(S, dtype=np.float64) - np.asarray(S0, dtype=np.float64)
    se = float(np.std(d, ddof=1)) / math.sqrt(d.size) if d.size > 1 else 0.0
    if realization:
        se = math.hypot(se, float(realization))
    base = float(np.mean(S0)) - float(slack)
    if base <= 0:  # SURE of the prior below its own scatter: no loss can be measured against it
        return 0.0 if float(d.mean()) + 2 * se <= 0 else math.inf
    return 10.0 * math.log10(max(1.0 + (float(d.mean()) + 2 * se) / base, 1e-12))


def choose_post_step(V: np.ndarray, F: np.ndarray, method: str, params: dict, model: NoiseModel, *,
                     ops: Operators | None = None, normals: np.ndarray | None = None, probes: int | None = None,
                     seed: int = 0, max_loss_db: float = POST_MAX_LOSS_DB, rows: np.ndarray | None = None,
                     smooth_params: dict | None = None, boundary_motion: str = "free") -> PostStep:
    """After a smooth prior: a multiple of its ``mu`` and a Taubin step count, by a normal-domain risk, guarded by SURE.

    SURE chooses the prior's ``mu`` for positions; face normals ask for a little more
    smoothing (docs/peers.md, "smooth-prior post-step": on the paper's elephant and Nefertiti
    at rho 0.2, ``mu`` x 1.5 then 5 Taubin steps takes the normal error below every peer's).
    Among :data:`POST_SCALES` x :data:`POST_STEPS`, the candidate of least normal-domain risk
    (:func:`post_step_estimates`: Stein's estimate of the squared turn of the face normals)
    is taken among those whose SURE on positions loses less than ``max_loss_db`` against the
    prior as chosen (the paired difference of the probes plus two standard errors, as
    ``two_stage``'s guard tests), so that a mesh whose positions lose more (Bunny0.2: -1.4 dB
    at ``mu`` x 1.5) keeps the prior's choice.

    Above :data:`REGION_FROM` vertices (and no ``rows`` given) it runs on a :class:`RiskRegion`
    (its margin :func:`risk_margin`), in time independent of the mesh's size: the scale and step
    count chosen there are applied to the whole mesh (both are per-vertex smoothing strengths of
    a filter whose weights depend on the graph only).

    Parameters
    ----------
    V, F, method, params, model, ops, normals, probes, seed, rows
        As :func:`post_step_estimates`.
    max_loss_db : float
        The SNR loss allowed (dB).
    smooth_params : dict, optional
        :data:`SMOOTH_METHOD`'s parameters, whose result's vertex normals are ``normals``
        (:func:`choose_default` passes them on meshes of at most :data:`SMALL_MESH` vertices).
        Given, with ``normals``, no ``rows`` and at most :data:`SMALL_MESH` vertices: when the
        probe normals' error (:func:`normal_error_share`, mean over vertices) is at least
        :data:`SMALL_TILT_FROM`, the candidates (:data:`POST_SCALES` x :data:`SMALL_POST_STEPS`)
        are scored by :func:`small_post_estimates` instead: the guard is SURE with tilted probes,
        two standard errors that include the noise realization's, and the criterion the
        recorrupted pairs' normal score (docs/peers.md, "Small meshes" and "Small meshes, session
        14": on the Nefertiti at rho 0.2, noise seeds 0-9, 0.95 to 2.9 degrees better than without;
        47 rows of small meshes: no SNR loss over 0.23 dB against it). Below that share, or without
        it, the rule above, bit for bit.
    boundary_motion : {"free", "normal"}
        How the run that follows moves open borders (``denoise``'s option, which
        :func:`choose_default` passes on): the small-mesh estimates run their candidates the same
        way (:func:`small_post_runs`). The rule of large meshes runs them free.

    Returns
    -------
    PostStep
        ``scale`` 1 and no step when the noise is 0 or correlated (``model.correlated``: measured, the
        estimates allowed mu x 2 on the elephant with scanner noise of 1.5 mean edge lengths correlated
        over 2, which lost 1.07 dB for no normal gain, and mu x 1.5 on pymeshlab's bunny, -0.64 dB and
        0.2 degrees worse), when the prior as chosen moves the vertices by
        less than :data:`NOT_SMOOTHING` mean edge lengths (rms: the default then says it does not
        smooth; measured, the clean Bunny0.2 read as detail would otherwise move 0.0078 h instead of
        0.0041), or when no other candidate is allowed.
    """
    if "mu" not in params:
        raise ValueError(f"choose_post_step: {method}'s parameters {sorted(params)} have no 'mu' to scale")
    if not float(model.rho) > 0 or not float(params["mu"]) > 0:
        return PostStep(1.0, 0, (), "no noise to remove: the smooth prior as chosen")
    if model.correlated:  # measured: it lost 0.6-1.1 dB with no normal gain (docs/peers.md, "Smooth-prior post-step")
        return PostStep(1.0, 0, (), "smooth-prior post-step: none under correlated noise (its estimates, measured, "
                                    "allowed a loss of up to 1.1 dB there with no gain in normal error)")
    ops = ops if ops is not None else get_operators(F, V.shape[0])
    if rows is None and V.shape[0] > REGION_FROM:  # 3 x (probes + 1) runs of the prior: on a region of fixed size
        region = RiskRegion.cut(np.asarray(V, dtype=np.float64), F, ops, risk_margin(float(params["mu"])), seed=seed)
        return choose_post_step(region.V, region.F, method, params, region.noise_model(model), ops=region.ops,
                                normals=None if normals is None else np.asarray(normals)[region.vertices],
                                probes=probes, seed=seed, max_loss_db=max_loss_db, rows=region.rows)
    keep = _rows(rows, V.shape[0], "choose_post_step")
    h = mean_edge_length(V, ops)
    base = np.asarray(get_filter(method).public((V, F), operators=ops, **params)[0])
    moved = np.sum((base - V) ** 2, axis=1)
    move = float(np.sqrt(np.mean(moved if keep is None else moved[keep]))) / h if h > 0 else 0.0
    if move < NOT_SMOOTHING:  # a clean mesh (or detail read as such): what the prior leaves is left alone
        return PostStep(1.0, 0, (), f"smooth-prior post-step: none: the prior as chosen moves the vertices by {move:.2g} "
                                    f"mean edge lengths (rms), under {NOT_SMOOTHING:g}: nothing to smooth further")
    del moved
    if smooth_params is not None and normals is not None and keep is None and V.shape[0] <= SMALL_MESH:
        small = _small_post_step(V, F, method, params, model, ops=ops, normals=np.asarray(normals, dtype=np.float64),
                                 smooth_params=smooth_params, base=base, seed=seed, max_loss_db=max_loss_db,
                                 boundary_motion=boundary_motion)
        if small is not None:
            return small
    del base
    est = post_step_estimates(V, F, method, params, model, ops=ops, normals=normals, probes=probes, seed=seed,
                              rows=keep)
    S0 = est[(1.0, 0)][1]
    G0 = float(np.mean(est[(1.0, 0)][0]))
    cands = []
    for (c, k), (G, S) in est.items():
        loss = 0.0 if (c, k) == (1.0, 0) else _loss_db(S, S0)
        cands.append(PostCandidate(c, k, float(np.mean(G)), float(np.mean(S)), loss, loss < max_loss_db))
    best = min((p for p in cands if p.allowed), key=lambda p: (p.normal_risk, p.scale, p.steps))
    said = lambda p: f"mu x {p.scale:g}, {p.steps} Taubin steps"  # noqa: E731
    refused = [p for p in cands if not p.allowed and p.normal_risk < best.normal_risk]
    if (best.scale, best.steps) == (1.0, 0):
        why = "smooth-prior post-step: none (mu as SURE chose it): no candidate allowed by SURE has a smaller normal-domain risk"
    else:
        why = (f"smooth-prior post-step: {said(best)}: the least normal-domain risk allowed (Stein, face normals' squared "
               f"turn: {best.normal_risk - G0:+.3g} rad^2 per face against mu as chosen; SURE on positions loses at most "
               f"{max(best.loss_db, 0):.2g} dB, under {max_loss_db:g})")
    if refused:
        worst = min(refused, key=lambda p: p.normal_risk)
        why += f"; {said(worst)} would lose up to {worst.loss_db:.2g} dB"
    return PostStep(best.scale, best.steps, tuple(cands), why)


def _checked_noise(noise: Any) -> float:
    if isinstance(noise, (bool, np.bool_)) or not isinstance(noise, (int, float, np.integer, np.floating)):
        raise TypeError(f"denoise: noise must be a number or a NoiseModel, got {noise!r}")
    if not (math.isfinite(noise) and noise >= 0):
        raise ValueError(f"denoise: parameter 'noise' = {noise!r} is out of range: noise >= 0")
    return float(noise)


def _short(v: Any) -> str:
    return f"{v:.4g}" if isinstance(v, float) else repr(v) if isinstance(v, str) else str(v)


OVERRIDE = ("to set the noise yourself: --noise RHO[h][,L] on the command line (h: in mean edge lengths), "
            "noise=NoiseModel(rho, correlation_length, V, F) in Python")


def noise_policy(band: NoiseModel, verdict: DetailVerdict, h: float, band_reason: str = "") -> tuple[NoiseModel, str, list[str]]:
    """The noise model the default uses, from the fine bands' reading and the detail fit's verdict.

    - the fine bands read independent noise (``band``, :func:`estimate_noise_model`, whose
      significance test rejected a correlation): ``band``, unless the detail fit's own correlation
      test (:attr:`DetailVerdict.correlated`, :func:`~meshdenoise.tuning.detail.correlation_test`)
      finds correlated noise and its verdict is ``"noise"``: then the detail fit's model (noise
      correlated over about one edge length is read as independent by the fine bands, at 0.66 to
      0.7 of its level: icosphere 0.25 h at l = 1 reads 0.164 h, the detail fit 0.233 h at 1.0);
    - they read correlated noise, and the verdict is ``"noise"`` or ``"detail"``: the detail fit's
      model (:attr:`DetailVerdict.model`: its best joint level and correlation length, or
      independent noise at ``estimate_noise``'s level);
    - ``"ambiguous"``: ``band`` with its level clipped into the allowed range
      :attr:`DetailVerdict.rho_range`, at its correlation length, and a caveat saying so and how
      to override it.

    Why (docs/noise-vs-detail.md): the detail fit's model leaves the clean meshes alone, but on the
    real range scan face000 (ambiguous, 0.018 to 0.109 h allowed) its lowest allowed level stops
    cleaning it; the fine bands' reading clipped into the range cleans it for 0.109 h.

    Parameters
    ----------
    band : NoiseModel
        :func:`~meshdenoise.tuning.covariance.estimate_noise_model`'s model.
    verdict : DetailVerdict
        :func:`~meshdenoise.tuning.detail.separate_detail`'s, on the same mesh.
    h : float
        The mean edge length (mesh units).
    band_reason : str
        ``estimate_noise_model``'s reason (``details=True``), said when ``band`` is kept.

    Returns
    -------
    (NoiseModel, str, list of str)
        The model, a reason (starting "the noise is independent" or "the noise is correlated"),
        and caveats (``note:`` lines).
    """
    lo, hi = verdict.rho_range
    e = h if h > 0 else float("nan")
    allowed = f"noise from {lo / e:.3g} to {hi / e:.3g} mean edge lengths is consistent with the band spectrum"

    def said(model: NoiseModel) -> str:
        return (f"the noise is correlated over {model.correlation_length:.3g} edge lengths" if model.correlated else
                "the noise is independent") + f" ({model.rho / e:.3g} mean edge lengths)"

    if not band.correlated:
        why = band_reason.split(": ", 1)[-1] if band_reason else "the fine bands read no correlation"
        if verdict.correlated and verdict.verdict == "noise" and verdict.model.correlated:
            model = verdict.model
            return model, (f"{said(model)}: the fine bands read independent noise ({why}), but the band spectrum "
                           f"is explained better with noise correlated over {model.correlation_length:.3g} edge lengths "
                           f"(relative misfit {verdict.misfit_white:.3g} independent, {verdict.misfit:.3g} correlated): "
                           f"{verdict.reason}"), [
                f"the fine bands alone read independent noise of {band.rho / e:.3g} mean edge lengths; the band "
                f"spectrum reads noise correlated over {model.correlation_length:.3g} edge lengths ({allowed}); "
                f"if the mesh may already be clean, look at the change (meshdenoise render IN OUT); {OVERRIDE} "
                "(docs/noise-vs-detail.md)"]
        return band, f"{said(band)}: {why} (surface detail or noise: {verdict.verdict}; {allowed})", []
    fine = (f"the fine bands read {band.rho / e:.3g} mean edge lengths correlated over "
            f"{band.correlation_length:.3g}")
    if verdict.verdict != "ambiguous":
        model = verdict.model
        caveats = []
        if verdict.verdict == "detail":
            caveats.append(f"{fine}, which the band spectrum explains as surface detail ({allowed}); the default "
                           f"smooths for {model.rho / e:.3g} only. If the mesh is a noisy scan, {OVERRIDE} "
                           "(docs/noise-vs-detail.md)")
        elif model.correlated:
            caveats.append(f"{fine}, more than surface detail continued from the coarse bands explains ({allowed}); "
                           "if the mesh may already be clean, look at the change (meshdenoise render IN OUT) "
                           "(docs/noise-vs-detail.md)")
        return model, f"{said(model)}: {verdict.reason}", caveats
    used = float(np.clip(band.rho, lo, hi))
    model = NoiseModel(used, band.correlation_length, band.V, band.F)
    clipped = "inside that range" if used == band.rho else f"{band.rho / e:.3g} clipped into that range"
    reason = (f"{said(model)}: ambiguous: {fine}; the band spectrum allows both surface detail and noise ({allowed}) "
              f"-> {used / e:.3g} ({clipped})")
    caveat = (f"the fine bands may be surface detail: {allowed}; the default smooths for {used:.4g} "
              f"({used / e:.3g} mean edge lengths) correlated over {band.correlation_length:.3g} edge lengths. If "
              f"the mesh may already be clean, look at the change (meshdenoise render IN OUT); {OVERRIDE}; this "
              f"choice is --noise {used / e:.3g}h,{band.correlation_length:.3g} (docs/noise-vs-detail.md)")
    return model, reason, [caveat]


def default_noise(V: np.ndarray, F: np.ndarray, h: float) -> tuple[NoiseModel, str, list[str], str, tuple[float, float]]:
    """The default's noise model: the fine bands' reading, and the detail fit where it reads correlated noise.

    :func:`estimate_noise_model` (on a sampled region above its ``sample`` vertices) reads the
    level and correlation length; when it reads correlated noise it also returns the band spectrum
    of the same coloured probes and smoothed mesh, which
    :func:`~meshdenoise.tuning.detail.separate_detail` fits (no second smoothing, no second
    colouring), and :func:`noise_policy` decides. When it reads independent noise but its own fit
    had found a correlation length of at least its ``ELL_MIN`` (0.75 edge lengths), which its
    significance test rejected, the detail fit is run as well (with the same smoothed mesh; its
    probes read on a sampled region above the noise model's ``FIT_SAMPLE`` vertices, as the
    noise model reads its own) and its correlation test decides (:func:`noise_policy`); below
    that length nothing more is done (independent noise costs nothing more).

    Parameters
    ----------
    V : ndarray, shape (n, 3)
    F : ndarray, shape (m, 3)
    h : float
        The mean edge length.

    Returns
    -------
    (NoiseModel, str, list of str, str, (float, float))
        The model, the reason, caveats, the verdict (``"independent"`` when the fine bands' reading
        of independent noise is kept; the detail fit's otherwise) and the allowed range of levels
        (NaN when the fine bands' independent reading is kept).
    """
    from .tuning.covariance import ELL_MIN as BAND_ELL_MIN
    from .tuning.covariance import FIT_SAMPLE

    band, info = estimate_noise_model((V, F), details=True, spectrum=(DETAIL_BANDS, DETAIL_LENGTHS))
    nan = (float("nan"), float("nan"))
    if not band.correlated:
        if float(info.get("ell_fit", 0.0)) < BAND_ELL_MIN:  # no correlation length to test: nothing more
            return band, "the noise is " + info["reason"], [], "independent", nan
        verdict = separate_detail((V, F), smooth=info["smooth"], rho_white=info["rho_white"], sample=FIT_SAMPLE)
        model, reason, caveats = noise_policy(band, verdict, h, info.get("reason", ""))
        if model is band:
            return band, "the noise is " + info["reason"], [], "independent", nan
        return model, reason, caveats, verdict.verdict, verdict.rho_range
    verdict = separate_detail((V, F), smooth=info["smooth"], rho_white=info["rho_white"], spectrum=info.get("spectrum"))
    model, reason, caveats = noise_policy(band, verdict, h, info.get("reason", ""))
    return model, reason, caveats, verdict.verdict, verdict.rho_range


def _candidate_rules(mesh: tuple[np.ndarray, np.ndarray], candidates: list[str], model: NoiseModel) -> dict[str, list]:
    """``{method: [params, risk]}``: each candidate's own rule (:func:`choose_parameters` with ``return_risk``).

    Up to :data:`RULES_BESIDE_UP_TO` vertices the smooth prior's rule runs on a worker thread, one kernel
    thread (:func:`~meshdenoise.kernels.start`), beside the others on this one: ``two_stage``'s rule
    leaves a core idle between its stages' runs side by side, and the prior's rule is mostly
    single-threaded sparse solves. Both colour the same probes (``NoiseModel.colour``: computed
    once, the other waits for it); the results are the same bits as one after another. Larger
    meshes (not measured side by side) run the rules one after another, each on every thread,
    their peaks of memory apart.
    """
    def rule(method: str) -> list:
        return list(choose_parameters(mesh, method, noise=model, return_risk=True))

    beside = SMOOTH_METHOD in candidates and len(candidates) > 1 and mesh[0].shape[0] <= RULES_BESIDE_UP_TO
    job = kernels.start(rule, SMOOTH_METHOD) if beside else None
    scored = {m: (None if job is not None and m == SMOOTH_METHOD else rule(m)) for m in candidates}
    if job is not None:
        scored[SMOOTH_METHOD] = job.result()
    return scored


def choose_default(mesh: Any, *, noise: float | NoiseModel | None = None, boundary_motion: str = "normal") -> DefaultChoice:
    """Choose the filter and its parameters for a noisy mesh, and say why.

    Parameters
    ----------
    mesh : (V, F) tuple, pymeshlab.MeshSet or Mesh, or open3d.geometry.TriangleMesh
    noise : float or NoiseModel, optional
        The noise level rho if known (mesh units; independent noise), or a noise model
        (level and correlation length); estimated otherwise.
    boundary_motion : {"normal", "free"}
        How the run will move open borders (only said in the reasons).

    Returns
    -------
    DefaultChoice

    Examples
    --------
    >>> from meshdenoise.shapes import icosphere
    >>> from meshdenoise import add_normal_noise
    >>> V, F = icosphere(3)
    >>> Vn, _ = add_normal_noise((V, F), rho=0.02, seed=0)
    >>> choose_default((Vn, F)).method  # 642 vertices: three candidates; the smallest estimated error
    'sobolev_normal'
    """
    return _choose(mesh, noise, boundary_motion)[0]


def _choose(mesh: Any, noise: float | NoiseModel | None, boundary_motion: str) -> tuple[DefaultChoice, np.ndarray | None]:
    """:func:`choose_default`, and the chosen filter's result on the whole mesh at the chosen parameters, (n, 3) in
    the caller's vertex order, when the choice made it (``two_stage`` scored on the whole mesh: its probes' runs'
    unprobed run) and the border's option leaves it as it is (None otherwise): :func:`denoise` then does not run
    the filter again (the same bits: ``tests/test_default.py``)."""
    start = time.perf_counter()
    data = read_mesh(mesh)
    V, F = data.V, data.F
    relabel = relabelling(F, V.shape[0])  # a large mesh in a cache-hostile order: choose on relabelled vertices
    if relabel is not None:
        V, F_in, F = relabel.vertices(V), F, relabel.faces
    ops = get_operators(F, V.shape[0])
    if relabel is not None:
        F = ops.F  # int64, as read_mesh gives (the relabelling's own faces are int32)
    h = mean_edge_length(V, ops)
    # the feature test needs no noise level: it runs beside the noise estimate, on one kernel thread (the
    # estimate's sparse products take the others); the same result as after it
    feature_job = kernels.start(_feature_test, V, F, ops)
    with stage("estimating the noise"):
        if noise is None:
            model, noise_reason, caveats, decided, rho_range = default_noise(V, F, h)
        else:
            model = noise if isinstance(noise, NoiseModel) else NoiseModel(_checked_noise(noise))
            if relabel is not None:
                model = relabelled_model(model, F_in, relabel)
            noise_reason, caveats = "the noise level was given", []
            decided, rho_range = "given", (float("nan"), float("nan"))
    rho = model.rho
    with stage("looking for sharp features"):
        features = feature_job.result()  # detect_features without its copies of V and F
    n = V.shape[0]

    def rms(risk: float) -> str:  # SURE's estimated squared error as an rms distance in mean edge lengths
        value = math.sqrt(max(risk, 0.0) / max(n, 1)) / h if h > 0 else float("nan")
        # SURE is unbiased, not positive: at or below 0 it says "smaller than its own scatter"
        return "below 0.001" if value < 1e-3 else f"{value:.3g}"

    candidates = [SMOOTH_METHOD] if features.too_noisy else [FEATURE_METHOD, SMOOTH_METHOD]
    if n <= SMALL_MESH:
        candidates.append(SMALL_MESH_METHOD)
    normals = None  # the smooth prior's result's vertex normals, when there are candidates to score
    smooth_params = None  # ... and the smooth prior's parameters that gave them
    region = None  # above REGION_FROM vertices: the estimates below run on a RiskRegion
    feature = None  # two_stage's result and probes' runs (ProbeRuns), kept for the Taubin steps after it
    if len(candidates) == 1:
        method = SMOOTH_METHOD
        params = choose_parameters((V, F), method, noise=model)
        reasons = [f"{features.reason} -> {method}, a smooth prior",
                   f"its parameters minimise {method}'s risk estimate (SURE) for that noise level"]
    else:  # the filter with the smaller estimated error (it picks two_stage on the CAD pairs by 2.5x)
        scored = _candidate_rules((V, F), candidates, model)
        with stage("estimating the candidates' errors"):  # along the smooth prior's normals
            if n > REGION_FROM:  # both candidates by Monte-Carlo SURE on one region, same probes: a paired comparison
                region = RiskRegion.cut(V, F, ops, risk_margin(float(scored[SMOOTH_METHOD][0]["mu"])))
                ops.drop_matrices()  # the whole mesh's vertex matrices: rebuilt if the smooth prior is chosen
                sub = (region.V, region.F)
                smooth = np.asarray(get_filter(SMOOTH_METHOD).public(sub, operators=region.ops,
                                                                     **scored[SMOOTH_METHOD][0])[0])
                normals = vertex_normals(smooth, region.F)
                del smooth
                sub_model = region.noise_model(model)
                for m in candidates:
                    probed = feature_runs(*sub, scored[m][0], sub_model, normals, ops=region.ops, method=m,
                                          rows=region.rows)
                    scored[m][1] = region.scale * float(np.mean(probed.sure()))
                    feature = probed if m == FEATURE_METHOD else feature
                    del probed
            else:  # on the whole mesh
                smooth = np.asarray(get_filter(SMOOTH_METHOD).public((V, F), operators=ops, **scored[SMOOTH_METHOD][0],
                                                                     solver=PRIOR_NORMALS_SOLVER)[0])
                normals = vertex_normals(smooth, F)
                smooth_params = scored[SMOOTH_METHOD][0]
                del smooth
                if all(m in (SMOOTH_METHOD, FEATURE_METHOD) for m in candidates):
                    # two_stage's runs below need its own topology only: the vertex matrices (about 260 bytes per
                    # vertex) are dropped for them, rebuilt if the smooth prior is chosen (issue 17)
                    ops.drop_matrices()
                for m in candidates:
                    if m != SMOOTH_METHOD:  # the smooth prior is linear: its own SURE is exact in expectation
                        probed = feature_runs(V, F, scored[m][0], model, normals, ops=ops, method=m)
                        scored[m][1] = float(np.mean(probed.sure()))
                        feature = probed if m == FEATURE_METHOD else feature
                        del probed
        method = min(scored, key=lambda m: scored[m][1])
        params = scored[method][0]
        others = ", ".join(f"{rms(scored[m][1])} for {m}" for m in candidates if m != method)
        reasons = [features.reason] + ([f"too noisy for normal filtering: the smooth priors only ({n:,} vertices: "
                                        f"{SMALL_MESH_METHOD} is tried as well)"] if features.too_noisy else []) + [
                   f"{method} has the smaller estimated error (SURE, rms over vertices"
                   + (f", on {int(np.count_nonzero(region.rows)):,} vertices of a sampled region" if region else "")
                   + f"): {rms(scored[method][1])} mean edge lengths against {others}; its parameters minimise it"]
    post = None
    if method == FEATURE_METHOD and feature is not None and rho > 0:
        if features.sharp:
            reasons.append("no Taubin steps after two_stage: they would round the sharp features")
        else:  # on the probes' runs that scored two_stage (no other run of it)
            with stage("choosing Taubin steps after two_stage"):
                post = feature_post_step(feature, region.F if region is not None else F,
                                         ops=region.ops if region is not None else ops)
            reasons.append(post.reason)
    # the chosen filter's run on the whole mesh, made for its probes, is denoise's result where the border's option
    # changes nothing (no open border, or a filter that moves every vertex along its normal)
    free = None
    if feature is not None and region is None and method == FEATURE_METHOD:
        spec = get_filter(method)
        if boundary_motion == "free" or not ops.boundary_vertices.any() or (
                spec.along_normals is not None and spec.along_normals(spec.resolve(dict(params)))):
            free = feature.out if relabel is None else relabel.restore(feature.out)
    feature = None
    if method in SMOOTH_PRIORS and rho > 0:  # the smooth prior's mu (SURE on positions) under-smooths the normals
        with stage("choosing the smooth prior's post-step"):  # along sobolev_bilaplacian's normals when computed
            if region is not None:
                post = choose_post_step(region.V, region.F, method, params, region.noise_model(model), ops=region.ops,
                                        normals=normals, rows=region.rows)
            else:  # on small meshes with the smooth prior's parameters: tilted probes where its normals are far off
                post = choose_post_step(V, F, method, params, model, ops=ops, normals=normals,
                                        smooth_params=smooth_params if n <= SMALL_MESH else None,
                                        boundary_motion=boundary_motion)
        params = {**params, "mu": params["mu"] * post.scale}
        reasons.append(post.reason)
    nb = int(np.count_nonzero(ops.boundary_vertices))
    if nb:
        reasons.append(f"{nb:,} vertices are on open borders: they move along their normals only (no inward shrinking)"
                       if boundary_motion == "normal" else
                       f"{nb:,} vertices are on open borders: they move freely (boundary_motion='free')")
    reasons.insert(0, noise_reason)
    choice = DefaultChoice(method, params, float(rho), float(h), model.correlation_length, features, nb, reasons,
                           time.perf_counter() - start, caveats, decided, (float(rho_range[0]), float(rho_range[1])),
                           post.steps if post is not None else 0, post,
                           (int(region.V.shape[0]), int(np.count_nonzero(region.rows))) if region is not None else (0, 0))
    for line in choice.lines():
        log.info("default: %s", line)
    return choice, free


def denoise(
    mesh: Any,
    method: str | None = None,
    *,
    noise: float | None = None,
    return_params: bool = False,
    boundary_motion: str = "normal",
    criterion: str | None = None,
    **params: Any,
) -> Any:
    """Denoise a mesh; with no method, the default for scans chooses the filter and its parameters.

    Parameters
    ----------
    mesh : (V, F) tuple, pymeshlab.MeshSet or Mesh, or open3d.geometry.TriangleMesh
    method : str, optional
        A registered filter. ``None`` (default): :func:`choose_default` chooses the filter
        (``two_stage`` or ``sobolev_bilaplacian``, by their estimated errors) and its parameters.
    noise : float or NoiseModel, optional
        The noise level (or level and correlation length) if known, else estimated; used only
        when choosing.
    return_params : bool
        Also return the parameters used: with a method, the dict of parameters; with none,
        the :class:`DefaultChoice` (method, parameters, noise estimate, reasons).
    boundary_motion : {"normal", "free"}
        ``"normal"`` (default): vertices on open borders move only along their normals, so
        borders do not shrink inward (:func:`meshdenoise.registry.boundary_along_normals`);
        ``"free"``: the filter as it is (what ``apply_filter`` does).
    criterion : {"normals", "sure", "gcv"}, optional
        With a method and its parameters chosen automatically, how: ``"normals"`` (the default
        for the linear filters, :func:`~meshdenoise.tuning.choose.normal_filters`) the least
        estimated error of the face normals, what a rendering shows; ``"sure"`` (the default for
        the others) the least estimated position error, which smooths 1 to 10 times less and
        keeps the volume better (docs/automatic-parameters.md). Not with ``method=None``.
    **params
        Filter parameters (held fixed) and the common options (``pinned``, ``region``,
        ``preserve_volume``, ``operators``). With none of the filter's own parameters
        given, all of them are chosen automatically.

    Returns
    -------
    Same type as ``mesh`` (a MeshSet is changed in place), or ``(mesh, params or choice)``.

    Warns
    -----
    UserWarning
        When the result moves the vertices by less than 1 % of a mean edge length (rms): the
        noise estimate (printed) was too small for the risk estimate to prefer smoothing.

    Examples
    --------
    >>> from meshdenoise.shapes import icosphere
    >>> from meshdenoise import add_normal_noise, snr
    >>> V, F = icosphere(3)
    >>> Vn, _ = add_normal_noise((V, F), rho=0.02, seed=0)
    >>> (Vd, Fd), choice = denoise((Vn, F), return_params=True)
    >>> choice.method, bool(snr(V, Vd) > snr(V, Vn))
    ('sobolev_normal', True)
    """
    options = {k: params.pop(k) for k in list(params) if k in COMMON_OPTIONS}
    options["boundary_motion"] = boundary_motion
    choice, free = None, None
    if method is None:
        if params:
            raise TypeError(f"denoise: filter parameters {sorted(params)} need method=; "
                            "with no method the default chooses the filter and its parameters")
        if criterion is not None:
            raise TypeError(f"denoise: criterion={criterion!r} needs method=; with no method the default "
                            "chooses by its own estimates (normal error under a position-error guard)")
        choice, free = _choose(mesh, noise, boundary_motion)
        method, chosen = choice.method, dict(choice.params)
        release_before_filter()  # the choice's memo entries are dead weight beside the filter
    else:
        if not isinstance(method, str):
            raise TypeError(f"denoise: method must be a filter name (str) or None, got {method!r}")
        spec = get_filter(method)
        if spec.auto is not None and set(spec.auto.tunes) - set(params):
            chosen = choose_parameters(mesh, method, noise=noise, criterion=rule_criterion(method, criterion), **params)
            log.info("denoise(%s): automatic parameters %s", method, chosen)
            release_before_filter()  # the choice's memo entries are dead weight beside the filter
        else:
            chosen = dict(params)
    before = read_mesh(mesh).V.copy() if choice is not None else None
    with stage(f"running {method}"):
        if choice is not None and free is not None and set(options) == {"boundary_motion"}:
            out = _finish_run(mesh, free)
        else:
            out = apply_filter(method, mesh, **chosen, **options)
    if choice is not None and choice.post_steps:
        out = run_post_step(choice, out, **options)
    if choice is not None:
        warn_if_not_smoothing(before, read_mesh(out).V, choice)
    if return_params:
        return out, (choice if choice is not None else chosen)
    return out


def _finish_run(mesh: Any, free: np.ndarray) -> Any:
    """``mesh`` with the vertices ``free`` (n, 3): ``apply_filter``'s result when ``free`` is the filter's run on it and
    the border's option changes nothing (:func:`_choose`)."""
    return read_mesh(mesh).write(np.array(free, dtype=np.float64))


def run_post_step(choice: DefaultChoice, mesh: Any, **options: Any) -> Any:
    """The choice's Taubin steps after its filter (:attr:`DefaultChoice.post_steps`; ``mesh`` as it is when 0).

    Parameters
    ----------
    choice : DefaultChoice
    mesh : (V, F) tuple, pymeshlab.MeshSet or Mesh, or open3d.geometry.TriangleMesh
        The filter's result.
    **options
        The common options the filter ran with (``boundary_motion``, ``pinned``, ...).

    Returns
    -------
    Same type as ``mesh``.
    """
    if not choice.post_steps:
        return mesh
    with stage(f"running {choice.post_steps} Taubin steps"):
        return apply_filter("taubin", mesh, iterations=choice.post_steps, **POST_TAUBIN, **options)


def warn_if_not_smoothing(before: np.ndarray, after: np.ndarray, choice: DefaultChoice) -> float:
    """Warn when the default barely moved the mesh; return the rms move in mean edge lengths."""
    h = choice.edge_length
    move = float(np.sqrt(np.mean(np.sum((after - before) ** 2, axis=1)))) / h if h > 0 and before.size else 0.0
    if move < NOT_SMOOTHING:
        warnings.warn(
            f"denoise: not smoothing: the estimated noise is {choice.noise:.3g} ({choice.noise_in_edges:.3g} mean edge "
            f"lengths), too small for {choice.method}'s risk estimate to prefer any smoothing (vertices moved "
            f"{move:.2g} edge lengths rms); to smooth anyway choose a filter and its parameters "
            "(--method and --param, or method= in Python)",
            UserWarning,
            stacklevel=3,
        )
    return move
