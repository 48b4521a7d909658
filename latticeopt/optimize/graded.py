"""Graded lattices: a channel width per line (grouped by the sensor's symmetry) of the design's square, diagonal or
triangular pattern, or per edge of its honeycomb, maximized by MMA with adjoint gradients through the channels'
smooth density (:class:`~latticeopt.density.graded.GradedSquare`,
:class:`~latticeopt.density.graded_strips.GradedStrips`, :class:`~latticeopt.density.graded_honeycomb.GradedHoneycomb`).

A ``kind = "graded"`` study (``studies/optimize_graded.toml``) shares the free-form studies' tables and loop
(:func:`~latticeopt.optimize.freeform.optimize_density`: resumable, a line per evaluation, the hydrogel fraction
bounds and the stretch cap as constraints); the fabrication limits are bounds: every channel at least
``min_width_mm``, every island at least ``min_island_mm`` (:func:`max_width_mm`). With ``max_shift_mm > 0`` the
lines' positions are variables too (square and diagonal patterns, through
:class:`~latticeopt.density.graded_strips.GradedStrips`), and the islands between neighbouring parallel lines
become linear constraints on widths and shifts. The outline it writes is exact
(the union of the channel strips, and for the slanted patterns the leads to electrodes the lines miss): the grid
mesher meshes a square one exactly, the extruded mesher a slanted one.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np

from .. import _validate as v
from ..errors import ParameterError
from .freeform import DensityStudyConfig, FreeformResult, optimize_density, warn_if_unresolved
from .layout_outputs import write_outputs

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class GradedConfig(DensityStudyConfig):
    """The ``[graded]`` table (``docs/studies.md``)."""

    TABLE: ClassVar[str] = "graded"
    min_width_mm: float = 1.0
    min_island_mm: float = 2.0
    start_width_mm: float = 4.0
    smoothing_mm: float = 0.5
    samples: int = 4
    iterations: int = 20
    max_shift_mm: float = 0.0

    # the shared loop's view: one stage
    betas: ClassVar[tuple] = (1.0,)

    @property
    def iterations_per_beta(self) -> int:
        return self.iterations

    @property
    def mould_limits_mm(self) -> tuple[tuple[str, float], tuple[str, float]]:
        """The narrowest gel and silicone the study means to cast, with their keys."""
        return ("graded.min_width_mm", self.min_width_mm), ("graded.min_island_mm", self.min_island_mm)

    def _check(self, set_) -> None:
        set_(self, "min_width_mm", v.real("graded.min_width_mm", self.min_width_mm, lo=0.05, hi=50.0))
        set_(self, "min_island_mm", v.real("graded.min_island_mm", self.min_island_mm, lo=0.0, hi=50.0))
        set_(self, "start_width_mm", v.real("graded.start_width_mm", self.start_width_mm, lo=self.min_width_mm,
                                            hi=50.0))
        set_(self, "smoothing_mm", v.real("graded.smoothing_mm", self.smoothing_mm, lo=0.0, lo_open=True, hi=10.0))
        set_(self, "samples", v.integer("graded.samples", self.samples, lo=1, hi=16))
        set_(self, "iterations", v.integer("graded.iterations", self.iterations, lo=1, hi=1000))
        set_(self, "max_shift_mm", v.real("graded.max_shift_mm", self.max_shift_mm, lo=0.0, hi=25.0))


#: The patterns a graded study grades: straight-line lattices by line, the honeycomb by edge.
GRADED_PATTERNS = ("square", "diagonal", "triangular", "hexagonal")


def check_graded_study(design, cfg: GradedConfig, name: Callable[[str], str] = str) -> None:
    """Raise :class:`ParameterError` (keys named through ``name``) unless the design can be graded with ``cfg``:
    a pattern of :data:`GRADED_PATTERNS`, a symmetry the pattern has, line shifts only where lines may move."""
    from ..density.graded_honeycomb import check_honeycomb_symmetry
    from ..density.graded_strips import check_max_shift

    if design.pattern not in GRADED_PATTERNS:
        raise ParameterError(name("design.pattern"), "a lattice to grade: one of " + ", ".join(GRADED_PATTERNS)
                             + " (a custom layout has no lines or edges)", design.pattern)
    if design.pattern == "hexagonal":
        check_honeycomb_symmetry(cfg.symmetry, name("graded.symmetry"))
    check_max_shift(design, cfg.max_shift_mm, name("graded.max_shift_mm"))


def graded_parametrization(design, cfg: GradedConfig):
    """The design's lattice with a width per line (or edge) orbit: :class:`~latticeopt.density.graded.GradedSquare`
    for the square pattern, :class:`~latticeopt.density.graded_strips.GradedStrips` (leads laid at
    ``min_width_mm``) for the diagonal and triangular ones and for lines that move (``max_shift_mm > 0``),
    :class:`~latticeopt.density.graded_honeycomb.GradedHoneycomb` for the hexagonal one; anything else is refused
    (:func:`check_graded_study`)."""
    from ..density.graded import GradedSquare
    from ..density.graded_honeycomb import GradedHoneycomb
    from ..density.graded_strips import GradedStrips

    check_graded_study(design, cfg)
    if design.pattern == "square" and cfg.max_shift_mm == 0:
        return GradedSquare(design, cfg.cells, cfg.symmetry, cfg.smoothing_mm, cfg.samples)
    if design.pattern == "hexagonal":
        return GradedHoneycomb(design, cfg.cells, cfg.symmetry, cfg.smoothing_mm, cfg.samples, cfg.min_width_mm)
    return GradedStrips(design, cfg.cells, cfg.symmetry, cfg.smoothing_mm, cfg.samples, cfg.min_width_mm,
                        cfg.max_shift_mm)


def max_width_mm(design, cfg: GradedConfig) -> float:
    """The widest channel that leaves islands of ``min_island_mm``: the pattern's no-island width (the pitch;
    2/3 of it for triangles) less the island (its side, or for triangles the inscribed circle's diameter)."""
    from ..layout import MAX_WIDTH_FRACTION

    return MAX_WIDTH_FRACTION[design.pattern] * design.pitch_mm - cfg.min_island_mm


def _widths_table(design, param, x: np.ndarray, cfg: GradedConfig) -> tuple[dict, list[str]]:
    """``widths.json`` and the report's lines on the widths."""
    widths = param.widths(x)
    if hasattr(param, "segments_mm"):  # the honeycomb, by edge
        table = {"pattern": design.pattern, "edges": [
            {"from_mm": a.tolist(), "to_mm": b.tolist(), "width_mm": float(w), "orbit": int(g)}
            for (a, b), w, g in zip(param.segments_mm, widths, param.group)],
            "variables_mm": x.tolist(), "symmetry": cfg.symmetry, "leads_area_mm2": float(param.leads.area)}
        return table, [f"graded honeycomb: pitch {design.pitch_mm:g} mm, {len(widths)} edges in {param.n_variables} "
                       f"orbits ({cfg.symmetry}), widths {widths.min():.3f} to {widths.max():.3f} mm (every edge in "
                       "widths.json)" + (f"; leads to electrodes the edges miss: {param.leads.area:.1f} mm^2"
                                         if param.leads.area else "")]
    if not hasattr(param, "normals"):  # the square lattice's outer-product form
        m = len(param.lines_mm)
        table = {"lines_mm": param.lines_mm.tolist(), "widths_along_y_mm": widths[:m].tolist(),
                 "widths_along_x_mm": widths[m:].tolist(), "variables_mm": x.tolist(), "symmetry": cfg.symmetry}
        return table, [f"graded square lattice: pitch {design.pitch_mm:g} mm, widths (mm) of the lines at "
                       + ", ".join(f"{c:g}" for c in param.lines_mm) + ": along y "
                       + ", ".join(f"{w:.3f}" for w in widths[:m]) + "; along x "
                       + ", ".join(f"{w:.3f}" for w in widths[m:])]
    angles = np.degrees(np.arctan2(param.normals[:, 1], param.normals[:, 0]))
    shifts = param.shifts(x)
    table = {"pattern": design.pattern, "lines": [
        {"normal_deg": float(a), "offset_mm": float(o + d), "shift_mm": float(d), "width_mm": float(w),
         "orbit": int(g)} for a, o, d, w, g in zip(angles, param.offsets_mm, shifts, widths, param.group)],
        "variables_mm": x.tolist(), "symmetry": cfg.symmetry, "leads_area_mm2": float(param.leads.area)}
    nw = param.n_widths
    lines = [f"graded {design.pattern} lattice: pitch {design.pitch_mm:g} mm, {len(widths)} lines in "
             f"{nw} orbits ({cfg.symmetry}), widths by orbit (mm): " + ", ".join(f"{w:.3f}" for w in x[:nw])
             + (f"; leads to electrodes the lines miss: {param.leads.area:.1f} mm^2" if param.leads.area else "")]
    if param.n_shifts:
        moved = sorted({int(g) for g in param.group[param.shift_group >= 0]})
        lines.append(f"line shifts (mm, within +-{cfg.max_shift_mm:g}) of the orbits that may move ("
                     + ", ".join(str(g) for g in moved) + "): " + ", ".join(f"{d:+.3f}" for d in x[nw:])
                     + "; the others carry an electrode or a lead, or are mapped onto themselves reversed")
    elif cfg.max_shift_mm:
        lines.append(f"no line may move (max_shift_mm {cfg.max_shift_mm:g}): every orbit carries an electrode or a "
                     "lead, or is mapped onto itself reversed")
    return table, lines


def run_graded(design, phantoms: list, mesh_settings, physics, cfg: GradedConfig, out_dir,
               progress: Callable[[str], None] | None = print, jobs: int = 1) -> FreeformResult:
    """Run (or resume) a graded-lattice optimization into ``out_dir`` (module docstring); ``jobs`` worker
    processes press the phantoms of each iterate."""
    param = graded_parametrization(design, cfg)
    warn_if_unresolved("graded.min_width_mm", cfg.min_width_mm, mesh_settings)
    upper_w = max_width_mm(design, cfg)
    if upper_w < max(cfg.min_width_mm, cfg.start_width_mm):
        raise ParameterError("graded.min_island_mm", f"room for a channel of at least start_width_mm "
                             f"{cfg.start_width_mm:g} mm at pitch {design.pitch_mm:g} mm", cfg.min_island_mm)
    n_w = getattr(param, "n_widths", param.n_variables)
    if cfg.max_shift_mm and n_w == param.n_variables:
        log.warning("graded.max_shift_mm = %g, but no line may move: every orbit of lines carries an electrode or a "
                    "lead, or is mapped onto itself reversed (%s symmetry)", cfg.max_shift_mm, cfg.symmetry)
    lower, upper = (param.bounds(cfg.min_width_mm, upper_w) if n_w < param.n_variables
                    else (np.full(n_w, cfg.min_width_mm), np.full(n_w, upper_w)))
    x0 = np.r_[np.full(n_w, cfg.start_width_mm), np.zeros(param.n_variables - n_w)]
    islands = param.island_constraints(cfg.min_island_mm) if n_w < param.n_variables else None
    x, history, rho, v_rel = optimize_density(design, phantoms, mesh_settings, physics, cfg, param, x0, lower,
                                              upper, out_dir, progress, jobs=jobs, linear_constraints=islands)
    table, lines = _widths_table(design, param, x, cfg)
    lines.append(f"fabrication bounds: {cfg.min_width_mm:g} <= w <= {upper_w:g} mm (islands >= "
                 f"{cfg.min_island_mm:g} mm" + (f", also between lines that moved: {len(islands[1])} linear "
                                                "constraints)" if islands is not None else ")"))
    out = Path(out_dir)
    (out / "widths.json").write_text(json.dumps(table, indent=1))
    files = write_outputs(design, rho, cfg, out, history, geometry=param.polygons(x), extra_lines=lines)
    files["widths"] = str(out / "widths.json")
    return FreeformResult(density=rho, variables=x, v_rel=v_rel, hydrogel_fraction=float(rho.mean()),
                          evaluations=len(history), history=history, files=files)
