"""Choosing a filter's parameters from the noisy mesh alone (``meshdenoise.denoise`` uses it: :mod:`meshdenoise.default`).

:func:`choose_parameters` finds the filter in the registry, builds a
:class:`~meshdenoise.tuning.context.TuningContext` (noise level and correlation length from
:func:`~meshdenoise.tuning.covariance.estimate_noise_model` unless given) and calls the rule the
filter registered (``register(..., auto=AutoRule(...))``); nothing here knows a filter.
"""

from __future__ import annotations

import logging
import math
import warnings
from typing import Any

import numpy as np

from ..adapters import read_mesh
from ..locality import Relabelling, relabelling
from ..operators import get_operators
from ..progress import stage
from ..registry import get_filter, list_filters
from ..solvers import retain_factors
from .context import TuningContext, as_configs
from .covariance import NoiseModel, estimate_noise_model
from .noise_level import mean_edge_length
from .normal_risk import NORMAL_FIRST, NORMAL_SCALES, NORMAL_WIDE_BELOW, NORMAL_WIDE_SCALES, NormalChoice, refine_for_normals
from .risk import Criterion, Point, noise_colouring
from .holdout import NoHoldout
from .config import SEARCH, SPECTRAL
from .search import REGION_MAX_MARGIN, region_rule, sure_smoothed

__all__ = ["choose_parameters", "auto_filters", "normal_filters", "rule_criterion", "CRITERIA"]

CRITERIA = ("sure", "gcv", "oracle", "normals")
NORMAL_REGION = 32_000  # criterion "normals" from SearchConfig.region_min_vertices: the search on a sampled region of this many vertices
NORMAL_PATCHES = 8  # ... made of this many balls
NORMAL_RETAINED_CANDIDATES = 3  # factorisations kept through the search: this many candidates' (solvers.retain_factors)

log = logging.getLogger("meshdenoise.auto")


def auto_filters() -> list[str]:
    """Names of the registered filters that have an automatic rule, sorted.

    Examples
    --------
    >>> {"filtering", "sobolev", "two_stage"} <= set(auto_filters())
    True
    """
    return [spec.name for spec in list_filters() if spec.auto is not None]


def normal_filters() -> list[str]:
    """Names of the registered filters whose rule takes ``criterion="normals"``: a held-out sweep
    (:func:`held_out_filters`), or a smoothing amount of a filter linear in the coordinates for what it reads of the
    mesh held.

    Examples
    --------
    >>> normal_filters()
    ['filtering', 'heat', 'sinkhorn', 'sobolev', 'sobolev_axes', 'sobolev_bilaplacian', 'sobolev_gls', 'taubin', 'two_stage']
    """
    return [spec.name for spec in list_filters() if spec.auto is not None and spec.auto.normals is not None]


def rule_criterion(method: str, criterion: str | None = None) -> str:
    """The criterion a filter's automatic choice uses when the caller names none: ``"normals"`` where the filter
    has it (:func:`normal_filters`), else ``"sure"``.

    ``denoise(mesh, method=M)``, the command line's ``--method M`` and a pipeline step's
    ``parameters: auto`` all ask it, so the three choose alike; :func:`choose_parameters` called
    directly keeps ``"sure"`` unless told.

    Examples
    --------
    >>> rule_criterion("sobolev"), rule_criterion("sobolev_normal"), rule_criterion("sobolev", "sure")
    ('normals', 'sure', 'sure')
    """
    if criterion is not None:
        return criterion
    return "normals" if method in normal_filters() else "sure"


def normal_candidates(start: float, integer: bool, high: float | None = None,
                      scales: tuple[float, ...] = NORMAL_SCALES) -> list[float]:
    """The values :func:`refine_for_normals` compares: ``start`` times ``scales`` (counts rounded, from 1).

    Examples
    --------
    >>> normal_candidates(3, True)
    [2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 9.0, 12.0, 15.0, 19.0, 24.0, 30.0]
    """
    values = [start * s for s in scales]
    if integer:
        values = [float(max(1, round(v))) for v in values]
    if high is not None:
        values = [v for v in values if v <= high]
    return sorted(set(values))


