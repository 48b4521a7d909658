"""Exact mesher for every layout: a constrained 2D triangulation of the sensor square, extruded into prisms.

The conductive layer is a 2D layout extruded through ``t`` and every other interface is a plane ``z =
const``, so a mesh that conforms to the layout in 2D and to the layer faces in z represents the sensor
exactly. The square ``[0, L]^2`` is triangulated with Shewchuk's Triangle (the ``triangle`` package) as a
planar straight-line graph whose segments are every edge of the hydrogel footprint's rings and the square's
sides, split at every electrode edge and wherever the footprint meets a side; Triangle keeps every segment as
a chain of triangle edges (splitting it where its quality refinement needs), so the triangulation conforms
and each triangle lies wholly in the hydrogel or in silicone. The
triangle vertices are repeated on the z levels of :func:`~latticeopt.mesh.grid.z_coordinates` (the grid
mesher's rule), each triangle becomes a stack of prisms, and each prism is split into three tets.

Prism split: each quadrilateral side face of a prism is cut along the diagonal from the bottom node of its
lower-numbered vertex to the top node of the higher-numbered one. The rule depends only on the two vertices
of the face, so the two prisms sharing a face cut it alike and the tet mesh is conforming; with the
triangle's vertices ordered ``a < b < c`` the three tets are ``(a0, b0, c0, c1)``, ``(a0, b0, c1, b1)`` and
``(a0, b1, c1, a1)`` (the standard rule of ordering by global vertex index).

Mean-dilatation cells: adjacent same-region triangles are paired by a greedy matching, and the two prisms of
a pair in one z layer form one patch (six tets on eight nodes, like a grid hexahedron), so there is about
one volume constraint per node, as on the grid; unpaired prisms form patches of their own.

Deterministic: the same design and settings give identical arrays.
"""

from __future__ import annotations

import math

import numpy as np

from ..design import LatticeDesign
from .facets import boundary_faces, tag_facets
from .grid import z_coordinates
from .tetmesh import TetMesh, tet_volumes

#: Smallest angle Triangle's quality refinement aims for (degrees); 30 terminates on every layout tested
#: (the triangular lattice meets the sides at 30 degrees).
MIN_ANGLE_DEG = 30.0


def equilateral_area(edge_mm: float) -> float:
    """Area (mm^2) of an equilateral triangle of edge ``edge_mm``: the max-area constraint for that size."""
    return math.sqrt(3.0) / 4.0 * edge_mm ** 2


def triangulate(vertices: np.ndarray, segments: np.ndarray, regions: np.ndarray,
                min_angle_deg: float = MIN_ANGLE_DEG) -> tuple[np.ndarray, np.ndarray]:
    """Quality conforming Delaunay triangulation of a planar straight-line graph.

    Parameters
    ----------
    vertices : ndarray, shape (n, 2)
        Points (mm).
    segments : ndarray, shape (s, 2)
        Vertex index pairs that the triangulation must contain (split by added points where needed).
    regions : ndarray, shape (r, 3)
        One ``(x, y, max_area_mm2)`` per face of the graph: a point inside it and its largest triangle area.
    min_angle_deg
        Quality bound (Triangle's ``q``).

    Returns
    -------
    points : ndarray, shape (N, 2)
    triangles : ndarray, shape (T, 3) int64, counter-clockwise
    """
    import triangle

    regions = np.asarray(regions, dtype=float)
    attr = np.column_stack([regions[:, :2], np.arange(len(regions)), regions[:, 2]])
    # a global bound as well, in case a face got no region point: the largest regional one
    opts = f"pq{min_angle_deg:g}Aaa{regions[:, 2].max():.17g}Q"
    out = triangle.triangulate({"vertices": np.asarray(vertices, dtype=float),
                                "segments": np.asarray(segments, dtype=np.int32), "regions": attr}, opts)
    return np.asarray(out["vertices"], dtype=float), np.asarray(out["triangles"], dtype=np.int64)


