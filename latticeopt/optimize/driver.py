"""The nlopt driver: one optimization's memo and history while nlopt calls back, multi-start, stopping."""

from __future__ import annotations

import functools
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..design import LatticeDesign
from ..errors import ParameterError
from .config import OptimizeConfig
from .problem import Problem

__all__ = ["RESULT_NAMES", "Assessment", "Optimum", "StartResult", "Step", "minimize"]

log = logging.getLogger(__name__)

RESULT_NAMES = {1: "SUCCESS", 2: "STOPVAL_REACHED", 3: "FTOL_REACHED", 4: "XTOL_REACHED", 5: "MAXEVAL_REACHED",
                6: "MAXTIME_REACHED", -1: "FAILURE", -2: "INVALID_ARGS", -3: "OUT_OF_MEMORY",
                -4: "ROUNDOFF_LIMITED", -5: "FORCED_STOP", 0: "BUDGET_EXHAUSTED"}


@dataclass(frozen=True)
class Assessment:
    """What one design scored (the optimizer's view of an evaluation).

    ``random_v``/``probe_v`` hold V_rel per phantom in phantom order (NaN where a phantom failed); ``score`` is
    NaN when the design could not be scored, which includes any failed phantom (infeasible). ``computed``
    counts phantoms computed now (the rest came from the store). With ``image_cc``, ``probe_cc`` holds each
    probe's image correlation and ``image_figures`` the mean GREIT position figures (mm) over the probes
    (:mod:`latticeopt.study.imaging`). ``min_reference_rel``: the smallest reference row over the largest, as the
    model reported it (:func:`latticeopt.metric.smallest_reference_rel`).
    """

    score: float
    se: float = math.nan
    terms: dict = field(default_factory=dict)
    v_rel_mean: float = math.nan
    v_rel_se: float = math.nan
    n_ok: int = 0
    n_failed: int = 0
    max_stretch: float | None = None
    computed: int = 0
    seconds: float = 0.0
    design_key: str = ""
    random_v: tuple[float, ...] = ()
    probe_v: tuple[float, ...] = ()
    probe_cc: tuple[float, ...] = ()
    image_figures: dict = field(default_factory=dict)
    min_reference_rel: float | None = None


@dataclass(frozen=True)
class Step:
    """One objective call (a row of the history): nlopt's, or the first, the start design's.

    ``x`` maps variable -> value (mm); ``f`` is what nlopt minimized (``-score`` plus any penalty, or the
    barrier); ``constraints`` maps name -> ``g`` (feasible when ``g <= 0``); ``repeat`` marks a point this run
    already assessed; ``assessment`` is ``None`` for a design that could not be built.
    """

    index: int
    start: int
    x: dict
    f: float
    constraints: dict
    feasible: bool
    repeat: bool
    assessment: Assessment | None
    note: str = ""

    @property
    def score(self) -> float:
        return self.assessment.score if self.assessment is not None else math.nan

    @property
    def se(self) -> float:
        return self.assessment.se if self.assessment is not None else math.nan


@dataclass(frozen=True)
class StartResult:
    """How one start ended: its point, nlopt's result code (name), the calls it made."""

    index: int
    x0: dict
    result: str
    evaluations: int
    message: str = ""


@dataclass(frozen=True)
class Optimum:
    """The outcome of :func:`minimize`: the whole history, the starts, the best feasible step (or ``None``)."""

    history: tuple[Step, ...]
    starts: tuple[StartResult, ...]
    best: Step | None
    start_step: Step | None


