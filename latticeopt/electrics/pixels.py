"""Projection of element quantities onto an ``n x n`` pixel grid over the sensor area.

``F[k, p]`` is the fraction of tet ``k``'s volume that lies above pixel ``p`` (in the vertical column over
it). If every hydrogel element takes the volume-weighted mean conductivity change of the pixels it
overlaps, the chain rule gives the pixel Jacobian ``J_pix = J F``: a pixel's column sums the element
columns beneath it weighted by their overlap. Rows of ``F`` sum to 1, so ``J_pix`` summed over pixels
equals ``J`` summed over elements, and ``F @ sigma_pixels`` is the element conductivity of a pixel image
(what :meth:`ForwardModel.with_conductivity` takes to simulate an image).

The fractions are exact (up to rounding): with ``C(a, b)`` the volume of the tet in ``{x <= a, y <= b}``, a
pixel ``(a0, a1] x (b0, b1]`` holds ``C(a1, b1) - C(a0, b1) - C(a1, b0) + C(a0, b0)``. ``C`` comes from
clipping the tet by the half-space ``x <= a`` into at most three tets, clipping those by ``y <= b`` and
adding the volumes. Only pixel lines strictly inside a tet's bounding box are clipped at; parts of a tet
outside the grid (a deformed rim) count for the border pixels.

Pixel numbering: ``p = iy * n + ix`` with ``ix`` along x and ``iy`` along y, both from the extent's low
corner, so ``values.reshape(n, n)`` is an image with row ``iy`` (plot with ``origin="lower"``).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .. import _validate as v
from ..errors import ParameterError
from ..mesh.tetmesh import TetMesh

#: The three tets of a triangular prism with triangles (a0, a1, a2) and (b0, b1, b2), ai joined to bi.
_PRISM = ((0, 1, 2, 3), (1, 2, 3, 4), (2, 3, 4, 5))


def _abs_volumes(P: np.ndarray) -> np.ndarray:
    d = P[:, 1:] - P[:, :1]
    return np.abs(np.linalg.det(d)) / 6.0 if len(P) else np.zeros(0)


def clip_below(P: np.ndarray, axis: int, value: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split tets by the half-space ``p[axis] <= value`` and keep the part inside.

    Parameters
    ----------
    P : ndarray, shape (J, 4, 3)
        Vertex coordinates of the tets.
    axis : int
        Coordinate axis of the cutting plane.
    value : ndarray, shape (J,)
        Plane position per tet.

    Returns
    -------
    pieces : ndarray, shape (Q, 4, 3)
        Tets (any orientation, possibly flat) whose union is the inside part.
    owner : ndarray of int, shape (Q,)
        Index in ``P`` of the tet each piece came from.
    """
    s = P[:, :, axis] - value[:, None]
    order = np.argsort(s, axis=1, kind="stable")
    P = np.take_along_axis(P, order[:, :, None], axis=1)
    s = np.take_along_axis(s, order, axis=1)
    below = (s <= 0).sum(axis=1)
    idx = np.arange(len(P))
    pieces, owner = [P[below == 4]], [idx[below == 4]]

    def cut(sel: np.ndarray, i: int, j: int) -> np.ndarray:
        # The point where the edge from vertex i (s <= 0) to vertex j (s > 0) meets the plane.
        si, sj = s[sel, i], s[sel, j]
        t = (si / (si - sj))[:, None]
        return P[sel, i] + t * (P[sel, j] - P[sel, i])

    sel = np.nonzero(below == 1)[0]
    if len(sel):
        pieces.append(np.stack([P[sel, 0], cut(sel, 0, 1), cut(sel, 0, 2), cut(sel, 0, 3)], axis=1))
        owner.append(sel)
    for k, prism in ((2, lambda sel: (P[sel, 0], cut(sel, 0, 2), cut(sel, 0, 3),
                                      P[sel, 1], cut(sel, 1, 2), cut(sel, 1, 3))),
                     (3, lambda sel: (P[sel, 0], P[sel, 1], P[sel, 2],
                                      cut(sel, 0, 3), cut(sel, 1, 3), cut(sel, 2, 3)))):
        sel = np.nonzero(below == k)[0]
        if len(sel):
            verts = np.stack(prism(sel), axis=1)  # (len, 6, 3), a convex prism with planar quads
            for tet in _PRISM:
                pieces.append(verts[:, list(tet)])
                owner.append(sel)
    return np.concatenate(pieces), np.concatenate(owner)


def default_extent_mm(mesh: TetMesh) -> tuple[float, float, float, float]:
    """``(x0, x1, y0, y1)``: the design's ``[0, L]^2`` if ``mesh.info`` names it, else the nodes' bounding box."""
    design = mesh.info.get("design") or {}
    if "size_mm" in design:
        L = float(design["size_mm"])
        return 0.0, L, 0.0, L
    lo, hi = mesh.nodes_mm[:, :2].min(0), mesh.nodes_mm[:, :2].max(0)
    return float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1])


