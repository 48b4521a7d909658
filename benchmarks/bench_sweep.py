"""Seconds per coupled phantom and the extrapolated wall time of a paper-size sweep.

    python benchmarks/bench_sweep.py [--size 2.0] [--channel-cells 2] [--phantoms 6] [--workers 1 2]
                                     [--designs 4,3 0,1 6,1 0,5 6,5 | --designs paper]

For each design (width,thickness in mm; default: the default design only; ``paper``: all 30 designs of
studies/paper_fig4.toml, the honest figure for the map), on paper_fig4.toml's mesh (``--size`` and
``--channel-cells`` override it), it times phantoms of
studies/paper_fig4.toml's phantom set (1, 2 and 3 touches in turn) split into set-up (mesh read, mechanics
operator, reference electrics), mechanics and electrics, with one worker and then with two processes (one BLAS
thread each). The paper map (30 designs x 300 phantoms) is extrapolated from the steady-state throughput --
workers / mean seconds per phantom measured while all workers run, averaged over the designs given -- plus one
set-up per design. The cost depends on the design (a narrow channel or gap adds grid lines across the whole
sensor), so time ``--designs paper`` for an honest figure. A phantom whose mechanics fails counts as failed,
its time still counted. Run it on a quiet machine: it prints the load average it saw.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

from latticeopt import LatticeDesign  # noqa: E402
from latticeopt.coupled import CoupledModel  # noqa: E402
from latticeopt.errors import ConvergenceError, MeshError  # noqa: E402
from latticeopt.mesh import mesh_design  # noqa: E402
from latticeopt.study.config import load_study  # noqa: E402
from latticeopt.study.phantoms import random_phantom  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
CACHE = ROOT / "meshes"


def _phantoms(n: int, seed: int = 2025):
    return [random_phantom(100.0, 1 + i % 3, i // 3, seed) for i in range(n)]


def _run(args):
    (w, t), mesh_settings, phantoms = args
    t0 = time.perf_counter()
    model = CoupledModel(LatticeDesign(width_mm=w, thickness_mm=t), mesh_settings, cache_dir=CACHE)
    setup = time.perf_counter() - t0
    rows = []
    for ph in phantoms:
        t1 = time.perf_counter()
        try:
            res = model.simulate(ph.touches)
        except (ConvergenceError, MeshError):  # counted, and its time still counts (a sweep spends it too)
            rows.append((np.nan, np.nan, np.nan, np.nan, time.perf_counter() - t1))
            continue
        rows.append((res.timings["mechanics"], res.timings["electrics"], res.v_rel, res.newton_steps,
                     time.perf_counter() - t1))
    return setup, rows, model.mesh.n_nodes


def _design(text: str) -> tuple[float, float] | str:
    if text == "paper":
        return text
    try:
        w, t = (float(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--designs: expected WIDTH,THICKNESS in mm or 'paper', got {text!r}") from None
    return w, t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=float, default=None, help="grid size (mm; default: paper_fig4.toml's)")
    ap.add_argument("--channel-cells", type=int, default=None, help="default: paper_fig4.toml's")
    ap.add_argument("--phantoms", type=int, default=6)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--designs", type=_design, nargs="+", default=[(4.0, 3.0)],
                    help="WIDTH,THICKNESS pairs in mm (default: 4,3), or 'paper' for the 30 designs of paper_fig4.toml")
    a = ap.parse_args()
    paper = load_study(ROOT / "studies" / "paper_fig4.toml")
    if "paper" in a.designs:
        a.designs = [(d.width_mm, d.thickness_mm) for d in paper.designs]
    mesh = paper.settings.mesh  # the converged mesh of the map
    mesh = dataclasses.replace(mesh, size_mm=mesh.size_mm if a.size is None else a.size,
                               channel_cells=mesh.channel_cells if a.channel_cells is None else a.channel_cells)
    phantoms = _phantoms(a.phantoms)
    print(f"load average before: {os.getloadavg()[0]:.2f} (2 cores)")
    print(f"mesh {mesh.as_dict()}; {a.phantoms} phantoms (1-3 touches) per design")
    print("| design w,t mm | nodes | workers | set-up s | mechanics s / phantom | linear solves | electrics s | "
          "seconds / phantom | throughput s / phantom | failed |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    per_phantom = {k: [] for k in a.workers}
    setups = []
    for design in a.designs:
        # mesh once here, so the workers read the cache instead of meshing side by side
        mesh_design(LatticeDesign(width_mm=design[0], thickness_mm=design[1]), mesh, cache_dir=CACHE)
        for workers in a.workers:
            chunks = [phantoms[i::workers] for i in range(workers)]
            with ProcessPoolExecutor(workers) as ex:
                out = list(ex.map(_run, [(design, mesh, c) for c in chunks]))
            rows = [r for _, rr, _ in out for r in rr]
            setup = float(np.mean([s for s, _, _ in out]))
            setups.append(setup)
            mech, elec = np.nanmean([r[0] for r in rows]), np.nanmean([r[1] for r in rows])
            steps, each = np.nanmean([r[3] for r in rows]), float(np.mean([r[4] for r in rows]))
            failed = int(np.isnan([r[0] for r in rows]).sum())
            per_phantom[workers].append(each / workers)
            print(f"| {design[0]:g},{design[1]:g} | {out[0][2]} | {workers} | {setup:.2f} | {mech:.2f} | {steps:.0f} | "
                  f"{elec:.3f} | {each:.2f} | {each / workers:.2f} | {failed} |", flush=True)
    best = min(a.workers, key=lambda k: np.mean(per_phantom[k]))
    rate = float(np.mean(per_phantom[best]))
    total_h = (rate * 30 * 300 + 30 * float(np.mean(setups)) / best) / 3600
    print(f"\npaper map (30 designs x 300 phantoms) at this mesh, {best} worker(s), from the mean throughput over "
          f"{len(a.designs)} design(s): {rate:.2f} s per phantom -> {total_h:.1f} h on this machine (target 8 h: "
          f"{'met' if total_h <= 8 else 'NOT met'})")

if __name__ == "__main__":
    main()
