"""The ``noise`` option of ``denoise`` and of automatic parameters: a known noise level, instead of the estimate.

Written ``RHO[h][,L]`` on the command line (``--noise``) and in pipelines (``noise:``): RHO the
level along the normals in mesh units, or in mean edge lengths with an ``h`` (``0.4h``); L the
correlation length in mean edge lengths (0, independent noise, when left out). A YAML number is
RHO in mesh units.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["NoiseOption", "parse_noise_option", "NOISE_SYNTAX"]

NOISE_SYNTAX = ("RHO[h][,L]: RHO the noise level in mesh units, or in mean edge lengths with 'h' (0.4h); "
                "L its correlation length in mean edge lengths (e.g. 0.002, 0.4h or 0.4h,2)")

_NUMBER = r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?"
_PATTERN = re.compile(rf"^\s*({_NUMBER})\s*(h?)\s*(?:,\s*({_NUMBER})\s*)?$")


@dataclass(frozen=True)
class NoiseOption:
    """A noise level given by the user.

    Attributes
    ----------
    level : float
        In mesh units, or in mean edge lengths when ``in_edges``.
    in_edges : bool
    correlation_length : float
        In mean edge lengths (0: independent).
    """

    level: float
    in_edges: bool = False
    correlation_length: float = 0.0

    def rho(self, h: float) -> float:
        """The level in mesh units on a mesh of mean edge length ``h``."""
        return self.level * h if self.in_edges else self.level

    def model(self, V: np.ndarray, F: np.ndarray) -> Any:
        """The :class:`~meshdenoise.tuning.covariance.NoiseModel` on the mesh (V, F)."""
        from ..operators import get_operators
        from ..tuning.choose import given_noise_model
        from ..tuning.noise_level import mean_edge_length

        h = mean_edge_length(V, get_operators(F, V.shape[0])) if self.in_edges else 1.0
        return given_noise_model((V, F), self.rho(h), self.correlation_length)

    def __str__(self) -> str:
        text = f"{self.level:g}{'h' if self.in_edges else ''}"
        return text + (f",{self.correlation_length:g}" if self.correlation_length else "")


def parse_noise_option(value: Any, where: str = "noise") -> NoiseOption:
    """Read ``RHO[h][,L]`` (a string) or RHO (a number, mesh units).

    Raises
    ------
    ValueError
        Not of that form, or a value negative or not finite; the message starts with ``where``.
    """
    if isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{where}: {value!r} is not a noise level; give {NOISE_SYNTAX}")
    if isinstance(value, (int, float, np.integer, np.floating)):
        level, in_edges, ell = float(value), False, 0.0
    elif isinstance(value, str):
        match = _PATTERN.match(value)
        if match is None:
            raise ValueError(f"{where}: {value!r} is not understood; give {NOISE_SYNTAX}")
        level, in_edges, ell = float(match.group(1)), bool(match.group(2)), float(match.group(3) or 0.0)
    else:
        raise ValueError(f"{where}: {value!r} is not a noise level; give {NOISE_SYNTAX}")
    for name, number in (("the level", level), ("the correlation length", ell)):
        if not (math.isfinite(number) and number >= 0):
            raise ValueError(f"{where}: {value!r}: {name} must be a finite number >= 0; give {NOISE_SYNTAX}")
    return NoiseOption(level, in_edges, ell)
