"""Structured conforming tet mesher for axis-aligned layouts.

Grid lines sit on every x (y) coordinate of the hydrogel footprint's vertices (channel edges, frame, rim
band, electrode leads), on every electrode edge and on every layer interface, so region volumes and electrode
areas are exact; each interval between two such lines is split into equal cells no longer than the target
size, with a minimum number of cells across every channel and through the conductive layer (the grading).
Every hexahedral cell is split into six tets along its main diagonal (Kuhn / Freudenthal split), which is
conforming across cells. Fully deterministic and vectorised.
"""

from __future__ import annotations

from itertools import permutations

import numpy as np

from .. import layout as _layout
from ..design import LatticeDesign
from ..errors import ParameterError
from .facets import tag_facets
from .tetmesh import TetMesh, tet_volumes


def require_axis_aligned(design: LatticeDesign) -> None:
    """Raise a one-line :class:`ParameterError` naming ``mesher`` unless every layout edge is parallel to x or y."""
    if not design.is_axis_aligned:
        raise ParameterError("mesher", "'extruded' (or 'auto') for a layout with edges not parallel to x or y "
                             f"(pattern {design.pattern!r}); the grid mesher needs an axis-aligned layout", "grid")


def footprint_coordinates(design: LatticeDesign, axis: int) -> np.ndarray:
    """Every distinct ``axis`` coordinate (0: x, 1: y) of the hydrogel footprint's vertices (mm), sorted."""
    import shapely

    if not design.has_lattice or design.footprint().is_empty:
        return np.zeros(0)
    coords = shapely.get_coordinates(design.footprint())
    return np.unique(np.round(coords[:, axis], 9))


def channel_intervals(design: LatticeDesign, axis: int) -> np.ndarray:
    """Hydrogel channels crossing the ``axis`` direction, as merged intervals of that coordinate, shape ``(k, 2)``.

    The square lattice's channel lines (:meth:`LatticeDesign.channel_intervals_mm`), plus the rim band inside
    a frame (``rim = "channel"`` with ``frame_mm > 0``) and the electrode leads on electrodes whose side runs
    along ``axis``; the grid's cell-count rules give these pieces ``channel_cells``. Other layouts (custom)
    have none: their cells follow the size alone.
    """
    iv = [np.asarray(design.channel_intervals_mm()).reshape(-1, 2)]
    if design.pattern == "square" and design.has_lattice:
        L, f, w = design.size_mm, design.frame_mm, design.width_mm
        if design.rim == "channel" and f > 0:
            iv.append(np.array([[f, f + w / 2], [L - f - w / 2, L - f]]))
        if design.electrode_leads:
            bare = _layout.parametric_footprint("square", L, w, design.pitch_mm, design.rim, f)
            el = design.electrodes()
            no_contact = _layout.electrode_contact_mm(bare, el) <= 1e-12 * L
            for cx, cy, _cz, _nx, _ny, t_axis, _ew, _h in el[no_contact]:
                if int(t_axis) == axis:
                    c = cx if axis == 0 else cy
                    iv.append(np.array([[c - w / 2, c + w / 2]]))
    raw = np.concatenate(iv)
    raw = raw[np.argsort(raw[:, 0], kind="stable")]
    merged: list[list[float]] = []
    for a, b in raw:
        if merged and a <= merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], b)
        else:
            merged.append([float(a), float(b)])
    return np.asarray(merged).reshape(-1, 2)


def _axis_breakpoints(design: LatticeDesign, tangent_axis: int, electrode_edges: bool = True) -> np.ndarray:
    L = design.size_mm
    # The centre line makes the cell count even, so the mirrored split of _kuhn_tets is symmetric.
    pts = [0.0, L / 2, L]
    pts += design.channel_intervals_mm().ravel().tolist()
    pts += footprint_coordinates(design, tangent_axis).tolist()
    for cx, cy, _cz, _nx, _ny, axis, width, _h in design.electrodes():
        if electrode_edges and int(axis) == tangent_axis:
            c = cx if tangent_axis == 0 else cy
            pts += [c - width / 2, c + width / 2]
    return np.unique(np.round(np.clip(pts, 0.0, L), 9))


