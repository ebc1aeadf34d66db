"""``sobolev_normal``'s settings and its projected update, which its filter and its rule share.

:class:`SobolevNormalConfig` holds the sizes that choose the filter's and its rule's paths (``plugins/sobolev_normal.py``
and ``plugins/sobolev_normal_rule.py`` read them); :func:`project_update` keeps the normal part of a smoothing's
update and a share of its tangential part, the filter's last step and the step its rule scores each candidate by."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..tuning.config import check_fields

__all__ = ["project_update", "SobolevNormalConfig", "DEFAULT", "SOBOLEV_NORMAL_ORDERS"]

def project_update(X: np.ndarray, Y: np.ndarray, N: np.ndarray, tangential: float) -> np.ndarray:
    """``x_i + (n_i n_i^T + t (I - n_i n_i^T)) (y_i - x_i)`` for every vertex (rows of ``X``, ``Y``, ``N``).

    .. math:: x'_i = x_i + \\big(n_i n_i^T + t\\,(I - n_i n_i^T)\\big)(y_i - x_i)

    ``t = tangential``: 0 keeps only the normal part of the update, 1 the whole update.

    Examples
    --------
    >>> import numpy as np
    >>> X = np.zeros((1, 3)); Y = np.array([[1.0, 2.0, 3.0]]); N = np.array([[0.0, 0.0, 1.0]])
    >>> project_update(X, Y, N, 0.0).tolist(), project_update(X, Y, N, 0.5).tolist()
    ([[0.0, 0.0, 3.0]], [[0.5, 1.0, 3.0]])
    """
    D = Y - X
    normal = np.einsum("ij,ij->i", D, N)[:, None] * N
    return X + normal + tangential * (D - normal)


SOBOLEV_NORMAL_ORDERS = (2, 3)  # candidate Laplacian powers of the automatic sobolev_normal rule


@dataclass(frozen=True)
class SobolevNormalConfig:
    """``sobolev_normal``'s paths by size, for its filter (``core(..., config=)``) and its rule
    (``choose_parameters(..., config=)``): the values, and where they were measured.

    Attributes
    ----------
    lanczos_min_vertices : int
        Without pinned vertices the filter factorises nothing from this size (the default runs ``sobolev_normal`` on
        small meshes only, so a run is a one-off here) ...
    pinned_cg_bound : float
        ... and with them solves by CG while its iteration bound is at most this (face000, its border held, mu 6.7:
        order 2, bound 370, 192 iterations, 0.58 s against a 1.22 s factor; order 3, bound 1,280, 531 iterations, 2.8
        against 3.3 s).
    order_margin : float
        An order's log search is refined when its grid's parabola predicts a score within this share of the least
        grid score (a refinement gains about 1 % on a grid 0.75 decades apart; the other order's search was half the
        rule's factorisations).
    rule_lanczos_min_vertices : int
        The whole-mesh rule's candidates by one Lanczos run from this size (the Bunny0.2's 14 candidates were 21
        factors and 23 51-column solves, 8.5 s), for the candidates whose poles lie ...
    rule_lanczos_reach : float
        ... near enough: d_max mu^(1/p) at most this (the steps grow like its square root, a factor costs the same at
        any mu: the elephant's grid reached mu = 10^3.9, 1.9 s a candidate by Lanczos at 1e-10; at the searches' 1e-6,
        25 -> 50 took the bunny scanner's two factored candidates into the run, 3.7 -> 3.2 s).
    batch_bytes : int
        Both orders' first grids in one second pass of that run while their results take at most this many bytes
        (Bunny0.2: 10 candidates of 51 columns, 142 MB; one pass fewer than a pass per order).
    region : int
        From ``SearchConfig.region_min_vertices`` the rule runs on a sampled region of this many vertices ...
    patches : int
        ... made of this many balls of vertices ...
    pin : int
        ... its vertices this few rings from a cut held at the whole mesh's result for each candidate (Dirichlet
        data, not a free border, whose drift biased the choice low: docs/scale.md); 0: a free border.
    divergence_chunk_bytes : int
        The Monte-Carlo divergence's probe terms ((n, 3) each) held at once, at most this many bytes.
    """

    lanczos_min_vertices: int = 20_000
    pinned_cg_bound: float = 600
    order_margin: float = 0.02
    rule_lanczos_min_vertices: int = 20_000
    rule_lanczos_reach: float = 50.0
    batch_bytes: int = 256 << 20
    region: int = 16_000
    patches: int = 8
    pin: int = max(SOBOLEV_NORMAL_ORDERS)
    divergence_chunk_bytes: int = 64 << 20

    def __post_init__(self) -> None:
        check_fields(self, positive=("region", "patches"),
                     nonnegative=("lanczos_min_vertices", "pinned_cg_bound", "order_margin", "rule_lanczos_min_vertices",
                                  "rule_lanczos_reach", "batch_bytes", "pin", "divergence_chunk_bytes"))


DEFAULT = SobolevNormalConfig()
