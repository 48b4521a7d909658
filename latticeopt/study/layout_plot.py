"""``layouts.png``: the conductive layer of every design of a sweep over layout files, seen from above.

A grid over ``layout`` labels its designs by content hashes in the tables; this figure shows what each hash is
(its file name and outline, the electrodes on the rim) beside its mean V_rel and SE, so a reader compares shapes
and responses at a glance.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

from ..captions import wrap_title
from ._rows import _grid_column, _names
from .config import Study

__all__ = ["draw_layout", "plot_layouts"]

#: At most this many panels per row.
COLUMNS = 5


def draw_layout(ax, design, title: str) -> None:
    """Draw one design's hydrogel footprint (blue) and its electrodes (black ticks on the rim) on ``ax``, from
    above, titled ``title``."""
    from shapely.plotting import plot_polygon

    L = design.size_mm
    plot_polygon(design.footprint(), ax=ax, add_points=False, facecolor="tab:blue", edgecolor="navy",
                 linewidth=0.4, alpha=0.85)
    half = design.electrode_width_mm / 2
    for c in design.electrode_centres_mm:  # the same positions on every side
        for seg in (((c - half, c + half), (0, 0)), ((c - half, c + half), (L, L)),
                    ((0, 0), (c - half, c + half)), ((L, L), (c - half, c + half))):
            ax.plot(*seg, color="black", linewidth=2.5, solid_capstyle="butt")
    ax.set(xlim=(-2, L + 2), ylim=(-2, L + 2), aspect="equal", xticks=[], yticks=[])
    ax.set_title(title, fontsize=8)


def plot_layouts(study: Study, summary: Sequence[dict], path: Path) -> Path | None:
    """Draw each design's hydrogel footprint (blue) and electrodes (black ticks), titled by its layout file's name
    (as ``probes.png`` names it, :func:`~latticeopt.study._rows._names`) and
    ``mean V_rel ± SE`` from ``summary`` (rows in ``study.designs`` order, :func:`~latticeopt.study.report.summarize`).

    Returns ``path``, or ``None`` when the study's grid does not vary ``layout`` (nothing to draw).
    """
    from matplotlib.figure import Figure

    if _grid_column(study, "layout") is None:
        return None
    n = len(study.designs)
    cols = min(COLUMNS, n)
    rows = math.ceil(n / cols)
    fig = Figure(figsize=(2.6 * cols, 2.9 * rows), layout="constrained")
    axes = fig.subplots(rows, cols, squeeze=False).ravel()
    for ax, design, name, row in zip(axes, study.designs, _names(study), summary):
        mean, se = row.get("v_rel_mean", math.nan), row.get("v_rel_se", math.nan)
        score = f"V_rel {mean:.4f} ± {se:.4f}" if math.isfinite(mean) else "not compared"
        draw_layout(ax, design, f"{name}\n{score} (n = {row.get('n', 0)})")
    for ax in axes[n:]:
        ax.set_axis_off()
    fig.suptitle(wrap_title(f"{study.name}: hydrogel (blue) and electrodes (black), t = "
                            f"{study.designs[0].thickness_mm:g} mm; mean V_rel ± SE over the common phantoms",
                            width=int(30 * cols)), fontsize=9)
    fig.savefig(path, dpi=110)
    return Path(path)
