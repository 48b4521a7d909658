"""Off-screen pictures of meshes with pyvista (no display needed)."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from .design import REGION_IDS
from .mesh.tetmesh import TetMesh

log = logging.getLogger(__name__)

REGION_COLOURS = {"substrate": "#d9d9d9", "hydrogel": "#2b7bba", "islands": "#f2f2f2", "sealing": "#ffe9b3"}


def _grid(mesh: TetMesh, mask: np.ndarray):
    import pyvista as pv

    tets = mesh.tets[mask]
    cells = np.hstack([np.full((len(tets), 1), 4), tets]).ravel()
    return pv.UnstructuredGrid(cells, np.full(len(tets), pv.CellType.TETRA), mesh.nodes_mm)


def render_mesh(mesh: TetMesh, path: str | Path, show_sealing: bool = False,
                window_size: tuple[int, int] = (1400, 1000)) -> Path:
    """Render ``mesh`` with the hydrogel lattice visible and the electrodes marked.

    The sealing layer is hidden (or drawn translucent with ``show_sealing``) and a quarter of the
    substrate and silicone islands is cut away so the channels show in 3D.

    Returns
    -------
    Path
        The PNG written.
    """
    import pyvista as pv

    # Without a display VTK first tries X, logs "bad X server connection" and falls back to off-screen
    # rendering; that warning is harmless, so only errors are let through while rendering.
    with pv.vtk_verbosity("error"):
        return _render(pv, mesh, Path(path), show_sealing, window_size)


def _render(pv, mesh: TetMesh, path: Path, show_sealing: bool, window_size: tuple[int, int]) -> Path:
    pl = pv.Plotter(off_screen=True, window_size=list(window_size))
    pl.set_background("white")
    L = float(mesh.nodes_mm[:, 0].max())
    centroids = mesh.nodes_mm[mesh.tets].mean(axis=1)
    cutaway = (centroids[:, 0] > 0.5 * L) & (centroids[:, 1] < 0.5 * L)
    for name, rid in REGION_IDS.items():
        mask = mesh.region == rid
        if name == "sealing":
            if not show_sealing or not mask.any():
                continue
            pl.add_mesh(_grid(mesh, mask), color=REGION_COLOURS[name], opacity=0.25, show_edges=False)
            continue
        if name in ("islands", "substrate"):
            mask &= ~cutaway
        if mask.any():
            pl.add_mesh(_grid(mesh, mask), color=REGION_COLOURS[name], show_edges=True, edge_color="#555555",
                        line_width=0.3, label=name)
    for k, tri in enumerate(mesh.electrode_facets()):
        if len(tri) == 0:
            continue
        faces = np.hstack([np.full((len(tri), 1), 3), tri]).ravel()
        patch = pv.PolyData(mesh.nodes_mm, faces)
        pl.add_mesh(patch, color="#d62728")
        centre = mesh.nodes_mm[tri].reshape(-1, 3).mean(axis=0)
        outward = np.sign(centre[:2] - L / 2) * (np.abs(centre[:2] - L / 2) > 0.45 * L)
        pl.add_point_labels([centre + np.r_[outward * 6, 0]], [str(k + 1)], font_size=14, point_size=1,
                            shape=None, text_color="#d62728", show_points=False, always_visible=True)
    pl.add_legend(bcolor="white", size=(0.16, 0.12))
    pl.camera_position = [(-0.55 * L, -1.25 * L, 1.2 * L), (0.5 * L, 0.5 * L, 0.0), (0, 0, 1)]
    pl.camera.zoom(1.15)
    path.parent.mkdir(parents=True, exist_ok=True)
    pl.screenshot(str(path))
    pl.close()
    return path
