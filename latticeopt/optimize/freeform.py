"""Free-form layouts: the density of every cell as the design, maximized by MMA with adjoint gradients.

A ``kind = "freeform"`` study (``studies/optimize_freeform.toml``; ``latticeopt optimize STUDY``) maximizes the mean
V_rel over its phantoms (common random numbers) with respect to the variables of a
:class:`~latticeopt.density.projection.FreeForm` map (symmetry, minimum-feature filter, Heaviside projection, gel
pads at the electrodes), subject to bounds on the hydrogel fraction, a cap on how far apart the layout puts its
electrodes (``max_isolation``: one piece of gel, :meth:`~latticeopt.density.DensityModel.isolation`) and optionally
a cap on the gel's stretch measure, with nlopt's ``LD_MMA`` or ``LD_CCSAQ``. The projection sharpness ``beta`` is
raised in stages (continuation) so the layout ends 0/1. Every evaluation appends to ``history.jsonl`` and rewrites
``state.json`` (both atomically) in the output folder: a killed run restarts from its last iterate of its current
stage. At the end the layout is thresholded, cleaned and written as GeoJSON (and DXF with ``ezdxf``), its region
solids as STL.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import ClassVar

import numpy as np

from .. import _validate as v
from .._npzfile import write_atomic
from ..errors import ParameterError

log = logging.getLogger(__name__)

FREEFORM_ALGORITHMS = ("LD_MMA", "LD_CCSAQ")


@dataclass(frozen=True)
class DensityStudyConfig:
    """What the free-form and graded tables share: the density grid, symmetry, constraints and algorithm.

    Subclasses name their table in ``TABLE`` (errors say ``<table>.<key>``) and check their own keys in
    ``_check``."""

    TABLE: ClassVar[str] = "density"
    cells: int = 50
    symmetry: str = "d4"
    max_hydrogel_fraction: float = 1.0
    min_hydrogel_fraction: float = 0.0
    max_stretch: float | None = None
    algorithm: str = "LD_MMA"
    max_isolation: float | None = None

    def __post_init__(self) -> None:
        from ..density.field import MAX_CELLS, MIN_CELLS
        from ..density.projection import SYMMETRIES

        t = self.TABLE
        set_ = object.__setattr__
        set_(self, "cells", v.integer(f"{t}.cells", self.cells, lo=MIN_CELLS, hi=MAX_CELLS))
        set_(self, "symmetry", v.choice(f"{t}.symmetry", self.symmetry, SYMMETRIES))
        set_(self, "max_hydrogel_fraction", v.real(f"{t}.max_hydrogel_fraction", self.max_hydrogel_fraction,
                                                   lo=0.0, lo_open=True, hi=1.0))
        set_(self, "min_hydrogel_fraction", v.real(f"{t}.min_hydrogel_fraction", self.min_hydrogel_fraction,
                                                   lo=0.0, hi=self.max_hydrogel_fraction))
        if self.max_stretch is not None:
            set_(self, "max_stretch", v.real(f"{t}.max_stretch", self.max_stretch, lo=1.0, lo_open=True, hi=10.0))
        set_(self, "algorithm", v.choice(f"{t}.algorithm", self.algorithm, FREEFORM_ALGORITHMS))
        if self.max_isolation is not None:
            set_(self, "max_isolation", v.real(f"{t}.max_isolation", self.max_isolation, lo=1.0, hi=1e12))
        self._check(set_)

    def _check(self, set_) -> None:
        """The subclass's own keys."""

    def isolation_sharpness(self, beta: float) -> float:
        """The projection sharpness at which the isolation bound reads the layout of a stage of sharpness ``beta``."""
        return beta

    @classmethod
    def from_dict(cls, values: dict | None):
        return v.from_table(cls, values, cls.TABLE + ".{key}")


