"""Volumetric locking evidence: flat-punch force against mesh size at nu = 0.45, 0.49, 0.499 and 0.4999.

A homogeneous layer (thickness h = 5 mm, 60 x 60 mm, bonded to a rigid base) is indented by a frictionless
flat punch of radius a = 5 mm (a/h = 1) to 0.5 % of h (small strain). The force is compared with Hayes et al.
(1972), ``F = 4 G a kappa d / (1 - nu)``, kappa from :func:`latticeopt.mechanics.verification.hayes_kappa`.
Plain P1 tets (``element``) lock as nu -> 0.5: their force is too high and falls slowly with refinement.
The patch (mean-dilatation) formulation converges at every nu.

    python benchmarks/bench_locking.py            # prints the table (about a minute on this machine)
    python benchmarks/bench_locking.py --mesher extruded 1.25 1.0 0.625 0.5   # the layer on another mesher

``--mesher``: ``grid`` (default: the tensor grid, Kuhn tets, hexahedral patches), ``extruded`` (the square
triangulated with Triangle, fine within 1.4 a of the axis, and extruded: paired-prism patches) or ``tetwild``
(fTetWild on the box surface with a background sizing field: the mechanics' virtual-grid patches; slow).
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
import time

for _v in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import numpy as np  # noqa: E402

from latticeopt.mechanics import IndentationSolver, IndentSettings, Materials, NeoHookean  # noqa: E402
from latticeopt.mechanics.verification import block_mesh, graded_axis, hayes_kappa  # noqa: E402

H, A, SIDE, G_KPA = 5.0, 5.0, 60.0, 20.0


def layer_mesh(fine_mm: float, mesher: str = "grid"):
    z = np.linspace(0.0, H, int(round(H / fine_mm)) + 1)
    if mesher == "extruded":
        from latticeopt.mesh.extruded import prism_block_mesh

        return prism_block_mesh(SIDE, z, fine_mm, 4.0, 1.4 * A, region="hydrogel")  # as block_mesh
    if mesher == "tetwild":
        return tetwild_layer(fine_mm)
    xy = graded_axis(SIDE, SIDE / 2, 1.4 * A, fine_mm, 4.0)
    return block_mesh(xy, xy, z)


def tetwild_layer(fine_mm: float):
    """fTetWild on the box's 12-triangle surface; edge length ``fine_mm`` within 1.4 a of the axis, growing
    by 0.3 mm per mm to 4 mm outside (a background sizing field); nodes within the envelope snapped onto the
    box faces."""
    import pytetwild

    from latticeopt.design import REGION_IDS
    from latticeopt.mesh.extruded import box_facets
    from latticeopt.mesh.tetmesh import TetMesh, tet_volumes

    v = np.array([[x, y, z] for z in (0, H) for y in (0, SIDE) for x in (0, SIDE)], dtype=float)
    f = np.array([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4], [2, 6, 3], [3, 6, 7],
                  [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]], dtype=np.uint32)
    bg = block_mesh(np.linspace(0, SIDE, 61), np.linspace(0, SIDE, 61), np.linspace(0, H, 3))
    reach = np.max(np.abs(bg.nodes_mm[:, :2] - SIDE / 2), axis=1) - 1.4 * A
    size = np.clip(fine_mm + 0.3 * np.maximum(reach, 0.0), fine_mm, 4.0)
    # fTetWild leaves __tracked_surface.stl in its working directory: run it in a scratch one
    with tempfile.TemporaryDirectory(prefix="bench-locking-") as tmp, contextlib.chdir(tmp):
        pts, tets = pytetwild.tetrahedralize(v, f, edge_length_abs=4.0, epsilon=1e-4, quiet=True, loglevel=6,
                                             num_threads=1, bg_vertices=np.array(bg.nodes_mm, order="C"),
                                             bg_tets=np.array(bg.tets, dtype=np.int32, order="C"), bg_values=size)
    pts, tets = np.array(pts, dtype=float), np.array(tets, dtype=np.int64)
    tol = 1e-4 * np.sqrt(2 * SIDE ** 2 + H ** 2)
    for axis, hi in ((0, SIDE), (1, SIDE), (2, H)):
        for plane in (0.0, hi):
            pts[np.abs(pts[:, axis] - plane) < tol, axis] = plane
    neg = tet_volumes(pts, tets) < 0
    tets[neg] = tets[neg][:, [0, 2, 1, 3]]
    return TetMesh(pts, tets, np.full(len(tets), REGION_IDS["hydrogel"]), box_facets(pts, tets), {},
                   {"mesher": "tetwild-block"})


def force(mesh, nu: float, volumetric: str) -> float:
    mat = Materials.uniform(NeoHookean(G_KPA, nu))
    s = IndentSettings(materials=mat, in_plane="frictionless", volumetric=volumetric)
    res = IndentationSolver(mesh, s).solve([(SIDE / 2, SIDE / 2, A, 0.005 * H)])
    return float(res.forces_N[0])


def main(sizes=(1.25, 1.0, 0.625, 0.5), mesher: str = "grid") -> None:
    print(f"frictionless flat punch, a = {A} mm on a bonded layer h = {H} mm, {SIDE} mm wide, d = {0.005 * H} mm")
    print("force / Hayes force (kappa from the Fredholm equation); nodes per mesh in brackets")
    header = f"{'nu':>6} {'formulation':>11} " + " ".join(f"{'h=' + format(s, 'g') + ' mm':>18}" for s in sizes)
    print(header)
    print(f"mesher: {mesher}")
    meshes = [layer_mesh(s, mesher) for s in sizes]
    for nu in (0.45, 0.49, 0.499, 0.4999):
        ref = 4 * G_KPA * 1e-3 * A * hayes_kappa(A / H, nu) * 0.005 * H / (1 - nu)
        for vol in ("element", "patch"):
            row = []
            for m in meshes:
                t = time.perf_counter()
                row.append(f"{force(m, nu, vol) / ref:8.4f} ({m.n_nodes:6d})")
                _ = time.perf_counter() - t
            print(f"{nu:6g} {vol:>11} " + " ".join(f"{c:>18}" for c in row), flush=True)
        print(f"{'':6} {'Hayes F':>11} {ref:.5g} N (kappa = {hayes_kappa(A / H, nu):.4f})")


if __name__ == "__main__":
    _args = sys.argv[1:]
    _mesher = "grid"
    if "--mesher" in _args:
        _i = _args.index("--mesher")
        _mesher = _args[_i + 1]
        del _args[_i:_i + 2]
        if _mesher not in ("grid", "extruded", "tetwild"):
            sys.exit(f"--mesher: expected one of grid, extruded, tetwild, got {_mesher!r}")
    main(tuple(float(a) for a in _args) or (1.25, 1.0, 0.625, 0.5), _mesher)
