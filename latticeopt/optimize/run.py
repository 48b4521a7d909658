"""Running an optimization study through the results store (the sweep engine) and writing its outputs."""

from __future__ import annotations

import contextlib
import functools
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..design import LatticeDesign
from ..errors import AllFailedError, LatticeoptError, ParameterError
from ..fabrication import Features, castable_widths, narrowest_features
from ..study.imaging import FIGURES, ReconstructorCache, probe_image_figures, probe_presses
from ..study.phantoms import Phantom
from ..study.report import mean_se
from ..study.settings import EvalSettings
from ..study.store import folder_lock
from .driver import Assessment, Optimum, Step, minimize
from .objectives import Objective
from .problem import Optimization

__all__ = ["CastableCheck", "OptimizationResult", "assess_design", "run_optimization"]


def _image_figures(design: LatticeDesign, evs, probes: Sequence[Phantom], objective: Objective,
                   settings: EvalSettings, images: ReconstructorCache | None) -> tuple[tuple, dict]:
    """Per-probe image correlations and the mean position figures of ``evs`` (the probes' evaluations)."""
    if not objective.needs_images:
        return (), {}
    if any(e.ok and e.voltages is None for e in evs):
        raise LatticeoptError(f"model {settings.model} returned no 'voltages', which optimize.objective.image_cc "
                              "needs (the probes' images are reconstructed from them)")
    volts = [e.voltages if e.ok else None for e in evs]
    if any(vv is not None for vv in volts):
        cache = images if images is not None else ReconstructorCache()
        model, lin = cache.get(design, settings, objective.image_prior)
        figs = probe_image_figures(model, lin, volts, probe_presses(probes), objective.image_lambda)
    else:  # every probe failed: nothing to reconstruct, and the score is NaN anyway
        figs = {k: np.full(len(evs), np.nan) for k in ("cc", *FIGURES)}
    means = {k: float(np.mean(figs[k])) if np.isfinite(figs[k]).all() else math.nan for k in FIGURES}
    return tuple(float(c) for c in figs["cc"]), means


def assess_design(design: LatticeDesign, *, phantoms: Sequence[Phantom], probes: Sequence[Phantom],
                  objective: Objective, settings: EvalSettings, out_dir: str | Path, evaluate: Callable,
                  need_stretch: bool = False, jobs: int = 1, backend: str = "local", scheduler=None,
                  images: ReconstructorCache | None = None, retry_failed: bool = False) -> Assessment:
    """Evaluate ``design`` on every phantom (and probe) through the store and score it.

    Phantoms already stored under ``settings.key`` are read, the rest computed (``jobs`` in parallel) and
    stored as they finish (:func:`latticeopt.study.sweep.evaluate_designs`). A failed phantom makes the score NaN
    (the design is infeasible, :mod:`latticeopt.study.objectives`); ``n_failed`` counts them, and ``v_rel_mean`` /
    ``max_stretch`` describe the successful ones only (for the history, never for ranking). With ``image_cc``
    the probes' stored voltages are reconstructed with the design's Jacobian from ``images`` (a per-run cache;
    ``None`` builds it afresh), :mod:`latticeopt.study.imaging`. ``retry_failed`` computes phantoms stored as
    failed again (after a solver change) instead of reading the failure.
    """
    from ..study.engine import evaluate_designs
    from ..study.report_lines import smallest_reference

    t0 = time.perf_counter()
    evs, computed = evaluate_designs([design], list(phantoms) + list(probes), settings, out_dir, evaluate,
                                     jobs=jobs, backend=backend, scheduler=scheduler, label=design.describe(),
                                     retry_failed=retry_failed)
    n = len(phantoms)
    vals = [e.v_rel if e.ok else math.nan for e in evs]
    rnd, prb = np.asarray(vals[:n]), np.asarray(vals[n:])
    cc, figures = _image_figures(design, evs[n:], probes, objective, settings, images)
    value = objective.evaluate(rnd, prb, cc)  # NaN (infeasible) if any phantom failed
    mean, se = mean_se(rnd[np.isfinite(rnd)])
    stretch = None
    if need_stretch:
        got = [e.extra.get("max_hydrogel_stretch") for e in evs if e.ok]
        if any(s is None for s in got):
            raise LatticeoptError(f"model {settings.model} returned no 'max_hydrogel_stretch', which "
                                  "optimize.constraints.max_hydrogel_stretch needs")
        stretch = max(got) if got else None
    n_ok = sum(e.ok for e in evs)
    return Assessment(score=value.score, se=value.se, terms=value.terms, v_rel_mean=mean, v_rel_se=se, n_ok=n_ok,
                      n_failed=len(evs) - n_ok, max_stretch=stretch, computed=computed,
                      seconds=time.perf_counter() - t0, design_key=design.content_hash(),
                      random_v=tuple(float(x) for x in rnd), probe_v=tuple(float(x) for x in prb), probe_cc=cc,
                      image_figures=figures, min_reference_rel=smallest_reference(evs))


