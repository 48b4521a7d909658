"""The fixed mesh of a density layout, and the map from density cells to its elements.

The conductive layer is meshed whole (the uniform design, every layer tet labelled ``hydrogel``) by the grid
mesher's Kuhn split, on grid lines at the sensor's centre, the electrode edges and the density cells' edges
(every edge when a cell is at least the mesh size, else every ``k``-th, ``k = floor(size / cell)``), each interval
then split to the mesh size. A density cell at least as large as the mesh size is thus a whole number of
element columns, and a 0/1 density gives 0/1 elements. An element column's density is the area average of the
density cells it overlaps (:func:`cell_matrix`, linear: the gradient with respect to the cells is its transpose
applied to the elements' gradient).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.sparse as sp

from ..design import REGION_IDS, LatticeDesign
from ..mesh import MeshSettings
from ..mesh.grid import _axis_breakpoints, _subdivide, tensor_mesh, z_coordinates
from ..mesh.tetmesh import TetMesh


def uniform_design(design: LatticeDesign) -> LatticeDesign:
    """``design``'s sensor (size, stack, electrodes) with the whole conductive layer as one region (w = 0)."""
    return LatticeDesign(width_mm=0.0, thickness_mm=design.thickness_mm, size_mm=design.size_mm,
                         total_thickness_mm=design.total_thickness_mm, sealing_mm=design.sealing_mm,
                         n_electrodes=design.n_electrodes, electrode_width_mm=design.electrode_width_mm,
                         electrode_positions_mm=design.electrode_positions_mm)


#: A cell edge across which the density jumps by at least this much somewhere is a grid line of the mesh.
SHARP_JUMP = 0.5


def sharp_edges(density: np.ndarray, axis: int) -> np.ndarray:
    """Indices ``k`` (1..n-1) of the cell edges at ``k L/n`` along ``axis`` (0: x, between columns; 1: y, between
    rows) across which ``density`` jumps by at least :data:`SHARP_JUMP` somewhere."""
    d = np.asarray(density, dtype=float)
    jump = np.abs(np.diff(d, axis=1 - axis)).max(axis=axis)
    return np.flatnonzero(jump >= SHARP_JUMP) + 1


def _lines(base: LatticeDesign, axis: int, n: int, size_mm: float, sharp: np.ndarray) -> np.ndarray:
    L = base.size_mm
    step = max(1, int(np.floor(size_mm / (L / n) + 1e-9)))
    edges = np.linspace(0.0, L, n + 1)
    breaks = np.unique(np.round(np.r_[_axis_breakpoints(base, axis), edges[::step], edges[sharp], L], 9))
    return _subdivide(breaks, size_mm, lambda a, b: 1)


def density_mesh(design: LatticeDesign, n: int, settings: MeshSettings | None = None,
                 density: np.ndarray | None = None) -> TetMesh:
    """The mesh a density layout of ``n x n`` cells is solved on (module docstring); ``settings`` gives
    ``size_mm`` and ``layer_cells`` (its other fields do not apply).

    ``density`` (optional, shape ``(n, n)``): also put grid lines on the cell edges across which it jumps by at
    least :data:`SHARP_JUMP` (:func:`sharp_edges`), so a sharp layout's edges are element faces even where its
    cells are finer than the mesh (the sharp limit: a 0/1 lattice is then meshed like its conforming mesh). The
    lines depend on the density only through its jumps: a small change of the density keeps the mesh.
    """
    s = settings or MeshSettings()
    base = uniform_design(design)
    sharp = [np.zeros(0, dtype=int)] * 2 if density is None else [sharp_edges(density, a) for a in (0, 1)]
    x, y = _lines(base, 0, n, s.size_mm, sharp[0]), _lines(base, 1, n, s.size_mm, sharp[1])
    z = z_coordinates(base, s.size_mm, s.layer_cells)
    mesh = tensor_mesh(base, x, y, z)
    info = {**mesh.info, "mesher": "density", "density_cells": n, "sharp_lines": sum(len(k) for k in sharp),
            "settings": {"size_mm": s.size_mm, "layer_cells": s.layer_cells}, "design": base.as_dict()}
    return dataclasses.replace(mesh, info=info)


def _overlap(model_lines: np.ndarray, n: int, L: float) -> sp.csr_matrix:
    """``(len(model_lines) - 1, n)``: the fraction of each model interval inside each density interval."""
    cells = np.linspace(0.0, L, n + 1)
    lo = np.maximum(model_lines[:-1, None], cells[None, :-1])
    hi = np.minimum(model_lines[1:, None], cells[None, 1:])
    frac = np.clip(hi - lo, 0.0, None) / np.diff(model_lines)[:, None]
    frac[frac < 1e-12] = 0.0
    return sp.csr_matrix(frac)


def cell_matrix(mesh: TetMesh, n: int) -> tuple[sp.csr_matrix, np.ndarray]:
    """Density of every conductive-layer tet as a linear map of the ``n x n`` cells.

    Returns
    -------
    A : scipy.sparse.csr_matrix, shape (n_layer_tets, n * n)
        ``rho_tet = A @ density.ravel()`` (cell ``(i, j)`` at column ``i * n + j``: row ``i`` is ``y``).
    layer_tets : ndarray of int, shape (n_layer_tets,)
        The conductive layer's tets in mesh order (the ``hydrogel`` region of the density mesh).
    """
    L = float(mesh.info["design"]["size_mm"])
    nx, ny, _ = mesh.info["grid_shape"]
    x = np.unique(mesh.nodes_mm[:, 0])
    y = np.unique(mesh.nodes_mm[:, 1])
    if len(x) != nx or len(y) != ny:
        raise ValueError("mesh: expected the tensor grid of density_mesh")
    layer_tets = np.flatnonzero(mesh.region == REGION_IDS["hydrogel"])
    cent = mesh.nodes_mm[mesh.tets[layer_tets]].mean(axis=1)
    ix = np.clip(np.searchsorted(x, cent[:, 0]) - 1, 0, nx - 2)
    iy = np.clip(np.searchsorted(y, cent[:, 1]) - 1, 0, ny - 2)
    columns = sp.kron(_overlap(y, n, L), _overlap(x, n, L), format="csr")  # row iy * (nx - 1) + ix
    return columns[iy * (nx - 1) + ix], layer_tets