def pixel_matrix(nodes_mm: np.ndarray, tets: np.ndarray, n: int = 48,
                 extent_mm: tuple[float, float, float, float] = (0.0, 100.0, 0.0, 100.0)) -> sp.csr_matrix:
    """Exact volume fraction of each tet above each pixel.

    Parameters
    ----------
    nodes_mm : ndarray, shape (N, 3)
    tets : ndarray, shape (M, 4)
    n
        Pixels per side.
    extent_mm
        ``(x0, x1, y0, y1)`` of the pixel grid (mm).

    Returns
    -------
    scipy.sparse.csr_matrix, shape (M, n * n)
        Rows sum to 1.
    """
    n = v.integer("n", n, lo=1, hi=4096)
    try:
        x0, x1, y0, y1 = (float(e) for e in extent_mm)
    except (TypeError, ValueError):
        raise ParameterError("extent_mm", "four numbers (x0, x1, y0, y1)", extent_mm) from None
    if not (x1 > x0 and y1 > y0):
        raise ParameterError("extent_mm", "(x0, x1, y0, y1) with x1 > x0 and y1 > y0", extent_mm)
    P = np.asarray(nodes_mm, dtype=float)[tets]  # (M, 4, 3)
    M = len(P)
    vol = _abs_volumes(P)
    lines = [np.linspace(x0, x1, n + 1), np.linspace(y0, y1, n + 1)]
    lo = [np.clip(np.searchsorted(lines[a], P[:, :, a].min(1), side="right") - 1, 0, n - 1) for a in (0, 1)]
    hi = [np.clip(np.searchsorted(lines[a], P[:, :, a].max(1), side="left") - 1, 0, n - 1) for a in (0, 1)]
    span = [hi[a] - lo[a] + 1 for a in (0, 1)]
    S = [int(span[a].max()) for a in (0, 1)]
    # C[k, p, q]: volume of tet k in {x <= line lo+p, y <= line lo+q}; p = 0 is below the tet, p >= span
    # means no cut (the whole extent in that direction).
    p = np.arange(S[0] + 1)[None, :]
    q = np.arange(S[1] + 1)[None, :]
    cut_x = (p >= 1) & (p < span[0][:, None])  # (M, S0+1): line lo+p lies strictly inside the tet's x-range
    cut_y = (q >= 1) & (q < span[1][:, None])
    kx, px = np.nonzero(cut_x)
    pieces, own = clip_below(P[kx], 0, lines[0][lo[0][kx] + px])
    Cx = np.zeros((M, S[0] + 1))
    Cx[kx, px] = np.bincount(own, _abs_volumes(pieces), minlength=len(kx))
    ky, qy = np.nonzero(cut_y)
    pieces, own = clip_below(P[ky], 1, lines[1][lo[1][ky] + qy])
    Cy = np.zeros((M, S[1] + 1))
    Cy[ky, qy] = np.bincount(own, _abs_volumes(pieces), minlength=len(ky))
    # C[k, p, q]: volume of tet k in {x <= line lo+p, y <= line lo+q}. p = 0 lies at or below the tet (0);
    # p >= span means no cut in x.
    cx, cy = cut_x[:, :, None], cut_y[:, None, :]
    C = np.where(cx, np.where(cy, 0.0, Cx[:, :, None]), np.where(cy, Cy[:, None, :], vol[:, None, None]))
    kb, pb, qb = np.nonzero(cx & cy)
    if len(kb):
        pieces, own = clip_below(P[kb], 0, lines[0][lo[0][kb] + pb])
        pieces2, own2 = clip_below(pieces, 1, lines[1][lo[1][kb] + qb][own])
        C[kb, pb, qb] = np.bincount(own[own2], _abs_volumes(pieces2), minlength=len(kb))
    C[:, 0, :] = 0.0
    C[:, :, 0] = 0.0
    cell = C[:, 1:, 1:] - C[:, :-1, 1:] - C[:, 1:, :-1] + C[:, :-1, :-1]  # (M, S0, S1)
    k, pc, qc = np.nonzero((np.arange(S[0])[None, :, None] < span[0][:, None, None])
                           & (np.arange(S[1])[None, None, :] < span[1][:, None, None]))
    vals = cell[k, pc, qc] / vol[k]
    cols = (lo[1][k] + qc) * n + (lo[0][k] + pc)
    keep = vals > 1e-14
    F = sp.csr_matrix((vals[keep], (k[keep], cols[keep])), shape=(M, n * n))
    F.sum_duplicates()
    return F