def _warn_if_worse_than_input(method: str, chosen: dict, found: NormalChoice, sure_choice: dict, sure_score: float,
                              noise_energy: float) -> None:
    """A ``UserWarning`` when the normals choice is estimated to leave the positions worse than the input's."""
    gain = found.position_gain_db
    if not gain < 0:
        return
    sure_gain = 10.0 * math.log10(noise_energy / sure_score) if sure_score > 0 and noise_energy > 0 else math.inf
    warnings.warn(
        f"choose_parameters({method}): the normals criterion's choice {chosen} is estimated to leave the vertex "
        f"positions {-gain:.1f} dB worse than the input's (the filter shrinks the mesh as it smooths the normals); "
        f"criterion='sure' ({sure_choice}) is estimated {sure_gain:+.1f} dB, or use a filter that shrinks less "
        f"({', '.join(f for f in LESS_SHRINKING if f != method)})", UserWarning, stacklevel=3)


#: Filters the warning above suggests instead (never the one being run).
LESS_SHRINKING = ("sobolev_bilaplacian", "taubin")


def _for_normals(spec: Any, ctx: TuningContext, chosen: dict) -> tuple[dict, NormalChoice | None]:
    """``chosen`` with its smoothing amount moved to the least estimated face-normal error (``None``: left as it is).

    The smoothing amount is the parameter ``spec.auto.normals`` names, or a common factor on the
    parameters it names (a tuple). From :attr:`SearchConfig.region_min_vertices <meshdenoise.tuning.config.SearchConfig>`
    vertices (or twice the rule's ``normals_region``) the search runs on a sampled region of about
    :data:`NORMAL_REGION` vertices (the rule's ``normals_region``)
    (:func:`~meshdenoise.tuning.search.region_rule`), scoring the faces more than a margin from
    its cuts, the margin the reach of the strongest smoothing compared (``2 sqrt(k)`` rings for
    ``k`` averaging steps, ``k`` ten times position SURE's); the weight is a property of the noise
    per edge and of the local shape, so it carries to the whole mesh.
    """
    rule = spec.auto
    names = (rule.normals,) if isinstance(rule.normals, str) else tuple(rule.normals)
    if any(name in ctx.given for name in names) or not ctx.rho or ctx.rho <= 0:
        return chosen, None  # held by the caller, or no noise to remove
    params = spec.resolve({**ctx.given, **chosen})
    # below an edge length of noise the search may go on to 100 times the rule's weight (NORMAL_WIDE_SCALES)
    # (edge lengths of the SURE-smoothed mesh: the noisy one's grow with the noise; the elephant at rho = 0.2 has
    # rho 0.88 noisy edge lengths, 29 smoothed ones, 26 clean ones); from one, the search ranks by the Dirichlet
    # energy's SURE instead of the linearised normal risk (refine_for_normals' edge_length, NORMAL_LINEAR_MAX)
    h = mean_edge_length(ctx.smoothed("sure").X, ctx.ops)
    scales = NORMAL_WIDE_SCALES if ctx.rho < NORMAL_WIDE_BELOW * h else NORMAL_SCALES
    if len(names) == 1:
        name = names[0]
        start = float(params[name])
        if start <= 0:
            return chosen, None
        candidates = normal_candidates(start, False, spec.param(name).high, scales)

        def values(value: float) -> dict:
            return {name: float(value)}
    else:  # one factor on the named weights (those the rule set to 0 stay 0)
        base = {name: float(params[name]) for name in names}
        if not any(v > 0 for v in base.values()):
            return chosen, None
        start, candidates = 1.0, normal_candidates(1.0, False, scales=scales)

        def values(value: float) -> dict:
            return {name: float(v * value) for name, v in base.items()}
    found: list[NormalChoice] = []

    def on(sub: TuningContext, scored: np.ndarray | None) -> tuple[dict, Point]:
        last: dict = {}  # the last value's linear map: a pass applies it to V, then to V with the probes

        def apply(value: float, block: np.ndarray) -> np.ndarray:
            at = {**params, **values(value)}
            if rule.linear_map is None:
                return spec.core(block, sub.F, ops=sub.ops, pinned=None, **at)
            if last.get("value") != value:  # the filter's map with what it reads of the mesh taken from sub.V
                last.clear()
                last.update(value=value, map=rule.linear_map(sub.V, sub.F, sub.ops, at))
            return last["map"](block)

        correlated = sub.noise is not None and sub.noise.correlated
        family = None
        if rule.spectral is not None and rule.spectral(sub.V, sub.F, sub.ops, {**params, **values(start)}):
            def family(value: float):
                return rule.spectral(sub.V, sub.F, sub.ops, {**params, **values(value)})
        found.append(refine_for_normals(sub.V, sub.F, apply, start, candidates, sub.rho, spectral=family,
                                        colour=sub.colour if correlated else None, edge_length=h,
                                        first=start * NORMAL_FIRST, rows=scored,
                                        guard_above=start * NORMAL_SCALES[-1] * 1.001,
                                        config=sub.config_for(SPECTRAL)))
        return values(found[-1].value), Point(found[-1].value, math.nan, math.nan, None, found[-1].risk)

    size = int(rule.normals_region or NORMAL_REGION)
    least = min(ctx.config_for(SEARCH).region_min_vertices, 2 * size)
    k = float(ctx.smoothed("sure").value) if ctx.n >= least else 0.0
    # the margin for 10 times SURE's weight, also with the wide scales: for 100 times, sobolev_axes on face000 took 363 s
    # (184 s) and chose 50 (63) times SURE's weights, 8.93 (8.99) degrees against the oracle's 8.30
    margin = int(min(REGION_MAX_MARGIN, math.ceil(2.0 * math.sqrt(k * NORMAL_SCALES[-1]))))
    # the second pass comes back to the first's last candidates: their factors kept (sobolev_axes: one per weight)
    with retain_factors(NORMAL_RETAINED_CANDIDATES * len(names)):
        region_rule(ctx, on, size, NORMAL_PATCHES, margin, min_vertices=least)
    return {**chosen, **values(found[-1].value)}, found[-1]


