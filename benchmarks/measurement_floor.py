"""How small the reference rows of a layout get, and what an instrument floor does to V_rel: tables for
docs/verification.md#reference-rows-at-round-off.

    python benchmarks/measurement_floor.py rows                       # smallest rows of the families (forward only)
    python benchmarks/measurement_floor.py floors square 1 --phantoms 12

``rows``: per layout (t = 3, p = 12.5, no rim channel, default 2 mm mesh), the smallest ``|V_ref|`` over the
largest and the number of rows below 1e-6 and 1e-4 of the largest; about 30 s a layout.
``floors``: V_rel of the same coupled solves (the optimize studies' phantoms: seed 2025, one-, two- and
three-touch phantoms interleaved) under the floors 0 (the paper's eq. 5), 1e-6, 1e-5, 1e-4 and 1e-3; about 20 s a
phantom on the square lattice, 1-3 min on the extruded families at w = 1.
"""

from __future__ import annotations

import argparse

import numpy as np

from latticeopt import LatticeDesign
from latticeopt.coupled import CoupledModel
from latticeopt.electrics.forward import ForwardModel
from latticeopt.errors import LatticeoptError
from latticeopt.mesh import mesh_design
from latticeopt.metric import relative_change, smallest_reference_rel
from latticeopt.study.phantoms import random_phantoms

FLOORS = (0.0, 1e-6, 1e-5, 1e-4, 1e-3)
LAYOUTS = (("diagonal", 1.25), ("diagonal", 3.0), ("diagonal", 3.43), ("diagonal", 4.0), ("diagonal", 4.2),
           ("diagonal", 4.4), ("diagonal", 4.75), ("square", 1.0), ("square", 2.0), ("square", 4.0),
           ("hexagonal", 1.0), ("triangular", 1.0))


def _design(pattern: str, width_mm: float, rim: str = "none") -> LatticeDesign:
    return LatticeDesign(pattern=pattern, width_mm=width_mm, thickness_mm=3.0, pitch_mm=12.5, rim=rim)


def rows() -> None:
    print(f"{'layout':<16} {'smallest':>9} {'< 1e-6':>7} {'< 1e-4':>7}")
    for pattern, w in LAYOUTS:
        ref = np.abs(ForwardModel(mesh_design(_design(pattern, w))).voltages)
        r = ref / ref.max()
        print(f"{pattern:<10} {w:5.2f} {smallest_reference_rel(ref):9.1e} {int((r < 1e-6).sum()):7d} "
              f"{int((r < 1e-4).sum()):7d}", flush=True)


def floors(pattern: str, width_mm: float, n: int, rim: str) -> None:
    model = CoupledModel(_design(pattern, width_mm, rim))
    ref = model.reference_voltages
    phantoms = random_phantoms(100.0, {1: 10, 2: 10, 3: 10}, 2025)
    order = [p for i in range(10) for p in phantoms if p.index == i][:n]
    print(f"{pattern} w = {width_mm:g}, rim {rim}: smallest row {smallest_reference_rel(ref):.1e} of the largest")
    print("index touches " + " ".join(f"{f:>8g}" for f in FLOORS))
    table = []
    for ph in order:
        try:
            volts = model.simulate(ph.touches).voltages
        except LatticeoptError as exc:  # reported, left out of the means
            print(f"{ph.index:5d} {ph.n_touches:7d} failed: {exc}", flush=True)
            continue
        table.append([relative_change(volts, ref, f) for f in FLOORS])
        print(f"{ph.index:5d} {ph.n_touches:7d} " + " ".join(f"{x:8.5f}" for x in table[-1]), flush=True)
    a = np.array(table)
    print("mean          " + " ".join(f"{x:8.5f}" for x in a.mean(0)))
    print("ratio to eq.5 " + " ".join(f"{x:8.4f}" for x in (a / a[:, :1]).mean(0)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="what", required=True)
    sub.add_parser("rows", help="smallest reference rows of the layout families")
    fl = sub.add_parser("floors", help="V_rel of one layout under several floors")
    fl.add_argument("pattern", choices=["square", "hexagonal", "triangular", "diagonal"])
    fl.add_argument("width_mm", type=float)
    fl.add_argument("--phantoms", type=int, default=12)
    fl.add_argument("--rim", choices=["none", "channel"], default="none")
    args = ap.parse_args()
    if args.what == "rows":
        rows()
    else:
        floors(args.pattern, args.width_mm, args.phantoms, args.rim)


if __name__ == "__main__":
    main()
