"""Seconds per coupled phantom and the extrapolated wall time of a paper-size sweep.

    python benchmarks/bench_sweep.py [--size 2.0] [--channel-cells 2] [--phantoms 6] [--workers 1 2]

For the default design it times phantoms of studies/paper_fig4.toml's phantom set (1, 2 and 3 touches in turn)
split into set-up (mesh read, mechanics operator, reference electrics), mechanics and electrics, first with
one worker and then with two processes (one BLAS thread each), and extrapolates to the paper map
(30 designs x 300 phantoms). Run it on a quiet machine: it prints the load average it saw.
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


def _phantoms(n: int, seed: int = 2025):
    return [random_phantom(100.0, 1 + i % 3, i // 3, seed) for i in range(n)]


def _run(args):
    size, cells, phantoms = args
    t0 = time.perf_counter()
    model = CoupledModel(LatticeDesign(), MeshSettings(size_mm=size, channel_cells=cells), cache_dir=CACHE)
    setup = time.perf_counter() - t0
    rows = []
    for ph in phantoms:
        res = model.simulate(ph.touches)
        rows.append((res.timings["mechanics"], res.timings["electrics"], res.v_rel, res.newton_steps))
    return setup, rows, model.mesh.n_nodes


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=float, default=MeshSettings().size_mm)
    ap.add_argument("--channel-cells", type=int, default=MeshSettings().channel_cells)
    ap.add_argument("--phantoms", type=int, default=6)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    a = ap.parse_args()
    phantoms = _phantoms(a.phantoms)
    _run((a.size, a.channel_cells, phantoms[:1]))  # warm the mesh cache and the imports
    print(f"load average before: {os.getloadavg()[0]:.2f} (2 cores)")
    print(f"default design w = 4, t = 3; grid mesh size {a.size} mm, "
          f"{a.channel_cells} channel cells; {a.phantoms} phantoms (1-3 touches)")
    per_phantom = {}
    for workers in a.workers:
        chunks = [phantoms[i::workers] for i in range(workers)]
        t0 = time.perf_counter()
        with ProcessPoolExecutor(workers) as ex:
            out = list(ex.map(_run, [(a.size, a.channel_cells, c) for c in chunks]))
        wall = time.perf_counter() - t0
        rows = [r for _, rr, _ in out for r in rr]
        setup = np.mean([s for s, _, _ in out])
        mech, elec = np.mean([r[0] for r in rows]), np.mean([r[1] for r in rows])
        steps = np.mean([r[3] for r in rows])
        per_phantom[workers] = wall / len(rows)
        print(f"\n{workers} worker(s): {out[0][2]} nodes")
        print("| stage | seconds per phantom |\n|---|---|")
        print(f"| set-up per design (mesh read, operator, reference) | {setup:.2f} |")
        print(f"| mechanics ({steps:.0f} linear solves on average) | {mech:.2f} |")
        print(f"| electrics (208 voltages on the deformed hydrogel) | {elec:.3f} |")
        print(f"| wall time per phantom (throughput) | {per_phantom[workers]:.2f} |")
        print(f"V_rel of these phantoms: {np.round([r[2] for r in rows], 4).tolist()}")
    best = min(per_phantom.values())
    total_h = best * 30 * 300 / 3600
    print(f"\npaper map (30 designs x 300 phantoms) at this mesh: {total_h:.1f} h on this machine "
          f"(target 8 h); set-up adds {30 * setup / 3600:.2f} h once per design")


if __name__ == "__main__":
    main()