def _layout_graph(design: LatticeDesign, electrode_edges: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (mm, shape ``(n, 2)``) and segments (shape ``(s, 2)``) of the design's planar graph.

    Footprint ring vertices within ``1e-9 L`` of a side are put on it; ring edges lying on a side are left to
    the side's own segments, which are split at the corners, at the electrode edges (unless
    ``electrode_edges`` is False) and at every ring vertex on that side.
    """
    import shapely

    L = design.size_mm
    tol = 1e-9 * L
    rings = []
    fp = design.footprint()
    if design.has_lattice and not fp.is_empty:
        for ring in shapely.get_rings(fp):
            c = np.asarray(ring.coords)[:-1, :2].copy()
            c[np.abs(c) < tol] = 0.0
            c[np.abs(c - L) < tol] = L
            rings.append(c)
    pts = np.concatenate(rings) if rings else np.zeros((0, 2))
    side_pts = [np.array([[0.0, 0.0], [L, 0.0], [L, L], [0.0, L]])]
    if electrode_edges:
        for cx, cy, _cz, _nx, _ny, axis, width, _h in design.electrodes():
            t = np.array([1.0, 0.0]) if int(axis) == 0 else np.array([0.0, 1.0])
            side_pts.append(np.array([cx, cy]) + np.outer([-0.5, 0.5], t) * width)
    side_pts = np.concatenate(side_pts)
    side_pts[np.abs(side_pts) < tol] = 0.0
    side_pts[np.abs(side_pts - L) < tol] = L
    every = np.concatenate([pts, side_pts])
    # one vertex per distinct position (rings share vertices; electrode edges may meet channel edges)
    _, first, inverse = np.unique(np.round(every / tol), axis=0, return_index=True, return_inverse=True)
    inverse = inverse.ravel()
    verts = every[first]
    segs = []
    start = 0
    for c in rings:
        idx = inverse[start:start + len(c)]
        start += len(c)
        a, b = idx, np.roll(idx, -1)
        pa, pb = verts[a], verts[b]
        on_side = np.zeros(len(a), dtype=bool)
        for axis in (0, 1):
            for v in (0.0, L):
                on_side |= (pa[:, axis] == v) & (pb[:, axis] == v)
        segs.append(np.stack([a[~on_side], b[~on_side]], axis=1))
    for axis, v in ((1, 0.0), (0, L), (1, L), (0, 0.0)):
        on = np.nonzero(verts[:, axis] == v)[0]
        on = on[np.argsort(verts[on, 1 - axis], kind="stable")]
        segs.append(np.stack([on[:-1], on[1:]], axis=1))
    segs = np.concatenate(segs)
    segs = segs[segs[:, 0] != segs[:, 1]]
    return verts, np.unique(np.sort(segs, axis=1), axis=0)


def _regions(design: LatticeDesign, size_mm: float, channel_cells: int) -> np.ndarray:
    """``(x, y, max_area)`` per face: hydrogel polygons fine enough for ``channel_cells`` across, silicone by size.

    The channel width is ``width_mm`` for the parametric families and ``2 area / perimeter`` of each polygon
    for custom layouts (exact for a long strip).
    """
    import shapely

    L = design.size_mm
    box = shapely.box(0.0, 0.0, L, L)
    fp = design.footprint() if design.has_lattice else shapely.MultiPolygon()
    out = []
    for poly in ([] if fp.is_empty else getattr(fp, "geoms", [fp])):
        if design.pattern == "custom":
            w = 2.0 * poly.area / poly.length
        elif design.width_mm > 0:
            w = design.width_mm
        else:
            w = np.inf  # the uniform layer: no channel
        p = poly.representative_point()
        out.append((p.x, p.y, equilateral_area(min(size_mm, w / channel_cells))))
    rest = box.difference(fp) if not fp.is_empty else box
    for poly in getattr(rest, "geoms", [rest]):
        if poly.area > 1e-12 * L * L:
            p = poly.representative_point()
            out.append((p.x, p.y, equilateral_area(size_mm)))
    return np.asarray(out, dtype=float)


def pair_triangles(triangles: np.ndarray, label: np.ndarray) -> np.ndarray:
    """Group each triangle with at most one edge neighbour of the same label (greedy matching).

    Triangles are visited in order of how few unpaired same-label neighbours they have (fewest first, ties
    by index), each paired with its unpaired neighbour that has the fewest; this leaves few triangles alone.

    Parameters
    ----------
    triangles : ndarray, shape (T, 3)
    label : ndarray, shape (T,)
        Triangles of different labels are never paired.

    Returns
    -------
    ndarray, shape (T,) int64
        Group id of each triangle (``0 .. G-1``, numbered by first member).
    """
    T = len(triangles)
    edges = np.sort(triangles[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2), axis=1)
    owner = np.repeat(np.arange(T), 3)
    order = np.lexsort((edges[:, 1], edges[:, 0]))
    e, o = edges[order], owner[order]
    same = np.all(e[1:] == e[:-1], axis=1)
    a, b = o[:-1][same], o[1:][same]
    ok = label[a] == label[b]
    a, b = a[ok], b[ok]
    nbrs: list[list[int]] = [[] for _ in range(T)]
    for i, j in zip(a.tolist(), b.tolist()):
        nbrs[i].append(j)
        nbrs[j].append(i)
    free_deg = np.array([len(n) for n in nbrs])
    mate = np.full(T, -1, dtype=np.int64)
    for i in np.lexsort((np.arange(T), free_deg)).tolist():
        if mate[i] >= 0:
            continue
        cand = [j for j in nbrs[i] if mate[j] < 0]
        if not cand:
            continue
        j = min(cand, key=lambda k: (free_deg[k], k))
        mate[i], mate[j] = j, i
        for k in nbrs[i] + nbrs[j]:
            free_deg[k] -= 1
    lead = np.where(mate >= 0, np.minimum(np.arange(T), mate), np.arange(T))
    _, group = np.unique(lead, return_inverse=True)
    return group.ravel().astype(np.int64)


def extrude(points: np.ndarray, triangles: np.ndarray, z: np.ndarray,
            groups: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Prism stack of a 2D triangulation over the levels ``z``, three positively oriented tets per prism.

    Parameters
    ----------
    points : ndarray, shape (n, 2)
        2D vertices (mm).
    triangles : ndarray, shape (T, 3)
    z : ndarray, shape (nz,)
        Increasing z levels (mm).
    groups : ndarray, shape (T,), optional
        Group id of each triangle (:func:`pair_triangles`); default one group per triangle.

    Returns
    -------
    nodes : ndarray, shape (n nz, 3)
        Node ``k n + i`` is vertex ``i`` on level ``k``.
    tets : ndarray, shape (3 T (nz - 1), 4) int64
        Layer by layer, triangle by triangle, the prism's three tets in turn.
    cells : ndarray, shape (3 T (nz - 1),) int64
        ``layer * G + group``: the prisms of one group in one layer form one cell.
    """
    n, T, nz = len(points), len(triangles), len(z)
    nodes = np.column_stack([np.tile(points, (nz, 1)), np.repeat(np.asarray(z, dtype=float), n)])
    a, b, c = np.sort(triangles, axis=1).T  # the split rule orders by global vertex index
    k = np.arange(nz - 1)[:, None] * n
    a0, b0, c0, a1, b1, c1 = a + k, b + k, c + k, a + k + n, b + k + n, c + k + n
    tets = np.stack([np.stack([a0, b0, c0, c1], -1), np.stack([a0, b0, c1, b1], -1),
                     np.stack([a0, b1, c1, a1], -1)], axis=2).reshape(-1, 4)
    neg = tet_volumes(nodes, tets) < 0
    tets[neg] = tets[neg][:, [0, 2, 1, 3]]
    groups = np.arange(T) if groups is None else np.asarray(groups, dtype=np.int64)
    G = int(groups.max()) + 1 if T else 0
    cells = np.repeat((np.arange(nz - 1)[:, None] * G + groups[None, :]).ravel(), 3)
    return nodes, tets, cells


