"""The sharp limit: a 0/1 density drawn from the square lattice against the conforming mesh of that lattice.

    python benchmarks/density_sharp_limit.py   # density meshes 4 and 2 mm, conforming 4, 2 and 1.4 mm

The density of the w = 4, t = 3 lattice on 200 x 200 cells (0.5 mm: every channel edge lies on a cell edge, so
every cell is 0 or 1) is solved by the density model on its fixed grid mesh of each size (an element that an
edge crosses takes the average of its cells), and the lattice itself by the grid mesher's conforming mesh
(electrics on the gel alone), for a centre and an off-centre press. The density model's V_rel should differ
from the conforming one by no more than the conforming mesh's own change under refinement.
"""

from __future__ import annotations

import argparse
import time

from latticeopt import LatticeDesign, MeshSettings
from latticeopt.coupled import CoupledModel
from latticeopt.density import DensityModel, density_of_design
from latticeopt.touches import Touch

PRESSES = {"centre": Touch(50.0, 50.0, 8.75, 3.0), "off-centre": Touch(31.25, 68.75, 8.75, 3.0)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--density-sizes", type=float, nargs="+", default=[4.0, 2.0])
    ap.add_argument("--conforming-sizes", type=float, nargs="*", default=[4.0, 2.0, 1.4])
    ap.add_argument("--cells", type=int, default=200)
    ap.add_argument("--sharp-lines", action="store_true",
                    help="grid lines on the density's jumps (what simulate --density does); default: the fixed mesh")
    args = ap.parse_args()
    design = LatticeDesign(width_mm=4.0, thickness_mm=3.0)
    density = density_of_design(design, args.cells)
    grey = int(((density > 0) & (density < 1)).sum())
    print(f"{design.describe()}; density {args.cells} x {args.cells} cells, {grey} grey; presses "
          + "; ".join(f"{k} {t.x_mm:g},{t.y_mm:g} r {t.radius_mm:g} d {t.depth_mm:g}" for k, t in PRESSES.items()))
    print("\n| model | mesh size (mm) | nodes | grey elements | V_rel centre | V_rel off-centre | seconds |"
          "\n|---|---|---|---|---|---|---|")
    for h in args.conforming_sizes:
        t0 = time.perf_counter()
        m = CoupledModel(design, MeshSettings(size_mm=h))
        v = [m.simulate([t]).v_rel for t in PRESSES.values()]
        print(f"| conforming (grid mesher) | {h:g} | {m.mesh.n_nodes} | 0 | {v[0]:.5f} | {v[1]:.5f} | "
              f"{time.perf_counter() - t0:.0f} |", flush=True)
    for h in args.density_sizes:
        t0 = time.perf_counter()
        m = DensityModel(design, args.cells, MeshSettings(size_mm=h), sharp_from=density if args.sharp_lines else None)
        rho = m.cells @ density.ravel()
        ev = m.evaluate(density, [[t] for t in PRESSES.values()], gradient=False)
        label = "density, lines on its jumps" if args.sharp_lines else "density"
        print(f"| {label} | {h:g} | {m.mesh.n_nodes} | {int(((rho > 1e-9) & (rho < 1 - 1e-9)).sum())} of {len(rho)} "
              f"| {ev.presses[0].v_rel:.5f} | {ev.presses[1].v_rel:.5f} | {time.perf_counter() - t0:.0f} |", flush=True)


if __name__ == "__main__":
    main()