def choose_parameters(
    mesh: Any,
    method: str = "sobolev",
    *,
    noise: float | NoiseModel | None = None,
    correlation_length: float | None = None,
    criterion: str = "sure",
    exact_trace: bool | None = None,
    reference: Any = None,
    return_risk: bool = False,
    config: Any = None,
    **given: Any,
) -> dict | tuple[dict, float]:
    """Choose a filter's parameters from the noisy mesh alone.

    Linear filters (``filtering``: iterations; ``heat``: time and tau; ``sobolev``,
    ``sobolev_bilaplacian``: mu; ``taubin``: iterations; ``sinkhorn`` in its linear
    configuration: t and iterations) minimise SURE (module docstring) with the noise level
    from :func:`estimate_noise`, or GCV with ``criterion="gcv"``; traces by Hutchinson
    probes carried along the run (exact below ``EXACT_TRACE_MAX`` vertices).
    ``sobolev_axes`` minimises one SURE per principal axis of the normals (mu1, mu2, mu3);
    ``sobolev_gls`` minimises SURE over mu and beta for its normals held fixed;
    ``two_stage`` (nonlinear) minimises Monte-Carlo SURE over its outer iterations.

    Parameters
    ----------
    mesh : (V, F) tuple, pymeshlab.MeshSet or Mesh, or open3d.geometry.TriangleMesh
    method : str
        A registered filter with an automatic rule (:func:`auto_filters`).
    noise : float or NoiseModel, optional
        The noise level rho if known, or a :class:`~meshdenoise.tuning.covariance.NoiseModel`
        (level and correlation length, e.g. from one
        :func:`~meshdenoise.tuning.covariance.estimate_noise_model` call for several filters);
        estimated otherwise, with its correlation length.
    correlation_length : float, optional
        The noise's correlation length in mean edge lengths, if known (with ``noise``:
        0 when not given, the independent noise of the paper; without it: estimated
        when not given). SURE then counts the noise that passes the smoother, :math:`\\mathrm{tr}(H\\Sigma)`.
    criterion : {"sure", "gcv", "oracle", "normals"}
        ``"oracle"`` needs ``reference`` (the clean mesh) and minimises the true error
        over the same search space: the best parameters in hindsight, for benchmarks.
        ``"normals"`` (:func:`normal_filters`): the least error of the face normals,
        what a rendering shows, at some position error (the result shrinks more); what
        ``denoise(mesh, method=M)`` uses. For the filters of :func:`held_out_filters` the value of least
        held-out face-normal loss along the rule's sweep (:class:`~meshdenoise.tuning.sweep.HeldOutRule`,
        no noise level read); for the others the rule's SURE choice, its smoothing amount then moved to
        the least estimated normal error (:func:`~meshdenoise.tuning.normal_risk.refine_for_normals`).
    exact_trace : bool, optional
        Force exact traces (identity probes) or Hutchinson ones.
    reference : mesh or (n, 3) array, optional
        The clean mesh, only for ``criterion="oracle"``.
    return_risk : bool
        Also return the chosen point's score: with ``criterion="sure"`` the estimated
        squared error :math:`\\|f(X) - X^0\\|_F^2` of the result (summed over vertices and
        coordinates), comparable between filters on the same mesh and noise level; with
        ``"normals"`` the estimated mean squared turn of the face normals (rad^2).
    **given
        Parameters held fixed (e.g. ``weights="meshlab"`` for filtering, ``tau`` for heat);
        the method's tuned parameters that are not given are chosen.
    config : settings object or sequence of them, optional
        Settings for the rule instead of the measured defaults: the tuning machinery's
        (:class:`~meshdenoise.tuning.config.SearchConfig`, :class:`~meshdenoise.tuning.config.SpectralConfig`) and
        the filter's own (e.g. ``GlsConfig`` in ``plugins/sobolev_gls.py``); each is read where its module reads its
        settings (:meth:`~meshdenoise.tuning.context.TuningContext.config_for`), e.g.
        ``config=(SearchConfig(region_min_vertices=1000), SinkhornConfig(region=3000))``.

    Returns
    -------
    dict, or (dict, float) with ``return_risk=True``
        The filter's parameters, ready for ``apply_filter(method, mesh, **params)``
        (given ones included), and the score.

    Examples
    --------
    >>> from meshdenoise.shapes import icosphere
    >>> from meshdenoise import add_normal_noise
    >>> V, F = icosphere(3)
    >>> Vn, _ = add_normal_noise((V, F), rho=0.02, seed=0)
    >>> sorted(choose_parameters((Vn, F), method="sobolev"))
    ['mu']
    """
    if not isinstance(method, str):
        raise TypeError(f"choose_parameters: method must be a filter name (str), got {method!r}")
    spec = get_filter(method)  # KeyError with suggestions for an unknown name
    if spec.auto is None:
        raise ValueError(
            f"choose_parameters: no automatic rule for filter '{method}'; "
            f"automatic parameters exist for: {', '.join(auto_filters())}"
        )
    if criterion not in CRITERIA:
        raise ValueError(f"choose_parameters: criterion must be one of {', '.join(CRITERIA)}, got {criterion!r}")
    if criterion == "normals" and method not in normal_filters():
        raise ValueError(f"choose_parameters: criterion 'normals' is for the filters with a rule for it "
                         f"({', '.join(normal_filters())}), not '{method}'")
    if (criterion == "oracle") != (reference is not None):
        raise ValueError("choose_parameters: reference= (the clean mesh) goes with criterion='oracle', and only with it")
    spec.resolve(given, where=f"choose_parameters(method='{method}')")  # names/types/ranges of held values
    configs = as_configs(config)
    if criterion == "normals" and spec.auto.held_out is not None:
        params, score = _held_out(spec, mesh, noise, correlation_length, given)
        return (params, score) if return_risk else params
    data = read_mesh(mesh)
    V, F = data.V, data.F
    relabel = relabelling(F, V.shape[0])  # a large mesh in a cache-hostile order: choose on relabelled vertices
    if relabel is not None:
        V, F_in, F = relabel.vertices(V), F, relabel.faces
    ops = get_operators(F, V.shape[0])
    if relabel is not None:
        F = ops.F  # int64, as read_mesh gives (the relabelling's own faces are int32)
    if correlation_length is not None:
        if isinstance(correlation_length, (bool, np.bool_)) or not isinstance(
                correlation_length, (int, float, np.integer, np.floating)):
            raise TypeError(f"choose_parameters: correlation_length must be a number, got {correlation_length!r}")
        if not (math.isfinite(correlation_length) and correlation_length >= 0):
            raise ValueError(f"choose_parameters: parameter 'correlation_length' = {correlation_length!r} "
                             "is out of range: correlation_length >= 0")
    model = None
    if isinstance(noise, NoiseModel):  # an estimate made once (estimate_noise_model) for several choices
        if correlation_length is not None:
            raise ValueError("choose_parameters: noise= is a NoiseModel, which holds its correlation length; "
                             "do not give correlation_length= too")
        model, rho = (noise if relabel is None else relabelled_model(noise, F_in, relabel)), noise.rho
    elif noise is None:
        if criterion != "gcv":
            model = estimate_noise_model((V, F))
            if correlation_length is not None:
                model = _with_length(model.rho, float(correlation_length), V, ops)
        rho = model.rho if model is not None else None
    else:
        if isinstance(noise, (bool, np.bool_)) or not isinstance(noise, (int, float, np.integer, np.floating)):
            raise TypeError(f"choose_parameters: noise must be a number, got {noise!r}")
        if not (math.isfinite(noise) and noise >= 0):
            raise ValueError(f"choose_parameters: parameter 'noise' = {noise!r} is out of range: noise >= 0")
        rho = float(noise)
        model = _with_length(rho, float(correlation_length or 0.0), V, ops)
    Y = None
    if criterion == "oracle":
        from ..metrics import coordinates

        Y = coordinates(reference)
        if Y.shape != V.shape:
            raise ValueError(f"choose_parameters: reference has {Y.shape[0]} vertices, the mesh {V.shape[0]}")
        if relabel is not None:
            Y = relabel.vertices(Y)
    ctx = TuningContext(V, F, ops, rho, Criterion("sure" if criterion == "normals" else criterion, Y), exact_trace,
                        dict(given), model, configs)
    with stage(f"choosing {method}'s parameters"), noise_colouring(model):
        chosen, point = spec.auto.choose(ctx)
        if criterion == "normals":
            sure_choice, sure_score = dict(chosen), float(point.score)
            chosen, found = _for_normals(spec, ctx, chosen)
            if found is not None:
                how = (f"rms {found.rms_degrees:.3g} deg" if found.criterion == "normals" else
                       "the noise past an edge length: ranked by SURE of the error's Dirichlet energy")
                log.info("choose_parameters(%s): normals moved %s to %s (passes %s; %s)", method, sure_choice, chosen,
                         found.path, how)
                point = Point(found.value, math.nan, math.nan, None, found.risk)
                _warn_if_worse_than_input(method, chosen, found, sure_choice, sure_score, ctx.n * ctx.rho**2)
    params = {**chosen, **given}
    log.info("choose_parameters(%s): %s (rho=%s, correlation length %s, %s score %.6g)", method, params, rho,
             ctx.correlation_length, criterion, point.score)
    return (params, float(point.score)) if return_risk else params


