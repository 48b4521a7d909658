"""Volumetric locking evidence: flat-punch force against mesh size at nu = 0.45, 0.49, 0.499 and 0.4999.

A homogeneous layer (thickness h = 5 mm, 60 x 60 mm, bonded to a rigid base) is indented by a frictionless
flat punch of radius a = 5 mm (a/h = 1) to 0.5 % of h (small strain). The force is compared with Hayes et al.
(1972), ``F = 4 G a kappa d / (1 - nu)``, kappa from :func:`latticeopt.mechanics.verification.hayes_kappa`.
Plain P1 tets (``element``) lock as nu -> 0.5: their force is too high and falls slowly with refinement.
The patch (mean-dilatation) formulation converges at every nu.

    python benchmarks/bench_locking.py            # prints the table (about a minute on this machine)
"""

from __future__ import annotations

import os
import sys
import time

for _v in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import numpy as np  # noqa: E402

from latticeopt.mechanics import IndentationSolver, IndentSettings, Materials, NeoHookean  # noqa: E402
from latticeopt.mechanics.verification import block_mesh, graded_axis, hayes_kappa  # noqa: E402

H, A, SIDE, G_KPA = 5.0, 5.0, 60.0, 20.0


def layer_mesh(fine_mm: float):
    xy = graded_axis(SIDE, SIDE / 2, 1.4 * A, fine_mm, 4.0)
    z = np.linspace(0.0, H, int(round(H / fine_mm)) + 1)
    return block_mesh(xy, xy, z)


def force(mesh, nu: float, volumetric: str) -> float:
    mat = Materials.uniform(NeoHookean(G_KPA, nu))
    s = IndentSettings(materials=mat, in_plane="frictionless", volumetric=volumetric)
    res = IndentationSolver(mesh, s).solve([(SIDE / 2, SIDE / 2, A, 0.005 * H)])
    return float(res.forces_N[0])


def main(sizes=(1.25, 1.0, 0.625, 0.5)) -> None:
    print(f"frictionless flat punch, a = {A} mm on a bonded layer h = {H} mm, {SIDE} mm wide, d = {0.005 * H} mm")
    print("force / Hayes force (kappa from the Fredholm equation); nodes per mesh in brackets")
    header = f"{'nu':>6} {'formulation':>11} " + " ".join(f"{'h=' + format(s, 'g') + ' mm':>18}" for s in sizes)
    print(header)
    meshes = [layer_mesh(s) for s in sizes]
    for nu in (0.45, 0.49, 0.499, 0.4999):
        ref = 4 * G_KPA * 1e-3 * A * hayes_kappa(A / H, nu) * 0.005 * H / (1 - nu)
        for vol in ("element", "patch"):
            row = []
            for m in meshes:
                t = time.perf_counter()
                row.append(f"{force(m, nu, vol) / ref:8.4f} ({m.n_nodes:6d})")
                _ = time.perf_counter() - t
            print(f"{nu:6g} {vol:>11} " + " ".join(f"{c:>18}" for c in row), flush=True)
        print(f"{'':6} {'Hayes F':>11} {ref:.5g} N (kappa = {hayes_kappa(A / H, nu):.4f})")


if __name__ == "__main__":
    main(tuple(float(a) for a in sys.argv[1:]) or (1.25, 1.0, 0.625, 0.5))
