"""Transfer of nodal fields between two tet meshes of the same body: P1 interpolation at points.

>>> import numpy as np
>>> from latticeopt import LatticeDesign, MeshSettings, mesh_design
>>> coarse = mesh_design(LatticeDesign(), MeshSettings(size_mm=8), cache_dir=False)
>>> fine = mesh_design(LatticeDesign(), MeshSettings(size_mm=6), cache_dir=False)
>>> P = interpolation_matrix(coarse, fine.nodes_mm)
>>> P.shape == (fine.n_nodes, coarse.n_nodes), bool(np.allclose(P @ coarse.nodes_mm, fine.nodes_mm))
(True, True)

The containing tet of each point comes from VTK's cell locator (through pyvista); the weights are the point's
barycentric coordinates in it, so a field linear over the source mesh is reproduced exactly and every row sums
to 1. Points on shared faces or edges may be given to either neighbour: the interpolant is continuous, so the
value is the same. The locator accepts a point within its tolerance of a cell (about 1e-3 of the cell's
size), so a weight can be slightly negative: the neighbouring tet's linear function continued that far.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .tetmesh import TetMesh

__all__ = ["interpolation_matrix"]


def interpolation_matrix(mesh: TetMesh, points_mm, tol_mm: float = 1e-6) -> sp.csr_matrix:
    """Sparse ``P`` with ``P @ values`` = the P1 interpolant of nodal ``values`` of ``mesh`` at ``points_mm``.

    Parameters
    ----------
    mesh
        The source tet mesh (mm).
    points_mm : array_like, shape (P, 3)
        Where to interpolate (mm), inside the mesh or within ``tol_mm`` of it (round-off on its boundary).
    tol_mm
        Largest distance of a point outside the mesh; such a point takes the nearest tet's clipped barycentric
        weights (the interpolant continued to the boundary).

    Returns
    -------
    scipy.sparse.csr_matrix, shape (P, mesh.n_nodes)
        Four weights per row summing to 1, non-negative but for the locator's tolerance (module docstring).

    Raises
    ------
    ValueError
        A point farther than ``tol_mm`` from the mesh (the two meshes do not cover the same body).
    """
    import pyvista as pv  # VTK: loaded only where fields are transferred

    pts = np.ascontiguousarray(points_mm, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points_mm: expected shape (P, 3), got {pts.shape}")
    grid = pv.UnstructuredGrid({pv.CellType.TETRA: mesh.tets}, mesh.nodes_mm)
    cell = np.asarray(grid.find_containing_cell(pts), dtype=np.int64)
    lost = np.flatnonzero(cell < 0)
    if len(lost):
        cell[lost] = np.asarray(grid.find_closest_cell(pts[lost]), dtype=np.int64)
    tet = mesh.tets[cell]
    corner = mesh.nodes_mm[tet]  # (P, 4, 3)
    edges = np.transpose(corner[:, 1:] - corner[:, :1], (0, 2, 1))  # columns: the three edges from node 0
    lam = np.linalg.solve(edges, (pts - corner[:, 0])[:, :, None])[:, :, 0]
    bary = np.concatenate([1.0 - lam.sum(axis=1, keepdims=True), lam], axis=1)
    if len(lost):
        clipped = np.clip(bary[lost], 0.0, None)
        clipped /= clipped.sum(axis=1, keepdims=True)
        bary[lost] = clipped
        gap = np.linalg.norm(np.einsum("pi,pij->pj", clipped, corner[lost]) - pts[lost], axis=1)
        if gap.max() > tol_mm:
            k = int(lost[np.argmax(gap)])
            raise ValueError(f"points_mm: point {k} at {pts[k].tolist()} lies outside the mesh (by about "
                             f"{gap.max():.3g} mm; tolerance {tol_mm:g} mm)")
    rows = np.repeat(np.arange(len(pts)), 4)
    return sp.csr_matrix((bary.ravel(), (rows, tet.ravel())), shape=(len(pts), mesh.n_nodes))
