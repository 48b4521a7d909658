"""Meshing: one interface over three meshers, with an on-disk cache keyed by content hash.

>>> from latticeopt import LatticeDesign, MeshSettings, mesh_design
>>> mesh = mesh_design(LatticeDesign(width_mm=4, thickness_mm=3), MeshSettings(size_mm=6), cache_dir=False)
>>> mesh.n_electrodes, mesh.region_volumes_mm3()["hydrogel"]   # exact: 48.2 % of the 100 x 100 x 3 mm layer
(16, 14448.0)

``mesher = "auto"`` (default) takes ``grid`` (structured, conforming) for an axis-aligned layout and
``extruded`` (a conforming 2D triangulation extruded into prisms, :mod:`latticeopt.mesh.extruded`) for any
other. Both are exact (region volumes and electrode areas) and deterministic, so cached and fresh meshes
agree bit for bit and a sweep repeats exactly; measured in ``benchmarks/bench_mesh.py`` they are hundreds of
times faster than ``tetwild`` (fTetWild), which stays as an independent cross-check.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import os
import time
import zipfile
from dataclasses import dataclass
from pathlib import Path

from .. import _validate as v
from ..design import LatticeDesign
from ..errors import ParameterError
from ..layout import RIM_WIDTH_FRACTION
from .tetmesh import FORMAT_VERSION, TetMesh, electrode_name

__all__ = ["MESHERS", "MeshSettings", "TetMesh", "electrode_name", "mesh_design", "default_cache_dir",
           "narrowest_feature_mm"]

log = logging.getLogger(__name__)

MESHERS = ("auto", "grid", "extruded", "tetwild")
#: Grid cell-count rules (:func:`latticeopt.mesh.grid.grid_coordinates`).
CELL_COUNTS = ("size", "fixed")
#: ``channel_cells = "auto"``: cells across a channel per layout family, the fewest whose V_rel lies within 2 % of
#: the finest mesh measured (four paper phantoms and a centre press; docs/verification.md, "Mesh convergence per
#: family"): 2 mm with 2 cells is 2.8 % off a 1 mm / 4-cell mesh on the hexagonal lattice, with 3 cells 1.1 %.
CHANNEL_CELLS_AUTO = {"hexagonal": 3}
#: ``channel_cells = "auto"`` for every family not in :data:`CHANNEL_CELLS_AUTO`.
CHANNEL_CELLS_DEFAULT = 2


@dataclass(frozen=True)
class MeshSettings:
    """How to mesh a design.

    Parameters
    ----------
    mesher
        ``"auto"`` (default: ``"grid"`` for an axis-aligned layout, else ``"extruded"``; see :meth:`resolved`),
        ``"grid"`` (structured, exact; axis-aligned layouts only), ``"extruded"`` (2D triangulation extruded
        into prisms, exact, every layout) or ``"tetwild"`` (fTetWild via pytetwild).
    size_mm
        Target edge length (mm): the largest grid cell, the extruded mesher's triangle edge and z cell, or
        tetwild's absolute ideal edge length.
    channel_cells
        Grid and extruded: minimum cells (triangles) across a channel, or ``"auto"`` (default): the family's
        converged count, :data:`CHANNEL_CELLS_AUTO` (3 for ``hexagonal``), else :data:`CHANNEL_CELLS_DEFAULT` (2);
        :meth:`resolved` replaces it.
    layer_cells
        Grid and extruded: minimum cells through the conductive layer.
    epsilon_rel
        Tetwild: envelope size relative to the bounding-box diagonal (fTetWild's ``-e``); its surfaces lie
        within this distance of the input.
    cell_counts
        Grid: ``"size"`` (default: ``ceil(length / size_mm)`` cells per interval, so counts jump as ``w`` and
        ``t`` move) or ``"fixed"`` (counts independent of ``w`` and ``t``, for smooth objectives in an optimizer;
        exactly ``channel_cells`` across channels and ``layer_cells`` through the layer); the extruded mesher
        applies it to its z levels only. Left out of :meth:`as_dict` at its default.
    electrode_edges
        Grid and extruded: put grid lines (2D graph points) on the electrode edges (default: every electrode
        triangle fully covered). False leaves them out (``cell_counts="size"`` only): on the grid those lines
        cross the whole sensor, up to 22 % of the nodes, and the triangles an electrode edge cuts enter the
        electrode with their covered fraction. Left out of :meth:`as_dict` at its default.
    """

    mesher: str = "auto"
    size_mm: float = 2.0
    channel_cells: int | str = "auto"
    layer_cells: int = 2
    epsilon_rel: float = 1e-3
    cell_counts: str = "size"
    electrode_edges: bool = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "mesher", v.choice("mesher", self.mesher, MESHERS))
        object.__setattr__(self, "size_mm", v.real("size_mm", self.size_mm, lo=0.05, hi=50.0))
        if self.channel_cells != "auto":
            object.__setattr__(self, "channel_cells", v.integer(
                "channel_cells", self.channel_cells, lo=1, hi=16,
                expected="'auto' or an integer 1 <= channel_cells <= 16"))
        object.__setattr__(self, "layer_cells", v.integer("layer_cells", self.layer_cells, lo=1, hi=32))
        object.__setattr__(self, "epsilon_rel", v.real("epsilon_rel", self.epsilon_rel, lo=1e-5, hi=1e-2))
        object.__setattr__(self, "cell_counts", v.choice("cell_counts", self.cell_counts, CELL_COUNTS))
        if self.electrode_edges not in (True, False):
            raise ParameterError("electrode_edges", "true or false", self.electrode_edges)
        if not self.electrode_edges and (self.mesher == "tetwild" or self.cell_counts != "size"):
            raise ParameterError("electrode_edges", "true unless mesher is 'auto', 'grid' or 'extruded' and "
                                 "cell_counts = 'size'", self.electrode_edges)

    def resolved(self, design: LatticeDesign) -> MeshSettings:
        """These settings with every ``"auto"`` replaced by what it picks for ``design``.

        ``mesher``: ``"grid"`` when the layout is axis-aligned (:attr:`LatticeDesign.is_axis_aligned`), else
        ``"extruded"``. ``channel_cells``: the family's count (:data:`CHANNEL_CELLS_AUTO`). Explicit values are
        kept.
        """
        mesher = self.mesher
        if mesher == "auto":
            mesher = "grid" if design.is_axis_aligned else "extruded"
        cells = self.channel_cells
        if cells == "auto":
            cells = CHANNEL_CELLS_AUTO.get(design.pattern, CHANNEL_CELLS_DEFAULT)
        return dataclasses.replace(self, mesher=mesher, channel_cells=cells)

    def identity(self) -> dict:
        """Every field, with what ``"auto"`` stands for spelled out (the per-family table), for result keys
        that must change when an automatic choice does."""
        out = dataclasses.asdict(self)
        if out["channel_cells"] == "auto":
            out["channel_cells"] = {"auto": {**CHANNEL_CELLS_AUTO, "*": CHANNEL_CELLS_DEFAULT}}
        return out

    def as_dict(self) -> dict:
        out = dataclasses.asdict(self)
        if out["cell_counts"] == "size":  # the default is implicit: keys computed before the option existed hold
            del out["cell_counts"]
        if out["electrode_edges"]:
            del out["electrode_edges"]
        return out


def default_cache_dir() -> Path:
    """``$LATTICEOPT_MESH_CACHE`` if set, else the user cache folder: ``platformdirs.user_cache_dir("latticeopt")
    / "meshes"`` (``~/.cache/latticeopt/meshes`` on Linux), so runs from any working directory share it."""
    env = os.environ.get("LATTICEOPT_MESH_CACHE")
    if env:
        return Path(env)
    import platformdirs

    return Path(platformdirs.user_cache_dir("latticeopt")) / "meshes"


def mesh_key(design: LatticeDesign, settings: MeshSettings) -> str:
    """Content hash of everything that determines the mesh.

    The design's fields, its hydrogel footprint itself (so a change in how a layout is drawn, such as where
    leads go, rebuilds the mesh even when the fields are the same), every field of the *resolved* settings
    (``"auto"`` replaced by the mesher it picks, options a mesher ignores included), the mesh file format and the
    package version: a new version rebuilds its meshes rather than trusting a hand-kept revision number.
    """
    import shapely

    from .. import __version__  # read at call time: the package imports this module before defining it

    footprint = hashlib.sha256(shapely.to_wkb(shapely.normalize(design.footprint()), hex=True).encode()).hexdigest()
    payload = {"design": design.as_dict(), "footprint": footprint,
               "settings": dataclasses.asdict(settings.resolved(design)), "format": FORMAT_VERSION,
               "version": __version__}
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()


def _build(design: LatticeDesign, settings: MeshSettings) -> TetMesh:
    if settings.mesher == "grid":
        from .grid import grid_mesh

        return grid_mesh(design, settings.size_mm, settings.channel_cells, settings.layer_cells, settings.cell_counts,
                         settings.electrode_edges)
    if settings.mesher == "extruded":
        from .extruded import extruded_mesh

        return extruded_mesh(design, settings.size_mm, settings.channel_cells, settings.layer_cells,
                             settings.cell_counts, settings.electrode_edges)
    from .tetwild import tetwild_mesh

    return tetwild_mesh(design, settings.size_mm, settings.epsilon_rel)


def narrowest_feature_mm(design: LatticeDesign) -> tuple[str, float]:
    """The narrowest in-plane feature of ``design`` a mesh has to resolve, as ``(name, width in mm)``: the
    channel width ``w`` of a parametric lattice, its rim channel (``w / 2`` wide) if ``rim = "channel"``, or the
    electrode width if that is narrower (or there are no channels: the uniform layer; a custom layout, whose
    polygons have no single width)."""
    features = [("electrode width", design.electrode_width_mm)]
    if design.pattern != "custom" and design.width_mm > 0:
        features.insert(0, ("channel width w", design.width_mm))  # named first when the two are as wide
        if design.rim == "channel":
            features.insert(0, (f"rim channel {RIM_WIDTH_FRACTION:g} w", RIM_WIDTH_FRACTION * design.width_mm))
    return min(features, key=lambda f: f[1])


#: (size_mm, feature, width) already warned about in this process: a sweep meshes (or reads) the same design
#: once per phantom, and one line per design says it.
_WARNED_COARSE: set[tuple] = set()


def _warn_if_coarser_than_features(design: LatticeDesign, settings: MeshSettings) -> None:
    name, width = narrowest_feature_mm(design)
    key = (settings.size_mm, name, width)
    if settings.size_mm <= width or key in _WARNED_COARSE:
        return
    _WARNED_COARSE.add(key)
    log.warning("mesh element size size_mm = %g mm (--mesh-size; mesh.size_mm in a study) is coarser than the "
                "design's narrowest feature (%s = %g mm): the mesh holds the geometry but V_rel on it can be far "
                "from a converged mesh's (docs/verification.md); size_mm <= %g resolves it",
                settings.size_mm, name, width, width)


def mesh_design(design: LatticeDesign, settings: MeshSettings | None = None,
                cache_dir: str | Path | None | bool = None, warn: bool = True) -> TetMesh:
    """Mesh ``design`` (or read it from the cache).

    Parameters
    ----------
    design
        The sensor design.
    settings
        Mesher and sizes; defaults to :class:`MeshSettings()`. ``"auto"`` is resolved for ``design``; the
        grid mesher refuses a layout that is not axis-aligned (:class:`ParameterError` naming ``mesher``). A
        ``size_mm`` coarser than :func:`narrowest_feature_mm` is logged as a warning (once per process).
    cache_dir
        Folder of the cache; ``None`` uses :func:`default_cache_dir`, ``False`` disables caching.
    warn
        Log that warning. False for a mesh that is coarse on purpose (a two-level sweep's coarse mechanics,
        whose error the fine level measures).

    Returns
    -------
    TetMesh
        ``info`` holds the (resolved) mesher, settings, key, build seconds and whether it came from the cache.
    """
    settings = (settings or MeshSettings()).resolved(design)
    if warn:  # every mesh (the CLI, studies, exports) is made here
        _warn_if_coarser_than_features(design, settings)
    if settings.mesher == "grid":  # before any work (a cache look-up included)
        from .grid import require_axis_aligned

        require_axis_aligned(design)
    key = mesh_key(design, settings)
    path = None
    if cache_dir is not False:
        folder = default_cache_dir() if cache_dir is None else Path(cache_dir)
        path = folder / f"{settings.mesher}-{key[:24]}.npz"
        if path.exists():
            try:
                mesh = TetMesh.load(path)
                return dataclasses.replace(mesh, info={**mesh.info, "cached": True})
            # corrupt, truncated (BadZipFile, EOFError) or old entry: rebuild it
            except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
                log.warning("ignoring unreadable mesh cache entry %s (%s)", path, exc)
    t0 = time.perf_counter()
    mesh = _build(design, settings)
    info = {**mesh.info, "mesher": settings.mesher, "settings": settings.as_dict(), "key": key,
            "design": design.as_dict(), "build_seconds": time.perf_counter() - t0}
    mesh = dataclasses.replace(mesh, info=info)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        mesh.save(path)
    return dataclasses.replace(mesh, info={**info, "cached": False})
