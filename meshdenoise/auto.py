"""Parameters chosen from the noisy mesh alone: the public names of :mod:`meshdenoise.tuning`.

Kept so that ``meshdenoise.auto.choose_parameters`` and friends stay importable; the
machinery lives in :mod:`meshdenoise.tuning` (risk estimates, searches, noise level) and
each filter's rule in its plugin module, registered with the filter.
"""

from __future__ import annotations

from .tuning import (
    EXACT_TRACE_MAX,
    auto_filters,
    choose_parameters,
    estimate_noise,
    gcv,
    probe_block,
    sure,
)
from .default import denoise

__all__ = ["estimate_noise", "choose_parameters", "denoise", "auto_filters", "sure", "gcv", "probe_block", "EXACT_TRACE_MAX"]
