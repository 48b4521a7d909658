"""Mesh convergence of V_rel for one design of any layout family (decides the default meshes).

    python benchmarks/convergence_vrel.py [--sizes 4 2.8 2 1.4] [--phantoms 6] [--jobs 2]
    python benchmarks/convergence_vrel.py --levels 2.8:2:2 2:2:2 1.4:3:3 --width 2 --thickness 1
    python benchmarks/convergence_vrel.py --press --phantoms 0 --levels 2.8:2:2:0 2:2:2:0 1.4:3:3:0 \
        --physics hydrogel_poisson_ratio=0.4999
    python benchmarks/convergence_vrel.py --pattern hexagonal --rim none --width 3 --press --phantoms 4 \
        --levels 2.8:2:2 2:2:2 2:3:3 1.4:3:3

Each level refines the grid (element size, and cells across a channel / through the layer with it) and
evaluates the same phantoms (the first ones of paper_fig4's seeded set: 1, 2 and 3 touches in turn). It
prints mean V_rel per mesh, the relative change between successive meshes (mean over phantoms of the
per-phantom relative change, and of the mean) and the seconds per phantom, as a Markdown table, and at the
end the same changes against the last (finest) level. ``--levels SIZE:CHANNEL_CELLS:LAYER_CELLS`` replaces the
ladder by explicit meshes. ``--press`` adds the press study's centre press (50, 50), r 8.75 mm, 4 mm deep, as
the first row, ``--per-phantom`` prints every phantom's V_rel per level, and ``--physics KEY=VALUE`` (repeatable,
any ``[physics]`` key, as on the command line) sets the model.
"""

from __future__ import annotations

import argparse
import os
import time
from concurrent.futures import ProcessPoolExecutor

for _var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402
from _common import mesh_level  # noqa: E402  (this folder's neighbour)

from latticeopt import LatticeDesign, MeshSettings  # noqa: E402
from latticeopt.cli._physics import add_physics_arg, physics_settings, physics_values  # noqa: E402
from latticeopt.coupled import CoupledModel  # noqa: E402
from latticeopt.errors import ParameterError  # noqa: E402
from latticeopt.study.phantoms import Phantom, random_phantom  # noqa: E402
from latticeopt.touches import Touch  # noqa: E402


def settings_for(size_mm: float) -> MeshSettings:
    """Refinement ladder: cells across a channel and through the layer grow as the size shrinks."""
    cells = max(1, int(round(4.0 / size_mm)))
    return MeshSettings(size_mm=size_mm, channel_cells=cells, layer_cells=max(2, cells))


def _run(args):
    mesh_settings, phantoms, design, physics = args
    model = CoupledModel(design, mesh_settings, physics)
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
    ap.add_argument("--pattern", default="square", choices=["square", "hexagonal", "triangular", "diagonal"])
    ap.add_argument("--rim", default="none", choices=["none", "channel"])
    ap.add_argument("--press", action="store_true", help="add the centre press (50, 50, r 8.75, 4 mm) first")
    ap.add_argument("--per-phantom", action="store_true", help="print each phantom's V_rel per level")
    ap.add_argument("--levels", type=mesh_level, nargs="+", default=None,
                    help="explicit meshes SIZE:CHANNEL_CELLS:LAYER_CELLS[:0] (replaces --sizes; a trailing :0 "
                         "leaves out the grid lines on electrode edges)")
    add_physics_arg(ap)
    a = ap.parse_args()
    try:
        physics = physics_settings(a)
    except ParameterError as exc:
        ap.error(str(exc))
    levels = a.levels or [settings_for(size) for size in a.sizes]
    design = LatticeDesign(width_mm=a.width, thickness_mm=a.thickness, pattern=a.pattern, rim=a.rim)
    phantoms = [random_phantom(100.0, 1 + i % 3, i // 3, 2025) for i in range(a.phantoms)]
    if a.press:
        phantoms.insert(0, Phantom((Touch(50.0, 50.0, 8.75, 4.0),), index=0))
    print(f"load average: {os.getloadavg()[0]:.2f}; {design.describe()}; {a.phantoms} phantoms"
          + (f"; physics {physics_values(a)}" if a.physics else ""))
    print("| size mm | channel cells | layer cells | electrode-edge lines | nodes | mean V_rel | change of mean | "
          "per-phantom change | s/phantom |")
    print("|---|---|---|---|---|---|---|---|---|")
    prev = None
    results = []
    for ms in levels:
        chunks = [phantoms[i::a.jobs] for i in range(a.jobs)]
        with ProcessPoolExecutor(a.jobs) as ex:
            parts = list(ex.map(_run, [(ms, c, design, physics) for c in chunks if c]))
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
        print(f"| {ms.size_mm:g} | {ms.channel_cells} | {ms.layer_cells} | {'yes' if ms.electrode_edges else 'no'} | "
              f"{nodes} | {vals.mean():.5f} | "
              f"{change_mean} | {change_each} | {np.mean(secs):.1f} |", flush=True)
        if a.per_phantom:
            print("  per phantom: " + " ".join(f"{v:.5f}" for v in vals), flush=True)
        prev = vals
        results.append((ms, vals))
    ref = results[-1][1]
    print(f"\nagainst the finest level ({levels[-1].size_mm:g} mm):")
    for ms, vals in results[:-1]:
        change = abs(vals.mean() - ref.mean()) / ref.mean()
        print(f"  {ms.size_mm:g}:{ms.channel_cells}:{ms.layer_cells}:{int(ms.electrode_edges)}  mean {change:.2%}"
              f"  per phantom {np.mean(np.abs(vals - ref) / ref):.2%}")


if __name__ == "__main__":
    main()
