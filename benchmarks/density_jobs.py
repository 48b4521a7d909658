"""Pressing a density layout's phantoms in worker processes (``DensityModel.evaluate(..., jobs=N)``) against one
process: wall time of a cold evaluation (the optimizer's first iterate) and of a warm-started one (every later
iterate), with the Newton steps beside them, and whether the results agree.

    python benchmarks/density_jobs.py                          # default 2 mm mesh, 50 x 50 cells, 6 phantoms
    python benchmarks/density_jobs.py --size 6 --cells 10 --phantoms 4   # coarse, a minute

The layout is the w = 4, t = 3 lattice as a density; the warm evaluation is a nearby density (a smooth change of
0.02) started from the cold one's displacements, as an optimizer's next iterate is. The workers build their own
model on their first task (its set-up is part of the first parallel evaluation and printed apart) and keep it.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from latticeopt import LatticeDesign, MeshSettings
from latticeopt.coupled import PhysicsSettings
from latticeopt.density import DensityModel, density_of_design
from latticeopt.study.phantoms import random_phantoms


def timed(model, density, presses, warm, jobs):
    t0 = time.perf_counter()
    ev = model.evaluate(density, presses, warm=warm, jobs=jobs)
    return ev, time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", type=float, default=2.0)
    ap.add_argument("--cells", type=int, default=50)
    ap.add_argument("--phantoms", type=int, default=6, help="phantoms, a third each of 1, 2 and 3 touches")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--seed", type=int, default=2025)
    args = ap.parse_args()
    design = LatticeDesign(width_mm=4.0, thickness_mm=3.0)
    density = density_of_design(design, args.cells)
    y, x = np.mgrid[0:args.cells, 0:args.cells] / args.cells
    nearby = np.clip(density + 0.02 * np.sin(2 * np.pi * x) * np.cos(np.pi * y), 0, 1)
    k = -(-args.phantoms // 3)
    phantoms = random_phantoms(design.size_mm, {1: k, 2: k, 3: k}, args.seed)[:args.phantoms]
    presses = [list(p.touches) for p in phantoms]
    model = DensityModel(design, args.cells, MeshSettings(size_mm=args.size), PhysicsSettings())
    print(f"mesh {args.size:g} mm ({model.mesh.n_nodes} nodes), {args.cells} x {args.cells} cells, "
          f"{len(presses)} phantoms, {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}; "
          f"model set-up {model.setup_seconds:.1f} s")
    print("\n| jobs | cold s | cold Newton | warm s | warm Newton | warm presses in one step |")
    print("|---|---|---|---|---|---|")
    rows = {}
    for jobs in (1, args.jobs):
        cold, t_cold = timed(model, density, presses, None, jobs)
        warm, t_warm = timed(model, nearby, presses, [p.displacement_mm for p in cold.presses], jobs)
        rows[jobs] = (cold, t_cold, warm, t_warm)
        print(f"| {jobs} | {t_cold:.1f} | {sum(p.newton_steps for p in cold.presses)} | {t_warm:.1f} | "
              f"{sum(p.newton_steps for p in warm.presses)} | "
              f"{sum(p.warm_start and p.newton_steps == 1 for p in warm.presses)} of {len(presses)} |", flush=True)
    (c1, tc1, w1, tw1), (cn, tcn, wn, twn) = rows[1], rows[args.jobs]
    print(f"\nspeed-up with {args.jobs} workers: cold {tc1 / tcn:.2f}x (includes each worker's model set-up), "
          f"warm {tw1 / twn:.2f}x")
    dv = max(abs(a.v_rel - b.v_rel) / abs(a.v_rel) for a, b in zip(c1.presses + w1.presses, cn.presses + wn.presses))
    dg = max(np.abs(a.dv_rel - b.dv_rel).max() / np.abs(a.dv_rel).max()
             for a, b in zip(c1.presses + w1.presses, cn.presses + wn.presses))
    print(f"largest relative difference, one process against workers: V_rel {dv:.1e}, gradient {dg:.1e}")


if __name__ == "__main__":
    main()
