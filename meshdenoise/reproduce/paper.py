"""The paper's reported figures, meshes, noise levels and parameter grids ("Mesh Denoising", 2022)."""

from __future__ import annotations

import numpy as np

__all__ = ["MESHES", "PAPER_SNR", "PAPER_MS", "PAPER_PARAMS", "NOT_SELF_CONSISTENT", "TAU_GRID", "MU_GRID"]

# mesh key -> (file in the data folder, noise levels rho of the paper's table)
MESHES: dict[str, tuple[str, tuple[float, ...]]] = {
    "elephant": ("elephant-50kv.off", (0.015, 0.2)),
    "nefertiti": ("nefertiti.off", (0.015, 0.2, 1.0)),
}

# (mesh, rho) -> method -> best SNR in dB, as printed in the paper ("noisy" is the input)
PAPER_SNR: dict[tuple[str, float], dict[str, float]] = {
    ("elephant", 0.015): {"noisy": 26.77, "filtering": 39.82, "heat": 39.81, "sobolev": 38.13},
    ("elephant", 0.2): {"noisy": 4.34, "filtering": 26.81, "heat": 26.81, "sobolev": 25.27},
    ("nefertiti", 0.015): {"noisy": 41.76, "filtering": 41.76, "heat": 41.83, "sobolev": 21.77},
    ("nefertiti", 0.2): {"noisy": 19.33, "filtering": 23.17, "heat": 24.17, "sobolev": 22.95},
    ("nefertiti", 1.0): {"noisy": 5.15, "filtering": 14.56, "heat": 14.62, "sobolev": 13.86},
}

# (mesh, rho) -> method -> time of the best setting in milliseconds, as printed in the paper
PAPER_MS: dict[tuple[str, float], dict[str, float]] = {
    ("elephant", 0.2): {"filtering": 50.8, "heat": 70.7, "sobolev": 0.0349},
}

# (mesh, rho) -> method -> the optimal parameters the paper quotes, in words
PAPER_PARAMS: dict[tuple[str, float], dict[str, str]] = {
    ("elephant", 0.2): {"filtering": "about 40 steps", "heat": "T about 40"},
    ("nefertiti", 0.2): {"heat": "tau near 0.5"},
    ("nefertiti", 1.0): {"filtering": "3 passes", "heat": "T about 3, tau near 0.7", "sobolev": "mu about 2"},
}

# Figures of the paper that cannot be right, with the reason shown in table.md.
NOT_SELF_CONSISTENT: dict[tuple[str, float, str], str] = {
    ("nefertiti", 0.015, "sobolev"): (
        "the paper's 21.77 dB is 20 dB below its own noisy input (41.76 dB), but the Sobolev solve "
        "(I + mu L) Y = X returns the input as mu -> 0, so the best mu can never score below the input"
    ),
    ("elephant", 0.2, "sobolev:time"): (
        "the paper's 0.0349 ms timed a function whose loop sat outside its body: it measured an empty call"
    ),
}

# The paper's heat step grid: 20 log-spaced values, 10^-2.5 .. 10^0.3 (its 19th value is the 1.42 it reports
# as diverging). Steps above the mesh's stability bound 2 / lambda_max(I - D^-1 W) are skipped and reported.
TAU_GRID: np.ndarray = np.logspace(-2.5, 0.3, 20)

# Sobolev weights: 0 (the input itself) and 6 values per decade from 1e-4 to 1e3.
MU_GRID: np.ndarray = np.concatenate([[0.0], np.logspace(-4, 3, 43)])
