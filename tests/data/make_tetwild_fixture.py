"""Write tests/data/tetwild_w4_t3_s3.npz: one raw fTetWild run of the test design (input hash, output).

fTetWild is multi-threaded and not deterministic from run to run; tests that bound a few-percent quantity of
its output (tests/test_mesh_tetwild.py::test_electrode_areas_agree_with_grid) finish this fixed output with
latticeopt's own (deterministic) checks and snapping. Re-run after a change to the region solids:
``python tests/data/make_tetwild_fixture.py``.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

from latticeopt.design import LatticeDesign
from latticeopt.geometry import build_solids
from latticeopt.mesh.tetwild import run_ftetwild

DESIGN = LatticeDesign(width_mm=4.0, thickness_mm=3.0)
SIZE_MM, EPSILON_REL = 3.0, 1e-3
PATH = Path(__file__).with_name("tetwild_w4_t3_s3.npz")


def solids_hash(design: LatticeDesign) -> str:
    """Content hash of fTetWild's input (every region solid's vertices and faces)."""
    solids = build_solids(design)
    h = hashlib.sha256()
    for name in solids.names:
        h.update(name.encode())
        h.update(np.ascontiguousarray(np.round(solids.vertices_mm[name], 9)).tobytes())
        h.update(np.ascontiguousarray(solids.faces[name], dtype=np.int64).tobytes())
    return h.hexdigest()


def main() -> None:
    nodes, tets, region = run_ftetwild(DESIGN, SIZE_MM, EPSILON_REL, num_threads=1)
    np.savez_compressed(PATH, nodes=nodes, tets=tets.astype(np.int32), region=region,
                        input_hash=np.array(solids_hash(DESIGN)))
    print(f"wrote {PATH} ({PATH.stat().st_size / 1e6:.2f} MB, {len(nodes)} nodes, {len(tets)} tets)")


if __name__ == "__main__":
    main()
