"""Figures of a finished sweep: V_rel against the first grid field, the two-field heat map, press curves, the
probe grid's heat maps.

Every figure names the layout (lattice family, pitch, rim channel or not), the mesh that made it, says whether
that mesh is converged (at least the default mesh for every design), and how many phantoms each mean is over.
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..captions import layout_caption, wrap_title
from ..mesh import MeshSettings
from ._rows import _by_design, _label, _names, _value
from .config import Study
from .store import Evaluation

__all__ = ["plot_heatmap", "plot_lines", "plot_press", "plot_probes"]


def _x_field(study: Study) -> str:
    varying = [f for f, vals in study.grid if len(vals) > 1] or list(study.grid_fields) or ["width_mm"]
    return "width_mm" if "width_mm" in varying else varying[0]


def _mesh_caption(study: Study) -> str:
    """What meshed the study's designs and, on a second line, whether that mesh is converged, e.g. ``grid mesh,
    2 mm, >= 2 cells across a channel, >= 2 through the layer`` / ``converged (at least the default mesh)``:
    every figure says which mesh made it (V_rel moves by a few per cent between meshes)."""
    m = study.settings.mesh
    meshers = sorted({m.resolved(d).mesher for d in study.designs}) or [m.mesher]
    parts = [f"{'/'.join(meshers)} mesh, {m.size_mm:g} mm"]
    if set(meshers) & {"grid", "extruded"}:
        cells = sorted({m.resolved(d).channel_cells for d in study.designs}) or [m.channel_cells]
        parts.append(f">= {'/'.join(map(str, cells))} cell{'s' if cells != [1] else ''} across a channel, "
                     f">= {m.layer_cells} through the layer")
    if "tetwild" in meshers:
        parts.append(f"envelope {m.epsilon_rel:g}")
    return ", ".join(parts) + "\n" + _convergence_status(study)


def _convergence_status(study: Study) -> str:
    """``converged`` when every design's mesh is at least as fine as the default mesh, the coarsest whose V_rel
    lies within 2 % of a finer one (the verification docs); else says it is coarser."""
    m = study.settings.mesh
    for d in study.designs:
        got, ref = m.resolved(d), MeshSettings().resolved(d)
        if got.mesher == "tetwild":
            return "convergence not checked for tetwild meshes"
        if got.size_mm > ref.size_mm or got.channel_cells < ref.channel_cells or got.layer_cells < ref.layer_cells:
            return "NOT converged (coarser than the default mesh): a quick look"
    return "converged (at least the default mesh)"


def _title(first: str, study: Study) -> str:
    """A figure title: ``first``, the layout, then the mesh caption, each line wrapped to fit over the axes (a
    long caption is otherwise cut at both edges of the figure)."""
    return wrap_title(f"{first}\n{layout_caption(study.designs)}\n{_mesh_caption(study)}")


def _phantom_caption(study: Study, summary: Sequence[dict]) -> str:
    n = max((s["n"] for s in summary), default=0)
    total = len(study.phantoms)
    if study.multilevel is not None:  # every phantom at the coarse level, a subset on the mesh named above
        fine = [s["n_fine"] for s in summary if s.get("n_fine")]
        span = f"{min(fine)}-{max(fine)}" if fine and min(fine) != max(fine) else f"{fine[0] if fine else 0}"
        return (f"two-level: {n} phantoms per design at the coarse level, {span} on this mesh "
                f"(SE <= {study.multilevel.se_factor:g} x all on it)")
    if study.adaptive is not None:  # designs ran different numbers of phantoms
        low = min((s["n"] for s in summary if s["n"]), default=0)
        return f"{low}-{n} of {total} phantoms per design (until SE <= {study.adaptive.target_se:g})"
    return f"{n} phantoms per design" + ("" if n == total else f" (the {n} of {total} all designs solved)")


def plot_lines(study: Study, summary: Sequence[dict], path: Path) -> Path:
    """V_rel against one grid field, one line per combination of the others, error bars = SE.

    The uniform layer (``width_mm = 0``) is a different topology, not the end of the channel-width axis: its
    points are drawn as isolated squares (legend "uniform layer"), never joined to ``w > 0`` by a line.
    """
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D

    x_field = _x_field(study)
    others = [f for f in study.grid_fields if f != x_field]
    fig = Figure(figsize=(6.4, 4.6), layout="constrained")
    ax = fig.add_subplot()
    lines: dict[tuple, list] = {}
    for design, s in zip(study.designs, summary):
        lines.setdefault(tuple(_value(design, f) for f in others), []).append((_value(design, x_field), s, design))

    def se(p):
        return 0.0 if math.isnan(p[1]["v_rel_se"]) else p[1]["v_rel_se"]

    any_uniform = False
    for _, pts in lines.items():
        pts.sort(key=lambda p: p[0])
        is_uniform = [x_field == "width_mm" and p[2].width_mm == 0 for p in pts]
        uniform = [p for p, u in zip(pts, is_uniform) if u]
        lattice = [p for p, u in zip(pts, is_uniform) if not u]
        label = _label(pts[0][2], others) or "all"
        color = None
        if lattice:
            bars = ax.errorbar([p[0] for p in lattice], [p[1]["v_rel_mean"] for p in lattice],
                               yerr=[se(p) for p in lattice], marker="o", capsize=3, label=label)
            color = bars.lines[0].get_color()
        if uniform:
            any_uniform = True
            ax.errorbar([p[0] for p in uniform], [p[1]["v_rel_mean"] for p in uniform],
                        yerr=[se(p) for p in uniform], marker="s", markersize=7, linestyle="none", capsize=3,
                        color=color, label=None if lattice else label)
    ax.set_xlabel(x_field.replace("_mm", " (mm)") + ("; 0 = uniform layer" if any_uniform else ""))
    ax.set_ylabel("mean $V_{rel}$ (± SE)")
    ax.set_title(_title(f"{study.name}: {_phantom_caption(study, summary)}", study), fontsize=8.5)
    ax.grid(alpha=0.3)
    handles, labels = ax.get_legend_handles_labels()
    if any_uniform:
        handles.append(Line2D([], [], marker="s", linestyle="none", color="0.4", markersize=7))
        labels.append("uniform layer (w = 0, no lattice)")
    if len(lines) > 1 or any_uniform:
        ax.legend(handles, labels, fontsize="small")
    fig.savefig(path, dpi=130)
    return path


def plot_heatmap(study: Study, summary: Sequence[dict], path: Path) -> Path | None:
    """Mean V_rel over a two-field grid as an annotated heat map; ``None`` for other grids."""
    varying = [(f, vals) for f, vals in study.grid if len(vals) > 1]
    if len(varying) != 2:
        return None
    from matplotlib.figure import Figure

    x_field = _x_field(study)
    y_field, = [f for f, _ in varying if f != x_field]
    xs = sorted({_value(d, x_field) for d in study.designs})
    ys = sorted({_value(d, y_field) for d in study.designs})
    grid = np.full((len(ys), len(xs)), np.nan)
    for design, s in zip(study.designs, summary):
        grid[ys.index(_value(design, y_field)), xs.index(_value(design, x_field))] = s["v_rel_mean"]
    fig = Figure(figsize=(6.4, 4.6), layout="constrained")
    ax = fig.add_subplot()
    im = ax.imshow(grid, origin="lower", cmap="viridis", aspect="auto")
    ax.set_xticks(range(len(xs)), [f"{x:g}" if isinstance(x, float) else str(x) for x in xs])
    ax.set_yticks(range(len(ys)), [f"{y:g}" if isinstance(y, float) else str(y) for y in ys])
    ax.set_xlabel(x_field.replace("_mm", " (mm)"))
    ax.set_ylabel(y_field.replace("_mm", " (mm)"))
    finite = grid[np.isfinite(grid)]
    mid = (finite.min() + finite.max()) / 2 if finite.size else 0.0
    for (r, c), val in np.ndenumerate(grid):
        if np.isfinite(val):
            ax.text(c, r, f"{val:.4f}", ha="center", va="center", fontsize=7,
                    color="black" if val > mid else "white")
    fig.colorbar(im, ax=ax, label="mean $V_{rel}$")
    ax.set_title(_title(f"{study.name}: mean V_rel, {_phantom_caption(study, summary)}", study), fontsize=8.5)
    fig.savefig(path, dpi=130)
    return path


def plot_press(study: Study, evaluations: Sequence[Evaluation], path: Path) -> Path:
    """V_rel against indentation depth, one curve per design (the paper's Fig. 8a layout)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6.4, 4.8), layout="constrained")
    ax = fig.add_subplot()
    depths = [p.touches[0].depth_mm for p in study.phantoms]
    for design, group in zip(study.designs, _by_design(study, evaluations)):
        ax.plot(depths, [e.v_rel if e.ok else np.nan for e in group], marker="o",
                label=_label(design, study.grid_fields) or design.describe())
    t = study.phantoms[0].touches[0]
    ax.set_xlabel("indentation depth (mm)")
    ax.set_ylabel("$V_{rel}$")
    ax.set_title(_title(f"{study.name}: one press, r = {t.radius_mm:g} mm at ({t.x_mm:g}, {t.y_mm:g}) mm, "
                        f"{len(depths)} depths", study), fontsize=8.5)
    ax.grid(alpha=0.3)
    ax.legend(fontsize="small")
    fig.savefig(path, dpi=130)
    return path


def plot_probes(study: Study, maps: Sequence[np.ndarray], summary: Sequence[dict], path: Path) -> Path:
    """Per design a heat map of probe V_rel on the ``n x n`` probe grid (x and y in mm, the sensor's own axes),
    every map on one colour scale, titled by the design (a layout file by its file name) and its uniformity; a
    failed probe is grey and crossed."""
    import matplotlib
    from matplotlib.figure import Figure

    grid, L = study.phantom_set, study.designs[0].size_mm
    cols = len(maps) if len(maps) <= 3 else min(math.ceil(math.sqrt(len(maps))), 4)
    rows = math.ceil(len(maps) / cols)
    fig = Figure(figsize=(max(6.4, 2.4 * cols + 1.2), 2.5 * rows + 1.3), layout="constrained")
    axes = fig.subplots(rows, cols, squeeze=False)
    finite = np.concatenate([m[np.isfinite(m)] for m in maps])
    lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
    cmap = matplotlib.colormaps["viridis"].with_extremes(bad="0.85")
    centres = (np.arange(grid.grid) + 0.5) * L / grid.grid
    image = None
    for k, (ax, vals, name, s) in enumerate(zip(axes.flat, maps, _names(study), summary)):
        image = ax.imshow(np.ma.masked_invalid(vals), origin="lower", extent=(0, L, 0, L), cmap=cmap, vmin=lo,
                          vmax=hi)
        for r, c in zip(*np.nonzero(~np.isfinite(vals))):
            ax.plot(centres[c], centres[r], marker="x", color="crimson", markersize=6)
        u = s["uniformity"]
        # a file name is one long word: wrap at its spaces only (", " between grid values), never inside it
        ax.set_title(textwrap.fill(name, 36, break_long_words=False) + "\n" + (
            f"uniformity {u:.3f}" if math.isfinite(u) else f"uniformity n/a, {s['failed']} failed"), fontsize=7.5)
        ax.tick_params(labelsize=6.5)
        if k % cols == 0:
            ax.set_ylabel("y (mm)", fontsize=7)
        if k + cols >= len(maps):  # nothing below it
            ax.set_xlabel("x (mm)", fontsize=7)
    for ax in axes.flat[len(maps):]:
        ax.set_visible(False)
    bar = fig.colorbar(image, ax=axes, shrink=0.9)
    bar.set_label("probe $V_{rel}$", fontsize=8)
    bar.ax.tick_params(labelsize=7)
    fig.suptitle(_title(f"{study.name}: V_rel of {grid.grid} x {grid.grid} probes, r = {grid.radius_mm:g} mm, "
                        f"{grid.depth_mm:g} mm deep, at the cell centres", study), fontsize=8.5)
    fig.savefig(path, dpi=130)
    return path
