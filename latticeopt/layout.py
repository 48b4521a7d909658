"""The conductive layer's 2D layout: hydrogel polygons inside the ``L x L`` square (mm), built with shapely.

The layer is this footprint extruded through the layer thickness ``t``; everything else in the layer is
silicone. Parametric families, all with channel width ``w`` and pitch ``p`` = the distance between the
centre lines of the two channels on either side of one island:

``square``
    Channels on the lines ``x = k p`` and ``y = k p`` (``k = 0, 1, ...``; plus a line at ``L`` if ``p`` does
    not divide it). With the default ``p = 12.5`` mm a channel end meets every electrode centre.
``diagonal``
    The square lattice turned by 45 degrees about the sensor centre.
``hexagonal``
    Honeycomb channels: the edges of regular hexagonal cells (flat top and bottom) whose centres are ``p``
    apart, one cell centred on the sensor centre.
``triangular``
    Three families of parallel lines (0, 60 and 120 degrees) ``p`` apart through the sensor centre; the
    islands are equilateral triangles (so ``w < 2 p / 3``).
``custom``
    Hydrogel polygons given by the user (GeoJSON or DXF, :func:`latticeopt.layout_files.read_layout`).

The rim: ``rim = "channel"`` lays a channel of width ``w / 2`` along the inside of the lattice's outer
boundary (for ``square`` with ``frame_mm = 0`` this is the half-width channel that the lines ``x, y = 0, L``
leave inside the sensor); ``rim = "none"`` leaves the rim band silicone, apart from channels that end on it.
``frame_mm`` clips the lattice to the square inset by that width: a silicone border. Electrodes are joined
to the lattice where the channels miss them (a frame, or a pattern whose channels meet less than half of
``min(w, electrode width)`` of an electrode) by straight *leads*: channels of width ``w`` along the wall normal
from the electrode centre to the nearest hydrogel (``electrode_leads``; custom layouts get none).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .errors import ParameterError

RIMS = ("none", "channel")
#: The rim channel is this fraction of the channel width ``w`` wide (a channel on the outer boundary, cut in half).
RIM_WIDTH_FRACTION = 0.5


def _box(x0: float, y0: float, x1: float, y1: float):
    import shapely

    return shapely.box(x0, y0, x1, y1)


def _rect(a: np.ndarray, b: np.ndarray, half_w: float):
    """The rectangle of half-width ``half_w`` around the segment ``a``-``b`` (flat ends)."""
    import shapely

    t = (b - a) / np.linalg.norm(b - a)
    nrm = np.array([-t[1], t[0]]) * half_w
    return shapely.Polygon([a - nrm, b - nrm, b + nrm, a + nrm])


def line_strip(normal: np.ndarray, offset: float, centre: np.ndarray, half_w: float, reach: float):
    """The rectangle of half-width ``half_w`` around the line ``normal . (x - centre) = offset`` (unit ``normal``),
    ``reach`` long either side of the line's point nearest ``centre`` (mm)."""
    tangent = np.array([-normal[1], normal[0]])
    foot = centre + offset * normal
    return _rect(foot - reach * tangent, foot + reach * tangent, half_w)


def _strips(normal_deg: float, offsets: np.ndarray, centre: np.ndarray, half_w: float, reach: float) -> list:
    """Rectangles of half-width ``half_w`` around the lines ``n . (x - centre) = offset`` (long enough to
    cross the sensor); ``n`` points at ``normal_deg``."""
    n = np.array([math.cos(math.radians(normal_deg)), math.sin(math.radians(normal_deg))])
    return [line_strip(n, off, centre, half_w, reach) for off in offsets]


def _line_offsets(pitch: float, reach: float) -> np.ndarray:
    k = int(math.ceil(reach / pitch)) + 1
    return np.arange(-k, k + 1) * pitch


def square_lines_mm(size_mm: float, pitch_mm: float, rim: str) -> np.ndarray:
    """Channel centre lines of the ``square`` pattern (same along x and y), shape ``(n,)``.

    ``rim = "none"`` leaves out the lines on the sensor's sides (``0`` and ``L``).
    """
    k = np.arange(int(np.floor(size_mm / pitch_mm + 1e-9)) + 1)
    lines = k * pitch_mm
    if size_mm - lines[-1] > 1e-9 * size_mm:
        lines = np.append(lines, size_mm)
    if rim == "none":
        lines = lines[(lines > 1e-9 * size_mm) & (lines < size_mm * (1 - 1e-9))]
    return lines


