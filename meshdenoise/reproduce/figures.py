"""The paper's figures as PNG (matplotlib, Agg backend): SNR along each parameter, and time per parameter."""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only, never a window
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ..io import atomic_path  # noqa: E402
from .result import SearchResult  # noqa: E402

__all__ = ["write_figures"]


def _panels(count: int, title: str):
    cols = min(3, count)
    rows = math.ceil(count / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.6 * cols, 3.6 * rows), squeeze=False)
    for ax in axes.ravel()[count:]:
        ax.set_visible(False)
    fig.suptitle(title)
    return fig, axes.ravel()


def _save(fig, path: Path) -> Path:
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
    return path


def _band(ax, x, snr, label=None, **kw):
    mean, std = snr.mean(axis=1), snr.std(axis=1)
    (line,) = ax.plot(x, mean, label=label, **kw)
    if snr.shape[1] > 1:
        ax.fill_between(x, mean - std, mean + std, color=line.get_color(), alpha=0.2, lw=0)


def _label(r: SearchResult) -> str:
    return f"{r.mesh}, rho = {r.rho:g}"


def _noisy(ax, r: SearchResult):
    ax.axhline(r.snr[0].mean(), color="grey", ls=":", lw=1, label="noisy input")


def filtering_figure(results: list[SearchResult], path: Path) -> Path:
    fig, axes = _panels(len(results), "Linear filtering: SNR vs number of iterations (mean ± std over seeds)")
    for ax, r in zip(axes, results):
        _band(ax, r.figure_data["iterations"], r.figure_data["snr"])
        ax.axvline(r.best_params["iterations"], color="k", lw=0.8, ls="--")
        _noisy(ax, r)
        ax.set(title=_label(r), xlabel="iterations k", ylabel="SNR (dB)")
    return _save(fig, path)


def _some_taus(taus: list[float], count: int = 6) -> list[float]:
    idx = np.unique(np.linspace(0, len(taus) - 1, count).round().astype(int))
    return [taus[i] for i in idx]


def heat_time_figure(results: list[SearchResult], path: Path) -> Path:
    fig, axes = _panels(len(results), "Heat diffusion: SNR vs time T for several steps tau")
    for ax, r in zip(axes, results):
        curves = r.figure_data["curves"]
        for tau in _some_taus(sorted(curves)):
            times, snr = curves[tau]
            ax.plot(times, snr.mean(axis=1), label=f"tau = {tau:.3g}")
        _noisy(ax, r)
        ax.set(title=_label(r), xlabel="T", ylabel="SNR (dB)")
        ax.legend(fontsize=7)
    return _save(fig, path)


def heat_tau_figure(results: list[SearchResult], path: Path) -> Path:
    fig, axes = _panels(len(results), "Heat diffusion: best SNR over T vs tau (unstable tau skipped)")
    for ax, r in zip(axes, results):
        curves = r.figure_data["curves"]
        taus = sorted(curves)
        best = np.array([curves[t][1].mean(axis=1).max() for t in taus])
        ax.semilogx(taus, best, "o-", ms=3)
        ax.axvline(r.figure_data["bound"], color="r", lw=0.8, ls="--", label="stability bound 2/lambda_max")
        for t in r.figure_data["unstable"]:
            ax.axvline(t, color="r", lw=0.5, alpha=0.4)
        _noisy(ax, r)
        ax.set(title=_label(r), xlabel="tau", ylabel="best SNR (dB)")
        ax.legend(fontsize=7)
    return _save(fig, path)


def sobolev_figure(results: list[SearchResult], path: Path) -> Path:
    fig, axes = _panels(len(results), "Sobolev: SNR vs mu (mean ± std over seeds)")
    for ax, r in zip(axes, results):
        mu = r.figure_data["mu"]
        keep = mu > 0
        _band(ax, mu[keep], r.figure_data["snr"][keep])
        ax.set_xscale("log")
        ax.axvline(r.best_params["mu"] or mu[keep][0], color="k", lw=0.8, ls="--")
        _noisy(ax, r)
        ax.set(title=_label(r), xlabel="mu", ylabel="SNR (dB)")
    return _save(fig, path)


def grid_figure(results: list[SearchResult], path: Path) -> Path:
    name = results[0].method
    param = results[0].figure_data["param"]
    fig, axes = _panels(len(results), f"{name}: SNR vs {param} (mean ± std over seeds)")
    for ax, r in zip(axes, results):
        _band(ax, r.figure_data["values"], r.figure_data["snr"])
        if r.figure_data["log"]:
            ax.set_xscale("log")
        ax.set(title=_label(r), xlabel=param, ylabel="SNR (dB)")
    return _save(fig, path)


def time_figure(curves: dict[str, dict[str, dict]], path: Path) -> Path:
    """``curves[mesh][method]`` as returned by :func:`~.timing.time_curve`."""
    methods = sorted({m for per_mesh in curves.values() for m in per_mesh})
    fig, axes = _panels(len(methods), "Time of one call vs parameter (median of repeats)")
    for ax, method in zip(axes, methods):
        for mesh, per_mesh in curves.items():
            c = per_mesh.get(method)
            if c is None:
                continue
            (line,) = ax.loglog(c["values"], np.array(c["seconds"]) * 1e3, "o-", ms=3, label=f"{mesh}")
            if c.get("seconds_cold"):
                ax.loglog(c["values"], np.array(c["seconds_cold"]) * 1e3, "s--", ms=3, color=line.get_color(),
                          label=f"{mesh}, with factorisation")
            param = c["param"]
        ax.set(title=method, xlabel=param, ylabel="ms")
        ax.legend(fontsize=6, loc="center right")
    return _save(fig, path)


FIGURES = {
    "filtering": [("filtering_snr_vs_iterations.png", filtering_figure)],
    "heat": [("heat_snr_vs_time.png", heat_time_figure), ("heat_best_snr_vs_tau.png", heat_tau_figure)],
    "sobolev": [("sobolev_snr_vs_mu.png", sobolev_figure)],
}


def write_figures(results: list[SearchResult], time_curves: dict, out_dir: Path) -> list[Path]:
    """Write every figure for ``results`` (grouped by method) and the timing curves; returns the paths."""
    out_dir = Path(out_dir)
    written = []
    for method in dict.fromkeys(r.method for r in results):
        group = [r for r in results if r.method == method]
        for name, draw in FIGURES.get(method, [(f"{method}_snr_vs_parameter.png", grid_figure)]):
            written.append(draw(group, out_dir / name))
    if time_curves:
        written.append(time_figure(time_curves, out_dir / "time_vs_parameter.png"))
    return written
