"""A tiny study in Python: two designs x one random phantom, tables and report in an output folder.

    python examples/small_sweep.py                       # 6 mm mesh, writes runs/small_sweep/
    python examples/small_sweep.py --out /tmp/sweep --mesh-size 4

Re-running resumes from the folder's results store (nothing stored is recomputed).
"""

import argparse

from latticeopt import run_sweep, study_from_dict

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--out", default="runs/small_sweep", help="output folder")
parser.add_argument("--mesh-size", type=float, default=6.0, help="mesh element size (mm), default 6")
args = parser.parse_args()

study = study_from_dict({
    "name": "small_sweep",
    "out": args.out,
    "jobs": 1,
    "design": {"thickness_mm": 3.0},
    "grid": {"width_mm": [0, 4]},                      # uniform layer against the w = 4 mm square lattice
    "phantoms": {"seed": 2025, "counts": {"1": 1}},    # one single-touch phantom (the same for both designs)
    "mesh": {"size_mm": args.mesh_size, "channel_cells": 1},
})
result = run_sweep(study, progress=False)
print("\n".join(result.report))
for name, path in result.outputs.items():
    print(f"{name}: {path}")