def held_out_filters() -> list[str]:
    """Names of the registered filters whose ``criterion="normals"`` choice reads held-out vertices
    (``AutoRule.held_out``, a :class:`~meshdenoise.tuning.sweep.HeldOutRule`).

    Examples
    --------
    >>> {"filtering", "taubin", "sobolev"} <= set(held_out_filters())
    True
    """
    return [spec.name for spec in list_filters() if spec.auto is not None and spec.auto.held_out is not None]


def _held_out(spec: Any, mesh: Any, noise: Any, correlation_length: Any, given: dict) -> tuple[dict, float]:
    """:func:`choose_parameters` with ``criterion="normals"`` for a filter whose rule has a held-out sweep."""
    method = spec.name
    if noise is not None or correlation_length is not None:
        raise ValueError(f"choose_parameters: with criterion 'normals' {method}'s parameters are chosen by held-out "
                         "vertices, which read no noise level: leave noise= and correlation_length= out, or choose "
                         "by criterion 'sure' for that level")
    data = read_mesh(mesh)
    V, F = data.V, data.F
    ops = get_operators(F, V.shape[0])

    def run(X: np.ndarray, F: np.ndarray, ops: Any, params: dict) -> np.ndarray:
        return spec.public((X, F), **params, operators=ops)[0]

    with stage(f"choosing {method}'s parameters"):
        try:
            chosen, score = spec.auto.held_out.choose(V, F, ops, run, dict(given))
        except NoHoldout as exc:
            warnings.warn(f"choose_parameters({method}): {exc}; the filter's defaults are kept", UserWarning,
                          stacklevel=3)
            chosen = {**{k: spec.param(k).default for k in spec.auto.tunes}, **given}
            score = math.nan
    log.info("choose_parameters(%s): %s by held-out vertices (loss %.6g)", method, chosen, score)
    return chosen, score


