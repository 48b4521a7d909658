"""The labelled tetrahedral mesh every solver consumes.

A :class:`TetMesh` is plain arrays: node coordinates in mm, positively oriented P1 tets, one region id per
tet (:data:`latticeopt.design.REGION_IDS`) and named facet sets. Facet sets are triangles given by node
indices (so they survive node moves and sub-meshing) with an optional per-triangle weight in ``[0, 1]``:
the fraction of the triangle covered by the named patch. Meshes whose triangles conform to every patch (the
grid mesher) have all weights 1; meshes that do not (tetwild, whose surface only approximates its input)
carry the exact overlap fraction, so patch areas are exact either way.

Tets may carry ``cells``: the patch of each tet for the mechanics' mean dilatation (the grid mesher's
hexahedral cell, the extruded mesher's pair of prisms), so the volumetric constraint count is the mesher's
explicit choice rather than a guess from node positions.

Facet set names: ``top``, ``bottom``, ``hydrogel_boundary`` and ``electrode_1`` ... ``electrode_N``
(numbering of :meth:`LatticeDesign.electrodes`; 1-based like the hardware).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._npzfile import write_npz_atomic
from ..design import REGION_IDS, REGION_NAMES

#: Version of the ``.npz`` layout; 2 added the optional ``cells`` array.
FORMAT_VERSION = 2

# Local faces of a tet (opposite vertex 0, 1, 2, 3), each ordered so its normal points out of a
# positively oriented tet.
TET_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])


def electrode_name(k: int) -> str:
    """Facet-set name of electrode ``k`` (1-based)."""
    return f"electrode_{k}"


def face_keys(faces: np.ndarray, n_nodes: int) -> np.ndarray:
    """Orientation-independent key of each triangle: equal keys mean the same three nodes.

    One int64 per face when ``n_nodes**3`` fits (sorting scalars is about 10x faster than sorting rows),
    else the sorted node triple, shape ``(K, 3)``; compare keys only among calls with the same ``n_nodes``.
    """
    s = np.sort(np.asarray(faces, dtype=np.int64).reshape(-1, 3), axis=1)
    if n_nodes < 2 ** 21:
        return (s[:, 0] * n_nodes + s[:, 1]) * n_nodes + s[:, 2]
    return s


def keys_isin(keys: np.ndarray, among: np.ndarray) -> np.ndarray:
    """Which of :func:`face_keys` ``keys`` occur in ``among`` (both from the same ``n_nodes``), shape ``(K,)``."""
    if keys.ndim == 1:
        return np.isin(keys, among)
    row = [("", np.int64)] * 3
    return np.isin(np.ascontiguousarray(keys).view(row).ravel(), np.ascontiguousarray(among).view(row).ravel())


def tet_volumes(nodes: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Signed volumes of tets, shape ``(M,)`` (positive for positive orientation)."""
    a, b, c, d = (nodes[tets[:, i]] for i in range(4))
    return np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) / 6.0


