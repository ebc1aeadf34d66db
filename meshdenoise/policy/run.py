"""The default run end to end: choose, run the choice with its guard, give the mesh back in its own type."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..adapters import read_mesh
from ..locality import LOCALITY_MIN_VERTICES, relabelled_operators, relabelling
from ..operators import get_operators
from ..progress import stage
from ..registry import get_filter
from .choose import NONE, DefaultChoice, choose, guard
from .config import DefaultConfig

__all__ = ["choose_default", "run_default"]


def _normalised(V: np.ndarray) -> tuple[np.ndarray, int]:
    """``V`` divided by a power of two ``2^k`` near its extent, and ``k``: exact (pinned vertices come back bit for
    bit), and the choice sees the same numbers at any scale (1e-150 or 1e150 included)."""
    extent = float(np.abs(V).max()) if V.size else 0.0
    k = int(np.frexp(extent)[1]) if extent > 0 and np.isfinite(extent) else 0
    return np.ldexp(V, -k), k


def _chosen(m: Any, config: DefaultConfig | None) -> tuple[np.ndarray, int, Any, DefaultChoice, DefaultConfig]:
    """The normalised vertices, their power of two, the operators and the choice for the read mesh ``m``."""
    config = DefaultConfig() if config is None else config
    X, k = _normalised(m.V)
    ops = get_operators(m.F, len(X))
    with stage("choosing the filter"):
        choice = choose(X, m.F, ops, config)
    return X, k, ops, choice, config


def choose_default(mesh: Any, config: DefaultConfig | None = None) -> DefaultChoice:
    """What :func:`run_default` would run on ``mesh``: the filter and its parameters (nothing run).

    Parameters
    ----------
    mesh : (V, F) tuple, pymeshlab.MeshSet or Mesh, or open3d.geometry.TriangleMesh
    config : DefaultConfig, optional

    Returns
    -------
    DefaultChoice
    """
    _, k, _, choice, _ = _chosen(read_mesh(mesh), config)
    return choice.rescaled(k)


def run_default(mesh: Any, config: DefaultConfig | None = None, **options: Any) -> tuple[Any, DefaultChoice]:
    """Choose (:func:`choose_default`), run the choice under its flip guard, return ``(mesh, choice)``.

    ``options`` are the common filter options (``boundary_motion``, ``pinned``, ``region``,
    ``preserve_volume``, ``operators``), passed to the chosen filter's runs.
    """
    m = read_mesh(mesh)
    X, k, ops, choice, config = _chosen(m, config)
    if choice.method == NONE:
        return m.write(np.array(m.V, dtype=np.float64)), choice.rescaled(k)
    spec = get_filter(choice.method)
    with stage(f"running {choice.method}"):
        if choice.method == "two_stage" and len(X) >= LOCALITY_MIN_VERTICES:
            # two_stage reads none of the vertex matrices of a large mesh (it runs in locality order, read from the
            # faces), and the guard reads the degrees and the border only: kept, the matrices dropped before the run's
            # peak (W, P and the edges: about 160 bytes per vertex)
            ops.degree, ops.boundary_vertices
        if options.get("operators") is None:
            # the vertex order the filter's run asks for (meshdenoise.locality, kept for it), from the adjacency the
            # choice built: not a second one; its operators know the border already
            r = relabelling(m.F, len(X), ops)
            if r is not None:
                relabelled_operators(r, ops)
        if choice.method == "two_stage" and len(X) >= LOCALITY_MIN_VERTICES:
            ops.drop_matrices()
        Y = guard(choice, X, m.F, ops, lambda params: spec.public((X, m.F), **params, **options)[0],
                  config.unfold_rounds)
    return m.write(np.ldexp(Y, k)), choice.rescaled(k)
