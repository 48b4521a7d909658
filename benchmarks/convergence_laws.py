"""Mesh convergence of V_rel under the conductivity laws, one mechanics solve per mesh for all laws.

    python benchmarks/convergence_laws.py --levels 2.8:2:2 2:2:2 1.4:3:3 1:4:4
    python benchmarks/convergence_laws.py --levels 2:2:2 1.4:3:3 --physics hydrogel_poisson_ratio=0.4999

For each mesh (SIZE:CHANNEL_CELLS:LAYER_CELLS) it presses the design once (default: w = 4, t = 3, centre punch
(50, 50), r 8.75 mm, 4 mm deep) and solves the electrics of that one deformed state under every law of
``--laws`` (``LAW:MEASURE:K``; ``geometry`` alone is the default law). A law changes only the hydrogel's
conductivity, not the mechanics, so one indentation serves them all and the laws differ on a mesh only by the
law. Printed as Markdown: V_rel per law and mesh, the relative change against the finest mesh, and the
patch-measure statistics that explain it (volume-weighted mean of ``1 - m`` over the gel, its extreme; ``lt`` is
the layer's thickness stretch).
"""

from __future__ import annotations

import argparse
import os
import time
import tomllib

for _var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402
from _common import mesh_level  # noqa: E402  (this folder's neighbour)

from latticeopt import LatticeDesign, PhysicsSettings, Touch  # noqa: E402
from latticeopt.conductivity import conductivity_factor, patch_measures  # noqa: E402
from latticeopt.coupled import CoupledModel, relative_change  # noqa: E402
from latticeopt.mechanics.assembly import dilatation_patches  # noqa: E402

DEFAULT_LAWS = ["geometry", "power:J:-1", "linear:J:2", "linear:thickness:2", "power:thickness:-2"]


def _law(text: str) -> tuple[str, str, float]:
    if text == "geometry":
        return "geometry", "J", 0.0
    law, measure, k = text.split(":")
    return law, measure, float(k)


def run_level(design, mesh_settings, physics, touch, laws):
    """V_rel of every law on one mesh, and the patch-measure statistics of the gel."""
    t0 = time.perf_counter()
    model = CoupledModel(design, mesh_settings, physics)
    ind = model.mechanics.solve([touch])
    t1 = time.perf_counter()
    gel = model.reference.gel_tet_ids
    tets = model.mesh.tets[gel]
    patch = dilatation_patches(model.mesh, model.mechanics.settings.volumetric)[gel]
    J, lt = patch_measures(model.mesh.nodes_mm, ind.deformed_mesh.nodes_mm, tets, patch)
    vol0 = np.abs(model.mesh.tet_volumes_mm3()[gel])
    out = {}
    for name, (law, measure, k) in laws.items():
        sigma = None if law == "geometry" else physics.sigma_S_per_m * conductivity_factor(law, measure, k, J, lt)
        volts = model.reference.with_nodes(ind.deformed_mesh.nodes_mm, sigma).voltages
        out[name] = relative_change(volts, model.reference_voltages)
    stats = {"n_nodes": model.mesh.n_nodes, "newton": int(ind.newton_steps), "seconds": time.perf_counter() - t0,
             "mechanics_s": t1 - t0,
             "mean_1-J": float(np.sum(vol0 * (1 - J)) / vol0.sum()), "max_1-J": float((1 - J).max()),
             "mean_1-lt": float(np.sum(vol0 * (1 - lt)) / vol0.sum()), "max_1-lt": float((1 - lt).max())}
    return out, stats


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--levels", nargs="+", default=["2.8:2:2", "2:2:2", "1.4:3:3"],
                    help="meshes SIZE:CHANNEL_CELLS:LAYER_CELLS, coarse to fine")
    ap.add_argument("--laws", nargs="+", default=DEFAULT_LAWS, help="LAW:MEASURE:K or geometry")
    ap.add_argument("--width", type=float, default=4.0)
    ap.add_argument("--thickness", type=float, default=3.0)
    ap.add_argument("--rim", default="none", choices=["none", "channel"])
    ap.add_argument("--touch", default="50,50,8.75,4", help="x,y,radius,depth (mm)")
    ap.add_argument("--physics", action="append", default=[], help="KEY=VALUE (TOML value), repeatable")
    a = ap.parse_args()
    physics = PhysicsSettings.from_dict({k: tomllib.loads(f"v = {val}")["v"]
                                         for k, val in (p.split("=", 1) for p in a.physics)})
    x, y, r, d = (float(s) for s in a.touch.split(","))
    touch = Touch(x_mm=x, y_mm=y, radius_mm=r, depth_mm=d)
    design = LatticeDesign(width_mm=a.width, thickness_mm=a.thickness, rim=a.rim)
    laws = {name: _law(name) for name in a.laws}
    rows = []
    for text in a.levels:
        v, s = run_level(design, mesh_level(text), physics, touch, laws)
        rows.append((text, v, s))
        print(f"# {text}: {s['n_nodes']} nodes, {s['newton']} Newton steps, {s['seconds']:.0f} s "
              f"(mechanics {s['mechanics_s']:.0f} s); " + ", ".join(f"{k} {val:.5f}" for k, val in v.items()),
              flush=True)
    print("\n| mesh | nodes | " + " | ".join(laws) + " | mean 1-J | max 1-J | mean 1-lt | max 1-lt |")
    print("|---" * (len(laws) + 6) + "|")
    fine = rows[-1][1]
    for text, v, s in rows:
        cells = [f"{v[k]:.5f} ({100 * (v[k] / fine[k] - 1):+.1f} %)" for k in laws]
        print(f"| {text} | {s['n_nodes']} | " + " | ".join(cells) +
              f" | {s['mean_1-J']:.4f} | {s['max_1-J']:.3f} | {s['mean_1-lt']:.4f} | {s['max_1-lt']:.3f} |")


if __name__ == "__main__":
    main()
