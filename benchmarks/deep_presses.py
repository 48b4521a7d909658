"""The deepest presses of the paper map, one at a time: which converge, in how long, and how they fail.

    python benchmarks/deep_presses.py --designs 2:1 6:1 --phantoms 1:13 2:70 3:22 [--rim channel] [--json out.jsonl]
    python benchmarks/deep_presses.py --deepest 8 --designs 2:1      # the 8 deepest paper phantoms
    python benchmarks/deep_presses.py ... --physics max_step_mm=0.5 -v

Phantoms are the paper map's seeded ones (``studies/paper_fig4.toml``: ``K:I`` is phantom ``I`` with ``K``
touches), on its mesh (2 mm grid, 2 channel cells, no electrode edge lines). Designs are ``W:T`` (width,
thickness, mm). One line per press: ok / failed, seconds, load steps, halvings, Newton iterations, shifted
factorizations, smallest det F, V_rel; ``-v`` logs every failed load step with its Newton residual history.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import time

for _var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from _common import check_paper_keys, pair, paper_phantoms  # noqa: E402  (this folder's neighbour)

from latticeopt import LatticeDesign, MeshSettings  # noqa: E402
from latticeopt.cli._physics import add_physics_arg, physics_settings  # noqa: E402
from latticeopt.coupled import CoupledModel  # noqa: E402
from latticeopt.errors import ConvergenceError, ParameterError  # noqa: E402


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--designs", nargs="+", type=pair("W:T", float, "2:1"), default=[(2.0, 1.0)],
                    help="W:T pairs (mm)")
    ap.add_argument("--phantoms", nargs="*", type=pair("K:I", int, "1:13"), default=[],
                    help="K:I pairs (touches:index)")
    ap.add_argument("--deepest", type=int, default=0, help="add the N deepest paper phantoms")
    ap.add_argument("--rim", default="none", choices=("none", "channel"))
    ap.add_argument("--json", help="append one JSON line per press to this file")
    ap.add_argument("-v", action="store_true", help="log failed load steps and their Newton history")
    add_physics_arg(ap)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.v else logging.WARNING, format="%(message)s")
    for name in ("numba", "matplotlib", "latticeopt.mesh", "latticeopt.electrics", "latticeopt.coupled"):
        logging.getLogger(name).setLevel(logging.WARNING)
    if args.deepest < 0:
        ap.error(f"--deepest: expected an integer >= 0, got {args.deepest}")
    try:
        physics = physics_settings(args)
    except ParameterError as exc:
        ap.error(str(exc))
    try:
        designs = {f"{w:g}:{t:g}": LatticeDesign(width_mm=w, thickness_mm=t, pitch_mm=12.5, rim=args.rim)
                   for w, t in args.designs}
    except ParameterError as exc:
        ap.error(f"--designs: {exc}")
    phantoms = paper_phantoms()
    check_paper_keys(ap, args.phantoms, phantoms)
    keys = list(args.phantoms)
    deepest = sorted(phantoms, key=lambda k: -max(t.depth_mm for t in phantoms[k].touches))
    keys += [k for k in deepest[:args.deepest] if k not in keys]
    mesh = MeshSettings(size_mm=2.0, channel_cells=2, layer_cells=2, electrode_edges=False)
    for d, design in designs.items():
        model = CoupledModel(design, mesh, physics)
        for k in keys:
            touches = phantoms[k].touches
            row = {"design": d, "rim": args.rim, "phantom": f"{k[0]}:{k[1]}",
                   "depth_mm": max(x.depth_mm for x in touches), "physics": physics.as_dict()}
            t0 = time.perf_counter()
            try:
                res = model.simulate(list(touches))
            except ConvergenceError as exc:
                row.update(ok=False, seconds=time.perf_counter() - t0, error=str(exc))
                print(f"{d} {args.rim} {k[0]}:{k[1]} d={row['depth_mm']:.3f} FAILED {row['seconds']:.1f} s: {exc}",
                      flush=True)
            else:
                ind = res.indentation
                row.update(ok=True, seconds=time.perf_counter() - t0, v_rel=res.v_rel, load_steps=ind.load_steps,
                           halvings=ind.step_halvings, newton=ind.newton_steps, min_det_F=ind.min_det_F,
                           shifted=ind.solver["shifted_factorizations"], forces_N=ind.forces_N.tolist())
                print(f"{d} {args.rim} {k[0]}:{k[1]} d={row['depth_mm']:.3f} ok {row['seconds']:.1f} s, "
                      f"{ind.load_steps} steps, {ind.step_halvings} halvings, {ind.newton_steps} Newton, "
                      f"{row['shifted']} shifted, min det F {ind.min_det_F:.3f}, V_rel {res.v_rel:.5f}", flush=True)
            if args.json:
                with open(args.json, "a") as fh:
                    fh.write(json.dumps(row) + "\n")


if __name__ == "__main__":
    main()
