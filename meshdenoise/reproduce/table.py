"""results.json (one row per mesh, noise level and method) and table.md (ours beside the paper's)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..io import atomic_path
from .paper import NOT_SELF_CONSISTENT, PAPER_MS, PAPER_PARAMS, PAPER_SNR, TAU_GRID
from .result import SearchResult

__all__ = ["make_row", "write_json", "write_table", "tolerance", "ROW_KEYS"]

ROW_KEYS = ("mesh", "rho", "method", "noisy_snr", "best_snr", "best_snr_std", "best_params", "seconds")


def tolerance(std: float) -> float:
    """The issue's agreement band: 0.5 dB, or two standard deviations over seeds where that is larger.

    Examples
    --------
    >>> tolerance(0.1), tolerance(0.4)
    (0.5, 0.8)"""
    return max(0.5, 2.0 * std)


def _plain(value):
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def make_row(result: SearchResult, timing: dict, noisy_snr: np.ndarray, seeds: tuple[int, ...]) -> dict:
    """One results.json row: the issue's keys first, then what explains them."""
    key = (result.mesh, result.rho)
    paper = PAPER_SNR.get(key, {})
    row = {
        "mesh": result.mesh,
        "rho": result.rho,
        "method": result.method,
        "noisy_snr": float(np.mean(noisy_snr)),
        "best_snr": result.best_snr,
        "best_snr_std": result.best_snr_std,
        "best_params": result.best_params,
        "seconds": timing["seconds"],
        "seconds_cold": timing["seconds_cold"],
        "timing_repeats": timing["repeats"],
        "per_seed_best_snr": result.per_seed_best_snr,
        "seeds": list(seeds),
        "settings_searched": len(result.params),
        "search": result.how,
        "notes": list(result.notes),
        "paper_snr": paper.get(result.method),
        "paper_noisy_snr": paper.get("noisy"),
        "paper_ms": PAPER_MS.get(key, {}).get(result.method),
    }
    return _plain(row)


def write_json(rows: list[dict], path: Path) -> Path:
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(rows, indent=1) + "\n")
    return path


def _fmt_params(params: dict) -> str:
    return ", ".join(f"{k} = {v:.3g}" if isinstance(v, float) else f"{k} = {v}" for k, v in params.items())