# -- running a study ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class OptimizationResult:
    """What :func:`run_optimization` did: the optimum, the history, the starts, the outputs.

    ``optimum_layout`` is the narrowest gel and silicone of the optimum's layout, measured on its footprint
    (:mod:`latticeopt.fabrication`; ``None`` without a feasible optimum). Where it breaks a mould limit (at the
    sensor's edge) and the width is a variable, ``castable_widths`` holds the widths in its bounds whose layout meets
    both limits everywhere, on a 0.1 mm grid with the other variables at the optimum
    (:func:`~latticeopt.fabrication.castable_widths`), else ``None``; ``castable_checks`` scores them
    (``[optimize] check_castable``).
    """

    optimization: Optimization
    settings: EvalSettings
    out_dir: Path
    optimum: Optimum
    seconds: float
    paired: tuple[float, float] | None = None
    optimum_layout: Features | None = None
    castable_widths: list[tuple[float, float]] | None = None
    castable_checks: tuple[CastableCheck, ...] = ()
    outputs: dict = field(default_factory=dict)
    report: tuple[str, ...] = ()

    @property
    def best(self) -> Step | None:
        return self.optimum.best

    @property
    def history(self) -> tuple[Step, ...]:
        return self.optimum.history

    @property
    def computed(self) -> int:
        """Phantoms computed by this run (the rest were read from the store)."""
        return sum(s.assessment.computed for s in self.history if s.assessment is not None and not s.repeat)


@dataclass(frozen=True)
class CastableCheck:
    """A castable width scored beside the optimum (``[optimize] check_castable``): the width of one interval of
    :attr:`OptimizationResult.castable_widths` nearest the optimum's, its assessment, and its score minus the
    optimum's, paired over the phantoms both solved (``None`` if it failed every phantom)."""

    width_mm: float
    assessment: Assessment
    minus_optimum: tuple[float, float] | None


def _fabrication(opt: Optimization, best: Step | None) -> tuple[Features | None, list[tuple[float, float]] | None]:
    """:attr:`OptimizationResult.optimum_layout` and :attr:`OptimizationResult.castable_widths`, measured once."""
    if best is None:
        return None, None
    c, problem = opt.config.constraints, opt.problem
    design = problem.design(np.array([best.x[n] for n in problem.names]))
    layout = narrowest_features(design.footprint(), design.size_mm)
    if "width_mm" not in problem.names or not layout.below(c.min_channel_mm, c.min_island_mm):
        return layout, None
    k = problem.names.index("width_mm")
    return layout, castable_widths(design, problem.lower[k], problem.upper[k], c.min_channel_mm, c.min_island_mm)


def _paired(objective: Objective, a: Assessment, b: Assessment) -> tuple[float, float] | None:
    """Score of ``a`` minus ``b``'s with its SE, over the phantoms (and probes) both solved."""
    ra, rb, pa, pb = (np.asarray(x) for x in (a.random_v, b.random_v, a.probe_v, b.probe_v))
    ca, cb = (np.asarray(x, dtype=float) for x in (a.probe_cc, b.probe_cc))
    keep_r, keep_p = np.isfinite(ra) & np.isfinite(rb), np.isfinite(pa) & np.isfinite(pb)
    if ca.size:
        keep_p &= np.isfinite(ca) & np.isfinite(cb)
        ca, cb = ca[keep_p], cb[keep_p]
    if not keep_r.any():
        return None
    return objective.paired_difference((ra[keep_r], pa[keep_p], ca), (rb[keep_r], pb[keep_p], cb))


def _check_castable(opt: Optimization, best: Step, spans: list[tuple[float, float]],
                    assess: Callable) -> tuple[CastableCheck, ...]:
    """Score, per interval of castable widths, its width nearest the optimum's (other variables at the optimum)."""
    widths = dict.fromkeys(round(min(max(best.x["width_mm"], a), b), 6) for a, b in spans)
    checks = []
    for w in widths:
        x = np.array([w if n == "width_mm" else best.x[n] for n in opt.problem.names])
        a = assess(opt.problem.design(x))
        checks.append(CastableCheck(w, a, _paired(opt.config.objective, a, best.assessment)))
    return tuple(checks)