def given_noise_model(mesh: Any, rho: float, correlation_length: float = 0.0) -> NoiseModel:
    """The :class:`~meshdenoise.tuning.covariance.NoiseModel` of a known level and correlation length on a mesh.

    A correlated model's heat filter is built on the mesh smoothed by SURE-chosen averaging,
    as :func:`~meshdenoise.tuning.covariance.estimate_noise_model` builds it, so a model given
    by the user and an estimated one colour their probes the same way.

    Parameters
    ----------
    mesh : (V, F) tuple, pymeshlab.MeshSet or Mesh, or open3d.geometry.TriangleMesh
        The noisy mesh.
    rho : float
        Noise level along the normals (mesh units, rms over vertices), >= 0.
    correlation_length : float
        In mean edge lengths, >= 0 (0: independent noise).

    Returns
    -------
    NoiseModel

    Examples
    --------
    >>> from meshdenoise.shapes import icosphere
    >>> V, F = icosphere(2)
    >>> m = given_noise_model((V, F), 0.01, 2.0)
    >>> m.rho, m.correlation_length, m.V.shape == V.shape
    (0.01, 2.0, True)
    """
    for name, value in (("rho", rho), ("correlation_length", correlation_length)):
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
            raise TypeError(f"given_noise_model: {name} must be a number, got {value!r}")
        if not (math.isfinite(value) and value >= 0):
            raise ValueError(f"given_noise_model: parameter {name!r} = {value!r} is out of range: {name} >= 0")
    data = read_mesh(mesh)
    return _with_length(float(rho), float(correlation_length), data.V, get_operators(data.F, data.V.shape[0]))


def relabelled_model(model: NoiseModel, F: np.ndarray, relabel: Relabelling) -> NoiseModel:
    """``model`` in the labels of ``relabel`` when it holds the mesh ``F`` (a correlated model), else itself."""
    if model.V is None or model.F is None or model.F.shape != F.shape or not np.array_equal(model.F, F):
        return model
    return NoiseModel(model.rho, model.correlation_length, relabel.vertices(model.V), relabel.faces)


def _with_length(rho: float, ell: float, V: np.ndarray, ops: Any) -> NoiseModel:
    if ell == 0 or rho == 0:
        return NoiseModel(rho)
    return NoiseModel(rho, ell, sure_smoothed(V, ops, rho).X, ops.F)
