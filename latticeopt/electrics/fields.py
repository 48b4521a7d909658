"""Field output of a forward model: VTU for ParaView and a picture of the mid-layer current flow.

The picture is the paper's Fig. 2 made quantitative: per model one row with the current density magnitude
``|J|`` (log colour scale, streamlines of the in-plane current) and the potential (equipotential lines) on a
horizontal slice through the middle of the conductive layer, electrodes drawn on the rim with the driving
pair marked. matplotlib and pyvista (for point location in the tet mesh) are imported lazily.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from .forward import ForwardModel

log = logging.getLogger(__name__)


def write_vtu(model: ForwardModel, path: str | Path, drive: int = 0) -> Path:
    """Write the hydrogel mesh with the fields of every drive.

    Point data ``potential_V_drive_DD`` (one per drive, DD 1-based); cell data ``current_density_A_per_m2``
    and ``current_density_abs_A_per_m2`` of ``drive`` (0-based) and ``sigma_S_per_m``.
    """
    path = Path(path)
    u = model.node_potentials
    J = model.current_density(drive)
    point_data = {f"potential_V_drive_{d + 1:02d}": u[d] for d in range(len(u))}
    cell_data = {"current_density_A_per_m2": J, "current_density_abs_A_per_m2": np.linalg.norm(J, axis=1),
                 "sigma_S_per_m": model.sigma}
    model.mesh.to_vtu(path, point_data=point_data, cell_data=cell_data)
    return path


def layer_mid_z_mm(model: ForwardModel) -> float:
    """Middle of the conductive layer: from the design in ``mesh.info``, else the middle of the hydrogel."""
    design = model.mesh.info.get("design") or {}
    if {"total_thickness_mm", "sealing_mm", "thickness_mm"} <= design.keys():
        top = design["total_thickness_mm"] - design["sealing_mm"]
        return float(top - design["thickness_mm"] / 2)
    z = model.mesh.nodes_mm[:, 2]
    return float((z.min() + z.max()) / 2)


def sample_slice(model: ForwardModel, drive: int = 0, z_mm: float | None = None,
                 resolution: int = 300) -> dict:
    """Fields on a regular ``resolution x resolution`` grid of the horizontal plane ``z = z_mm``.

    Returns
    -------
    dict
        ``x_mm``, ``y_mm`` (1D grids), ``potential_V``, ``J_A_per_m2`` (shape ``(res, res, 3)``) and
        ``inside`` (bool), each image indexed ``[iy, ix]``; values outside the hydrogel are NaN.
    """
    import pyvista as pv

    mesh = model.mesh
    z = layer_mid_z_mm(model) if z_mm is None else float(z_mm)
    lo, hi = mesh.nodes_mm[:, :2].min(0), mesh.nodes_mm[:, :2].max(0)
    x = np.linspace(lo[0], hi[0], resolution)
    y = np.linspace(lo[1], hi[1], resolution)
    X, Y = np.meshgrid(x, y)
    pts = pv.PolyData(np.column_stack([X.ravel(), Y.ravel(), np.full(X.size, z)]))
    cells = np.hstack([np.full((mesh.n_tets, 1), 4), mesh.tets]).ravel()
    grid = pv.UnstructuredGrid(cells, np.full(mesh.n_tets, pv.CellType.TETRA), mesh.nodes_mm)
    grid.point_data["u"] = model.node_potentials[drive]
    grid.cell_data["J"] = model.current_density(drive)
    s = pts.sample(grid)
    inside = np.asarray(s.point_data["vtkValidPointMask"], bool).reshape(X.shape)
    u = np.where(inside, np.asarray(s.point_data["u"]).reshape(X.shape), np.nan)
    J = np.asarray(s.point_data["J"]).reshape(X.shape + (3,))
    J[~inside] = np.nan
    return {"x_mm": x, "y_mm": y, "z_mm": z, "potential_V": u, "J_A_per_m2": J, "inside": inside}


def _electrodes(ax, model: ForwardModel, drive: int) -> None:
    from matplotlib.patches import Rectangle

    mesh = model.mesh
    src, snk = model.protocol.drive_pairs[drive]
    centre = mesh.nodes_mm[:, :2].mean(0)
    for k, tri in enumerate(mesh.electrode_facets()):
        p = mesh.nodes_mm[np.unique(tri)][:, :2]
        (x0, y0), (x1, y1) = p.min(0), p.max(0)
        thick = 1.6
        if x1 - x0 < 1e-6:  # wall x = const
            x0, x1 = x0 - thick / 2, x0 + thick / 2
        if y1 - y0 < 1e-6:
            y0, y1 = y0 - thick / 2, y0 + thick / 2
        colour = "#d62728" if k == src else "#1f77b4" if k == snk else "#444444"
        ax.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, color=colour, zorder=5, clip_on=False))
        c = np.array([(x0 + x1) / 2, (y0 + y1) / 2])
        out = c + 4.5 * (c - centre) / np.linalg.norm(c - centre)
        ax.text(out[0], out[1], str(k + 1), ha="center", va="center", fontsize=7, color=colour)


def plot_fields(models: list[ForwardModel], path: str | Path, titles: list[str] | None = None,
                drive: int = 0, resolution: int = 300) -> Path:
    """Draw ``|J|`` with streamlines and the potential on the mid-layer slice, one row per model.

    Parameters
    ----------
    models
        Forward models (e.g. a uniform and a lattice layer, as the paper's Fig. 2).
    path
        PNG file to write.
    titles
        Row titles (default: the models' designs).
    drive
        Drive index (0-based) whose fields are shown.
    resolution
        Samples per side of the slice.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm, TwoSlopeNorm

    path = Path(path)
    rows = len(models)
    fig, axes = plt.subplots(rows, 2, figsize=(11.5, 5.3 * rows), squeeze=False, constrained_layout=True)
    for r, model in enumerate(models):
        sl = sample_slice(model, drive, resolution=resolution)
        x, y, J, u = sl["x_mm"], sl["y_mm"], sl["J_A_per_m2"], sl["potential_V"]
        mag = np.linalg.norm(J[..., :2], axis=-1)
        title = titles[r] if titles else _describe(model)
        ax = axes[r, 0]
        ax.set_facecolor("#e6e6e6")  # silicone (no hydrogel)
        pos = mag[np.isfinite(mag) & (mag > 0)]
        vmax = float(np.nanpercentile(pos, 99.8))
        im = ax.imshow(np.where(mag > 0, mag, np.nan), origin="lower", extent=(x[0], x[-1], y[0], y[-1]),
                       cmap="inferno", norm=LogNorm(vmin=vmax * 1e-3, vmax=vmax), interpolation="nearest")
        Jx, Jy = (np.nan_to_num(J[..., i]) for i in (0, 1))
        ax.streamplot(x, y, Jx, Jy, density=2.0, color=(1, 1, 1, 0.5), linewidth=0.55, arrowsize=0.55)
        fig.colorbar(im, ax=ax, shrink=0.85, label="|J| in plane (A/m$^2$)")
        ax.set_title(f"{title}\ncurrent density, z = {sl['z_mm']:.2f} mm", fontsize=10)
        ax = axes[r, 1]
        ax.set_facecolor("#e6e6e6")
        lim = float(np.nanpercentile(np.abs(u), 99.5))
        im = ax.imshow(u, origin="lower", extent=(x[0], x[-1], y[0], y[-1]), cmap="RdBu_r",
                       norm=TwoSlopeNorm(0.0, -lim, lim), interpolation="nearest")
        # Equipotentials at quantiles of u: evenly spread over the area instead of bunched at the electrodes.
        levels = np.unique(np.nanquantile(u, np.linspace(0.01, 0.99, 33)))
        ax.contour(x, y, u, levels=levels, colors="k", linewidths=0.35)
        fig.colorbar(im, ax=ax, shrink=0.85, label="potential (V)")
        ax.set_title(f"{title}\npotential (ground: mean electrode potential 0)", fontsize=10)
        for ax in axes[r]:
            _electrodes(ax, model, drive)
            ax.set_aspect("equal")
            ax.set_xlim(x[0] - 7, x[-1] + 7)
            ax.set_ylim(y[0] - 7, y[-1] + 7)
            ax.set_xlabel("x (mm)")
            ax.set_ylabel("y (mm)")
    src, snk = models[0].protocol.drive_pairs[drive]
    if src >= 0:
        fig.suptitle(f"Drive {drive + 1}: +{models[0].current_A * 1e3:g} mA into electrode {src + 1} (red), "
                     f"out of electrode {snk + 1} (blue)", fontsize=11)
    else:
        fig.suptitle(f"Drive {drive + 1} ({models[0].protocol.name} protocol)", fontsize=11)
    fig.savefig(path, dpi=130)
    plt.close(fig)
    return path


def _describe(model: ForwardModel) -> str:
    design = model.mesh.info.get("design") or {}
    if not design:
        return "hydrogel"
    w, t = design.get("width_mm", 0), design.get("thickness_mm", 0)
    kind = "uniform layer" if not w else f"lattice w = {w:g} mm, p = {design.get('pitch_mm', 0):g} mm"
    return f"{kind}, t = {t:g} mm"
