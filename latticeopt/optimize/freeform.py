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
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

import numpy as np

from .. import _validate as v
from .._npzfile import write_atomic
from ..errors import ParameterError
from .identity import extends_run, run_identity, same_run, stored_final
from .layout_outputs import write_outputs
from .probes import FLOOR_TOL, ProbeGrid, ProbeKeys, final_record, uniformity_constraint

log = logging.getLogger(__name__)

FREEFORM_ALGORITHMS = ("LD_MMA", "LD_CCSAQ")


@dataclass(frozen=True)
class DensityStudyConfig(ProbeKeys):
    """What the free-form and graded tables share: the density grid, symmetry, constraints, algorithm and the
    probe grid (:class:`~latticeopt.optimize.probes.ProbeKeys`).

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
        self._check_probes(set_)
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
    betas: tuple = (1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 64.0, 128.0)
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

    @property
    def mould_limits_mm(self) -> tuple[tuple[str, float], tuple[str, float]]:
        """The narrowest gel and silicone the study means to cast, with their keys (the filter's radius)."""
        return ("freeform.min_feature_mm", self.min_feature_mm), ("freeform.min_feature_mm", self.min_feature_mm)

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


def _write_json(path: Path, obj) -> None:
    write_atomic(path, lambda fh: fh.write(json.dumps(obj).encode()))


def warn_if_unresolved(key: str, width_mm: float, mesh_settings) -> bool:
    """Log a warning (and return True) when the narrowest channel a study allows (``key``, ``width_mm``) spans
    fewer than two elements of the density model's mesh: the model under-reads such a channel's response, most
    near the electrodes (the w = 1 mm square lattice's corner probe: 0.18 on the 2 mm mesh, 0.39 on its exact
    mesh; ``docs/gradients.md``)."""
    from ..mesh import MeshSettings

    size_mm = (mesh_settings or MeshSettings()).size_mm
    if width_mm >= 2.0 * size_mm:
        return False
    log.warning("%s = %g mm is narrower than two elements of the %g mm density mesh: the density model under-reads "
                "such channels (docs/gradients.md, accuracy of a density model); score the outline on its exact mesh "
                "(latticeopt sweep with design.layout), or mesh.size_mm <= %g", key, width_mm, size_mm, width_mm / 2)
    return True


def run_freeform(design, phantoms: list, mesh_settings, physics, cfg: FreeformConfig, out_dir,
                 progress: Callable[[str], None] | None = print, jobs: int = 1) -> FreeformResult:
    """Run (or resume) a free-form optimization into ``out_dir`` (module docstring).

    Parameters
    ----------
    design
        The sensor (its layout is replaced by the density).
    phantoms
        Lists of :class:`~latticeopt.touches.Touch`, one per phantom.
    mesh_settings, physics
        :class:`~latticeopt.mesh.MeshSettings` and :class:`~latticeopt.coupled.PhysicsSettings`.
    jobs
        Worker processes pressing the phantoms of each iterate side by side (the path does not depend on it).
    """
    from ..density.projection import FreeForm

    ff = FreeForm(design, cfg.cells, cfg.symmetry, cfg.min_feature_mm, cfg.pad_mm)
    warn_if_unresolved("freeform.min_feature_mm", cfg.min_feature_mm, mesh_settings)
    n = ff.n_variables
    # the bound reads the layout eroded to isolation_threshold: a bridge parked at the outline's threshold is cut
    eroded = dataclasses.replace(ff, eta=cfg.isolation_threshold)
    x, history, rho, v_rel = optimize_density(design, phantoms, mesh_settings, physics, cfg, ff,
                                              np.full(n, cfg.start), np.zeros(n), np.ones(n), out_dir, progress,
                                              isolation_param=eroded, jobs=jobs)
    files = write_outputs(design, rho, cfg, Path(out_dir), history, extra_lines=(
        f"free-form layout: minimum feature {cfg.min_feature_mm:g} mm, pads {cfg.pad_mm:g} mm",))
    return FreeformResult(density=rho, variables=x, v_rel=v_rel, hydrogel_fraction=float(rho.mean()),
                          evaluations=len(history), history=history, files=files)


def optimize_density(design, phantoms: list, mesh_settings, physics, cfg, param, x0: np.ndarray, lower: np.ndarray,
                     upper: np.ndarray, out_dir, progress: Callable[[str], None] | None = print, isolation_param=None,
                     jobs: int = 1, linear_constraints: tuple | None = None):
    """The resumable MMA loop over a density parametrization ``param`` (``n_variables``, ``density(x, beta)``,
    ``gradient(x, beta, d_rho)``): stages ``cfg.betas`` of ``cfg.iterations_per_beta`` iterations, the hydrogel
    fraction bounds, stretch cap and isolation bound of ``cfg`` as constraints (the last on ``isolation_param``'s
    layout, default ``param``'s, at ``cfg.isolation_sharpness(beta)``) and ``linear_constraints`` ``(A, b)``,
    ``A x <= b``, if given; ``jobs`` worker processes press the phantoms
    and probes of each iterate. Returns ``(x, history, density, v_rel)``, the last two of the final layout (read
    from ``final.json`` when a finished run is run again)."""
    import nlopt

    from ..density import DensityModel
    from ..density.plot import plot_density

    probes = ProbeGrid(design, cfg) if cfg.probes_on else None  # checks that the probes fit, before any work
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    ff = param
    identity = run_identity(design, phantoms, mesh_settings, physics, cfg)
    state_path, hist_path = out / "state.json", out / "history.jsonl"
    x, stage, done = np.asarray(x0, dtype=float), 0, 0
    history = []
    if state_path.exists():
        state = json.loads(state_path.read_text())
        extended = extends_run(state.get("identity"), identity)
        if not (extended or same_run(state.get("identity"), identity)):
            raise ParameterError("out", "an output folder of this same study (its settings differ from "
                                 "the stored state.json other than by stages appended to betas; choose "
                                 "another --out)", str(out))
        if extended and progress:
            progress(f"extending the continuation of {out}: betas {state['identity']['config']['betas']} -> "
                     f"{list(cfg.betas)}")
        x, stage, done = np.asarray(state["x"], dtype=float), int(state["stage"]), int(state["iterations"])
        history = [json.loads(line) for line in hist_path.read_text().splitlines()] if hist_path.exists() else []
        if progress:
            where = (f"stage {stage + 1} of {len(cfg.betas)}, {done} iterations done" if stage < len(cfg.betas)
                     else "every stage done, writing the outputs again")
            progress(f"resuming {out}: {where}; {len(history)} evaluations stored")
    if stage >= len(cfg.betas):
        final = stored_final(out / "final.json", identity, x)
        if final is not None:  # nothing left to solve: the outline keys alone changed, or the run is repeated
            if progress:
                progress(f"final layout read from {out / 'final.json'} (mean V_rel {final['v_rel']:.5f})")
            return x, history, ff.density(x, cfg.betas[-1]), final["v_rel"]
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

    def cache_key(xv: np.ndarray, beta: float) -> tuple:
        return xv.tobytes(), beta

    def evaluate(xv: np.ndarray, beta: float):
        nonlocal warm
        key = cache_key(xv, beta)
        if key not in cache:
            cache.clear()
            rho = ff.density(xv, beta)
            t0 = time.perf_counter()
            ev = model.evaluate(rho, phantoms, warm=warm, jobs=jobs)
            warm = [p.displacement_mm for p in ev.presses]
            pe = probes.solve(model, rho, jobs=jobs) if probes else None
            cache[key] = (rho, ev, time.perf_counter() - t0, pe)
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
            # nlopt asks again for the point it is parked on: count the call (its maxeval and the resume point
            # count it) but mark it, so the history does not read as work done
            repeat = cache_key(xv, beta) in cache
            rho, ev, secs, pe = evaluate(xv, beta)
            secs = 0.0 if repeat else secs
            if grad.size:
                grad[:] = -ff.gradient(xv, beta, ev.dv_rel_ddensity)
            count["n"] += 1
            rec = {"stage": k, "beta": beta, "iteration": count["n"], "v_rel": ev.v_rel,
                   "hydrogel_fraction": float(rho.mean()), "stretch": ev.stretch, "force_N": ev.force_N,
                   "grey": float(np.mean((rho > 0.05) & (rho < 0.95))), "seconds": secs,
                   "newton_steps": 0 if repeat else sum(p.newton_steps for p in ev.presses),
                   "repeat": repeat, **(pe.record() if pe else {})}
            if repeat and pe:
                rec["probe_seconds"] = 0.0
            if cfg.max_isolation is not None:
                rec["isolation"] = isolation(xv, beta)[0]
            history.append(rec)
            with open(hist_path, "a") as fh:
                fh.write(json.dumps(rec) + "\n")
            _write_json(state_path, {"identity": identity, "x": xv.tolist(), "stage": k, "iterations": count["n"]})
            if progress:
                progress(f"[stage {k + 1}/{len(cfg.betas)} beta {beta:g} it {count['n']:3d}] V_rel {ev.v_rel:.5f}  "
                         f"gel {rec['hydrogel_fraction']:.3f}  stretch {ev.stretch:.3f}  grey {rec['grey']:.2f}  "
                         + (f"uniformity {pe.uniformity:.4f}  " if pe else "")
                         + ("(repeat of the previous point)" if repeat else f"{secs:.1f} s")
                         + (f"  isolation {rec['isolation']:.3g}" if "isolation" in rec else ""))
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
            ev = evaluate(xv, beta)[1]
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
        if cfg.min_uniformity is not None:
            opt.add_inequality_constraint(uniformity_constraint(evaluate, ff, beta, cfg.min_uniformity), FLOOR_TOL)
        if linear_constraints is not None and len(linear_constraints[1]):
            A, b = linear_constraints

            def linear(result, xv, grad, A=A, b=b):
                result[:] = A @ xv - b
                if grad.size:
                    grad[:] = A

            opt.add_inequality_mconstraint(linear, np.full(len(b), 1e-6))
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
    rho, ev, _, pe = evaluate(np.asarray(x), beta)
    final = {**final_record(ev, rho, pe, identity), "x": np.asarray(x).tolist()}
    if cfg.max_isolation is not None:  # the returned point's, not the last evaluated one's
        final["isolation"] = isolation(np.asarray(x), beta)[0]
    _write_json(out / "final.json", final)
    return np.asarray(x), history, rho, ev.v_rel