def _subdivide(breaks: np.ndarray, size_mm: float, min_cells, reference: np.ndarray | None = None,
               vanishing_cells: int | None = None) -> np.ndarray:
    """Coordinates after splitting each interval ``[b_i, b_i+1]`` into equal cells.

    The count is ``max(ceil(length / size), min_cells)``, where the length is the interval's own, or, given
    ``reference`` (one coordinate per breakpoint), ``|reference[i+1] - reference[i]|``; an interval whose
    reference length is zero gets ``vanishing_cells`` cells when that is given.
    """
    ref = breaks if reference is None else reference
    out = [breaks[:1]]
    for i, (a, b) in enumerate(zip(breaks[:-1], breaks[1:])):
        length = abs(ref[i + 1] - ref[i])
        if vanishing_cells is not None and length < 1e-9:
            n = vanishing_cells
        else:
            n = max(int(np.ceil(length / size_mm - 1e-9)), int(min_cells(a, b)), 1)
        out.append(np.linspace(a, b, n + 1)[1:])
    return np.concatenate(out)


def _reference_breakpoints(design: LatticeDesign, breaks: np.ndarray, tangent_axis: int) -> np.ndarray:
    """Each breakpoint's position in the reference layout of ``cell_counts="fixed"``.

    Sensor sides and electrode edges stay; the edges of the channel on line ``c`` move to
    ``c -/+ electrode_width / 2``, i.e. every channel takes the electrode width. Reference lengths, hence cell
    counts, then do not depend on ``w``; and where a channel edge crosses an electrode edge (at ``w`` = electrode
    width when channels are centred on the electrodes, as in the default layout) the piece between them has zero
    reference length on both sides of the crossing, so the counts agree across it.
    """
    L = design.size_mm
    fixed = [0.0, L / 2, L] + [(cx if tangent_axis == 0 else cy) + s * width / 2
                        for cx, cy, _cz, _nx, _ny, axis, width, _h in design.electrodes() if int(axis) == tangent_axis
                        for s in (-1, 1)]
    fixed = np.clip(fixed, 0.0, L)
    lines, half = design.line_positions_mm(), design.electrode_width_mm / 2
    edges = np.clip(np.concatenate([lines - design.width_mm / 2, lines + design.width_mm / 2]), 0.0, L)
    moved = np.clip(np.concatenate([lines - half, lines + half]), 0.0, L)
    out = breaks.copy()
    for i, b in enumerate(breaks):
        if design.has_lattice and not np.any(np.abs(fixed - b) < 1e-9):
            hit = np.abs(edges - b) < 1e-9
            if hit.any():
                out[i] = moved[np.argmax(hit)]
    return out


