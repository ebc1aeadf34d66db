"""The sweep's charts: each measurement against a swept parameter, drawn with matplotlib and embedded as PNG."""

from __future__ import annotations

import base64
import io

from .sweeps import _is_numeric_param, _is_swept, _key, sweep_parameters, sweep_series
from .text import _e

_CHART_W, _CHART_H, _DPI = 2.9, 2.4, 100  # inches per panel; a chart of 4 panels is 1160 px wide


def _charts(rows: list[dict], sweep_keys: list[str] | None) -> str:
    """The sweep's charts: one per swept parameter, a panel per metric with points; nothing without a sweep."""
    params, metrics = sweep_parameters(rows, sweep_keys)
    keys = list(dict.fromkeys(k for r in rows for k in r))
    swept = [k for k in keys if _is_swept(k, sweep_keys)]
    out = []
    for param in params:
        shown = [m for m in metrics if any(sweep_series(rows, param, m, swept).values())]
        if not shown:
            continue
        png = _chart_png(rows, param, shown, swept)
        alt = f"{', '.join(shown)} against {param}"
        out.append(f"<figure><img src=\"data:image/png;base64,{base64.b64encode(png).decode('ascii')}\" "
                   f"alt=\"{_e(alt)}\" loading=\"eager\">"
                   f"<figcaption>{_e(alt)}</figcaption></figure>")
    return "<h3>Sweep</h3>" + "".join(out) if out else ""


def _chart_png(rows, param, metrics, swept) -> bytes:
    buf = io.BytesIO()
    _chart_figure(rows, param, metrics, swept).savefig(buf, format="png")
    return buf.getvalue()


def _plain(text) -> str:
    """User text for a matplotlib label: a ``$`` is shown as itself, never starts mathtext."""
    return str(text).replace("$", r"\$")


def _chart_figure(rows, param, metrics, swept):
    """The chart of ``metrics`` against ``param`` as a matplotlib Figure (no pyplot: no global state).

    Names from the rows (parameter, metric, input and method names) are escaped for mathtext
    (:func:`_plain`); tick labels keep matplotlib's own mathtext (a log axis labels ``10^-2`` as
    a power), so no ``$\\mathdefault{...}$`` source is ever drawn as text.
    """
    from matplotlib.figure import Figure

    n = len(metrics)
    ok = [r for r in rows if r.get("status", "ok") == "ok"]
    numeric = _is_numeric_param(ok, param)
    names = list(dict.fromkeys(_key(r[param]) for r in ok if param in r))
    height = _CHART_H if numeric else max(_CHART_H, 0.9 + 0.2 * len(names))
    fig = Figure(figsize=(_CHART_W * n, height), dpi=_DPI, layout="constrained")
    axes = fig.subplots(1, n, squeeze=False, sharey=not numeric)[0]
    series = {}
    for ax, metric in zip(axes, metrics):
        series = sweep_series(rows, param, metric, swept)
        for i, (label, pts) in enumerate(series.items()):
            if numeric:
                xs, ys = zip(*pts)
                ax.plot(xs, ys, marker="o", markersize=3, color=f"C{i % 10}", label=_plain(label) if label else None)
            else:  # one bar per value of the parameter (a method...), one colour per line
                bar = 0.8 / len(series)
                at = {name: j for j, name in enumerate(names)}
                ax.barh([at[x] + (i - (len(series) - 1) / 2) * bar for x, _ in pts], [y for _, y in pts],
                        height=bar, color=f"C{i % 10}", label=_plain(label) if label else None)
        if numeric:
            xs_all = [x for pts in series.values() for x, _ in pts]
            if xs_all and min(xs_all) > 0 and max(xs_all) / min(xs_all) >= 20:
                ax.set_xscale("log")
            ax.set_xlabel(_plain(param))
        else:
            ax.set_yticks(range(len(names)), [_plain(n) for n in names], fontsize=7)
            ax.tick_params(axis="y", labelleft=ax is axes[0])
            if ax is axes[0]:
                ax.invert_yaxis()  # the first value on top (the y axis is shared: invert it once)
        ax.set_title(_plain(metric), fontsize=10)
        ax.grid(True, alpha=0.3)
    if 1 < len(series) <= 12:  # the same lines in every panel: one legend under them
        handles, labels = axes[0].get_legend_handles_labels()
        per_label = 4.5 * max(len(lb) for lb in labels) + 45  # pixels of a 7-point label and its handle
        ncols = max(1, min(len(labels), int(_CHART_W * n * _DPI // per_label)))
        fig.legend(handles, labels, loc="outside lower center", ncols=ncols, fontsize=7, frameon=False)
    return fig