def triangulate_layout(design: LatticeDesign, size_mm: float = 2.0, channel_cells: int = 2,
                       electrode_edges: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """The conforming 2D triangulation of the sensor square (mm): ``points (n, 2)``, ``triangles (T, 3)``."""
    verts, segs = _layout_graph(design, electrode_edges)
    return triangulate(verts, segs, _regions(design, size_mm, channel_cells))


def extruded_mesh(design: LatticeDesign, size_mm: float = 2.0, channel_cells: int = 2, layer_cells: int = 2,
                  cell_counts: str = "size", electrode_edges: bool = True) -> TetMesh:
    """Exact labelled tet mesh of any layout by extruding a conforming 2D triangulation.

    Parameters
    ----------
    design
        The sensor design (every pattern, custom included).
    size_mm
        Target edge length (mm): triangles no larger than an equilateral one of this edge, and z cells no
        longer than this.
    channel_cells
        Hydrogel triangles no larger than an equilateral one of edge ``w / channel_cells`` (custom layouts:
        ``w = 2 area / perimeter`` per polygon), so about that many across a channel.
    layer_cells
        Minimum cells through the conductive layer.
    cell_counts
        z levels only (:func:`~latticeopt.mesh.grid.z_coordinates`); the triangulation follows the size.
    electrode_edges
        False leaves the electrode edges out of the 2D graph; electrode triangles then carry their covered
        fraction (:func:`~latticeopt.mesh.facets.tag_facets`).

    Returns
    -------
    TetMesh
        Region labels from :meth:`LatticeDesign.region_at` at the tet centroids, all facet sets, ``cells`` =
        the mean-dilatation patches (pairs of prisms). ``info`` holds the 2D counts and the paired fraction.
    """
    points, tris = triangulate_layout(design, size_mm, channel_cells, electrode_edges)
    z0, z1 = design.layer_z_mm
    mid = np.column_stack([points[tris].mean(axis=1), np.full(len(tris), 0.5 * (z0 + z1))])
    groups = pair_triangles(tris, design.region_at(mid))
    z = z_coordinates(design, size_mm, layer_cells, cell_counts)
    nodes, tets, cells = extrude(points, tris, z, groups)
    region = design.region_at(nodes[tets].mean(axis=1))
    facets, weights = tag_facets(nodes, tets, region, design, tol_mm=1e-7 * design.size_mm)
    paired = 1.0 - (2 * (groups.max() + 1) - len(tris)) / len(tris)
    info = {"mesher": "extruded", "triangles_2d": len(tris), "points_2d": len(points), "levels_z": len(z),
            "paired_fraction": float(paired)}
    return TetMesh(nodes, tets, region, facets, weights, info, cells=cells)


def box_facets(nodes: np.ndarray, tets: np.ndarray) -> dict:
    """``top`` and ``bottom`` facet sets of a box mesh (the outer faces on its highest and lowest z)."""
    faces = boundary_faces(tets)
    zf = nodes[faces][:, :, 2]
    zmin, zmax = nodes[:, 2].min(), nodes[:, 2].max()
    return {"top": faces[np.all(np.isclose(zf, zmax), axis=1)],
            "bottom": faces[np.all(np.isclose(zf, zmin), axis=1)]}


def prism_block_mesh(side_mm: float, z_mm: np.ndarray, fine_mm: float, coarse_mm: float,
                     fine_half_width_mm: float, region: str = "substrate") -> TetMesh:
    """A homogeneous ``side x side`` box, extruded from a triangulation that is fine in a centred square.

    For verification against layer solutions (the flat punch of ``benchmarks/bench_locking.py`` and the
    mechanics tests): triangles of edge ``fine_mm`` within ``centre +- fine_half_width_mm``, ``coarse_mm``
    outside (Triangle grades between them), levels ``z_mm``. Cells are the paired prisms, as in
    :func:`extruded_mesh`; facet sets ``top`` and ``bottom``.

    Parameters
    ----------
    side_mm
        Box side (mm); the box is ``[0, side]^2 x [z_mm[0], z_mm[-1]]``.
    z_mm : ndarray, shape (nz,)
        Increasing z levels (mm).
    fine_mm, coarse_mm
        Triangle edge lengths (mm) inside and outside the centred square.
    fine_half_width_mm
        Half side of the centred square (mm).
    region
        Region name of every tet.
    """
    from ..design import REGION_IDS

    L, c, h = side_mm, side_mm / 2, fine_half_width_mm
    verts = np.array([[0, 0], [L, 0], [L, L], [0, L], [c - h, c - h], [c + h, c - h], [c + h, c + h], [c - h, c + h]],
                     dtype=float)
    segs = np.array([[0, 1], [1, 2], [2, 3], [3, 0], [4, 5], [5, 6], [6, 7], [7, 4]])
    regions = np.array([[c, c, equilateral_area(fine_mm)], [(c - h) / 2, c, equilateral_area(coarse_mm)]])
    points, tris = triangulate(verts, segs, regions)
    groups = pair_triangles(tris, np.zeros(len(tris), dtype=np.int64))
    nodes, tets, cells = extrude(points, tris, np.asarray(z_mm, dtype=float), groups)
    return TetMesh(nodes, tets, np.full(len(tets), REGION_IDS[region]), box_facets(nodes, tets), {},
                   {"mesher": "extruded-block", "triangles_2d": len(tris)}, cells=cells)