@contextlib.contextmanager
def _dask_client(scheduler, jobs: int):
    """A ``distributed.Client``: the given one, one connected to an address, or one on a local cluster of ``jobs``
    single-threaded worker processes (as :mod:`latticeopt.execution` starts them)."""
    if scheduler is not None and not isinstance(scheduler, str):
        yield scheduler
        return
    try:
        from distributed import Client, LocalCluster
    except ImportError as exc:
        raise ParameterError("backend", "'local', or 'dask' with dask.distributed installed", f"dask ({exc})") from None
    with contextlib.ExitStack() as stack:
        if scheduler is None:
            cluster = stack.enter_context(LocalCluster(n_workers=jobs, threads_per_worker=1, processes=True,
                                                       dashboard_address=None))
            client = stack.enter_context(Client(cluster))
        else:
            try:
                client = stack.enter_context(Client(scheduler, timeout="30s"))
            except (OSError, TimeoutError) as exc:
                raise LatticeoptError(f"cannot reach the dask scheduler at {scheduler!r}: {exc}") from None
        yield client


def run_optimization(opt: Optimization, evaluate: Callable | None = None, *, jobs: int | None = None,
                     backend: str = "local", scheduler=None, out_dir: str | Path | None = None,
                     outputs: bool = True, callback: Callable[[Step], None] | None = None,
                     retry_failed: bool = False) -> OptimizationResult:
    """Run an optimization study through the results store and write its outputs.

    Parameters
    ----------
    opt
        From :func:`load_optimization`.
    evaluate
        Top-level ``evaluate(design, phantom, settings) -> dict`` (``None``: the study's ``model``). A given
        function replaces ``settings.model`` (part of the store key), as in :func:`latticeopt.study.sweep.run_sweep`.
    jobs, backend, scheduler
        Parallel phantoms of each design (:func:`latticeopt.study.sweep.evaluate_designs`).
    out_dir
        Folder of the store and outputs (default: the study's ``out``).
    outputs
        Write the history CSV, plots and report (:mod:`latticeopt.optimize.report`).
    callback
        Called with every :class:`Step`.
    retry_failed
        Compute the phantoms stored as failed again (each design once per run: a repeated point is not assessed
        twice), as ``latticeopt sweep --retry-failed`` does; the path then follows the new results.
    """
    from ..study.engine import resolve_model

    t0 = time.perf_counter()
    study = opt.study
    settings = study.settings
    if evaluate is None:
        evaluate = resolve_model(settings.model)
    else:
        settings = replace(settings, model=f"{evaluate.__module__}:{evaluate.__qualname__}")
    out = Path(study.out_dir if out_dir is None else out_dir)
    jobs = study.jobs if jobs is None else jobs
    with contextlib.ExitStack() as stack:
        # one run per folder for the whole optimization (the sweep engine re-enters the same lock per design)
        stack.enter_context(folder_lock(out))
        if backend == "dask":  # one cluster connection for the whole run, not one per candidate design
            scheduler = stack.enter_context(_dask_client(scheduler, jobs))
        assess = functools.partial(
            assess_design, phantoms=study.phantoms, probes=opt.probes, objective=opt.config.objective,
            settings=settings, out_dir=out, evaluate=evaluate,
            need_stretch=opt.config.constraints.max_hydrogel_stretch is not None, jobs=jobs, backend=backend,
            scheduler=scheduler, images=ReconstructorCache(), retry_failed=retry_failed)
        optimum = minimize(opt.problem, opt.config, assess, callback=callback)
        layout, spans = _fabrication(opt, optimum.best)
        checks = _check_castable(opt, optimum.best, spans, assess) if opt.config.check_castable and spans else ()
    paired = None
    if optimum.best is not None and optimum.start_step is not None and optimum.start_step.assessment is not None:
        paired = _paired(opt.config.objective, optimum.best.assessment, optimum.start_step.assessment)
    result = OptimizationResult(optimization=opt, settings=settings, out_dir=out, optimum=optimum,
                                seconds=time.perf_counter() - t0, paired=paired, optimum_layout=layout,
                                castable_widths=spans, castable_checks=checks)
    if outputs:
        from .report import write_optimization_outputs

        with folder_lock(out):
            files, lines = write_optimization_outputs(result)
        result = replace(result, outputs=files, report=tuple(lines))
    assessed = [s.assessment for s in optimum.history if s.assessment is not None]
    if assessed and not any(a.n_ok for a in assessed):
        n = sum(a.n_failed for a in assessed)
        raise AllFailedError(f"every one of the {n} phantom evaluations of the {len(assessed)} designs assessed "
                             f"failed, so there is nothing to optimize; the errors are in {out / 'results.sqlite'}"
                             " (sweep the start design to see them in results.csv)", result)
    return result