class _Driver:
    """Holds one optimization's memo and history while nlopt calls back into it."""

    def __init__(self, problem: Problem, config: OptimizeConfig, assess: Callable[[LatticeDesign], Assessment],
                 callback: Callable[[Step], None] | None):
        self.problem, self.config, self.assess, self.callback = problem, config, assess, callback
        self.memo: dict[tuple, Assessment | None] = {}
        self.history: list[Step] = []
        self.error: BaseException | None = None
        self.start = 0
        self.penalty = config.resolved_constraint_method(problem) == "penalty"

    def _assessment(self, x: np.ndarray) -> tuple[Assessment | None, bool]:
        key = tuple(x.tolist())
        if key in self.memo:
            return self.memo[key], True
        try:
            design = self.problem.design(x)
        except ParameterError:
            result = None
        else:
            result = self.assess(design)
        self.memo[key] = result
        return result, False

    def _g(self, x: np.ndarray, a: Assessment | None) -> dict:
        g = {c.name: c.value(self.problem.values(x)) for c in self.problem.general}
        limit = self.config.constraints.max_hydrogel_stretch
        if limit is not None:
            s = None if a is None else a.max_stretch
            g["max_hydrogel_stretch"] = math.nan if s is None else s - limit
        return g

    def objective(self, x_in: np.ndarray) -> float:
        x = self.problem.clean(x_in)
        a, repeat = self._assessment(x)
        g = self._g(x, a)
        viol = sum(max(0.0, val) for val in g.values() if math.isfinite(val))
        scored = a is not None and math.isfinite(a.score)
        if scored:
            f = -a.score
            if self.penalty:
                f += self.config.penalty_weight * sum(max(0.0, val) ** 2 for val in g.values() if math.isfinite(val))
        else:
            worst = max((s.f for s in self.history if s.assessment is not None and math.isfinite(s.score)),
                        default=0.0)
            f = max(0.0, worst) + 1.0 + viol
        feasible = scored and all(math.isfinite(val) and val <= 1e-9 for val in g.values())
        if scored:
            note = ""
        elif a is None:
            note = "design cannot be built"
        elif a.n_failed:
            note = (f"{a.n_failed} of {a.n_ok + a.n_failed} phantoms failed: infeasible (a design is scored on "
                    "every phantom or not at all)")
        else:
            note = "score undefined"
        step = Step(index=len(self.history) + 1, start=self.start, x=dict(zip(self.problem.names, x.tolist())),
                    f=float(f), constraints=g, feasible=feasible, repeat=repeat, assessment=a, note=note)
        self.history.append(step)
        if self.callback is not None:
            self.callback(step)
        return float(f)

    def constraint(self, name: str, x_in: np.ndarray) -> float:
        x = self.problem.clean(x_in)
        if name == "max_hydrogel_stretch":
            a, _ = self._assessment(x)
            val = self._g(x, a)[name]
            return val if math.isfinite(val) else 1.0  # no stretch (design not built / all failed): infeasible
        return next(c for c in self.problem.general if c.name == name).value(self.problem.values(x))

    # nlopt callbacks: our exceptions (KeyboardInterrupt included) are stashed and re-raised after optimize()
    def nlopt_objective(self, x, grad) -> float:
        try:
            return self.objective(np.asarray(x, dtype=float))
        except BaseException as exc:
            import nlopt

            self.error = exc
            raise nlopt.ForcedStop() from None

    def nlopt_constraint(self, name: str, x, grad) -> float:
        try:
            return self.constraint(name, np.asarray(x, dtype=float))
        except BaseException as exc:
            import nlopt

            self.error = exc
            raise nlopt.ForcedStop() from None