def grid_coordinates(design: LatticeDesign, size_mm: float, channel_cells: int, layer_cells: int,
                     cell_counts: str = "size",
                     electrode_edges: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The x, y and z grid lines of the structured mesh (mm).

    ``cell_counts="size"`` (default) splits every interval into ``ceil(length / size_mm)`` cells (at least
    ``channel_cells`` across a channel and ``layer_cells`` through the conductive layer), so counts jump as ``w``
    or ``t`` move. ``"fixed"`` takes the lengths from a reference layout instead — every channel as wide as an
    electrode (:func:`_reference_breakpoints`), the conductive layer shrunk onto its top face — so the counts,
    hence the node count, stay constant while ``w`` and ``t`` move and the nodes move smoothly with them (what a
    local optimizer needs). In the default layout the one exception is ``w`` exactly equal to the electrode width,
    where channel and electrode edges merge; the meshes on either side converge to that one. The conductive
    layer gets exactly ``layer_cells`` cells; a channel ``max(channel_cells, ceil(electrode width / size))``.
    ``electrode_edges=False`` (``"size"`` only) leaves out the lines on electrode edges (they cross the whole
    sensor); every material interface (channel edges, layer faces) is still a grid line, and triangles the
    electrode edges cut get partial-coverage weights (:func:`~latticeopt.mesh.facets.tag_facets`).
    """
    if not electrode_edges and cell_counts != "size":
        raise ValueError("electrode_edges=False needs cell_counts='size'")
    centre = design.size_mm / 2

    def rules(axis: int):
        iv = channel_intervals(design, axis)

        def channel_of(a: float, b: float) -> np.ndarray | None:
            """The channel interval holding the piece ``[a, b]``, or None."""
            mid = 0.5 * (a + b)
            hit = (iv[:, 0] <= mid) & (mid <= iv[:, 1])
            return iv[np.argmax(hit)] if hit.any() else None

        def in_channel(a: float, b: float) -> int:
            return 1 if channel_of(a, b) is None else channel_cells

        def channel_share(a: float, b: float) -> int:
            # Each side of the centre line of a channel gets channel_cells, a piece of it that electrode edges
            # cut off only its share. channel_cells per piece made 0.25-0.5 mm slivers at w > electrode width
            # (grid lines across the whole sensor, 21 % more nodes) and moved V_rel by < 0.03 %; the centre
            # channel's halves keep theirs (halving them moved V_rel 0.6 % at w = 4: touches land there).
            channel = channel_of(a, b)
            if channel is None:
                return 1
            lo, hi = channel
            lo, hi = (lo, min(hi, centre)) if 0.5 * (a + b) < centre else (max(lo, centre), hi)
            return int(np.ceil(channel_cells * (b - a) / (hi - lo) - 1e-9))

        return in_channel, channel_share

    xb, yb = _axis_breakpoints(design, 0, electrode_edges), _axis_breakpoints(design, 1, electrode_edges)
    (x_in, x_share), (y_in, y_share) = rules(0), rules(1)
    if cell_counts == "fixed":
        x = _subdivide(xb, size_mm, x_in, _reference_breakpoints(design, xb, 0), vanishing_cells=1)
        y = _subdivide(yb, size_mm, y_in, _reference_breakpoints(design, yb, 1), vanishing_cells=1)
    else:
        x, y = _subdivide(xb, size_mm, x_share), _subdivide(yb, size_mm, y_share)
    return x, y, z_coordinates(design, size_mm, layer_cells, cell_counts)


def z_coordinates(design: LatticeDesign, size_mm: float, layer_cells: int, cell_counts: str = "size") -> np.ndarray:
    """The z levels of the layered meshes (mm), shape ``(nz,)``, shared by the grid and extruded meshers.

    Levels on ``0``, the layer faces ``z0, z1`` and ``H``; each interval split into ``ceil(length / size_mm)``
    equal cells, at least ``layer_cells`` through the conductive layer. ``cell_counts="fixed"`` takes the
    substrate's count from the substrate plus layer (the layer shrunk onto its top face), so it does not move
    with ``t``, and the layer gets exactly ``layer_cells``.
    """
    z0, z1 = design.layer_z_mm
    zb = np.unique(np.round([0.0, z0, z1, design.total_thickness_mm], 9))
    zref = (np.where(np.abs(zb - z0) < 1e-9, z1, zb) if z0 > 0 else None) if cell_counts == "fixed" else None
    return _subdivide(zb, size_mm, lambda a, b: layer_cells if (a >= z0 - 1e-9 and b <= z1 + 1e-9) else 1, zref)


def _kuhn_tets(x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Tets (node indices into the ``len(x) * len(y) * len(z)`` lattice, x fastest) of every cell's six-tet split.

    Each cell is split along a main diagonal into the six tets of the monotone corner paths (Kuhn). Cells
    beyond the middle of the x (y) range use the split mirrored in x (y): mirrored neighbours share their
    face diagonals, so the mesh stays conforming, and with an even cell count per axis the whole mesh is
    invariant under the eight symmetries of the square (mirrors and quarter turns). Symmetric physics then
    gives exactly symmetric discrete results, which the tests and the data augmentation rely on.
    """
    nx, ny, nz = len(x), len(y), len(z)
    i, j, k = np.meshgrid(np.arange(nx - 1), np.arange(ny - 1), np.arange(nz - 1), indexing="ij")
    flip_x = (0.5 * (x[:-1] + x[1:]) > 0.5 * (x[0] + x[-1]))[i].ravel()
    flip_y = (0.5 * (y[:-1] + y[1:]) > 0.5 * (y[0] + y[-1]))[j].ravel()
    i, j, k = i.ravel(), j.ravel(), k.ravel()
    tets = []
    for perm in permutations(range(3)):
        corner = np.zeros(3, dtype=int)
        verts = []
        for step in (None, *perm):
            if step is not None:
                corner = corner.copy()
                corner[step] = 1
            bx = np.where(flip_x, 1 - corner[0], corner[0])
            by = np.where(flip_y, 1 - corner[1], corner[1])
            verts.append((i + bx) + nx * ((j + by) + ny * (k + corner[2])))
        tets.append(np.stack(verts, axis=1))
    return np.concatenate(tets)


def grid_mesh(design: LatticeDesign, size_mm: float = 2.0, channel_cells: int = 2,
              layer_cells: int = 2, cell_counts: str = "size", electrode_edges: bool = True) -> TetMesh:
    """Structured conforming mesh of ``design``.

    Parameters
    ----------
    design
        A design whose layout is axis-aligned (:attr:`LatticeDesign.is_axis_aligned`; else a
        :class:`ParameterError` naming ``mesher`` before any work).
    size_mm
        Largest cell edge (mm).
    channel_cells
        Minimum number of cells across every channel (on each side of the sensor's centre line; a piece of a
        channel that electrode edges cut off gets its share, at least one cell).
    layer_cells
        Minimum number of cells through the conductive layer.
    cell_counts
        ``"size"`` or ``"fixed"`` (counts independent of ``w`` and ``t``; see :func:`grid_coordinates`).
    electrode_edges
        False: no grid lines on the electrode edges; the electrode facets then carry partial-coverage weights.

    Returns
    -------
    TetMesh
        With region labels from the design's geometry, all named facet sets and ``cells`` = the hexahedral
        cell of each tet (the mean-dilatation patches).
    """
    require_axis_aligned(design)
    x, y, z = grid_coordinates(design, size_mm, channel_cells, layer_cells, cell_counts, electrode_edges)
    return tensor_mesh(design, x, y, z)


def tensor_mesh(design: LatticeDesign, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> TetMesh:
    """The Kuhn-split tensor mesh on the grid lines ``x``, ``y``, ``z`` (mm, sorted), labelled by ``design``.

    Regions are exact only where every material interface of the design lies on a grid line (what
    :func:`grid_coordinates` guarantees); the density mesher (:mod:`latticeopt.density.mesh`) adds its own lines.
    """
    X, Y, Z = np.meshgrid(x, y, z, indexing="ij")
    # x fastest, matching _kuhn_tets' numbering.
    nodes = np.stack([X.transpose(2, 1, 0).ravel(), Y.transpose(2, 1, 0).ravel(),
                      Z.transpose(2, 1, 0).ravel()], axis=1)
    tets = _kuhn_tets(x, y, z)
    neg = tet_volumes(nodes, tets) < 0
    tets[neg] = tets[neg][:, [0, 2, 1, 3]]
    region = design.region_at(nodes[tets].mean(axis=1))
    facets, weights = tag_facets(nodes, tets, region, design, tol_mm=1e-7 * design.size_mm)
    # _kuhn_tets lists the six tets of every cell, cell by cell in (i, j, k) order, once per corner path
    cells = np.tile(np.arange((len(x) - 1) * (len(y) - 1) * (len(z) - 1), dtype=np.int64), 6)
    return TetMesh(nodes, tets, region, facets, weights,
                   {"mesher": "grid", "grid_shape": [len(x), len(y), len(z)]}, cells=cells)
