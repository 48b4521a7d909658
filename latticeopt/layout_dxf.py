"""Custom hydrogel layouts from DXF drawings (the format CAD and laser-cutting tools write).

Every closed curve in the drawing's model space is one boundary of hydrogel: closed LWPOLYLINE and POLYLINE
(arcs from bulges included), CIRCLE, ELLIPSE and closed SPLINE. Curves are flattened to within
:data:`FLATTEN_TOL_MM` and combined by the even-odd rule (a loop inside a loop is a hole, a loop inside that
is gel again), as CAD hatches and laser cutters treat nested outlines. Anything else in model space (an open
polyline, a line, text) is rejected with a line that names it rather than ignored, because a layout that
silently loses an outline would be simulated as a different sensor.

Units come from the header's ``$INSUNITS``: unitless or millimetres are read as mm; inches, centimetres and
metres are converted; other units are rejected. Reading needs ``ezdxf`` (``pip install "latticeopt[dxf]"``).
"""

from __future__ import annotations

from pathlib import Path

from .errors import ParameterError
from .layout_files import polygons_from_geometry

__all__ = ["FLATTEN_TOL_MM", "read_dxf", "write_dxf"]

#: Largest distance (mm) between a curve and the polygon that replaces it.
FLATTEN_TOL_MM = 0.01

#: ``$INSUNITS`` code -> mm per drawing unit (0 = unitless, read as mm).
_MM_PER_UNIT = {0: 1.0, 1: 25.4, 4: 1.0, 5: 10.0, 6: 1000.0}
_UNIT_NAMES = {0: "unitless", 1: "inches", 4: "millimetres", 5: "centimetres", 6: "metres"}
_CURVES = ("LWPOLYLINE", "POLYLINE", "CIRCLE", "ELLIPSE", "SPLINE")


def read_dxf(path: str | Path, name: str = "--layout") -> tuple:
    """Hydrogel polygons (mm) from a DXF file.

    Parameters
    ----------
    path
        A ``.dxf`` file whose model space holds only closed curves (module docstring).
    name
        The flag or key named in errors.

    Returns
    -------
    tuple
        The nested ``((shell, *holes), ...)`` tuples of :func:`latticeopt.layout_files.polygons_from_geometry`, in
        mm in the drawing's coordinates (the sensor is ``[0, L] x [0, L]``); validation against a sensor
        happens in :class:`~latticeopt.LatticeDesign`.
    """
    p = Path(path)
    if p.suffix.lower() != ".dxf":
        raise ParameterError(name, "a DXF file (.dxf)", str(p))
    try:
        import ezdxf
        from ezdxf import path as ezpath
    except ImportError:
        raise ParameterError(name, "a GeoJSON layout, or ezdxf installed to read DXF (pip install "
                             "'latticeopt[dxf]')", str(p)) from None
    import shapely

    if not p.is_file():
        raise ParameterError(name, "an existing DXF file", str(p))
    try:
        doc = ezdxf.readfile(p)
    except (OSError, ezdxf.DXFError) as exc:
        raise ParameterError(name, "a readable DXF file", f"{p} ({exc})") from None
    units = int(doc.header.get("$INSUNITS", 0))
    if units not in _MM_PER_UNIT:
        raise ParameterError(f"{name} $INSUNITS", "unitless, inches, millimetres, centimetres or metres "
                             f"({', '.join(map(str, sorted(_MM_PER_UNIT)))})", f"{units} in {p}")
    scale = _MM_PER_UNIT[units]
    gel = shapely.Polygon()
    n_loops = 0
    for entity in doc.modelspace():
        kind = entity.dxftype()
        label = f"{kind} (handle {entity.dxf.handle}) in {p}"
        if kind not in _CURVES:
            raise ParameterError(name, "only closed curves (" + ", ".join(_CURVES) + ") in model space", label)
        curve = ezpath.make_path(entity)
        points = [(v.x * scale, v.y * scale) for v in curve.flattening(FLATTEN_TOL_MM / scale)]
        if len(points) < 3 or not (curve.is_closed or _closed(points)):
            raise ParameterError(name, "closed curves (an open outline bounds no gel)", label)
        loop = shapely.Polygon(points)
        if not loop.is_valid or loop.area <= 0:
            raise ParameterError(name, "simple closed curves enclosing an area (no self-intersection)", label)
        gel = gel.symmetric_difference(loop)  # even-odd rule: nested loops alternate gel and hole
        n_loops += 1
    gel = shapely.union_all([g for g in getattr(gel, "geoms", [gel]) if g.area > 0])  # drop slivers of zero area
    if n_loops == 0 or gel.is_empty:
        raise ParameterError(name, "at least one closed curve of hydrogel", f"none in {p}")
    return polygons_from_geometry(gel)


def _closed(points) -> bool:
    (x0, y0), (x1, y1) = points[0], points[-1]
    return abs(x0 - x1) <= 1e-9 and abs(y0 - y1) <= 1e-9


def write_dxf(footprint, path: str | Path) -> Path:
    """Write a footprint's outlines as closed LWPOLYLINEs in millimetres (``$INSUNITS`` 4), one per ring (holes
    too: :func:`read_dxf`'s even-odd rule reads them back as the same layout). Needs ``ezdxf``."""
    try:
        import ezdxf
    except ImportError:
        raise ParameterError("--dxf", 'the ezdxf package (pip install -e ".[dxf]")', "not installed") from None
    import shapely

    doc = ezdxf.new()
    doc.header["$INSUNITS"] = 4
    msp = doc.modelspace()
    for poly in shapely.get_parts(footprint):
        for ring in (poly.exterior, *poly.interiors):
            msp.add_lwpolyline([(float(x), float(y)) for x, y in list(ring.coords)[:-1]], close=True)
    doc.saveas(str(path))
    return Path(path)
