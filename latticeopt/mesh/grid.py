"""Structured conforming tet mesher for axis-aligned patterns.

Grid lines sit on every channel edge, electrode edge and layer interface, so region volumes and electrode
areas are exact; each interval between two such lines is split into equal cells no longer than the target
size, with a minimum number of cells across every channel and through the conductive layer (the grading).
Every hexahedral cell is split into six tets along its main diagonal (Kuhn / Freudenthal split), which is
conforming across cells. Fully deterministic and vectorised.
"""

from __future__ import annotations

from itertools import permutations

import numpy as np

from ..design import LatticeDesign
from .facets import tag_facets
from .tetmesh import TetMesh, tet_volumes


def _axis_breakpoints(design: LatticeDesign, tangent_axis: int) -> np.ndarray:
    L = design.size_mm
    pts = [0.0, L]
    pts += design.channel_intervals_mm().ravel().tolist()
    for cx, cy, _cz, _nx, _ny, axis, width, _h in design.electrodes():
        if int(axis) == tangent_axis:
            c = cx if tangent_axis == 0 else cy
            pts += [c - width / 2, c + width / 2]
    return np.unique(np.round(np.clip(pts, 0.0, L), 9))


def _subdivide(breaks: np.ndarray, size_mm: float, min_cells) -> np.ndarray:
    """Coordinates after splitting each interval ``[b_i, b_i+1]`` into equal cells of length <= size."""
    out = [breaks[:1]]
    for a, b in zip(breaks[:-1], breaks[1:]):
        n = max(int(np.ceil((b - a) / size_mm - 1e-9)), int(min_cells(a, b)), 1)
        out.append(np.linspace(a, b, n + 1)[1:])
    return np.concatenate(out)


def grid_coordinates(design: LatticeDesign, size_mm: float, channel_cells: int,
                     layer_cells: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The x, y and z grid lines of the structured mesh (mm)."""
    iv = design.channel_intervals_mm()

    def in_channel(a: float, b: float) -> int:
        mid = 0.5 * (a + b)
        return channel_cells if np.any((iv[:, 0] <= mid) & (mid <= iv[:, 1])) else 1

    x = _subdivide(_axis_breakpoints(design, 0), size_mm, in_channel)
    y = _subdivide(_axis_breakpoints(design, 1), size_mm, in_channel)
    z0, z1 = design.layer_z_mm
    zb = np.unique(np.round([0.0, z0, z1, design.total_thickness_mm], 9))
    z = _subdivide(zb, size_mm, lambda a, b: layer_cells if (a >= z0 - 1e-9 and b <= z1 + 1e-9) else 1)
    return x, y, z


def _kuhn_tets(nx: int, ny: int, nz: int) -> np.ndarray:
    """Tets (node indices into an ``nx * ny * nz`` lattice, x fastest) of the six-tet split of every cell."""
    i, j, k = np.meshgrid(np.arange(nx - 1), np.arange(ny - 1), np.arange(nz - 1), indexing="ij")
    base = (i + nx * (j + ny * k)).ravel()
    step = np.array([1, nx, nx * ny])
    tets = []
    for perm in permutations(range(3)):
        v0 = base
        v1 = v0 + step[perm[0]]
        v2 = v1 + step[perm[1]]
        v3 = v2 + step[perm[2]]
        tets.append(np.stack([v0, v1, v2, v3], axis=1))
    return np.concatenate(tets)


def grid_mesh(design: LatticeDesign, size_mm: float = 2.0, channel_cells: int = 2,
              layer_cells: int = 2) -> TetMesh:
    """Structured conforming mesh of ``design``.

    Parameters
    ----------
    design
        An axis-aligned design (the square pattern).
    size_mm
        Largest cell edge (mm).
    channel_cells
        Minimum number of cells across every channel (and across each part of a channel that an electrode
        edge splits).
    layer_cells
        Minimum number of cells through the conductive layer.

    Returns
    -------
    TetMesh
        With region labels from the design's geometry and all named facet sets.
    """
    x, y, z = grid_coordinates(design, size_mm, channel_cells, layer_cells)
    X, Y, Z = np.meshgrid(x, y, z, indexing="ij")
    # x fastest, matching _kuhn_tets' numbering.
    nodes = np.stack([X.transpose(2, 1, 0).ravel(), Y.transpose(2, 1, 0).ravel(),
                      Z.transpose(2, 1, 0).ravel()], axis=1)
    tets = _kuhn_tets(len(x), len(y), len(z))
    neg = tet_volumes(nodes, tets) < 0
    tets[neg] = tets[neg][:, [0, 2, 1, 3]]
    region = design.region_at(nodes[tets].mean(axis=1))
    facets, weights = tag_facets(nodes, tets, region, design, tol_mm=1e-7 * design.size_mm)
    return TetMesh(nodes, tets, region, facets, weights,
                   {"mesher": "grid", "grid_shape": [len(x), len(y), len(z)]})
