"""How well a density model resolves narrow channels: the probe grid of the density studies pressed on outline
layouts drawn as densities, at chosen cell counts, mesh sizes and conductivity exponents.

    python benchmarks/density_resolution.py                                   # w = 1, w = 4, graded; 50 cells, 2 mm
    python benchmarks/density_resolution.py --layout studies/data/square_w1.geojson --corner 100:1 --law 1

Each layout is read from its outline (``studies/data``) as the exact-area density of ``--cells`` cells, on the
density model of the graded study (t = 3 mm, default mesh). Per layout and exponent ``p`` of the conductivity law:
the probe grid's uniformity (1 - std/mean), worst-to-best ratio, mean and range of the probes' V_rel, and seconds.
The same outlines on the exact mesh: ``latticeopt sweep studies/uniformity_layouts.toml``. ``--corner CELLS:MESH``
also presses the corner probe alone on a density model of ``CELLS`` cells and a ``MESH`` mm mesh (finer meshes:
does the model's reading approach the exact mesh's?).
"""

from __future__ import annotations

import argparse
import os
import time

for _var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from latticeopt import MeshSettings  # noqa: E402
from latticeopt.density import DensityModel  # noqa: E402
from latticeopt.density.field import InterpolationLaw, density_of_design  # noqa: E402
from latticeopt.design import design_from_table  # noqa: E402
from latticeopt.optimize.graded import GradedConfig  # noqa: E402
from latticeopt.optimize.probes import ProbeGrid  # noqa: E402

LAYOUTS = ["studies/data/square_w1.geojson", "studies/data/square_w4.geojson", "studies/data/graded_d4_t3.geojson"]


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--layout", action="append", help="outline file (repeatable; default: w = 1, w = 4, graded)")
    ap.add_argument("--cells", type=int, default=50, help="density cells per side (default 50: 2 mm)")
    ap.add_argument("--mesh", type=float, default=2.0, help="mesh size (mm) of the probe-grid model (default 2)")
    ap.add_argument("--law", default="3", help="conductivity exponents p, comma-separated (default 3)")
    ap.add_argument("--corner", action="append", default=[], metavar="CELLS:MESH",
                    help="also the corner probe alone at this resolution (repeatable)")
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args(argv)
    laws = [float(p) for p in args.law.split(",")]
    cfg = GradedConfig(cells=args.cells, probes=True)
    print("layout | p | uniformity | worst-to-best | mean | probes | solved | s")
    for path in args.layout or LAYOUTS:
        design = design_from_table({"thickness_mm": 3.0, "layout": path})
        rho = density_of_design(design, args.cells)
        probes = ProbeGrid(design, cfg)
        for p in laws:
            model = DensityModel(design, args.cells, MeshSettings(size_mm=args.mesh),
                                 law=InterpolationLaw(conductivity_exponent=p))
            t0 = time.perf_counter()
            pe = probes.solve(model, rho, gradient=False, jobs=args.jobs)
            v = pe.v_rel
            print(f"{os.path.basename(path)} | {p:g} | {pe.uniformity:.4f} | {pe.worst_to_best:.4f} | {v.mean():.4f} | "
                  f"{v.min():.4f}-{v.max():.4f} | {pe.solved} | {time.perf_counter() - t0:.0f}", flush=True)
        for spec in args.corner:
            cells, mesh = spec.split(":")
            t0 = time.perf_counter()
            model = DensityModel(design, int(cells), MeshSettings(size_mm=float(mesh)))
            corner = probes.touches[0]
            ev = model.evaluate(density_of_design(design, int(cells)), [corner], gradient=False)
            c = corner[0]
            print(f"{os.path.basename(path)}: corner probe at ({c.x_mm:.2f}, {c.y_mm:.2f}) mm on {cells} cells, "
                  f"{mesh} mm mesh ({model.mesh.n_nodes} nodes): V_rel {ev.v_rel:.4f} "
                  f"({time.perf_counter() - t0:.0f} s)",
                  flush=True)


if __name__ == "__main__":
    main()
