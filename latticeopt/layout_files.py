"""Hydrogel layouts as files and as hashable polygons: GeoJSON reading and writing, and the nested tuples
``((shell, *holes), ...)`` of ``(x, y)`` points (mm) that :class:`~latticeopt.LatticeDesign` stores for a
``custom`` layout. DXF drawings are read and written by :mod:`latticeopt.layout_dxf`.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .errors import ParameterError

__all__ = ["geometry_from_polygons", "polygons_from_geometry", "read_geojson", "read_layout", "write_geojson"]


def polygons_from_geometry(geom) -> tuple:
    """A shapely (Multi)Polygon as nested tuples ``((shell, *holes), ...)`` of ``(x, y)`` pairs (hashable)."""
    polys = getattr(geom, "geoms", [geom])
    out = []
    for p in polys:
        rings = [p.exterior, *p.interiors]
        out.append(tuple(tuple((float(x), float(y)) for x, y in np.asarray(r.coords)[:, :2]) for r in rings))
    return tuple(out)


def geometry_from_polygons(polygons) -> object:
    """The inverse of :func:`polygons_from_geometry` (no validation)."""
    import shapely

    return shapely.MultiPolygon([shapely.Polygon(rings[0], rings[1:]) for rings in polygons])


def read_layout(path: str | Path, name: str = "--layout") -> tuple:
    """Hydrogel polygons (mm) from a layout file: GeoJSON (:func:`read_geojson`) or DXF
    (:func:`latticeopt.layout_dxf.read_dxf`), chosen by the suffix."""
    suffix = Path(path).suffix.lower()
    if suffix == ".dxf":
        from .layout_dxf import read_dxf

        return read_dxf(path, name)
    if suffix not in (".geojson", ".json"):
        raise ParameterError(name, "a GeoJSON (.geojson, .json) or DXF (.dxf) layout file", str(path))
    return read_geojson(path, name)


def read_geojson(path: str | Path, name: str = "--layout") -> tuple:
    """Hydrogel polygons (mm) from a GeoJSON file: a FeatureCollection, Feature, Polygon or MultiPolygon.

    Returns the nested tuples of :func:`polygons_from_geometry`, in the file's coordinates (mm, the sensor
    being ``[0, L] x [0, L]``). Validation against a sensor happens in :class:`~latticeopt.LatticeDesign`.
    """
    import shapely.geometry

    p = Path(path)
    if p.suffix.lower() not in (".geojson", ".json"):
        raise ParameterError(name, "a GeoJSON file (.geojson or .json)", str(p))
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ParameterError(name, "a readable GeoJSON file", f"{p} ({exc.strerror})") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ParameterError(name, "a GeoJSON file (UTF-8 JSON)", f"{p} ({exc})") from None
    if not isinstance(doc, dict):
        raise ParameterError(name, "a GeoJSON object", type(doc).__name__)
    kind = doc.get("type")
    geoms = {"FeatureCollection": lambda d: [f.get("geometry") for f in d.get("features", [])],
             "Feature": lambda d: [d.get("geometry")]}.get(kind, lambda d: [d])(doc)
    polys = []
    for g in geoms:
        if not isinstance(g, dict) or g.get("type") not in ("Polygon", "MultiPolygon"):
            got = g.get("type") if isinstance(g, dict) else g
            raise ParameterError(name, "Polygon or MultiPolygon geometries", f"{got} in {p}")
        try:
            shp = shapely.geometry.shape(g)
        except (ValueError, TypeError, IndexError, AttributeError) as exc:
            raise ParameterError(name, "well-formed Polygon coordinates", f"{p} ({exc})") from None
        polys.extend(polygons_from_geometry(shp))
    if not polys:
        raise ParameterError(name, "at least one hydrogel polygon", f"none in {p}")
    return tuple(polys)


def write_geojson(footprint, path: str | Path) -> None:
    """Write a footprint as a GeoJSON FeatureCollection (mm), readable by :func:`read_geojson`."""
    import shapely.geometry

    feature = {"type": "Feature", "properties": {"units": "mm", "material": "hydrogel"},
               "geometry": shapely.geometry.mapping(footprint)}
    Path(path).write_text(json.dumps({"type": "FeatureCollection", "features": [feature]}), encoding="utf-8")
