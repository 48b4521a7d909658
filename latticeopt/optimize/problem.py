"""The optimization in nlopt's terms: variables with effective bounds, general constraints, start points."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..design import LatticeDesign
from ..errors import ParameterError
from ..study.config import Study
from ..study.phantoms import Phantom
from .config import ROUND_DECIMALS, Constraints, LinearConstraint, OptimizeConfig, Variable

__all__ = ["Optimization", "Problem", "effective_bounds_text"]


@dataclass(frozen=True)
class Problem:
    """The optimization in nlopt's terms: variables, effective bounds (fabrication limits folded in), general
    constraints. Build it with :meth:`build`.

    ``fixed`` holds every design field at its start value; ``folded`` says which limit tightened which bound.
    """

    names: tuple[str, ...]
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    start: tuple[float, ...]
    fixed: tuple[tuple[str, object], ...]
    general: tuple[LinearConstraint, ...] = ()
    folded: tuple[str, ...] = ()

    @classmethod
    def build(cls, start_design: LatticeDesign, variables: Sequence[Variable], constraints: Constraints) -> Problem:
        """Fold single-variable limits into bounds, check fixed ones, keep the rest as general constraints."""
        names = tuple(x.name for x in variables)
        lo = {x.name: x.lower for x in variables}
        hi = {x.name: x.upper for x in variables}
        fixed = start_design.as_dict()
        general, folded = [], []
        for c in constraints.linear(start_design.pattern, start_design.rim):
            if c.name == "min_channel_mm" and "width_mm" not in names and not start_design.has_lattice:
                continue  # a uniform layer has no channel
            free = [(f, a) for f, a in c.coefficients if f in names]
            if len(free) > 1:
                general.append(c)
                continue
            rest = sum(a * fixed[f] for f, a in c.coefficients if f not in names)
            if not free:
                if rest - c.bound > 1e-12:
                    raise ParameterError(f"constraints.{c.name}", f"a design satisfying it (g = {rest - c.bound:.4g}"
                                         " mm > 0 for the fixed design)", start_design.describe())
                continue
            (f, a), = free
            limit = (c.bound - rest) / a
            if a > 0 and limit < hi[f]:
                folded.append(f"{f} <= {limit:g} (was {hi[f]:g}) by {c.name}")
                hi[f] = limit
            elif a < 0 and limit > lo[f]:
                folded.append(f"{f} >= {limit:g} (was {lo[f]:g}) by {c.name}")
                lo[f] = limit
        for f in names:
            if lo[f] >= hi[f]:
                raise ParameterError(f"variables.{f}", f"bounds leaving room under the constraints "
                                     f"({'; '.join(folded)})", [lo[f], hi[f]])
        problem = cls(names=names, lower=tuple(lo[f] for f in names), upper=tuple(hi[f] for f in names),
                      start=tuple(fixed[f] for f in names), fixed=tuple(fixed.items()), general=tuple(general),
                      folded=tuple(folded))
        x0 = np.asarray(problem.start)
        for f, val, a, b in zip(names, x0, problem.lower, problem.upper):
            if not a <= val <= b:
                raise ParameterError(f"variables.{f}.start", f"a start within the effective bounds [{a:g}, {b:g}] "
                                     f"({'; '.join(folded) or 'as given'})", val)
        for i, f in enumerate(names):  # every single-variable extreme must be a buildable design
            for end in (problem.lower[i], problem.upper[i]):
                x = x0.copy()
                x[i] = end
                try:
                    problem.design(x)
                except ParameterError as exc:
                    raise ParameterError(f"variables.{f}", f"bounds giving valid designs ({exc})",
                                         [problem.lower[i], problem.upper[i]]) from None
        return problem

    def values(self, x: np.ndarray) -> dict:
        vals = dict(self.fixed)
        vals.update(zip(self.names, (float(t) for t in x)))
        return vals

    def design(self, x: np.ndarray) -> LatticeDesign:
        """The design at ``x`` (raises :class:`ParameterError` if it cannot be built)."""
        return LatticeDesign(**self.values(x))

    def clean(self, x: np.ndarray) -> np.ndarray:
        """``x`` clipped to the bounds and rounded to ``10**-6`` mm (what is evaluated and stored)."""
        return np.round(np.clip(np.asarray(x, dtype=float), self.lower, self.upper), ROUND_DECIMALS)

    def starts(self, n: int, seed: int) -> list[np.ndarray]:
        """Start 0 is :attr:`start`; start ``k`` is uniform in the bounds from ``SeedSequence(seed, (k,))``,
        redrawn until the general constraints hold."""
        out = [np.asarray(self.start, dtype=float)]
        lo, hi = np.asarray(self.lower), np.asarray(self.upper)
        for k in range(1, n):
            rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence(seed, spawn_key=(k,))))
            for _ in range(10_000):
                x = self.clean(lo + (hi - lo) * rng.random(len(lo)))
                if all(c.value(self.values(x)) <= 0 for c in self.general):
                    break
            else:
                raise ParameterError("starts", "start points satisfying the constraints (none found in 10000 draws)",
                                     n)
            out.append(x)
        return out


@dataclass(frozen=True)
class Optimization:
    """A loaded optimization study: the study (its single design is the start), the config, the problem and the
    uniformity probes."""

    study: Study
    config: OptimizeConfig
    problem: Problem
    probes: tuple[Phantom, ...] = ()


def effective_bounds_text(problem: Problem) -> str:
    """``"width_mm in [0.5, 8], thickness_mm in [1, 5]"`` (for reports)."""
    return ", ".join(f"{n} in [{a:g}, {b:g}]" for n, a, b in zip(problem.names, problem.lower, problem.upper))
