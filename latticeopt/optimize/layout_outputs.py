"""What a density-layout optimization writes at the end: the density, the cast outline (GeoJSON, DXF), the region
solids (STL), the convergence plot and ``report.txt`` (shared by free-form and graded studies)."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from ..errors import ParameterError
from .probes import final_lines

log = logging.getLogger(__name__)


def shapely_parts(geom) -> list:
    import shapely

    return [] if geom.is_empty else list(shapely.get_parts(geom))



def mould_lines(geom, size_mm: float, limits) -> list[str]:
    """What a mould must make for the outline ``geom``: its narrowest gel and silicone (measured on it,
    :mod:`latticeopt.fabrication`), and a warning per limit of ``limits`` (``((key, mm), (key, mm))``: gel,
    silicone) it breaks, which the density's filter or the widths' bounds do not rule out where pieces meet."""
    from ..fabrication import narrowest_features

    f = narrowest_features(geom, size_mm)
    (gel_key, gel_mm), (sil_key, sil_mm) = limits
    lines = [f"what the mould must make: {f.describe()}"]
    for phrase in f.below(gel_mm, sil_mm, (gel_key, sil_key)):
        lines.append(f"WARNING: the outline has {phrase} (fill or trim it before casting)")
        log.warning("the outline has %s", phrase)
    return lines


def write_outputs(design, rho: np.ndarray, cfg, out: Path, history: list, geometry=None,
                  extra_lines: tuple = ()) -> dict:
    """Density, outline (GeoJSON; DXF when ezdxf is installed), region solids (STL), convergence plot, report.

    The outline is ``geometry`` when given (an exact layout, e.g. a graded lattice's rectangles), else the
    density's thresholded and cleaned outline (:func:`~latticeopt.density.outline.density_outline`)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..density import save_density
    from ..density.outline import density_outline
    from ..geometry import build_solids, write_stl
    from ..layout_files import polygons_from_geometry, write_geojson

    files = {"density": str(save_density(out / "density.npz", rho))}
    if geometry is None:
        geom, report = density_outline(design, rho, cfg.threshold, cfg.smooth_mm)
        outline = f"outline (threshold {cfg.threshold:g}, smoothing {cfg.smooth_mm:g} mm)"
    else:
        geom, outline = geometry, "exact outline"
        report = {"hydrogel_fraction": float(geom.area / design.size_mm ** 2), "pieces": len(shapely_parts(geom)),
                  "pieces_dropped": 0, "dropped_area_mm2": 0.0}
    if not geom.is_empty:
        write_geojson(geom, out / "layout.geojson")
        files["geojson"] = str(out / "layout.geojson")
        try:
            from ..layout_dxf import write_dxf

            files["dxf"] = str(write_dxf(geom, out / "layout.dxf"))
        except ParameterError as exc:
            log.warning("no DXF written: %s", exc)
        try:
            cast = design.replace(pattern="custom", custom_polygons_mm=polygons_from_geometry(geom))
            files["stl"] = {k: str(p) for k, p in write_stl(build_solids(cast), out / "stl").items()}
        except (ParameterError, ValueError) as exc:  # the outline is kept: the user can fix it by hand
            report["not_castable"] = str(exc)
            log.warning("outline not castable as a layout: %s", exc)
    if history:
        fig, ax = plt.subplots(figsize=(6.4, 3.6), layout="constrained")
        it = np.arange(1, len(history) + 1)
        ax.plot(it, [h["v_rel"] for h in history], "o-", ms=3, label="mean V_rel")
        ax.set_xlabel("evaluation")
        ax.set_ylabel("mean V_rel")
        ax2 = ax.twinx()
        ax2.plot(it, [h["hydrogel_fraction"] for h in history], "s--", ms=2, color="tab:orange", label="gel fraction")
        ax2.plot(it, [h["grey"] for h in history], ":", color="tab:gray", label="grey fraction")
        ax2.set_ylabel("fraction")
        for k in sorted({h["stage"] for h in history})[1:]:
            ax.axvline(next(i for i, h in enumerate(history, 1) if h["stage"] == k) - 0.5, color="k", lw=0.5)
        fig.legend(loc="lower right", fontsize=8)
        ax.set_title(f"free-form optimization, {cfg.cells}x{cfg.cells} cells (lines: beta stages)", fontsize=9)
        fig.savefig(out / "convergence.png", dpi=100)
        plt.close(fig)
        files["convergence"] = str(out / "convergence.png")
    repeats = sum(bool(h.get("repeat")) for h in history)
    counted = f"{len(history)} evaluations" + (f" ({repeats} repeats of the point before, not solved again)"
                                                if repeats else "")
    lines = [*extra_lines, f"{counted}, {cfg.cells} x {cfg.cells} cells, symmetry {cfg.symmetry}",
             f"final density: gel fraction {rho.mean():.4f}, grey cells {np.mean((rho > 0.05) & (rho < 0.95)):.3f}"]
    if history:
        last = history[-1]
        lines.append(f"last evaluation (not necessarily the result): mean V_rel {last['v_rel']:.5f}, stretch "
                     f"{last['stretch']:.4f}" + (f", isolation {last['isolation']:.4g}" if "isolation" in last else ""))
    lines.extend(final_lines(out, cfg.max_isolation))
    lines.append(f"{outline}: gel fraction "
                 f"{report['hydrogel_fraction']:.4f}, {report['pieces']} pieces, {report['pieces_dropped']} "
                 f"dropped (no electrode), {report['dropped_area_mm2']:.1f} mm^2 dropped")
    if not geom.is_empty:
        lines += mould_lines(geom, design.size_mm, cfg.mould_limits_mm)
    if report["pieces"] > 1:
        # separate pieces conduct to each other only through the density model's insulating floor: the model then
        # reads large relative changes on rows across pieces that a cast sensor could not measure at all
        warn = (f"the layout is {report['pieces']} separate pieces of gel: no current flows between electrodes "
                "on different pieces, so this is not a working sensor; its V_rel in the density model comes from the "
                "insulating floor (lower max_isolation, raise isolation_threshold)")
        lines.append("WARNING: " + warn)
        log.warning(warn)
    if "not_castable" in report:
        lines.append(f"the outline is not a valid layout ({report['not_castable']}): no STL written")
    lines.append("check the outline on held-out presses before trusting it: latticeopt sweep with "
                 "design.layout = layout.geojson")
    (out / "report.txt").write_text("\n".join(lines) + "\n")
    files["report"] = str(out / "report.txt")
    return files