def write_table(rows: list[dict], noisy: dict, path: Path, elapsed: float, n_seeds: int) -> Path:
    """table.md: SNR and times beside the paper's, agreement per row, notes and a short comparison.

    ``noisy[(mesh, rho)]`` is the (mean, std) SNR of the noisy inputs.
    """
    lines = [
        "# Reproduction of \"Mesh Denoising\" (2022): best SNR per method, ours beside the paper's",
        "",
        f"Ours: mean ± sample std over {n_seeds} noise seed(s) of the SNR at the setting with the best mean; the paper "
        "used one noise draw. Agreement: |ours - paper| <= max(0.5 dB, 2 std). Whole run: "
        f"{elapsed:.0f} s.",
        "",
        "| mesh | rho | method | paper (dB) | ours (dB) | ours - paper | agrees | our best setting | paper's setting |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    outside, flagged = [], []
    for key in dict.fromkeys((r["mesh"], r["rho"]) for r in rows):
        mean, std = noisy[key]
        p = PAPER_SNR.get(key, {}).get("noisy")
        lines.append(_line(key, "noisy input", p, mean, std, "", "", outside, flagged))
        for r in (r for r in rows if (r["mesh"], r["rho"]) == key):
            paper_params = PAPER_PARAMS.get(key, {}).get(r["method"], "")
            lines.append(_line(key, r["method"], r["paper_snr"], r["best_snr"], r["best_snr_std"],
                               _fmt_params(r["best_params"]), paper_params, outside, flagged))
    lines += ["", "## Times of the best settings (ms, one call, median of repeats in one process)", "",
              "| mesh | rho | method | setting | ours | ours, first call (factorisation) | paper |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        cold = f"{r['seconds_cold'] * 1e3:.3g}" if r.get("seconds_cold") else ""
        paper_ms = f"{r['paper_ms']:g}" if r.get("paper_ms") is not None else ""
        if (r["mesh"], r["rho"], r["method"] + ":time") in NOT_SELF_CONSISTENT:
            paper_ms += " (timed an empty call)"
        lines.append(f"| {r['mesh']} | {r['rho']:g} | {r['method']} | {_fmt_params(r['best_params'])} | "
                     f"{r['seconds'] * 1e3:.3g} | {cold} | {paper_ms} |")
    lines += ["", "## Notes", ""]
    for reason in flagged:
        lines.append(f"- Not self-consistent in the paper: {reason}")
    for r in rows:
        for note in r["notes"]:
            lines.append(f"- {r['mesh']} rho = {r['rho']:g}, {r['method']}: {note}.")
    lines.append(f"- Heat step grid: the paper's {TAU_GRID.size} values 10^-2.5 .. 10^0.3 ({TAU_GRID[-2]:.3g} and "
                 f"{TAU_GRID[-1]:.3g} are its last two). Our heat runs ceil(T / tau) Euler steps of length tau, so the "
                 "searched times are the multiples k tau.")
    for method in dict.fromkeys(r["method"] for r in rows):
        hows = sorted({f"{r['mesh']}: {r['search']}" for r in rows if r["method"] == method})
        lines.append(f"- How {method} was searched: " + "; ".join(hows) + ".")
    lines += ["", "## Comparison", ""]
    lines += _comparison(rows, outside)
    with atomic_path(path) as tmp:
        tmp.write_text("\n".join(lines) + "\n")
    return path


def _line(key, method, paper, mean, std, ours_params, paper_params, outside, flagged) -> str:
    mesh, rho = key
    reason = NOT_SELF_CONSISTENT.get((mesh, rho, method))
    if paper is None:
        diff, verdict = "", "no paper figure"
    else:
        d = mean - paper
        diff = f"{d:+.2f}"
        if reason:
            verdict = "paper not self-consistent"
            flagged.append(f"{mesh} rho = {rho:g} {method}: {reason}; ours is {mean:.2f} dB.")
        elif abs(d) <= tolerance(std):
            verdict = "yes"
        else:
            verdict = f"no (band {tolerance(std):.2f})"
            outside.append((mesh, rho, method, mean, paper, std))
    paper_text = "" if paper is None else f"{paper:.2f}"
    return (f"| {mesh} | {rho:g} | {method} | {paper_text} | {mean:.2f} ± {std:.2f} | {diff} | {verdict} | "
            f"{ours_params} | {paper_params} |")


def _comparison(rows: list[dict], outside: list) -> list[str]:
    compared = [r for r in rows if r["paper_snr"] is not None
                and (r["mesh"], r["rho"], r["method"]) not in NOT_SELF_CONSISTENT]
    out = [f"- {len(compared) - len([o for o in outside if o[2] != 'noisy input'])} of {len(compared)} comparable "
           "best-SNR figures agree with the paper within max(0.5 dB, 2 std)."]
    for mesh, rho, method, mean, paper, std in outside:
        out.append(f"- Outside the band: {mesh} rho = {rho:g} {method}: ours {mean:.2f} ± {std:.2f} dB, paper {paper:.2f} "
                   f"({mean - paper:+.2f} dB). See the explanation below.")
    out += ["", "### Findings behind the differences (reference run: 5 seeds; numbers in the README section Reproducing the paper)", ""]
    out += EXPLANATIONS
    return out


# Findings of the investigation behind the table (the README section "Reproducing the paper" gives the numbers behind each).
EXPLANATIONS: list[str] = [
    "- Elephant: every figure agrees within 0.3 dB (ours slightly higher: our search grids are finer, and we average "
    "5 draws where the paper has one). Filtering and heat tie, as in the paper: the best heat step is tau ~ 1, where "
    "heat is filtering.",
    "- Nefertiti (299 vertices) moves with the draw, and 5 seeds underestimate the spread: at rho = 1 the best "
    "filtering SNR over 20 seeds is 15.83 ± 0.90 dB and over 200 seeds 16.02 ± 0.76 dB, so the paper's 14.56 (one "
    "draw) lies within 2 std of our mean; with --seeds 20 every Nefertiti figure agrees. Checked and ruled out as "
    "causes of a systematic gap (each moves the means by < 0.15 dB): area-weighted instead of unit-face-normal vertex "
    "normals, isotropic noise of the same energy, uniform instead of Gaussian eps, and an SNR normalised by the "
    "candidate instead of the clean mesh (that one breaks the noisy SNR by +1.2 dB).",
    "- Heat beats filtering on Nefertiti at rho = 0.2 by ~1.5 dB (paper: 1.0 dB): a step tau ~ 0.7 is a gentler, "
    "finer-grained smoother than one full averaging step, and the best filtering count is a single step.",
    "- The paper's tau grid reaches 1.42 and 2.0; both exceed the stability bound of both meshes (1.35 elephant, 1.29 "
    "Nefertiti), so explicit Euler diverges there (the paper saw 1.42 diverge); we skip them and say so above.",
    "- Times: ours are one call of the public filter with cached operators (warm), median of repeats in one process; "
    "the first Sobolev call on a mesh also factorises I + mu L (column 'first call'). The paper's Sobolev 0.0349 ms "
    "measured an empty function. Absolute times depend on the machine and its load.",
]