def triangle_areas(nodes: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Areas of triangles, shape ``(K,)``."""
    a, b, c = (nodes[tris[:, i]] for i in range(3))
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)


def mean_ratio_quality(nodes: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Mean-ratio quality ``12 (3 V)^(2/3) / sum(l^2)`` per tet: 1 for a regular tet, 0 for a flat one."""
    vol = np.abs(tet_volumes(nodes, tets))
    p = nodes[tets]
    edges = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
    l2 = sum(np.sum((p[:, i] - p[:, j]) ** 2, axis=1) for i, j in edges)
    return 12.0 * (3.0 * vol) ** (2.0 / 3.0) / l2


@dataclass(frozen=True, eq=False)
class TetMesh:
    """A labelled P1 tetrahedral mesh (lengths in mm).

    Attributes
    ----------
    nodes_mm
        Node coordinates, shape ``(N, 3)`` float64.
    tets
        Node indices of each tet, shape ``(M, 4)`` int64, positive orientation.
    region
        Region id of each tet, shape ``(M,)`` int8.
    facets
        Facet-set name -> triangles, shape ``(K, 3)`` int64, oriented out of the region they bound.
    facet_weights
        Facet-set name -> covered fraction of each triangle, shape ``(K,)``; missing names mean all ones.
    info
        Provenance: mesher, settings, design hash, build seconds (JSON-serialisable values only).
    cells
        Optional mean-dilatation patch (cell) id of each tet, shape ``(M,)`` int64, or None (the mechanics
        then groups tets itself).
    """

    nodes_mm: np.ndarray
    tets: np.ndarray
    region: np.ndarray
    facets: dict = field(default_factory=dict)
    facet_weights: dict = field(default_factory=dict)
    info: dict = field(default_factory=dict)
    cells: np.ndarray | None = None

    def __post_init__(self) -> None:
        nodes = np.ascontiguousarray(self.nodes_mm, dtype=np.float64)
        tets = np.ascontiguousarray(self.tets, dtype=np.int64)
        region = np.ascontiguousarray(self.region, dtype=np.int8)
        if nodes.ndim != 2 or nodes.shape[1] != 3:
            raise ValueError(f"nodes_mm: expected shape (N, 3), got {nodes.shape}")
        if tets.ndim != 2 or tets.shape[1] != 4 or region.shape != (len(tets),):
            raise ValueError(f"tets/region: expected shapes (M, 4) and (M,), got {tets.shape}, {region.shape}")
        cells = None
        if self.cells is not None:
            cells = np.ascontiguousarray(self.cells, dtype=np.int64)
            if cells.shape != (len(tets),):
                raise ValueError(f"cells: expected shape ({len(tets)},), got {cells.shape}")
            cells.flags.writeable = False
        object.__setattr__(self, "cells", cells)
        for arr in (nodes, tets, region):
            arr.flags.writeable = False
        object.__setattr__(self, "nodes_mm", nodes)
        object.__setattr__(self, "tets", tets)
        object.__setattr__(self, "region", region)
        facets = {k: np.ascontiguousarray(v, dtype=np.int64).reshape(-1, 3) for k, v in self.facets.items()}
        weights = {k: np.ascontiguousarray(v, dtype=np.float64) for k, v in self.facet_weights.items()}
        for arr in (*facets.values(), *weights.values()):
            arr.flags.writeable = False
        object.__setattr__(self, "facets", facets)
        object.__setattr__(self, "facet_weights", weights)

    # -- sizes and measures -----------------------------------------------------------------------
    @property
    def n_nodes(self) -> int:
        return len(self.nodes_mm)

    @property
    def n_tets(self) -> int:
        return len(self.tets)

    @property
    def n_electrodes(self) -> int:
        return sum(1 for k in self.facets if k.startswith("electrode_"))

    def tet_volumes_mm3(self) -> np.ndarray:
        return tet_volumes(self.nodes_mm, self.tets)

    def region_volumes_mm3(self) -> dict[str, float]:
        """Volume per region name (mm^3); regions without tets report 0."""
        vol = self.tet_volumes_mm3()
        return {name: float(vol[self.region == rid].sum()) for name, rid in REGION_IDS.items()}

    def weights(self, name: str) -> np.ndarray:
        """Covered fraction of each triangle of facet set ``name``, shape ``(K,)``."""
        if name in self.facet_weights:
            return self.facet_weights[name]
        return np.ones(len(self.facets[name]))

    def facet_area_mm2(self, name: str) -> float:
        """Area of facet set ``name`` (weighted by coverage)."""
        return float(triangle_areas(self.nodes_mm, self.facets[name]) @ self.weights(name))

    def electrode_facets(self) -> list[np.ndarray]:
        """Triangles of each electrode in numbering order."""
        return [self.facets[electrode_name(k + 1)] for k in range(self.n_electrodes)]

    def electrode_areas_mm2(self) -> np.ndarray:
        """Area of each electrode patch (mm^2), shape ``(n_electrodes,)``."""
        return np.array([self.facet_area_mm2(electrode_name(k + 1)) for k in range(self.n_electrodes)])

    def quality(self) -> np.ndarray:
        """Mean-ratio quality of each tet, shape ``(M,)``."""
        return mean_ratio_quality(self.nodes_mm, self.tets)

    def summary(self) -> dict:
        """JSON-ready summary used by the CLI and the benchmarks."""
        return {
            "nodes": self.n_nodes,
            "tets": self.n_tets,
            "region_volumes_mm3": self.region_volumes_mm3(),
            "electrode_areas_mm2": self.electrode_areas_mm2().tolist(),
            "min_quality": float(self.quality().min()),
            "min_volume_mm3": float(self.tet_volumes_mm3().min()),
        }

    # -- derived meshes ---------------------------------------------------------------------------
    def with_nodes(self, nodes_mm: np.ndarray) -> TetMesh:
        """The same mesh with moved nodes (e.g. deformed by the mechanics); labels and facets kept."""
        nodes_mm = np.asarray(nodes_mm, dtype=float)
        if nodes_mm.shape != self.nodes_mm.shape:
            raise ValueError(f"nodes_mm: expected shape {self.nodes_mm.shape}, got {nodes_mm.shape}")
        return dataclasses.replace(self, nodes_mm=nodes_mm)

    def restrict(self, regions: tuple[str, ...] = ("hydrogel",)) -> tuple[TetMesh, np.ndarray]:
        """Sub-mesh of the tets in ``regions``, nodes renumbered.

        Facet sets keep the triangles that are faces of kept tets, so electrode patches carry over to the
        hydrogel sub-mesh (and ``top`` keeps only the part of the top surface the sub-mesh has).

        Returns
        -------
        sub : TetMesh
        node_ids : ndarray, shape (n_sub,)
            Index in this mesh of each node of ``sub`` (use it to map displacements onto the sub-mesh).
        """
        unknown = [r for r in regions if r not in REGION_IDS]
        if unknown:
            raise ValueError(f"regions: expected names from {sorted(REGION_IDS)}, got {unknown}")
        keep = np.isin(self.region, [REGION_IDS[r] for r in regions])
        tets = self.tets[keep]
        node_ids = np.unique(tets)
        new_index = np.full(self.n_nodes, -1, dtype=np.int64)
        new_index[node_ids] = np.arange(len(node_ids))
        n_sub = len(node_ids)
        sub_faces = face_keys(new_index[tets][:, TET_FACES].reshape(-1, 3), n_sub)
        facets, weights = {}, {}
        for name, tri in self.facets.items():
            ok = np.all(new_index[tri] >= 0, axis=1)
            # Three kept nodes are not enough: e.g. a top triangle over an island whose corners all touch gel.
            ok[ok] = keys_isin(face_keys(new_index[tri[ok]], n_sub), sub_faces)
            facets[name] = new_index[tri[ok]]
            if name in self.facet_weights:
                weights[name] = self.facet_weights[name][ok]
        sub = TetMesh(self.nodes_mm[node_ids], new_index[tets], self.region[keep], facets, weights,
                      {**self.info, "restricted_to": list(regions)},
                      cells=None if self.cells is None else self.cells[keep])
        return sub, node_ids

    def to_skfem(self):
        """A ``skfem.MeshTet`` (coordinates in mm) with the region ids as ``subdomains`` (name -> elements)."""
        from skfem import MeshTet

        subdomains = {REGION_NAMES[int(r)]: np.nonzero(self.region == r)[0] for r in np.unique(self.region)}
        return MeshTet(self.nodes_mm.T.copy(), self.tets.T.copy(), _subdomains=subdomains)

    # -- files ------------------------------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        """Write an ``.npz`` (no pickles) that :meth:`load` reads back exactly."""
        import json

        arrays = {"nodes_mm": self.nodes_mm, "tets": self.tets, "region": self.region,
                  "format_version": np.array(FORMAT_VERSION),
                  "info_json": np.array(json.dumps(self.info, sort_keys=True))}
        if self.cells is not None:
            arrays["cells"] = self.cells
        for name, tri in self.facets.items():
            arrays[f"facet:{name}"] = tri
        for name, w in self.facet_weights.items():
            arrays[f"weight:{name}"] = w
        write_npz_atomic(path, arrays, compressed=True)  # a crash never leaves a half-written cache entry

    @classmethod
    def load(cls, path: str | Path) -> TetMesh:
        import json

        with np.load(path, allow_pickle=False) as z:
            version = int(z["format_version"])
            if version != FORMAT_VERSION:
                raise ValueError(f"{path}: mesh format version {version}, this latticeopt reads {FORMAT_VERSION}")
            facets = {k[6:]: z[k] for k in z.files if k.startswith("facet:")}
            weights = {k[7:]: z[k] for k in z.files if k.startswith("weight:")}
            cells = z["cells"] if "cells" in z.files else None
            return cls(z["nodes_mm"], z["tets"], z["region"], facets, weights, json.loads(str(z["info_json"])),
                       cells=cells)

    def to_vtu(self, path: str | Path, point_data: dict | None = None, cell_data: dict | None = None) -> None:
        """Write a VTU for ParaView: tets with ``region`` cell data plus the top, bottom and electrode triangles.

        Triangles carry ``region = -1`` and ``electrode`` = electrode number (0 elsewhere); ``surface`` codes
        triangles 1 = top, 2 = bottom, 3 = electrode. ``cell_data`` arrays of length M are written on tets
        (NaN on triangles).
        """
        import meshio

        tri_sets = [("top", 1, 0), ("bottom", 2, 0)] + [
            (electrode_name(k + 1), 3, k + 1) for k in range(self.n_electrodes)]
        tris = [self.facets[n] for n, _, _ in tri_sets if n in self.facets]
        surf = np.concatenate([np.full(len(self.facets[n]), s) for n, s, _ in tri_sets if n in self.facets])
        elec = np.concatenate([np.full(len(self.facets[n]), e) for n, _, e in tri_sets if n in self.facets])
        tri = np.concatenate(tris) if tris else np.zeros((0, 3), dtype=np.int64)
        cd = {"region": [self.region.astype(np.int32), np.full(len(tri), -1, np.int32)],
              "electrode": [np.zeros(self.n_tets, np.int32), elec.astype(np.int32)],
              "surface": [np.zeros(self.n_tets, np.int32), surf.astype(np.int32)]}
        for k, val in (cell_data or {}).items():
            val = np.asarray(val, dtype=float)
            cd[k] = [val, np.full((len(tri),) + val.shape[1:], np.nan)]
        meshio.Mesh(self.nodes_mm, [("tetra", self.tets), ("triangle", tri)],
                    point_data=point_data or {}, cell_data=cd).write(str(path))
