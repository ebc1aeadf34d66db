"""Generic tuning machinery: noise estimation, risk estimates, searches, and the automatic choice.

Floors, bottom up (none knows a filter; each filter's rule lives in its plugin module
and is registered with it, ``register(..., auto=AutoRule(...))``):

- :mod:`~meshdenoise.tuning.risk`: SURE, GCV, trace probes, the :class:`Point` and :class:`Criterion` of a search;
- :mod:`~meshdenoise.tuning.walk`: :func:`walk`, the one walk along an iterative run until every score is past its
  minimum (any score: SURE for the rules, the clean mesh for ``reproduce`` and the benchmarks' oracles);
- :mod:`~meshdenoise.tuning.search`: the searches (along an iterative run, over a log weight) and shifted solves;
- :mod:`~meshdenoise.tuning.noise_level`: :func:`estimate_noise` and the normals' spread;
- :mod:`~meshdenoise.tuning.covariance`: :func:`estimate_noise_model` (level and correlation length) and :class:`NoiseModel`;
- :mod:`~meshdenoise.tuning.region`: a sampled region of a large mesh (balls of vertex rings) that fits run on;
- :mod:`~meshdenoise.tuning.context`: the :class:`TuningContext` a rule is given;
- :mod:`~meshdenoise.tuning.choose`: :func:`choose_parameters` (``meshdenoise.denoise``, which also chooses
  the filter, is the policy above this floor: :mod:`meshdenoise.policy`);
- :mod:`~meshdenoise.tuning.memo`: the bounded memo of repeated solves;
- :mod:`~meshdenoise.tuning.config`: the machinery's settings (:class:`SearchConfig`, :class:`SpectralConfig`,
  :class:`NoiseKernelConfig`), frozen objects a caller hands in (``choose_parameters(..., config=...)``) instead of
  module constants; each filter's own (``GlsConfig``, ``SinkhornConfig``, ...) lives in its plugin module.
"""

from .choose import auto_filters, choose_parameters, given_noise_model
from .config import NoiseKernelConfig, SearchConfig, SpectralConfig
from .context import TuningContext
from .covariance import NoiseModel, estimate_noise_model
from .noise_level import estimate_noise
from .risk import EXACT_TRACE_MAX, Criterion, Point, gcv, probe_block, sure
from .walk import Walk, walk

__all__ = [
    "choose_parameters",
    "auto_filters",
    "given_noise_model",
    "estimate_noise",
    "estimate_noise_model",
    "NoiseModel",
    "TuningContext",
    "Criterion",
    "Point",
    "sure",
    "gcv",
    "probe_block",
    "EXACT_TRACE_MAX",
    "walk",
    "Walk",
    "SearchConfig",
    "SpectralConfig",
    "NoiseKernelConfig",
]
