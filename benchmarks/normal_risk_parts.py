"""The normals criterion's estimate taken apart on one benchmark row, for averaging steps (``filtering``).

For each linearisation point ``--at`` (averaging steps giving the mesh ``R`` where the normals'
derivative ``J`` is taken) and each candidate count ``--steps``: Stein's estimate of the mean squared
turn (:func:`meshdenoise.tuning.normal_risk.normal_risk`), its parts (the residual term and the trace
terms, with the Hutchinson standard error), the same trace term computed on the noise realisation
itself (the clean mesh known), the linearised truth ``||J (HX - X0)||^2 / m`` and the true mean angle.
The noise level is the true one, so what is left is the estimate's own error. With ``--directions
clean`` the probes point along the clean mesh's normals (the noise's true directions) instead of
``R``'s.

    PYTHONPATH=. python benchmarks/normal_risk_parts.py "elephant rho=0.2" --at 38 77 240 --steps 38 77 240
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))


def parts(row: str, ats: list[int], steps: list[int], probes: int, directions: str, seed: int = 0) -> list[dict]:
    from peers import MESHES

    from meshdenoise.geometry import face_normals, vertex_normals
    from meshdenoise.operators import get_operators
    from meshdenoise.tuning.normal_risk import NORMAL_MIN_HEIGHT, NormalJacobian

    m = MESHES[row]()
    V0, F, X = m["V0"], m["F"], m["Vn"]
    n = len(X)
    P = get_operators(F, n).P
    eps = X - V0
    rho = float(np.sqrt(np.mean(np.sum(eps**2, axis=1))))

    def run(k: int, B: np.ndarray) -> np.ndarray:
        for _ in range(int(k)):
            B = P @ B
        return B

    N0f = face_normals(V0, F)
    Z = np.random.default_rng(seed).choice([-1.0, 1.0], size=(n, probes))
    out = []
    for at in ats:
        R = run(at, X)
        J = NormalJacobian(R, F, NORMAL_MIN_HEIGHT)
        c = J.counted
        m_ = max(int(np.count_nonzero(c)), 1)
        N = vertex_normals(V0 if directions == "clean" else R, F)
        B = [Z[:, [p]] * N for p in range(probes)]
        JB = [J(b)[c] for b in B]
        Jeps = J(eps)[c]
        for k in steps:
            Y = run(k, X)
            A = float(np.sum(J(Y - X)[c] ** 2)) / m_
            T = np.array([np.sum(jb * J(run(k, b))[c]) for jb, b in zip(JB, B)]) / m_
            C = np.array([np.sum(jb**2) for jb in JB]) / m_
            Nf = face_normals(Y, F)
            angle = np.arccos(np.clip(np.sum(Nf * N0f, axis=1), -1.0, 1.0))
            out.append({"at": at, "steps": k, "estimate": A + rho**2 * float(np.mean(2 * T - C)),
                        "residual": A, "trace": 2 * rho**2 * float(T.mean()),
                        "trace_se": 2 * rho**2 * float(T.std(ddof=1) / np.sqrt(probes)),
                        "trace_realised": 2 * float(np.sum(Jeps * J(run(k, eps))[c])) / m_,
                        "noise": rho**2 * float(C.mean()), "noise_realised": float(np.sum(Jeps**2)) / m_,
                        "linearised_truth": float(np.sum(J(Y - V0)[c] ** 2)) / m_,
                        "mean_angle_deg": float(np.degrees(angle.mean()))})
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("row")
    ap.add_argument("--at", nargs="+", type=int, required=True, help="averaging steps of the linearisation points")
    ap.add_argument("--steps", nargs="+", type=int, required=True, help="candidate averaging steps")
    ap.add_argument("--probes", type=int, default=8)
    ap.add_argument("--directions", choices=("smoothed", "clean"), default="smoothed")
    a = ap.parse_args(argv)
    keys = ("estimate", "residual", "trace", "trace_se", "trace_realised", "noise", "noise_realised",
            "linearised_truth", "mean_angle_deg")
    print("| at | steps | " + " | ".join(keys) + " |")
    print("|---|---|" + "---|" * len(keys))
    for r in parts(a.row, a.at, a.steps, a.probes, a.directions):
        print(f"| {r['at']} | {r['steps']} | " + " | ".join(f"{r[k]:.4f}" for k in keys) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