def _make_opt(config: OptimizeConfig, problem: Problem, driver: _Driver, remaining_evals: int, remaining_s: float):
    import nlopt

    n = len(problem.names)
    method = config.resolved_constraint_method(problem)

    def tolerances(o) -> None:
        if config.xtol_abs_mm > 0:
            o.set_xtol_abs(np.full(n, config.xtol_abs_mm))
        if config.xtol_rel > 0:
            o.set_xtol_rel(config.xtol_rel)
        if config.ftol_abs > 0:
            o.set_ftol_abs(config.ftol_abs)
        if config.ftol_rel > 0:
            o.set_ftol_rel(config.ftol_rel)

    def base(name: str):
        o = nlopt.opt(getattr(nlopt, name), n)
        o.set_lower_bounds(np.asarray(problem.lower))
        o.set_upper_bounds(np.asarray(problem.upper))
        o.set_initial_step(config.initial_step * (np.asarray(problem.upper) - np.asarray(problem.lower)))
        tolerances(o)
        if name == "G_MLSL_LDS":
            o.set_local_optimizer(base(config.local_algorithm))
        return o

    if method == "auglag":
        opt = nlopt.opt(nlopt.AUGLAG, n)
        opt.set_lower_bounds(np.asarray(problem.lower))
        opt.set_upper_bounds(np.asarray(problem.upper))
        tolerances(opt)
        opt.set_local_optimizer(base(config.algorithm))
    else:
        opt = base(config.algorithm)
    opt.set_min_objective(driver.nlopt_objective)
    if method in ("native", "auglag"):
        names = [c.name for c in problem.general]
        if config.constraints.max_hydrogel_stretch is not None:
            names.append("max_hydrogel_stretch")
        for name in names:
            opt.add_inequality_constraint(functools.partial(driver.nlopt_constraint, name), 0.0)
    if remaining_evals > 0:
        opt.set_maxeval(remaining_evals)
    if math.isfinite(remaining_s):
        opt.set_maxtime(max(remaining_s, 1e-3))
    return opt


def minimize(problem: Problem, config: OptimizeConfig, assess: Callable[[LatticeDesign], Assessment], *,
             callback: Callable[[Step], None] | None = None) -> Optimum:
    """Maximize ``assess(design).score`` over the problem's variables with nlopt (see the module docstring).

    Parameters
    ----------
    problem
        Variables, effective bounds, start and general constraints (:meth:`Problem.build`).
    config
        Algorithm, constraints, stopping rules, starts.
    assess
        ``design -> Assessment``; deterministic for resuming to replay (the store-backed one is
        :func:`assess_design`).
    callback
        Called with every :class:`Step` as it is made.

    Returns
    -------
    Optimum
        The best *feasible* step is the optimum (``None`` if there is none).
    """
    import nlopt

    driver = _Driver(problem, config, assess, callback)
    starts: list[StartResult] = []
    t0 = time.monotonic()
    points = problem.starts(config.starts, config.seed)
    # The start design is assessed first, whatever the algorithm does with x0 (BOBYQA moves an x0 lying within
    # its first trust radius of a bound; DIRECT ignores x0): it is the reference the optimum is compared with.
    driver.objective(points[0])
    for k, x0 in enumerate(points):
        used = len(driver.history)
        remaining_evals = config.max_evals - used if config.max_evals else 0
        remaining_s = config.max_time_s - (time.monotonic() - t0) if config.max_time_s else math.inf
        x0d = dict(zip(problem.names, x0.tolist()))
        if (config.max_evals and remaining_evals <= 0) or remaining_s <= 0:
            starts.append(StartResult(k, x0d, RESULT_NAMES[0], 0, "no evaluations or time left for this start"))
            continue
        driver.start = k
        nlopt.srand(config.seed + k)
        opt = _make_opt(config, problem, driver, remaining_evals, remaining_s)
        message = ""
        try:
            opt.optimize(x0)
            code = opt.last_optimize_result()
        except nlopt.ForcedStop:
            if driver.error is not None:
                raise driver.error from None
            code = nlopt.FORCED_STOP
        except nlopt.RoundoffLimited:
            code, message = nlopt.ROUNDOFF_LIMITED, "nlopt: roundoff limited (the best point so far is kept)"
        except RuntimeError as exc:  # nlopt's generic failure; our own errors come back through driver.error
            code, message = nlopt.FAILURE, f"nlopt failure: {exc}"
        if message:
            log.warning("start %d: %s", k, message)
        starts.append(StartResult(k, x0d, RESULT_NAMES.get(code, str(code)), len(driver.history) - used, message))
    feasible = [s for s in driver.history if s.feasible]
    best = max(feasible, key=lambda s: (s.score, -s.index)) if feasible else None
    return Optimum(tuple(driver.history), tuple(starts), best, driver.history[0])
