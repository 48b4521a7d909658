"""Optimize lattice geometry with nlopt: continuous design variables, bounds, fabrication constraints.

>>> from latticeopt.optimize import load_optimization, run_optimization
>>> result = run_optimization(load_optimization("studies/optimize_square.toml"), jobs=2)  # doctest: +SKIP
>>> result.best.x, result.best.score, result.best.se  # doctest: +SKIP

A study file with an ``[optimize]`` table (schema: ``docs/studies.md``) names the design variables with their
bounds and start, the objective (:mod:`latticeopt.optimize.objectives`), the constraints, the nlopt algorithm and the
stopping rules. Every candidate design is evaluated on the study's fixed phantoms through the sweep engine
(:func:`latticeopt.study.sweep.evaluate_designs`), so every phantom result lands in the same SQLite store as sweeps
and a design already stored is read, not recomputed.

Constraints. The fabrication constraints are linear in the design fields: channel width ``w >= min_channel_mm``
(the rim channel's ``w / 2`` with ``rim = "channel"``), island ``p - w >= min_island_mm`` (triangular: the
island's inscribed circle, ``2/3 p - w``), substrate ``H - sealing - t >= min_substrate_mm``. One that involves a single
free variable is folded into that variable's bounds (every algorithm honours bounds), one with no free variable
is checked on load, and one coupling several variables (e.g. ``w`` and ``p`` both free) stays a nonlinear
inequality, as does ``max_hydrogel_stretch`` (the largest hydrogel stretch over the phantoms, from the
model's ``max_hydrogel_stretch``). Those go to nlopt as inequality constraints for algorithms that take them
(:data:`CONSTRAINED`: LN_COBYLA, GN_ISRES); for the others ``constraint_method`` must say how: ``"auglag"``
(nlopt's augmented Lagrangian around the algorithm; thorough but evaluation-hungry) or ``"penalty"``
(minimize ``-score + penalty_weight * sum(max(0, g)^2)``, g in mm or stretch); ``"auto"`` refuses rather than
guess. A candidate whose design cannot be built (e.g. ``w >= p``) is not evaluated: nlopt sees a barrier value,
``max(0, worst value so far) + 1 + total violation (mm)``.

Determinism and resuming. Design values are rounded to ``10**-6`` mm, multi-start points and nlopt's own
random numbers are seeded, and the objective is a deterministic function of stored results, so the same run
makes the same nlopt calls in the same order. An interrupted run, started again, replays its path from the
store (no phantom computed twice) and continues where it stopped. ``max_time_s`` counts this process's wall
time, so a resumed run with a time limit may get further than the interrupted one; evaluation counts
(``max_evals``, all nlopt calls including replays) do not have that caveat.

Modules: :mod:`.config` (the validated ``[optimize]`` table), :mod:`.problem` (bounds with the fabrication limits
folded in, general constraints, start points), :mod:`.load` (reading a study file), :mod:`.driver` (nlopt,
multi-start, history), :mod:`.run` (the store-backed objective, :func:`run_optimization`), :mod:`.report`
(history CSV, plots, report), :mod:`.categories` (an outer loop over layout families and rim layouts).
"""

from .config import (
    ALGORITHMS,
    CONSTRAINED,
    CONSTRAINT_METHODS,
    CONTINUOUS_FIELDS,
    LOCAL_ALGORITHMS,
    Constraints,
    LinearConstraint,
    OptimizeConfig,
    Variable,
)
from .driver import RESULT_NAMES, Assessment, Optimum, StartResult, Step, minimize
from .load import load_categories, load_optimization, optimization_from_dict
from .problem import Optimization, Problem, effective_bounds_text
from .run import OptimizationResult, assess_design, run_optimization

__all__ = ["ALGORITHMS", "CONSTRAINED", "CONSTRAINT_METHODS", "CONTINUOUS_FIELDS", "LOCAL_ALGORITHMS", "RESULT_NAMES",
           "Assessment", "Constraints", "LinearConstraint", "OptimizationResult", "Optimization", "OptimizeConfig",
           "Optimum", "Problem", "StartResult", "Step", "Variable", "assess_design", "effective_bounds_text",
           "load_categories", "load_optimization", "minimize", "optimization_from_dict", "run_optimization"]