@dataclass(frozen=True)
class FreeformConfig(DensityStudyConfig):
    """The ``[freeform]`` table (meanings: module docstring and ``docs/studies.md``)."""

    TABLE: ClassVar[str] = "freeform"
    max_hydrogel_fraction: float = 0.5
    max_isolation: float | None = 100.0
    isolation_sharpening: float = 8.0
    isolation_threshold: float = 0.6
    min_feature_mm: float = 4.0
    pad_mm: float = 4.0
    start: float = 0.5
    betas: tuple = (1.0, 2.0, 4.0, 8.0, 16.0)
    iterations_per_beta: int = 10
    threshold: float = 0.5
    smooth_mm: float = 0.5

    def _check(self, set_) -> None:
        set_(self, "min_feature_mm", v.real("freeform.min_feature_mm", self.min_feature_mm, lo=0.0, hi=25.0))
        set_(self, "pad_mm", v.real("freeform.pad_mm", self.pad_mm, lo=0.0, hi=50.0))
        set_(self, "start", v.real("freeform.start", self.start, lo=0.0, hi=1.0))
        betas = tuple(v.real("freeform.betas", b, lo=0.0, lo_open=True, hi=1000.0) for b in np.atleast_1d(self.betas))
        if not betas or any(b2 < b1 for b1, b2 in zip(betas, betas[1:])):
            raise ParameterError("freeform.betas", "a non-empty, non-decreasing list of positive numbers", self.betas)
        set_(self, "betas", betas)
        set_(self, "iterations_per_beta", v.integer("freeform.iterations_per_beta", self.iterations_per_beta,
                                                    lo=1, hi=1000))
        set_(self, "threshold", v.real("freeform.threshold", self.threshold, lo=0.0, lo_open=True, hi=1.0,
                                       hi_open=True))
        set_(self, "smooth_mm", v.real("freeform.smooth_mm", self.smooth_mm, lo=0.0, hi=10.0))
        set_(self, "isolation_sharpening", v.real("freeform.isolation_sharpening", self.isolation_sharpening,
                                                  lo=1.0, hi=1000.0))
        set_(self, "isolation_threshold", v.real("freeform.isolation_threshold", self.isolation_threshold,
                                                 lo=0.05, hi=0.95))

    def isolation_sharpness(self, beta: float) -> float:
        # the stage's grey cells conduct in the model but are cut at the threshold when the layout is cast: read
        # the bound on a sharper projection, so that a grey bridge does not count as a join; raised with the stage,
        # since at the start every cell sits at the threshold, where a steep projection leaves MMA no room
        return self.isolation_sharpening * beta


@dataclass(frozen=True, eq=False)
class FreeformResult:
    """The optimized layout and the run's record."""

    density: np.ndarray
    variables: np.ndarray
    v_rel: float
    hydrogel_fraction: float
    evaluations: int
    history: list = field(repr=False, default_factory=list)
    files: dict = field(default_factory=dict)


def shapely_parts(geom) -> list:
    import shapely

    return [] if geom.is_empty else list(shapely.get_parts(geom))


def _write_json(path: Path, obj) -> None:
    write_atomic(path, lambda fh: fh.write(json.dumps(obj).encode()))


def run_freeform(design, phantoms: list, mesh_settings, physics, cfg: FreeformConfig, out_dir,
                 progress: Callable[[str], None] | None = print) -> FreeformResult:
    """Run (or resume) a free-form optimization into ``out_dir`` (module docstring).

    Parameters
    ----------
    design
        The sensor (its layout is replaced by the density).
    phantoms
        Lists of :class:`~latticeopt.touches.Touch`, one per phantom.
    mesh_settings, physics
        :class:`~latticeopt.mesh.MeshSettings` and :class:`~latticeopt.coupled.PhysicsSettings`.
    """
    from ..density.projection import FreeForm

    ff = FreeForm(design, cfg.cells, cfg.symmetry, cfg.min_feature_mm, cfg.pad_mm)
    n = ff.n_variables
    # the bound reads the layout eroded to isolation_threshold: a bridge parked at the outline's threshold is cut
    eroded = dataclasses.replace(ff, eta=cfg.isolation_threshold)
    x, history, rho, ev = optimize_density(design, phantoms, mesh_settings, physics, cfg, ff, np.full(n, cfg.start),
                                           np.zeros(n), np.ones(n), out_dir, progress, isolation_param=eroded)
    files = write_outputs(design, rho, cfg, Path(out_dir), history, extra_lines=(
        f"free-form layout: minimum feature {cfg.min_feature_mm:g} mm, pads {cfg.pad_mm:g} mm",))
    return FreeformResult(density=rho, variables=x, v_rel=ev.v_rel, hydrogel_fraction=float(rho.mean()),
                          evaluations=len(history), history=history, files=files)


