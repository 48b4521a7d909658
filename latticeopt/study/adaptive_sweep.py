"""Run a study with adaptive phantom counts (``target_se`` in ``[phantoms]``): each design runs phantoms in batches
until the standard error of its mean V_rel is at most the target, or it has run every phantom.

Which phantoms. The study's phantoms come ordered by touch count (all single touches first), so their first
``n`` would be single touches only. They are taken instead in :func:`~latticeopt.study.multilevel.fine_order`
(touch counts interleaved in proportion to their counts, within a touch count in sequence order), the order the
two-level estimator uses: every design runs a prefix of that one order, so any two designs share the shorter of
their prefixes (common random numbers, nested), and every prefix is a near-proportional sample of each touch count.

The rule (:func:`next_count`). A design first runs ``min_per_design`` phantoms; while its SE
(``std(ddof=1) / sqrt(n)`` over its prefix, the plain sweep's SE) is above ``target_se`` it runs ``batch_size``
more, up to every phantom of ``counts``. Designs asking for the same prefix are evaluated together. The rule looks
at the spread, never at the mean, so it does not select on the value being estimated; with few phantoms the
estimated SE is itself noisy, which is why ``min_per_design`` exists. That SE treats the prefix as one sample; as
the prefix is near-proportional per touch count it is, if anything, slightly larger than a stratified one.

Failures follow the plain sweep's rule: a phantom that any compared design (one with at least one success, or
none run yet) failed is left out for every design; the order is filtered, so a prefix that now reaches a phantom a
design has not run makes that design run it. Everything goes through :func:`~latticeopt.study.engine.evaluate_designs`
into the one store under the study's settings key, so an interrupted run started again reads every stored row,
makes the same decisions from the same numbers and computes only what is missing; the rows are also exactly
those a plain sweep of the same study would reuse.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from .config import Study
from .engine import run_prefixes
from .multilevel import fine_order
from .report import mean_se
from .settings import AdaptiveSettings, EvalSettings
from .store import Evaluation

__all__ = ["AdaptiveRun", "next_count", "phantom_order", "run_adaptive"]

log = logging.getLogger(__name__)


def phantom_order(study: Study) -> tuple[int, ...]:
    """Positions in ``study.phantoms`` in the order designs take them (touch counts interleaved)."""
    return tuple(int(j) for j in fine_order(np.array([p.n_touches for p in study.phantoms])))


def next_count(values: Sequence[float], available: int, adaptive: AdaptiveSettings) -> int:
    """How many phantoms (a prefix of the common order) a design should have next.

    Parameters
    ----------
    values
        V_rel of the design's current prefix (all of it run).
    available
        Phantoms in the order (every phantom not excluded by a failure): the maximum.
    adaptive
        ``min_per_design``, ``batch_size``, ``target_se``.

    Returns
    -------
    int
        ``len(values)`` when it is done (SE <= target, or every phantom run); otherwise a longer prefix:
        ``min_per_design`` first, then ``batch_size`` more at a time, never more than ``available``.
    """
    n = len(values)
    start = min(available, adaptive.min_per_design)
    if n < start:
        return start
    if n >= available or mean_se(values)[1] <= adaptive.target_se:
        return min(n, available)
    return min(available, n + adaptive.batch_size)


@dataclass(frozen=True)
class AdaptiveRun:
    """What an adaptive sweep evaluated.

    Attributes
    ----------
    evaluations
        ``(design position, phantom position) -> Evaluation`` of every evaluation made or read.
    order
        Phantom positions not excluded by a failure, in the common order: design ``i`` used ``order[:n[i]]``.
    n
        Phantoms used per design (0 for a design not compared).
    compared
        Positions of the designs with at least one success.
    excluded
        Phantom positions left out because a compared design failed them.
    computed
        Evaluations computed now (the rest came from the store).
    """

    evaluations: dict
    order: tuple[int, ...]
    n: tuple[int, ...]
    compared: tuple[int, ...]
    excluded: tuple[int, ...]
    computed: int

    def values(self, design: int, n: int | None = None) -> list[float]:
        """V_rel of ``design`` over the first ``n`` (default: its own count) phantoms of :attr:`order`."""
        return [self.evaluations[(design, j)].v_rel for j in self.order[:self.n[design] if n is None else n]]

    def rows(self) -> tuple[Evaluation, ...]:
        """Every evaluation, design-major, phantoms in sequence order."""
        return tuple(self.evaluations[k] for k in sorted(self.evaluations))


def _state(nd: int, full: Sequence[int], evals: dict) -> tuple[list[int], list[int]]:
    """The designs compared and the phantoms of the common order that none of them failed."""
    ran, solved = set(), set()
    for (i, _), e in evals.items():
        ran.add(i)
        if e.ok:
            solved.add(i)
    compared = [i for i in range(nd) if i in solved or i not in ran]  # a design yet to run is compared
    order = [j for j in full if all(evals[(i, j)].ok for i in compared if (i, j) in evals)]
    return compared, order


def run_adaptive(study: Study, settings: EvalSettings, out_dir, evaluate: Callable, *, jobs: int = 1,
                 backend: str = "local", scheduler=None, progress: bool = False,
                 retry_failed: bool = False) -> AdaptiveRun:
    """Evaluate ``study`` with adaptive phantom counts through the store in ``out_dir`` (module docstring).

    Parameters
    ----------
    study
        A study with ``study.adaptive`` set.
    settings
        The settings (the study's, with the model :func:`~.sweep.run_sweep` resolved).
    out_dir, evaluate, jobs, backend, scheduler, progress, retry_failed
        As in :func:`latticeopt.study.engine.evaluate_designs`.
    """
    ad = study.adaptive
    run = dict(evaluate=evaluate, jobs=jobs, backend=backend, scheduler=scheduler, progress=progress,
               retry_failed=retry_failed)
    nd = len(study.designs)
    full = phantom_order(study)
    evals: dict = {}
    n = [0] * nd
    computed = 0
    while True:
        compared, order = _state(nd, full, evals)
        want: dict[int, int] = {}
        for i in compared:
            n[i] = min(n[i], len(order))
            if any((i, j) not in evals for j in order[:n[i]]):  # an exclusion moved a new phantom into the prefix
                want[i] = n[i]
                continue
            nxt = next_count([evals[(i, j)].v_rel for j in order[:n[i]]], len(order), ad)
            if nxt != n[i]:
                want[i] = nxt
        if not want:
            break
        computed += run_prefixes(study.designs, study.phantoms, want, order, settings, out_dir, evals, n, run,
                                 label=lambda m: f"{study.name} ({m} phantoms)")
        log.info("%s: phantoms per design %s", study.name, sorted({n[i] for i in compared}))
    compared, order = _state(nd, full, evals)
    counts = tuple(min(n[i], len(order)) if i in compared else 0 for i in range(nd))
    return AdaptiveRun(evaluations=evals, order=tuple(order), n=counts, compared=tuple(compared),
                       excluded=tuple(j for j in full if j not in set(order)), computed=computed)
