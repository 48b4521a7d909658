"""Adjoint gradients of a density layout against central finite differences: a table for docs/verification.md.

    python benchmarks/gradient_check.py --size 6 --cells 8            # coarse mesh (a minute)
    python benchmarks/gradient_check.py --size 2 --cells 50           # default mesh (about 15 min on 2 cores)

For a grey layout (the w = 4, t = 3 lattice's density, smoothed, mixed with 0.5) and a press, the directional
derivative ``sum(g * direction)`` of V_rel, the punch force and the gel's stretch measure in random smooth
directions (low-order Fourier modes over the sensor) and along single cells, against central differences of
step ``h`` with ``mechanics_rtol`` 1e-10; and the two parts of the V_rel gradient, each against differences that
move only its part (electrics: the displacement held; mechanics: the conductivities held).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from latticeopt import LatticeDesign, MeshSettings
from latticeopt.coupled import PhysicsSettings, relative_change
from latticeopt.density import DensityModel, density_of_design
from latticeopt.touches import Touch

QUANTITIES = (("v_rel", "dv_rel_ddensity"), ("force_N", "dforce_ddensity"), ("stretch", "dstretch_ddensity"))


def smooth_direction(n: int, rng: np.random.Generator, modes: int = 3) -> np.ndarray:
    y, x = (np.mgrid[0:n, 0:n] + 0.5) / n
    out = np.zeros((n, n))
    for kx in range(modes):
        for ky in range(modes):
            a, phx, phy = rng.normal(), rng.uniform(0, 2 * np.pi), rng.uniform(0, 2 * np.pi)
            out += a * np.cos(np.pi * kx * x + phx) * np.cos(np.pi * ky * y + phy)
    return out / np.abs(out).max()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", type=float, default=2.0, help="mesh size (mm)")
    ap.add_argument("--cells", type=int, default=50, help="density cells per side")
    ap.add_argument("--directions", type=int, default=3, help="random smooth directions")
    ap.add_argument("--h", type=float, default=1e-4, help="difference step (density units)")
    ap.add_argument("--touch", default="40,55,8.75,3", help="X,Y,R,D of the press")
    args = ap.parse_args()
    n = args.cells
    design = LatticeDesign(width_mm=4.0, thickness_mm=3.0)
    density = 0.5 * density_of_design(design, n, smoothing_mm=2.0) + 0.25
    press = [[Touch(*(float(v) for v in args.touch.split(",")))]]
    t0 = time.perf_counter()
    model = DensityModel(design, n, MeshSettings(size_mm=args.size), PhysicsSettings(mechanics_rtol=1e-10))
    ev = model.evaluate(density, press)
    print(f"mesh {args.size:g} mm, {n} x {n} cells, {model.mesh.n_nodes} nodes; press {args.touch}; h = {args.h:g}; "
          "\n"
          f"V_rel {ev.v_rel:.6g}, force {ev.force_N:.6g} N, stretch {ev.stretch:.6g} "
          f"({time.perf_counter() - t0:.1f} s)")
    print("\n| direction | quantity | central difference | adjoint | relative error |\n|---|---|---|---|---|")
    rng = np.random.default_rng(0)
    dirs = [(f"smooth {k + 1}", smooth_direction(n, rng)) for k in range(args.directions)]
    for i, j in ((n // 2, n // 2), (n // 2, n // 4), (0, n // 8)):
        e = np.zeros((n, n))
        e[i, j] = 1.0
        dirs.append((f"cell ({i}, {j})", e))
    worst = 0.0
    for label, d in dirs:
        plus = model.evaluate(density + args.h * d, press, gradient=False)
        minus = model.evaluate(density - args.h * d, press, gradient=False)
        for name, grad in QUANTITIES:
            fd = (getattr(plus, name) - getattr(minus, name)) / (2 * args.h)
            ad = float(np.sum(getattr(ev, grad) * d))
            err = abs(ad - fd) / abs(fd)
            worst = max(worst, err) if label.startswith("smooth") else worst
            print(f"| {label} | {name} | {fd:.9g} | {ad:.9g} | {err:.1e} |")
    # the split: each part against differences that move only its part
    p0 = ev.presses[0]
    nodes = model.mesh.nodes_mm + p0.displacement_mm
    d = dirs[0][1]

    def vrel(dens_e, dens_m):
        _, (_, _, sigma), _ = model.materials(dens_e)
        ref = model.electrics.with_conductivity(sigma)
        x = nodes
        if dens_m is not None:
            _, (mu, kappa, _), _ = model.materials(dens_m)
            x = model.mechanics.with_moduli(mu, kappa).solve(press[0]).deformed_mesh.nodes_mm
        return relative_change(ref.with_nodes(x).voltages, ref.voltages)

    h = args.h
    fd_e = (vrel(density + h * d, None) - vrel(density - h * d, None)) / (2 * h)
    fd_m = (vrel(density, density + h * d) - vrel(density, density - h * d)) / (2 * h)
    print("\n| V_rel part (smooth 1) | central difference | adjoint | relative error |\n|---|---|---|---|")
    for label, fd, g in (("electrics (displacement held)", fd_e, p0.dv_rel_electrics),
                         ("mechanics (conductivities held)", fd_m, p0.dv_rel_mechanics)):
        ad = float(np.sum(g * d))
        print(f"| {label} | {fd:.9g} | {ad:.9g} | {abs(ad - fd) / abs(fd):.1e} |")
    print(f"\nworst relative error over the smooth directions: {worst:.1e}; total {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
