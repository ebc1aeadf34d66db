"""The default's settings: one frozen object a caller (and a test) passes in.

Every constant here was chosen on the corpus's tune half (``benchmarks/corpus.py``; the split is by a
hash of each case's name) and is reported on its check half too: ``python benchmarks/policy_tune.py``
writes the comparison of the values tried to ``benchmarks/results/policy-tune.md``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from ..plugins.two_stage import TWO_STAGE_NORMALS
from ..tuning.sweep import HoldoutConfig

__all__ = ["Family", "DefaultConfig", "HoldoutConfig", "FAMILIES", "OTHER_FAMILIES"]


@dataclass(frozen=True)
class Family:
    """A registered filter with all its parameters fixed but one count, the step along its run.

    Attributes
    ----------
    method : str
        The filter's registered name.
    fixed : tuple of (name, value)
        Its other parameters.
    count : str
        The parameter counted along a run (``iterations``): the k-th state of one run is the filter
        with ``count = k``.
    """

    method: str
    fixed: tuple = ()
    count: str = "iterations"

    def params(self, k: int) -> dict[str, Any]:
        """The filter's parameters at step ``k``."""
        return {**dict(self.fixed), self.count: int(k)}

    @property
    def label(self) -> str:
        inner = ", ".join(f"{k}={v}" for k, v in self.fixed)
        return f"{self.method}({inner})"


def _two_stage(sigma_r: float, keep_tangential: bool) -> Family:
    # one normal pass and five vertex steps per outer iteration: the run reaches every amount of smoothing
    # in small steps (PyGEL's anisotropic smoothing is this with its own range kernel)
    return Family("two_stage", (("normal_iterations", 1), ("vertex_iterations", 5), ("sigma_r", sigma_r),
                                ("sigma_s", 1.0), ("guidance", "bilateral"), ("keep_tangential", keep_tangential)))


# two_stage's own rule's runs (meshdenoise.plugins.two_stage.TWO_STAGE_NORMALS, where the tune-half measurements that
# keep each are): the sharp normal filter (sigma_r 0.35) keeping or relaxing the input's tangential part and the
# smooth one (sigma_r 2.0) relaxing it, so that denoise(mesh) and denoise(mesh, method="two_stage") choose alike.
# The others tried are OTHER_FAMILIES (benchmarks/results/policy-tune.md)
FAMILIES = tuple(Family("two_stage", sweep.fixed) for sweep in TWO_STAGE_NORMALS.sweeps)
OTHER_FAMILIES = (
    _two_stage(0.35, False),
    _two_stage(2.0, False),
    _two_stage(2.0, True),
    Family("taubin", (("lam", 0.5), ("mu", -0.53), ("weights", "uniform"))),
)


@dataclass(frozen=True)
class DefaultConfig:
    """What the default may try and how it scores the tries.

    Attributes
    ----------
    families : tuple of Family
        The candidates; each is scored along one run per mask.
    holdout : HoldoutConfig
        How the held-out losses are read (:class:`meshdenoise.tuning.sweep.HoldoutConfig`: rings hidden
        around each held-out vertex, masks, the centres wanted on a small mesh, patience, the sampled
        region above 12,000 vertices); two_stage's rule's (``TWO_STAGE_NORMALS.config``), so that both
        choose alike. On a small mesh masks are added until 300 vertices are held out: the
        corpus has no mesh under 2,800 vertices and its tune half reads about the same with or without
        it (1.309 and 1.309); a 400-vertex noisy plane needs it (with 3 masks alone, about 40 hidden
        vertices, one iteration was chosen: tests/test_policy.py).
    steps : int
        Most steps read along a run.
    unfold_rounds : int
        Most rounds of averaging the corners of faces the chosen run turned over
        (:func:`meshdenoise.folds.unfold`); 0 leaves folds as they are.
    """

    families: tuple = field(default=FAMILIES)
    holdout: HoldoutConfig = field(default=TWO_STAGE_NORMALS.config)
    steps: int = 40
    unfold_rounds: int = 10

    def __post_init__(self):
        for name, low in (("steps", 1), ("unfold_rounds", 0)):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < low:
                raise ValueError(f"DefaultConfig: {name} must be an int >= {low}, got {value!r}")
        if not isinstance(self.holdout, HoldoutConfig):
            raise ValueError(f"DefaultConfig: holdout must be a HoldoutConfig, got {self.holdout!r}")
        if not self.families or not all(isinstance(f, Family) for f in self.families):
            raise ValueError(f"DefaultConfig: families must be a non-empty tuple of Family, got {self.families!r}")
