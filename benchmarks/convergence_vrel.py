"""Mesh convergence of V_rel for the default design (decides the mesh of studies/paper_fig4.toml).

    python benchmarks/convergence_vrel.py [--sizes 4 2.8 2 1.4] [--phantoms 6] [--jobs 2]

Each level refines the grid (element size, and cells across a channel / through the layer with it) and
evaluates the same phantoms (the first ones of paper_fig4's seeded set: 1, 2 and 3 touches in turn). It
prints mean V_rel per mesh, the relative change between successive meshes (mean over phantoms of the
per-phantom relative change, and of the mean) and the seconds per phantom, as a Markdown table.
"""

from __future__ import annotations

import argparse
import os
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

from latticeopt import LatticeDesign, MeshSettings  # noqa: E402
from latticeopt.coupled import CoupledModel  # noqa: E402
from latticeopt.phantoms import random_phantom  # noqa: E402

CACHE = Path(__file__).resolve().parent.parent / "meshes"


def settings_for(size_mm: float) -> MeshSettings:
    """Refinement ladder: cells across a channel and through the layer grow as the size shrinks."""
    cells = max(1, int(round(4.0 / size_mm)))
    return MeshSettings(size_mm=size_mm, channel_cells=cells, layer_cells=max(2, cells))


def _run(args):
    size, phantoms, design = args
    model = CoupledModel(design, settings_for(size), cache_dir=CACHE)
    out = []
    for ph in phantoms:
        t0 = time.perf_counter()
        res = model.simulate(ph.touches)
        out.append((res.v_rel, time.perf_counter() - t0))
    return model.mesh.n_nodes, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=float, nargs="+", default=[4.0, 2.8, 2.0])
    ap.add_argument("--phantoms", type=int, default=6)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--width", type=float, default=4.0)
    ap.add_argument("--thickness", type=float, default=3.0)
    a = ap.parse_args()
    design = LatticeDesign(width_mm=a.width, thickness_mm=a.thickness)
    phantoms = [random_phantom(100.0, 1 + i % 3, i // 3, 2025) for i in range(a.phantoms)]
    print(f"load average: {os.getloadavg()[0]:.2f}; {design.describe()}; {a.phantoms} phantoms")
    print("| size mm | channel cells | nodes | mean V_rel | change of mean | per-phantom change | s/phantom |")
    print("|---|---|---|---|---|---|---|")
    prev = None
    for size in a.sizes:
        chunks = [phantoms[i::a.jobs] for i in range(a.jobs)]
        with ProcessPoolExecutor(a.jobs) as ex:
            parts = list(ex.map(_run, [(size, c, design) for c in chunks]))
        vals = np.empty(len(phantoms))
        secs = []
        for j, (_, rows) in enumerate(parts):
            vals[j::a.jobs] = [r[0] for r in rows]
            secs += [r[1] for r in rows]
        nodes = parts[0][0]
        if prev is None:
            change_mean = change_each = "-"
        else:
            change_mean = f"{abs(vals.mean() - prev.mean()) / vals.mean():.2%}"
            change_each = f"{np.mean(np.abs(vals - prev) / vals):.2%}"
        print(f"| {size:g} | {settings_for(size).channel_cells} | {nodes} | {vals.mean():.5f} | {change_mean} | "
              f"{change_each} | {np.mean(secs):.1f} |", flush=True)
        prev = vals


if __name__ == "__main__":
    main()
