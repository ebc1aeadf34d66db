"""Generic search for any other registered filter: a grid over one declared parameter, each seed filtered in turn."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..registry import get_filter
from .batch import NoisyBatch
from .result import SearchResult

__all__ = ["GridSpec", "GRIDS", "search_grid"]


@dataclass(frozen=True)
class GridSpec:
    """Values of one parameter of a registered filter to try, the others fixed.

    Parameters
    ----------
    param : str
        A parameter the filter declares (checked when the search runs).
    values : tuple
        Values to try, in order.
    given : dict
        Other parameters, held at these values (defaults otherwise); ``**given`` of
        :func:`~meshdenoise.tuning.choose.choose_parameters` is the same concept.
    log_scale : bool
        Plot the parameter on a log axis.
    """

    param: str
    values: tuple
    given: dict = field(default_factory=dict)
    log_scale: bool = True


# Filter name -> grid. An entry is used only when its filter is registered, so a new filter
# appears in the tables by adding one line here.
GRIDS: dict[str, GridSpec] = {
    # down to t = 1e-3, where the filter returns nearly its input: at low noise the best is "almost nothing"
    "sinkhorn": GridSpec("t", tuple(float(t) for t in np.logspace(-3, 2, 21))),
    "sobolev_bilaplacian": GridSpec("mu", tuple(float(m) for m in np.r_[0.0, np.logspace(-4, 3, 22)])),
}


def search_grid(batch: NoisyBatch, name: str, grid: GridSpec, advance=None) -> SearchResult:
    """SNR of the registered filter ``name`` at each value of ``grid.param``, for every seed.

    Examples
    --------
    >>> from meshdenoise.reproduce.batch import make_batch
    >>> from meshdenoise.shapes import icosphere
    >>> b = make_batch("sphere", *icosphere(1), rho=0.05, seeds=(0, 1))
    >>> r = search_grid(b, "sobolev", GridSpec("mu", (0.1, 1.0)))
    >>> [p["mu"] for p in r.params], r.snr.shape
    ([0.1, 1.0], (2, 2))"""
    spec = get_filter(name)
    try:
        spec.param(grid.param)
    except KeyError:
        declared = ", ".join(p.name for p in spec.params) or "none"
        raise ValueError(
            f"reproduce grid for filter '{name}': parameter '{grid.param}' is not declared; its parameters are {declared}"
        ) from None
    snr = np.empty((len(grid.values), batch.n_seeds))
    params = []
    for i, value in enumerate(grid.values):
        kwargs = {**grid.given, grid.param: value}
        params.append(kwargs)
        for s in range(batch.n_seeds):
            Y, _ = spec.public((batch.noisy(s).copy(), batch.F), operators=batch.ops, **kwargs)
            snr[i, s] = _snr_one(batch, Y)
        if advance is not None:
            advance(1.0 / len(grid.values))
    return SearchResult(
        name, batch.mesh, batch.rho, params, snr,
        figure_data={"param": grid.param, "values": np.array(grid.values, dtype=float), "snr": snr, "log": grid.log_scale},
        how=f"grid over {grid.param}, each seed filtered separately",
    )


def _snr_one(batch: NoisyBatch, Y: np.ndarray) -> float:
    err = Y - batch.V
    return float(-10.0 * np.log10(np.einsum("ij,ij->", err, err) / batch.clean_norm2))
