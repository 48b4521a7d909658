"""How far V_rel of a probe and of its mirror images differ on a D4-symmetric density: the mesh's own asymmetry,
which decides whether a density study may solve one probe per symmetry orbit (docs/gradients.md).

    python benchmarks/probe_symmetry.py --size 4 --cells 20           # 49 presses with gradients (13 min, loaded)

Every probe of the 7 x 7 grid (6.25 mm radius, 3 mm deep) is solved on the w = 4, t = 3 square lattice's exact-area
density, which the square's eight symmetries leave unchanged; then, per probe, the largest relative difference
between its V_rel and those of its images, and between its gradient mirrored and its images' gradients (relative
to the largest gradient entry), and the uniformity (1 - CV) from all probes against the one the orbit
representatives give (:class:`latticeopt.optimize.probes.ProbeGrid`).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from latticeopt import LatticeDesign, MeshSettings
from latticeopt.density import DensityModel, density_of_design
from latticeopt.optimize.graded import GradedConfig
from latticeopt.optimize.probes import OPS, ProbeGrid


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=float, default=4.0, help="mesh size (mm)")
    ap.add_argument("--cells", type=int, default=20, help="density cells per side")
    ap.add_argument("--grid", type=int, default=7, help="probes per side")
    args = ap.parse_args()
    design = LatticeDesign(thickness_mm=3.0, width_mm=4.0)
    model = DensityModel(design, args.cells, MeshSettings(size_mm=args.size))
    rho = density_of_design(design, args.cells)
    assert all(np.array_equal(op(rho), rho) for op in OPS)
    cfg = GradedConfig(cells=args.cells, probe_grid=args.grid, probes=True)
    t0 = time.perf_counter()
    every = ProbeGrid(design, GradedConfig(cells=args.cells, probe_grid=args.grid, probes=True, probe_orbits=False))
    ev = model.evaluate(rho, every.touches)
    seconds = time.perf_counter() - t0
    n = args.grid
    v = np.array([p.v_rel for p in ev.presses]).reshape(n, n)
    g = np.array([p.dv_rel for p in ev.presses]).reshape(n, n, args.cells, args.cells)
    dv, dg = 0.0, 0.0
    for b in range(n):
        for a in range(n):
            for op in OPS:
                mark = np.zeros((n, n), bool)
                mark[b, a] = True
                bb, aa = np.argwhere(op(mark))[0]
                dv = max(dv, abs(v[bb, aa] - v[b, a]) / v[b, a])
                dg = max(dg, np.abs(op(g[b, a]) - g[bb, aa]).max() / np.abs(g[bb, aa]).max())
    orbits = ProbeGrid(design, cfg)
    rep, _ = orbits.plan(orbits.symmetries(model, rho))
    u_all = 1 - v.std() / v.mean()
    vo = v.ravel()[rep]
    u_orb = 1 - vo.std() / vo.mean()
    print(f"mesh {args.size:g} mm, {args.cells} x {args.cells} cells, {model.mesh.n_nodes} nodes; {n * n} probes "
          f"({len(set(rep.tolist()))} orbits) in {seconds:.0f} s")
    print(f"| largest V_rel difference to an image | largest gradient difference | uniformity, all probes | "
          f"uniformity, orbit representatives |\n|---|---|---|---|\n| {dv:.1e} | {dg:.1e} | {u_all:.5f} | "
          f"{u_orb:.5f} |")


if __name__ == "__main__":
    main()