#: The directions (degrees) of the line normals of the straight-line patterns.
LINE_ANGLES = {"square": (0.0, 90.0), "diagonal": (45.0, 135.0), "triangular": (90.0, 210.0, 330.0)}


def lattice_lines(pattern: str, size_mm: float, pitch_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """The centre lines of a straight-line pattern without rim channel, as unit normals ``(m, 2)`` and offsets
    ``(m,)`` (mm) from the sensor's centre: ``n . (p - centre) = offset``. Only lines crossing the sensor's inside
    (a line on a side would be part of a rim channel); ``square`` has the lines of :func:`square_lines_mm`."""
    L = size_mm
    if pattern not in LINE_ANGLES:
        raise ValueError(f"pattern: expected one of {tuple(LINE_ANGLES)}, got {pattern!r}")
    normals, offsets = [], []
    for deg in LINE_ANGLES[pattern]:
        n = np.array([math.cos(math.radians(deg)), math.sin(math.radians(deg))])
        n[np.abs(n) < 1e-12] = 0.0
        offs = (square_lines_mm(L, pitch_mm, "none") - L / 2 if pattern == "square"
                else _line_offsets(pitch_mm, L))
        reach = L / 2 * (abs(n[0]) + abs(n[1]))  # the largest |offset| of a line still touching the square
        for o in offs:
            if abs(o) < reach * (1 - 1e-9):
                normals.append(n)
                offsets.append(float(o))
    return np.array(normals), np.array(offsets)


def _square_strips(size_mm: float, pitch_mm: float, h: float) -> list:
    L = size_mm
    lines = square_lines_mm(L, pitch_mm, "channel")
    return [_box(a - h, -1, a + h, L + 1) for a in lines] + [_box(-1, a - h, L + 1, a + h) for a in lines]


def _diagonal_strips(size_mm: float, pitch_mm: float, h: float) -> list:
    centre, reach = np.array([size_mm / 2, size_mm / 2]), size_mm
    offs = _line_offsets(pitch_mm, reach)
    return [s for ang in LINE_ANGLES["diagonal"] for s in _strips(ang, offs, centre, h, reach)]


def _triangular_strips(size_mm: float, pitch_mm: float, h: float) -> list:
    centre, reach = np.array([size_mm / 2, size_mm / 2]), size_mm
    offs = _line_offsets(pitch_mm, reach)
    return [s for ang in LINE_ANGLES["triangular"] for s in _strips(ang, offs, centre, h, reach)]


def _hexagonal_strips(size_mm: float, pitch_mm: float, h: float) -> list:
    return _honeycomb(np.array([size_mm / 2, size_mm / 2]), pitch_mm, h, size_mm)


def _lattice(pattern: str, size_mm: float, width_mm: float, pitch_mm: float, rim: str):
    """The channel network of a parametric pattern over the whole sensor (before frame and rim band)."""
    import shapely

    L, h = size_mm, width_mm / 2
    family = FAMILIES.get(pattern)
    if family is None or family.strips is None:
        raise ValueError(f"pattern: expected one of {PARAMETRIC}, got {pattern!r}")
    # every strip crosses the sensor from anywhere inside it (half-length L)
    strips = family.strips(L, pitch_mm, h)
    box = _box(0, 0, L, L)
    pieces = [s.intersection(box) for s in strips]
    pieces = [s for s in pieces if s.area > 1e-12 * L * L]
    if rim == "none":
        # A channel lying wholly in the band along a side would be (part of) a rim channel: leave it out.
        inner = _box(h * (1 + 1e-9), h * (1 + 1e-9), L - h * (1 + 1e-9), L - h * (1 + 1e-9))
        pieces = [s for s in pieces if s.intersection(inner).area > 1e-9 * s.area]
    return shapely.union_all(pieces)


def honeycomb_segments(centre: np.ndarray, pitch: float, reach: float) -> np.ndarray:
    """The edges of the honeycomb whose cells are ``pitch`` apart, one cell centred on ``centre``, covering a
    square of side ``reach`` about it: shape ``(k, 2, 2)`` (edge, end, x/y; mm).

    Cells have vertices at 0, 60, ..., 300 degrees (flat top and bottom); flat-capped rectangles meeting at a
    120-degree vertex cover it exactly (every direction lies within 60 degrees of an arm), so the union of the
    edges' rectangles is the mitred channel network.
    """
    R = pitch / math.sqrt(3.0)  # circumradius of a cell with flat-to-flat distance ``pitch``
    a1, a2 = np.array([0.0, pitch]), np.array([pitch * math.sqrt(3) / 2, pitch / 2])
    n = int(math.ceil(2 * reach / pitch)) + 2
    ij = np.array([(i, j) for i in range(-n, n + 1) for j in range(-n, n + 1)], dtype=float)
    cells = centre + ij[:, :1] * a1 + ij[:, 1:] * a2
    cells = cells[np.all(np.abs(cells - centre) <= reach / 2 + 2 * pitch, axis=1)]
    ang = np.radians(60.0 * np.arange(6))
    verts = cells[:, None, :] + R * np.stack([np.cos(ang), np.sin(ang)], axis=1)[None]
    segs = np.stack([verts, np.roll(verts, -1, axis=1)], axis=2).reshape(-1, 2, 2)
    _, first = np.unique(np.round((segs[:, 0] + segs[:, 1]) / 2, 6), axis=0, return_index=True)
    return segs[first]


def _honeycomb(centre: np.ndarray, pitch: float, half_w: float, reach: float) -> list:
    """Rectangles (flat ends) around every edge of :func:`honeycomb_segments`."""
    return [_rect(a, b, half_w) for a, b in honeycomb_segments(centre, pitch, reach)]


@dataclass(frozen=True)
class Family:
    """A layout family: how its channels are laid and how wide they may be.

    Attributes
    ----------
    name
        The ``pattern`` value.
    strips
        ``(size_mm, pitch_mm, half_width_mm) -> shapely polygons`` around every channel, each crossing the
        sensor; ``None`` for ``custom`` (the user's polygons).
    max_width_fraction
        Channels this wide, as a fraction of the pitch, leave no island (``inf`` for ``custom``).
    max_width_text
        That bound as an error message names it.
    """

    name: str
    strips: Callable[[float, float, float], list] | None
    max_width_fraction: float
    max_width_text: str

    @property
    def parametric(self) -> bool:
        return self.strips is not None


#: The layout families, by ``pattern``: the one table the design's checks, the lattice builder, the CLI's
#: choices and the optimizer's categories read.
FAMILIES: dict[str, Family] = {f.name: f for f in (
    Family("square", _square_strips, 1.0, "pitch_mm"),
    Family("hexagonal", _hexagonal_strips, 1.0, "pitch_mm"),
    Family("triangular", _triangular_strips, 2.0 / 3.0, "2/3 pitch_mm (triangular islands vanish there)"),
    Family("diagonal", _diagonal_strips, 1.0, "pitch_mm"),
    Family("custom", None, math.inf, ""),
)}
PARAMETRIC = tuple(n for n, f in FAMILIES.items() if f.parametric)
PATTERNS = tuple(FAMILIES)
#: Channels wider than this fraction of the pitch leave no island (derived from :data:`FAMILIES`).
MAX_WIDTH_FRACTION = {n: f.max_width_fraction for n, f in FAMILIES.items() if f.parametric}


def parametric_footprint(pattern: str, size_mm: float, width_mm: float, pitch_mm: float, rim: str,
                         frame_mm: float):
    """Hydrogel footprint of a parametric lattice (no leads), a shapely (Multi)Polygon inside the sensor."""
    L, f = size_mm, frame_mm
    inner = _box(f, f, L - f, L - f)
    if width_mm == 0:
        return _box(0, 0, L, L)
    net = _lattice(pattern, L, width_mm, pitch_mm, rim).intersection(inner)
    if rim == "channel":
        r = RIM_WIDTH_FRACTION * width_mm
        band = inner.difference(_box(f + r, f + r, L - f - r, L - f - r))
        net = net.union(band)
    return _clean(net)


def _clean(geom):
    import shapely

    geom = shapely.make_valid(geom)
    polys = [g for g in getattr(geom, "geoms", [geom]) if g.geom_type == "Polygon" and g.area > 0]
    if not polys:
        return shapely.MultiPolygon()
    return shapely.union_all(polys).normalize()


def electrode_segments(electrodes: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each electrode's footprint on the sensor outline as two 2D end points (mm)."""
    out = []
    for cx, cy, _cz, _nx, _ny, axis, width, _h in electrodes:
        t = np.array([1.0, 0.0]) if int(axis) == 0 else np.array([0.0, 1.0])
        c = np.array([cx, cy])
        out.append((c - t * width / 2, c + t * width / 2))
    return out


def electrode_contact_mm(footprint, electrodes: np.ndarray) -> np.ndarray:
    """Length (mm) of each electrode's segment that lies on the hydrogel footprint, shape ``(n,)``."""
    import shapely

    return np.array([footprint.intersection(shapely.LineString([a, b])).length
                     for a, b in electrode_segments(electrodes)])


def add_leads(footprint, electrodes: np.ndarray, width_mm: float, size_mm: float):
    """Join every electrode that the channels miss to the nearest hydrogel by a straight lead channel.

    "Miss" means less than half of ``min(w, electrode width)`` of the electrode's width lies on hydrogel: a channel
    grazing an electrode's corner would leave it connected through a sliver (a honeycomb edge at 0.07 mm of a
    4 mm electrode, say), which no one would build.
    """
    import shapely

    contact = electrode_contact_mm(footprint, electrodes)
    leads = []
    for k, (cx, cy, _cz, nx, ny, _axis, ew, _h) in enumerate(electrodes):
        if contact[k] >= 0.5 * min(width_mm, ew) or footprint.is_empty:
            continue
        start = np.array([cx, cy])
        ray = shapely.LineString([start, start - size_mm * np.array([nx, ny])])
        hit = ray.intersection(footprint)
        if hit.is_empty:
            continue
        depth = shapely.Point(start).distance(hit) + width_mm / 2
        t = np.array([-ny, nx]) * width_mm / 2
        end = start - depth * np.array([nx, ny])
        leads.append(shapely.Polygon([start - t, start + t, end + t, end - t]))
    if not leads:
        return footprint
    return _clean(shapely.union_all([footprint, *leads]).intersection(_box(0, 0, size_mm, size_mm)))


def check_electrodes(footprint, electrodes: np.ndarray, size_mm: float, name: str = "layout") -> None:
    """Raise :class:`ParameterError` naming the first electrode (1-based) that touches no hydrogel."""
    contact = electrode_contact_mm(footprint, electrodes)
    bad = np.nonzero(contact <= 1e-12 * size_mm)[0]
    if len(bad):
        k = int(bad[0])
        cx, cy = electrodes[k, :2]
        raise ParameterError(name, f"a hydrogel layout that every electrode touches (electrode {k + 1} at "
                             f"x = {cx:g}, y = {cy:g} mm touches none; {len(bad)} electrode(s) in all)",
                             "a layout without hydrogel there")


# -- custom layouts -----------------------------------------------------------------------------------------
def validate_polygons(polygons, size_mm: float, name: str = "custom_polygons_mm"):
    """Check custom hydrogel polygons and return their union (shapely).

    Rings must be closed (first point = last point), each polygon valid (no self-intersection), and all of
    them inside the ``L x L`` sensor (within 1e-9 L).
    """
    import shapely

    if not isinstance(polygons, (tuple, list)) or not polygons:
        raise ParameterError(name, "one or more polygons ((shell, *holes) rings of (x, y) points in mm)",
                             type(polygons).__name__)
    parts = []
    for i, rings in enumerate(polygons):
        where = f"{name}[{i}]"
        try:
            rings = [np.asarray(r, dtype=float) for r in rings]
        except (TypeError, ValueError):
            raise ParameterError(where, "rings of numeric (x, y) points", "non-numeric coordinates") from None
        for r in rings:
            if r.ndim != 2 or r.shape[1] < 2 or len(r) < 4 or not np.all(np.isfinite(r)):
                raise ParameterError(where, "closed rings of at least 4 finite (x, y) points", f"shape {r.shape}")
            if not np.allclose(r[0, :2], r[-1, :2], atol=1e-9 * size_mm, rtol=0):
                raise ParameterError(where, "closed rings (first point equal to the last)",
                                     f"first {tuple(r[0, :2])}, last {tuple(r[-1, :2])}")
        poly = shapely.Polygon(rings[0][:, :2], [r[:, :2] for r in rings[1:]])
        if not poly.is_valid:
            raise ParameterError(where, "a valid polygon", shapely.is_valid_reason(poly))
        if poly.area <= 0:
            raise ParameterError(where, "a polygon of positive area", poly.area)
        outside = poly.difference(_box(0, 0, size_mm, size_mm)).area
        if outside > 1e-9 * size_mm ** 2:
            x0, y0, x1, y1 = poly.bounds
            raise ParameterError(where, f"a polygon inside the sensor [0, {size_mm:g}] x [0, {size_mm:g}] mm",
                                 f"bounds ({x0:g}, {y0:g}, {x1:g}, {y1:g}), {outside:.3g} mm^2 outside")
        parts.append(poly.intersection(_box(0, 0, size_mm, size_mm)))
    return _clean(shapely.union_all(parts))
