"""The validated ``[optimize]`` table: algorithms, variables, constraints, objective, stopping rules.

Defaults and meanings: ``docs/studies.md``, section *Optimization studies*.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from .. import _validate as v
from ..errors import ParameterError
from ..layout import MAX_WIDTH_FRACTION, RIM_WIDTH_FRACTION
from .objectives import Objective

if TYPE_CHECKING:
    from .problem import Problem

__all__ = ["ALGORITHMS", "CONSTRAINED", "CONSTRAINT_METHODS", "CONTINUOUS_FIELDS", "LOCAL_ALGORITHMS", "Constraints",
           "LinearConstraint", "OptimizeConfig", "Variable"]

#: nlopt algorithms offered, name -> "local" or "global".
ALGORITHMS = {"LN_BOBYQA": "local", "LN_COBYLA": "local", "LN_NELDERMEAD": "local", "LN_SBPLX": "local",
              "GN_DIRECT_L": "global", "GN_CRS2_LM": "global", "GN_ISRES": "global", "G_MLSL_LDS": "global"}
#: Algorithms that take nonlinear inequality constraints themselves.
CONSTRAINED = ("LN_COBYLA", "GN_ISRES")
#: Local solvers for G_MLSL_LDS.
LOCAL_ALGORITHMS = tuple(a for a, kind in ALGORITHMS.items() if kind == "local")
CONSTRAINT_METHODS = ("auto", "native", "auglag", "penalty")
#: Design fields that may be optimization variables (``size_mm`` is excluded: the phantoms depend on it).
CONTINUOUS_FIELDS = ("width_mm", "thickness_mm", "pitch_mm", "total_thickness_mm", "sealing_mm",
                     "electrode_width_mm", "frame_mm")
#: Strict inequalities of the design (``w < p``) are kept this far from equality (mm).
STRICT_MARGIN_MM = 1e-3
ROUND_DECIMALS = 6


@dataclass(frozen=True)
class Variable:
    """A continuous design variable: a :data:`CONTINUOUS_FIELDS` name, its bounds and start value (mm)."""

    name: str
    lower: float
    upper: float
    start: float

    def __post_init__(self) -> None:
        v.choice("variable", self.name, CONTINUOUS_FIELDS)
        lo = v.real(f"{self.name}.lower", self.lower)
        hi = v.real(f"{self.name}.upper", self.upper, lo=lo, lo_open=True,
                    expected=f"a number > lower = {lo:g}")
        x0 = v.real(f"{self.name}.start", self.start, lo=lo, hi=hi)
        if self.name == "width_mm" and lo <= 0:
            raise ParameterError("width_mm.lower", "> 0 (w = 0 is the uniform layer, a different topology, not "
                                 "the limit of a lattice: compare with it in a sweep)", self.lower)
        for name, val in (("lower", lo), ("upper", hi), ("start", x0)):
            object.__setattr__(self, name, val)


@dataclass(frozen=True)
class Constraints:
    """Fabrication and mechanical limits (mm; stretch dimensionless).

    Parameters
    ----------
    min_channel_mm
        Narrowest hydrogel channel that can be made (``w``; the rim channel is ``w / 2``).
    min_island_mm
        Narrowest silicone island that can be made (``p - w``; triangular ``2/3 p - w``).
    min_substrate_mm
        Thinnest substrate ``H - sealing - t`` (0: only non-negative).
    max_hydrogel_stretch
        Largest principal stretch allowed in the hydrogel over all phantoms (``None``: no limit); needs the
        model to return ``max_hydrogel_stretch``.
    """

    min_channel_mm: float = 0.5
    min_island_mm: float = 1.0
    min_substrate_mm: float = 0.0
    max_hydrogel_stretch: float | None = None

    def __post_init__(self) -> None:
        for name in ("min_channel_mm", "min_island_mm", "min_substrate_mm"):
            object.__setattr__(self, name, v.real(name, getattr(self, name), lo=0))
        if self.max_hydrogel_stretch is not None:
            object.__setattr__(self, "max_hydrogel_stretch", v.real("max_hydrogel_stretch",
                                                                    self.max_hydrogel_stretch, lo=1, lo_open=True))

    def linear(self, pattern: str = "square", rim: str = "none") -> tuple[LinearConstraint, ...]:
        """The fabrication limits of a ``pattern`` lattice with ``rim`` as ``sum(a * field) <= b``.

        The narrowest channel is ``w``, or the rim channel's ``w / 2`` with ``rim = "channel"``; the narrowest
        island is ``f p - w`` with ``f`` the family's no-island fraction (1; 2/3 for the triangular lattice,
        whose islands' inscribed circle is ``2/3 p - w`` across).
        """
        narrowest = RIM_WIDTH_FRACTION if rim == "channel" else 1.0
        f = MAX_WIDTH_FRACTION.get(pattern, 1.0)
        return (LinearConstraint("min_channel_mm", (("width_mm", -narrowest),), -self.min_channel_mm),
                LinearConstraint("min_island_mm", (("width_mm", 1.0), ("pitch_mm", -f)),
                                 -max(self.min_island_mm, STRICT_MARGIN_MM)),
                LinearConstraint("min_substrate_mm", (("thickness_mm", 1.0), ("sealing_mm", 1.0),
                                                      ("total_thickness_mm", -1.0)), -self.min_substrate_mm))


@dataclass(frozen=True)
class LinearConstraint:
    """``g = sum(a_k * field_k) - b <= 0`` over design fields (mm)."""

    name: str
    coefficients: tuple[tuple[str, float], ...]
    bound: float

    def value(self, values: Mapping[str, float]) -> float:
        return float(sum(a * values[f] for f, a in self.coefficients) - self.bound)


@dataclass(frozen=True)
class OptimizeConfig:
    """A validated ``[optimize]`` table (defaults as documented in ``docs/studies.md``)."""

    variables: tuple[Variable, ...]
    algorithm: str = "LN_BOBYQA"
    local_algorithm: str = "LN_BOBYQA"
    objective: Objective = field(default_factory=Objective)
    constraints: Constraints = field(default_factory=Constraints)
    constraint_method: str = "auto"
    penalty_weight: float = 1.0
    max_evals: int = 50
    max_time_s: float = 0.0
    xtol_abs_mm: float = 0.05
    xtol_rel: float = 0.0
    ftol_abs: float = 0.0
    ftol_rel: float = 0.0
    initial_step: float = 0.25
    starts: int = 1
    seed: int = 0
    check_castable: bool = False

    def __post_init__(self) -> None:
        if not self.variables or not all(isinstance(x, Variable) for x in self.variables):
            raise ParameterError("variables", "at least one design variable, e.g. width_mm = { lower = 0.5, "
                                 "upper = 8, start = 3 }", self.variables)
        names = [x.name for x in self.variables]
        if len(set(names)) != len(names):
            raise ParameterError("variables", "each field once", names)
        object.__setattr__(self, "algorithm", v.choice("algorithm", self.algorithm, ALGORITHMS))
        object.__setattr__(self, "local_algorithm", v.choice("local_algorithm", self.local_algorithm,
                                                             LOCAL_ALGORITHMS))
        object.__setattr__(self, "constraint_method", v.choice("constraint_method", self.constraint_method,
                                                               CONSTRAINT_METHODS))
        for name in ("penalty_weight", "max_time_s", "xtol_abs_mm", "xtol_rel", "ftol_abs", "ftol_rel"):
            object.__setattr__(self, name, v.real(name, getattr(self, name), lo=0))
        object.__setattr__(self, "initial_step", v.real("initial_step", self.initial_step, lo=0, hi=1, lo_open=True))
        object.__setattr__(self, "max_evals", v.integer("max_evals", self.max_evals, lo=0))
        object.__setattr__(self, "starts", v.integer("starts", self.starts, lo=1))
        object.__setattr__(self, "seed", v.integer("seed", self.seed, lo=0))
        if not isinstance(self.check_castable, bool):
            raise ParameterError("check_castable", "true or false", self.check_castable)
        if not (self.max_evals or self.max_time_s):
            raise ParameterError("max_evals", "a limit (max_evals > 0 or max_time_s > 0): evaluations are expensive "
                                 "and global algorithms stop only on these", self.max_evals)
        if ALGORITHMS[self.algorithm] == "local" and not (self.xtol_abs_mm or self.xtol_rel or self.ftol_abs
                                                          or self.ftol_rel or self.max_evals):
            raise ParameterError("xtol_abs_mm", "a tolerance > 0 for a local algorithm", self.xtol_abs_mm)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(x.name for x in self.variables)

    def resolved_constraint_method(self, problem: Problem) -> str:
        """``"none"`` when no nonlinear constraint is left, else the method used (``"auto"`` resolved)."""
        if not problem.general and self.constraints.max_hydrogel_stretch is None:
            return "none"
        if self.constraint_method == "auto":
            return "native"
        return self.constraint_method

    def check_constraint_method(self, problem: Problem) -> None:
        """Refuse an algorithm that cannot take the problem's nonlinear constraints the way asked."""
        method = self.resolved_constraint_method(problem)
        if method == "native" and self.algorithm not in CONSTRAINED:
            left = [c.name for c in problem.general]
            if self.constraints.max_hydrogel_stretch is not None:
                left.append("max_hydrogel_stretch")
            raise ParameterError("constraint_method", f"'penalty' or 'auglag': {self.algorithm} does not take the "
                                 f"nonlinear constraints {', '.join(left)} (the algorithms that do: "
                                 f"{', '.join(CONSTRAINED)})", self.constraint_method)
