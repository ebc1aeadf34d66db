"""The default for scans: which filter, with which parameters, chosen from the noisy mesh alone.

:mod:`.config` holds the settings (:class:`DefaultConfig`, the candidate :class:`Family` list),
:mod:`.paths` one run of a candidate read state by state, :mod:`.choose` the steps (score, pick,
guard). :func:`meshdenoise.denoise` with no method runs them.
"""

from .choose import DefaultChoice, Score, choose, guard, pick, score
from .config import FAMILIES, OTHER_FAMILIES, DefaultConfig, Family, HoldoutConfig
from .run import choose_default, run_default

__all__ = ["DefaultChoice", "DefaultConfig", "FAMILIES", "OTHER_FAMILIES", "Family", "HoldoutConfig", "Score", "choose", "guard",
           "pick", "score", "choose_default", "run_default"]
