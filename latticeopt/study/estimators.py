"""The estimators of a study's mean V_rel per design: one object per kind, with ``run()`` and ``write_outputs()``.

- :class:`PlainEstimator`: every design on every phantom (:func:`~.engine.evaluate_designs`); tables and
  figures by :func:`~.report.write_outputs`.
- :class:`TwoLevelEstimator` (a ``[multilevel]`` table): every phantom on a coarse mesh, a nested subset on the
  fine one (:mod:`.multilevel_sweep`, :mod:`.multilevel_report`).
- :class:`AdaptiveEstimator` (``target_se`` in ``[phantoms]``): per design a prefix of one common phantom order,
  until its SE meets the target (:mod:`.adaptive_sweep`, :mod:`.adaptive_report`).
- :class:`ProbeEstimator` (``kind = "probes"``): every design on every probe of the grid, as the plain estimator;
  not a mean but the uniformity over the probes (:mod:`.probe_report`).

:func:`estimator_for` picks one from the study, once; :func:`~.sweep.run_sweep` and ``sweep --dry-run`` use
what it returns. Each estimator also names its :meth:`levels`: the settings it evaluates under and how many
evaluations each may take, which is what a dry run counts and prices.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .adaptive_report import write_adaptive_outputs
from .adaptive_sweep import AdaptiveRun, run_adaptive
from .config import Study
from .engine import evaluate_designs
from .multilevel import take_all_mask
from .multilevel_report import write_multilevel_outputs
from .multilevel_sweep import MultilevelRun, run_multilevel
from .probe_report import write_probe_outputs
from .report import write_outputs
from .settings import EvalSettings, coarse_level_settings
from .store import Evaluation

__all__ = ["AdaptiveEstimator", "Level", "Outcome", "PlainEstimator", "ProbeEstimator", "TwoLevelEstimator",
           "estimator_for"]


@dataclass(frozen=True)
class Outcome:
    """What an estimator's :meth:`run` evaluated.

    Attributes
    ----------
    evaluations
        The rows a sweep reports as its own (all of them; the coarse level's of a two-level run; those made of an
        adaptive one), design-major.
    computed
        Evaluations computed now, every level together (the rest came from the store).
    total
        Evaluations made or read, every level together.
    multilevel, adaptive
        The two-level or adaptive run's own record, ``None`` for the other kinds.
    """

    evaluations: tuple[Evaluation, ...]
    computed: int
    total: int
    multilevel: MultilevelRun | None = None
    adaptive: AdaptiveRun | None = None


@dataclass(frozen=True)
class Level:
    """One settings key an estimator evaluates under, and between how many evaluations of the study it makes."""

    name: str
    settings: EvalSettings
    min_evaluations: int
    max_evaluations: int


@dataclass(frozen=True)
class PlainEstimator:
    """Every design on every phantom; the mean and SE over the phantoms every compared design solved."""

    study: Study

    def levels(self, settings: EvalSettings) -> tuple[Level, ...]:
        """The settings keys this estimator evaluates under (``settings``: the study's, model resolved)."""
        return (Level("all", settings, self.study.n_tasks, self.study.n_tasks),)

    def describe(self, settings: EvalSettings, stored: dict[str, int]) -> list[str]:
        """Lines ``sweep --dry-run`` prints after the task count; ``stored``: stored rows per settings key."""
        return []

    def run(self, settings: EvalSettings, out_dir: Path, evaluate: Callable, **executor) -> Outcome:
        """Evaluate the study through the store in ``out_dir``; ``executor``: as in :func:`evaluate_designs`."""
        study = self.study
        rows, computed = evaluate_designs(study.designs, study.phantoms, settings, out_dir, evaluate,
                                          label=study.name, **executor)
        return Outcome(rows, computed, len(rows))

    def write_outputs(self, outcome: Outcome, out_dir: Path) -> tuple[dict, list[str]]:
        """Write the tables, figures and ``report.txt``; return the files written and the report's lines."""
        return write_outputs(self.study, outcome.evaluations, out_dir)


@dataclass(frozen=True)
class TwoLevelEstimator:
    """Every phantom on the coarse level, a nested subset on the fine one (:mod:`.multilevel_sweep`)."""

    study: Study

    def levels(self, settings: EvalSettings) -> tuple[Level, ...]:
        study, ml = self.study, self.study.multilevel
        n = study.n_tasks
        strata = np.array([p.n_touches for p in study.phantoms])
        first = int(take_all_mask(np.zeros(strata.size), strata, ml.take_all).sum()) + ml.pilot
        pilot = len(study.designs) * min(first, len(study.phantoms))
        return (Level("coarse", coarse_level_settings(settings, ml), n, n), Level("fine", settings, pilot, n))

    def describe(self, settings: EvalSettings, stored: dict[str, int]) -> list[str]:
        ml = self.study.multilevel
        stored_coarse = stored.get(coarse_level_settings(settings, ml).key, 0)
        extra = "".join(f", {k} = {v}" for k, v in ml.coarse_physics)
        return [f"two-level: every phantom also with the mechanics on the coarse mesh {ml.coarse.size_mm:g} mm "
                f"(electrics on the {ml.coarse_electrics} mesh{extra}; {stored_coarse} of {self.study.n_tasks} "
                f"stored), the fine level on the take-all share {ml.take_all:g} of each touch count and a pilot of "
                f"{ml.pilot}, and more until SE <= {ml.se_factor:g} x the plain fine SE (control {ml.control}; "
                "counted above: the fine level if every phantom were run)"]

    def run(self, settings: EvalSettings, out_dir: Path, evaluate: Callable, **executor) -> Outcome:
        ml = run_multilevel(self.study, settings, out_dir, evaluate, **executor)
        return Outcome(ml.coarse, ml.computed_coarse + ml.computed_fine, len(ml.coarse) + len(ml.fine),
                       multilevel=ml)

    def write_outputs(self, outcome: Outcome, out_dir: Path) -> tuple[dict, list[str]]:
        return write_multilevel_outputs(self.study, outcome.multilevel, out_dir)


@dataclass(frozen=True)
class AdaptiveEstimator:
    """Per design a prefix of one common phantom order, until its SE meets the target (:mod:`.adaptive_sweep`)."""

    study: Study

    def levels(self, settings: EvalSettings) -> tuple[Level, ...]:
        study = self.study
        least = len(study.designs) * min(study.adaptive.min_per_design, len(study.phantoms))
        return (Level("adaptive", settings, least, study.n_tasks),)

    def describe(self, settings: EvalSettings, stored: dict[str, int]) -> list[str]:
        ad = self.study.adaptive
        return [f"adaptive: each design runs {ad.min_per_design} phantoms, then {ad.batch_size} more at a time "
                f"until the SE of its mean V_rel <= {ad.target_se:g} (counted above: every phantom, the maximum)"]

    def run(self, settings: EvalSettings, out_dir: Path, evaluate: Callable, **executor) -> Outcome:
        ad = run_adaptive(self.study, settings, out_dir, evaluate, **executor)
        rows = ad.rows()
        return Outcome(rows, ad.computed, len(rows), adaptive=ad)

    def write_outputs(self, outcome: Outcome, out_dir: Path) -> tuple[dict, list[str]]:
        return write_adaptive_outputs(self.study, outcome.adaptive, out_dir)


@dataclass(frozen=True)
class ProbeEstimator(PlainEstimator):
    """Every design on every probe of the grid (``kind = "probes"``), reported as uniformity (:mod:`.probe_report`)."""

    def describe(self, settings: EvalSettings, stored: dict[str, int]) -> list[str]:
        g = self.study.phantom_set
        return [f"probes: a {g.grid} x {g.grid} grid, one punch of radius {g.radius_mm:g} mm pressed "
                f"{g.depth_mm:g} mm at every cell centre; per design uniformity = 1 - std/mean of its probe V_rel"]

    def write_outputs(self, outcome: Outcome, out_dir: Path) -> tuple[dict, list[str]]:
        return write_probe_outputs(self.study, outcome.evaluations, out_dir)


def estimator_for(study: Study) -> PlainEstimator | TwoLevelEstimator | AdaptiveEstimator | ProbeEstimator:
    """The study's estimator: two-level with ``[multilevel]``, adaptive with ``target_se``, the probe grid's report
    for ``kind = "probes"``, else plain."""
    if study.kind == "probes":
        return ProbeEstimator(study)
    if study.multilevel is not None:
        return TwoLevelEstimator(study)
    if study.adaptive is not None:
        return AdaptiveEstimator(study)
    return PlainEstimator(study)
