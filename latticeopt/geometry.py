"""Solid geometry of a design: one watertight manifold3d solid per region.

The solids tile the sensor box exactly (they share their interfaces), so their volumes add up to
``L * L * H``. The tetwild mesher meshes their surfaces; the grid mesher and the tet labelling use the
analytic :meth:`LatticeDesign.region_at` instead, and tests check that both agree.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .design import REGION_IDS, LatticeDesign


def _box(lo, hi):
    import manifold3d as m3

    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    return m3.Manifold.cube(list(hi - lo)).translate(list(lo))


@dataclass(frozen=True, eq=False)
class RegionSolids:
    """Watertight triangle surfaces of every non-empty region.

    Attributes
    ----------
    vertices_mm
        Region name -> vertices, shape ``(n_v, 3)`` float64 (mm).
    faces
        Region name -> triangles, shape ``(n_f, 3)`` int64, outward oriented.
    volumes_mm3
        Region name -> enclosed volume (mm^3) as manifold3d computes it.
    genus
        Region name -> topological genus (the square lattice's hydrogel has one handle per island).
    """

    vertices_mm: dict
    faces: dict
    volumes_mm3: dict
    genus: dict

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self.vertices_mm)


def _hydrogel_solid(design: LatticeDesign):
    """The design's hydrogel footprint extruded through the conductive layer."""
    import manifold3d as m3
    import shapely

    z0, z1 = design.layer_z_mm
    # Shells counter-clockwise, holes clockwise: what manifold3d's Positive fill rule reads as solid and void.
    gel = shapely.orient_polygons(design.footprint(), exterior_cw=False)
    # get_rings reads a Polygon's rings only: a layout of several pieces (a MultiPolygon) is taken part by part
    rings = [np.ascontiguousarray(np.asarray(r.coords)[:-1, :2], dtype=np.float64)
             for part in shapely.get_parts(gel) for r in shapely.get_rings(part)]
    section = m3.CrossSection(rings, m3.FillRule.Positive)
    return m3.Manifold.extrude(section, z1 - z0).translate([0.0, 0.0, z0])


def build_solids(design: LatticeDesign) -> RegionSolids:
    """Build the region solids of ``design`` with manifold3d.

    Parameters
    ----------
    design
        The sensor design.

    Returns
    -------
    RegionSolids
        Regions with zero volume (a zero-thickness substrate, the islands of a uniform layer) are left out.
    """
    L, H = design.size_mm, design.total_thickness_mm
    z0, z1 = design.layer_z_mm
    gel = _hydrogel_solid(design)
    solids = {}
    if design.substrate_mm > 0:
        solids["substrate"] = _box((0, 0, 0), (L, L, z0))
    solids["hydrogel"] = gel
    if design.has_lattice:
        islands = _box((0, 0, z0), (L, L, z1)) - gel
        if not islands.is_empty():
            solids["islands"] = islands
    if design.sealing_mm > 0:
        solids["sealing"] = _box((0, 0, z1), (L, L, H))
    verts, faces, vols, genus = {}, {}, {}, {}
    for name in sorted(solids, key=REGION_IDS.get):
        m = solids[name].to_mesh64()
        verts[name] = np.ascontiguousarray(m.vert_properties[:, :3], dtype=np.float64)
        faces[name] = np.ascontiguousarray(m.tri_verts, dtype=np.int64)
        vols[name] = float(solids[name].volume())
        genus[name] = int(solids[name].genus())
    return RegionSolids(verts, faces, vols, genus)


def merged_surface(solids: RegionSolids, tol_mm: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:
    """All region surfaces as one triangle soup with shared vertices and shared interfaces kept once.

    Returns
    -------
    vertices_mm : ndarray, shape (n, 3)
    faces : ndarray, shape (m, 3), int64
    """
    verts = np.concatenate([solids.vertices_mm[n] for n in solids.names])
    offsets = np.cumsum([0] + [len(solids.vertices_mm[n]) for n in solids.names])
    faces = np.concatenate([solids.faces[n] + o for n, o in zip(solids.names, offsets[:-1])])
    key = np.round(verts / tol_mm).astype(np.int64) if tol_mm > 0 else verts
    uniq, inverse = np.unique(key, axis=0, return_inverse=True)
    new_verts = np.zeros((len(uniq), 3))
    new_verts[inverse.ravel()] = verts
    faces = inverse.ravel()[faces]
    # An interface appears twice with opposite orientation; keep one copy so the soup has no duplicates.
    sorted_f = np.sort(faces, axis=1)
    _, first = np.unique(sorted_f, axis=0, return_index=True)
    faces = faces[np.sort(first)]
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])]
    return new_verts, faces


def write_stl(solids: RegionSolids, folder) -> dict:
    """Write every region solid as a binary STL (mm) for fabrication: ``<folder>/<region>.stl``.

    The hydrogel solid is the channel network to cast; ``islands`` plus ``substrate`` is the silicone mould it is
    cast into, ``sealing`` the lid. Written through trimesh, which checks each surface is watertight first.

    Returns
    -------
    dict
        Region name -> path written.
    """
    from pathlib import Path

    import trimesh

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    out = {}
    for name in solids.names:
        surface = trimesh.Trimesh(solids.vertices_mm[name], solids.faces[name], process=False)
        if not surface.is_watertight:
            raise ValueError(f"region {name}: the solid's surface is not watertight")
        path = folder / f"{name}.stl"
        surface.export(path)
        out[name] = path
    return out
