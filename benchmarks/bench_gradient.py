"""Cost of the adjoint gradient against the forward press, and Newton iterations saved by a warm start.

    python benchmarks/bench_gradient.py                      # default 2 mm mesh, 50 x 50 cells, 3 phantoms
    python benchmarks/bench_gradient.py --size 6 --cells 10  # coarse, a minute

For the first phantoms of the quick study's seed (1, 2 and 3 touches) on the w = 4, t = 3 lattice's density: the
forward press (mechanics and electrics, V_rel, force and stretch) and the three gradients (V_rel, force,
stretch: three solves on the converged tangent by GMRES preconditioned by the last Newton factorization), with
operation counts beside the times; then the same phantoms on a nearby density (a smooth change of 0.02) solved
cold and warm-started from the first layout's displacement.
"""

from __future__ import annotations

import argparse
import os

import numpy as np

from latticeopt import LatticeDesign, MeshSettings
from latticeopt.coupled import PhysicsSettings
from latticeopt.density import DensityModel, density_of_design
from latticeopt.study.phantoms import random_phantoms


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", type=float, default=2.0)
    ap.add_argument("--cells", type=int, default=50)
    ap.add_argument("--seed", type=int, default=2025)
    args = ap.parse_args()
    design = LatticeDesign(width_mm=4.0, thickness_mm=3.0)
    density = density_of_design(design, args.cells)
    phantoms = random_phantoms(design.size_mm, {1: 1, 2: 1, 3: 1}, args.seed)
    presses = [list(p.touches) for p in phantoms]
    model = DensityModel(design, args.cells, MeshSettings(size_mm=args.size), PhysicsSettings())
    print(f"mesh {args.size:g} mm ({model.mesh.n_nodes} nodes, {3 * model.mesh.n_nodes} mechanics DOFs), "
          f"{args.cells} x {args.cells} cells, threads {os.environ.get('OMP_NUM_THREADS', 'default')}; "
          f"set-up {model.setup_seconds:.1f} s")
    print("\n| phantom | touches | forward s | gradient s | ratio | Newton steps | factorizations | GMRES its "
          "| adjoint GMRES its (3 solves) | adjoint factorizations |\n|---|---|---|---|---|---|---|---|---|---|")
    forward_total = grad_total = 0.0
    first = model.evaluate(density, presses)
    for k, p in enumerate(first.presses):
        fwd = p.timings["mechanics"] + p.timings["electrics"]
        c = p.counts
        forward_total += fwd
        grad_total += p.timings["gradient"]
        print(f"| {k} | {len(presses[k])} | {fwd:.2f} | {p.timings['gradient']:.2f} | "
              f"{(fwd + p.timings['gradient']) / fwd:.2f} | {c['newton_steps']} | {c['factorizations']} | "
              f"{c['krylov_iterations']} | {c['adjoint_krylov_iterations']} | {c['adjoint_factorizations']} |")
    print(f"| all | | {forward_total:.2f} | {grad_total:.2f} | {(forward_total + grad_total) / forward_total:.2f} "
          "| | | | | |")
    y, x = (np.mgrid[0:args.cells, 0:args.cells] + 0.5) / args.cells
    nearby = np.clip(density + 0.02 * np.cos(np.pi * x) * np.cos(2 * np.pi * y), 0, 1)
    cold = model.evaluate(nearby, presses, gradient=False)
    warm = model.evaluate(nearby, presses, gradient=False, warm=[p.displacement_mm for p in first.presses])
    print("\n| phantom | cold Newton steps | cold factorizations | cold s | warm Newton steps | warm factorizations "
          "| warm s | warm converged in one step | V_rel difference |\n|---|---|---|---|---|---|---|---|---|")
    for k, (c, w) in enumerate(zip(cold.presses, warm.presses)):
        print(f"| {k} | {c.counts['newton_steps']} | {c.counts['factorizations']} | {c.timings['mechanics']:.2f} | "
              f"{w.counts['newton_steps']} | {w.counts['factorizations']} | {w.timings['mechanics']:.2f} | "
              f"{w.warm_start} | {abs(w.v_rel - c.v_rel):.1e} |")
    cs = sum(p.counts["newton_steps"] for p in cold.presses)
    ws = sum(p.counts["newton_steps"] for p in warm.presses)
    ct = sum(p.timings["mechanics"] for p in cold.presses)
    wt = sum(p.timings["mechanics"] for p in warm.presses)
    print(f"\nwarm start: {ws} Newton steps against {cs} ({1 - ws / cs:.0%} fewer), mechanics {wt:.1f} s against "
          f"{ct:.1f} s")


if __name__ == "__main__":
    main()
