"""Named facet sets of a labelled tet mesh, found geometrically with a tolerance.

Works for any mesher: the grid mesher's surfaces are exact, tetwild's lie within its envelope ``epsilon`` of
the input, so planes are matched with ``tol_mm`` and normals, never with equality. Electrode patches carry
the exact fraction of each triangle inside the electrode rectangle, so their areas are right even where the
triangles do not follow the electrode outline.
"""

from __future__ import annotations

import numpy as np

from ..design import REGION_IDS, LatticeDesign
from .tetmesh import TET_FACES, electrode_name, face_keys, keys_isin


def boundary_faces(tets: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """Faces of the tets selected by ``mask`` that no other selected tet shares, outward oriented.

    Parameters
    ----------
    tets : ndarray, shape (M, 4), positively oriented
    mask : ndarray of bool, shape (M,), optional (default all)

    Returns
    -------
    ndarray, shape (K, 3) int64
    """
    sel = tets if mask is None else tets[mask]
    faces = sel[:, TET_FACES].reshape(-1, 3)
    key = face_keys(faces, int(tets.max()) + 1 if tets.size else 0)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return faces[counts[inverse.ravel()] == 1]


def _normals(nodes: np.ndarray, tri: np.ndarray) -> np.ndarray:
    a, b, c = (nodes[tri[:, i]] for i in range(3))
    n = np.cross(b - a, c - a)
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


def _polygon_area(poly: list) -> float:
    if len(poly) < 3:
        return 0.0
    a = np.asarray(poly)
    return 0.5 * abs(float(np.dot(a[:, 0], np.roll(a[:, 1], -1)) - np.dot(a[:, 1], np.roll(a[:, 0], -1))))


def _clip_fraction(t_coords: np.ndarray, z_coords: np.ndarray, lo_t: float, hi_t: float,
                   lo_z: float, hi_z: float, slack: float = 0.0) -> np.ndarray:
    """Fraction of each planar triangle (2D coords, two arrays ``(K, 3)``) inside an axis-aligned rectangle.

    Sutherland–Hodgman clipping against the rectangle's four half-planes. Triangles inside the rectangle
    grown by ``slack`` (all of them on conforming meshes, up to rounding) count as fully inside and skip the
    clipping.
    """
    frac = np.zeros(len(t_coords))
    inside = ((t_coords.min(1) >= lo_t - slack) & (t_coords.max(1) <= hi_t + slack)
              & (z_coords.min(1) >= lo_z - slack) & (z_coords.max(1) <= hi_z + slack))
    frac[inside] = 1.0
    planes = ((0, lo_t, 1.0), (0, hi_t, -1.0), (1, lo_z, 1.0), (1, hi_z, -1.0))
    for k in np.nonzero(~inside)[0]:
        tri = [(t_coords[k, i], z_coords[k, i]) for i in range(3)]
        poly = tri
        for axis, bound, sign in planes:
            out = []
            for i, p in enumerate(poly):
                q = poly[(i + 1) % len(poly)]
                dp, dq = sign * (p[axis] - bound), sign * (q[axis] - bound)
                if dp >= 0:
                    out.append(p)
                if dp * dq < 0:
                    s = dp / (dp - dq)
                    out.append((p[0] + s * (q[0] - p[0]), p[1] + s * (q[1] - p[1])))
            poly = out
            if not poly:
                break
        full = _polygon_area(tri)
        frac[k] = _polygon_area(poly) / full if full > 0 else 0.0
    return np.clip(frac, 0.0, 1.0)


def tag_facets(nodes: np.ndarray, tets: np.ndarray, region: np.ndarray, design: LatticeDesign,
               tol_mm: float) -> tuple[dict, dict]:
    """Find the named facet sets of a labelled mesh.

    Parameters
    ----------
    nodes, tets, region
        The labelled mesh (mm, positively oriented tets, region ids).
    design
        The design the mesh represents (planes, electrode rectangles).
    tol_mm
        How far a surface may sit from its nominal plane (0 would do for exact meshes; use a small
        positive value anyway to absorb rounding).

    Returns
    -------
    facets : dict name -> (K, 3) int64
    weights : dict name -> (K,) float, only for electrode sets with partially covered triangles
    """
    H = design.total_thickness_mm
    outer = boundary_faces(tets)
    n_out = _normals(nodes, outer)
    zs = nodes[outer][:, :, 2]
    facets = {
        "top": outer[(zs.min(axis=1) > H - tol_mm) & (n_out[:, 2] > 0.9)],
        "bottom": outer[(zs.max(axis=1) < tol_mm) & (n_out[:, 2] < -0.9)],
    }
    gel_bnd = boundary_faces(tets, region == REGION_IDS["hydrogel"])
    facets["hydrogel_boundary"] = gel_bnd
    # Electrodes sit on the outer side walls of the hydrogel: gel-boundary faces that are also outer faces.
    n = len(nodes)
    gel_keys, outer_keys = face_keys(gel_bnd, n), face_keys(outer, n)
    is_outer = keys_isin(gel_keys, outer_keys)
    wall = gel_bnd[is_outer]
    n_wall = _normals(nodes, wall)
    pts = nodes[wall]  # (K, 3, 3)
    z0, z1 = design.layer_z_mm
    weights = {}
    for k, (cx, cy, _cz, nx, ny, axis, width, _h) in enumerate(design.electrodes()):
        wall_coord = cx if nx != 0 else cy
        normal_axis = 0 if nx != 0 else 1
        sign = nx if nx != 0 else ny
        on_wall = (np.abs(pts[:, :, normal_axis] - wall_coord).max(axis=1) < tol_mm) & \
                  (n_wall[:, normal_axis] * sign > 0.9)
        t_axis = int(axis)
        centre = cx if t_axis == 0 else cy
        lo, hi = centre - width / 2, centre + width / 2
        cand = np.nonzero(on_wall & (pts[:, :, t_axis].max(axis=1) > lo) & (pts[:, :, t_axis].min(axis=1) < hi))[0]
        # The patch is exactly the electrode rectangle: a gel wall reaching past the layer (tetwild's
        # envelope) gets fractional weights rather than extra area.
        frac = _clip_fraction(pts[cand][:, :, t_axis], pts[cand][:, :, 2], lo, hi, z0, z1,
                              slack=1e-9 * design.size_mm)
        keep = frac > 1e-9
        name = electrode_name(k + 1)
        facets[name] = wall[cand[keep]]
        if np.any(frac[keep] < 1 - 1e-9):
            weights[name] = frac[keep]
    return facets, weights
