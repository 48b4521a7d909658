"""Off-screen pictures of meshes with pyvista (no display needed)."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from .design import REGION_IDS
from .mesh.tetmesh import TetMesh

log = logging.getLogger(__name__)

REGION_COLOURS = {"substrate": "#c8c8c8", "hydrogel": "#2b7bba", "islands": "#e9e4d4", "sealing": "#ffe9b3"}


def _grid(mesh: TetMesh, mask: np.ndarray):
    import pyvista as pv

    tets = mesh.tets[mask]
    cells = np.hstack([np.full((len(tets), 1), 4), tets]).ravel()
    return pv.UnstructuredGrid(cells, np.full(len(tets), pv.CellType.TETRA), mesh.nodes_mm)


def _swatch(pv, colour: str):
    """A filled square of ``colour`` as a legend symbol (VTK colours a symbol by its cell data)."""
    import matplotlib.colors as mcolors

    square = pv.Plane(i_resolution=1, j_resolution=1).triangulate()
    rgb = (np.array(mcolors.to_rgb(colour)) * 255).astype(np.uint8)
    square.cell_data["rgb"] = np.tile(rgb, (square.n_cells, 1))
    square.cell_data.active_scalars_name = "rgb"
    return square


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


def caption(mesh: TetMesh) -> str:
    """The figure's title: layout, channel width, thickness and the mesh (size, cells, nodes); empty for a mesh
    that does not say which design it is."""
    from .captions import layout_caption, mesh_caption
    from .design import LatticeDesign

    info = mesh.info.get("design")
    if not info:
        return ""
    design = LatticeDesign(**info)
    text = layout_caption([design]) + (f", w = {design.width_mm:g} mm" if design.has_lattice else "")
    settings = {**mesh.info.get("settings", {}), "mesher": mesh.info.get("mesher", "")}
    mesh_text = mesh_caption(settings) if "size_mm" in settings else f"{settings['mesher']} mesh"
    return f"{text}\n{mesh_text}, {mesh.n_nodes} nodes"


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
                        line_width=0.3)
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
    # A legend of solid swatches with dark text (VTK's default legend draws each entry in its own pale colour).
    entries = [[f"silicone {name}" if name in ("islands", "substrate") else name, REGION_COLOURS[name]]
               for name in ("hydrogel", "islands", "substrate") if np.any(mesh.region == REGION_IDS[name])]
    entries.append(["electrodes", "#d62728"])
    legend = pl.add_legend(entries, bcolor="#ffffff", border=True, size=(0.26, 0.13), face="rectangle",
                           loc="upper left", font_family="arial")
    legend.SetPosition(0.01, 0.77)  # below the two-line title at the upper edge
    for i, (_, colour) in enumerate(entries):  # dark text, coloured swatch
        legend.SetEntryColor(i, 0.1, 0.1, 0.1)
        legend.SetEntrySymbol(i, _swatch(pv, colour))
    text = caption(mesh)
    if text:
        pl.add_text(text, position="upper_edge", font_size=11, color="#222222")
    pl.camera_position = [(-0.55 * L, -1.25 * L, 1.2 * L), (0.5 * L, 0.5 * L, 0.0), (0, 0, 1)]
    pl.camera.zoom(1.15)
    path.parent.mkdir(parents=True, exist_ok=True)
    pl.screenshot(str(path))
    pl.close()
    return path