def optimize_density(design, phantoms: list, mesh_settings, physics, cfg, param, x0: np.ndarray, lower: np.ndarray,
                     upper: np.ndarray, out_dir, progress: Callable[[str], None] | None = print, isolation_param=None):
    """The resumable MMA loop over a density parametrization ``param`` (``n_variables``, ``density(x, beta)``,
    ``gradient(x, beta, d_rho)``): stages ``cfg.betas`` of ``cfg.iterations_per_beta`` iterations, the hydrogel
    fraction bounds, stretch cap and isolation bound of ``cfg`` as constraints (the last on ``isolation_param``'s
    layout, default ``param``'s, at ``cfg.isolation_sharpness(beta)``). Returns ``(x, history, density, ev)``."""
    import nlopt

    from ..density import DensityModel
    from ..density.plot import plot_density

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    ff = param
    identity = {"config": asdict(cfg), "design": design.as_dict(), "mesh": mesh_settings.as_dict(),
                "physics": physics.as_dict(), "phantoms": [[t.as_dict() for t in p] for p in phantoms]}
    state_path, hist_path = out / "state.json", out / "history.jsonl"
    x, stage, done = np.asarray(x0, dtype=float), 0, 0
    history = []
    if state_path.exists():
        state = json.loads(state_path.read_text())
        if state.get("identity") != json.loads(json.dumps(identity)):
            raise ParameterError("out", "an output folder of this same study (its settings differ from "
                                 "the stored state.json; choose another --out)", str(out))
        x, stage, done = np.asarray(state["x"], dtype=float), int(state["stage"]), int(state["iterations"])
        history = [json.loads(line) for line in hist_path.read_text().splitlines()] if hist_path.exists() else []
        if progress:
            where = (f"stage {stage + 1} of {len(cfg.betas)}, {done} iterations done" if stage < len(cfg.betas)
                     else "every stage done, writing the outputs again")
            progress(f"resuming {out}: {where}; {len(history)} evaluations stored")
    t_setup = time.perf_counter()
    model = DensityModel(design, cfg.cells, mesh_settings, physics)
    if progress:
        progress(f"{type(ff).__name__}: {ff.n_variables} variables ({cfg.cells} x {cfg.cells} cells, {cfg.symmetry}), "
                 f"{len(phantoms)} phantoms, mesh {model.mesh.n_nodes} nodes (set-up "
                 f"{time.perf_counter() - t_setup:.1f} s)")
    warm: list | None = None
    cache: dict = {}
    iso_cache: dict = {}
    iso_param = param if isolation_param is None else isolation_param

    def evaluate(xv: np.ndarray, beta: float):
        nonlocal warm
        key = (xv.tobytes(), beta)
        if key not in cache:
            cache.clear()
            rho = ff.density(xv, beta)
            t0 = time.perf_counter()
            ev = model.evaluate(rho, phantoms, warm=warm)
            warm = [p.displacement_mm for p in ev.presses]
            cache[key] = (rho, ev, time.perf_counter() - t0)
        return cache[key]

    def isolation(xv: np.ndarray, beta: float):
        b = cfg.isolation_sharpness(beta)
        key = (xv.tobytes(), b)
        if key not in iso_cache:
            iso_cache.clear()
            value, g = model.isolation(iso_param.density(xv, b))
            iso_cache[key] = value, iso_param.gradient(xv, b, g)
        return iso_cache[key]

    ones = np.full((cfg.cells, cfg.cells), 1.0 / cfg.cells ** 2)
    for k in range(stage, len(cfg.betas)):
        beta = cfg.betas[k]
        remaining = cfg.iterations_per_beta - (done if k == stage else 0)
        if remaining <= 0:
            continue
        opt = nlopt.opt(getattr(nlopt, cfg.algorithm), ff.n_variables)
        opt.set_lower_bounds(np.asarray(lower, dtype=float))
        opt.set_upper_bounds(np.asarray(upper, dtype=float))
        count = {"n": done if k == stage else 0}

        def objective(xv, grad, beta=beta, k=k, count=count):
            rho, ev, secs = evaluate(xv, beta)
            if grad.size:
                grad[:] = -ff.gradient(xv, beta, ev.dv_rel_ddensity)
            count["n"] += 1
            rec = {"stage": k, "beta": beta, "iteration": count["n"], "v_rel": ev.v_rel,
                   "hydrogel_fraction": float(rho.mean()), "stretch": ev.stretch, "force_N": ev.force_N,
                   "grey": float(np.mean((rho > 0.05) & (rho < 0.95))), "seconds": secs,
                   "newton_steps": sum(p.newton_steps for p in ev.presses)}
            if cfg.max_isolation is not None:
                rec["isolation"] = isolation(xv, beta)[0]
            history.append(rec)
            with open(hist_path, "a") as fh:
                fh.write(json.dumps(rec) + "\n")
            _write_json(state_path, {"identity": identity, "x": xv.tolist(), "stage": k, "iterations": count["n"]})
            if progress:
                progress(f"[stage {k + 1}/{len(cfg.betas)} beta {beta:g} it {count['n']:3d}] V_rel {ev.v_rel:.5f}  "
                         f"gel {rec['hydrogel_fraction']:.3f}  stretch {ev.stretch:.3f}  grey {rec['grey']:.2f}  "
                         f"{secs:.1f} s" + (f"  isolation {rec['isolation']:.3g}" if "isolation" in rec else ""))
            return -ev.v_rel

        def fraction_max(xv, grad, beta=beta):
            rho = ff.density(xv, beta)
            if grad.size:
                grad[:] = ff.gradient(xv, beta, ones)
            return float(rho.mean()) - cfg.max_hydrogel_fraction

        def fraction_min(xv, grad, beta=beta):
            rho = ff.density(xv, beta)
            if grad.size:
                grad[:] = -ff.gradient(xv, beta, ones)
            return cfg.min_hydrogel_fraction - float(rho.mean())

        def stretch_cap(xv, grad, beta=beta):
            _, ev, _ = evaluate(xv, beta)
            if grad.size:
                grad[:] = ff.gradient(xv, beta, ev.dstretch_ddensity)
            return ev.stretch - cfg.max_stretch

        def isolation_cap(xv, grad, beta=beta):
            # log scale: the measure runs from 1 (the uniform layer) to 1e4 and more (pieces joined by the floor)
            value, g = isolation(xv, beta)
            if grad.size:
                grad[:] = g / value
            return math.log(value / cfg.max_isolation)

        opt.set_min_objective(objective)
        opt.add_inequality_constraint(fraction_max, 1e-4)
        if cfg.min_hydrogel_fraction > 0:
            opt.add_inequality_constraint(fraction_min, 1e-4)
        if cfg.max_stretch is not None:
            opt.add_inequality_constraint(stretch_cap, 1e-4)
        if cfg.max_isolation is not None:
            opt.add_inequality_constraint(isolation_cap, 1e-3)
        opt.set_maxeval(remaining)
        opt.set_xtol_rel(1e-6)  # MMA parked on its bounds otherwise repeats the same point until maxeval
        try:
            x = opt.optimize(x)
        except nlopt.RoundoffLimited:
            log.info("stage %d: nlopt stopped at round-off", k + 1)
        done = 0
        _write_json(state_path, {"identity": identity, "x": np.asarray(x).tolist(), "stage": k + 1, "iterations": 0})
        plot_density(ff.density(x, beta), out / f"layout_stage{k + 1}.png", design.size_mm,
                     f"stage {k + 1}: beta {beta:g}, {cfg.cells}x{cfg.cells} cells, {len(phantoms)} phantoms")
    beta = cfg.betas[-1]
    rho, ev, _ = evaluate(np.asarray(x), beta)
    return np.asarray(x), history, rho, ev


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
    from ..layout import polygons_from_geometry, write_geojson

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
    lines = [*extra_lines, f"{len(history)} evaluations, {cfg.cells} x {cfg.cells} cells, symmetry {cfg.symmetry}",
             f"final density: gel fraction {rho.mean():.4f}, grey cells {np.mean((rho > 0.05) & (rho < 0.95)):.3f}"]
    if history:
        last = history[-1]
        lines.append(f"last evaluation: mean V_rel {last['v_rel']:.5f}, stretch {last['stretch']:.4f}"
                     + (f", isolation {last['isolation']:.4g} (bound {cfg.max_isolation:g})" if "isolation" in last
                        else ""))
    lines.append(f"{outline}: gel fraction "
                 f"{report['hydrogel_fraction']:.4f}, {report['pieces']} pieces, {report['pieces_dropped']} "
                 f"dropped (no electrode), {report['dropped_area_mm2']:.1f} mm^2 dropped")
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
