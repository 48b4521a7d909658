"""Run a study with a ``[multilevel]`` table: every phantom on the coarse mesh, a nested subset on the fine one.

The statistics are :mod:`latticeopt.study.multilevel`; this module only decides what to evaluate and reads the
store. Steps:

1. Every design x phantom at the coarse level (:func:`~latticeopt.study.settings.coarse_level_settings`: the
   mechanics on ``multilevel.coarse``, the electrics on the fine mesh or, with ``coarse_electrics = "coarse"``,
   on the coarse one; the ``[physics]`` keys of ``multilevel.coarse_physics`` changed).
2. The phantoms every compared design solved at the coarse level: first the take-all ones (``multilevel.take_all``
   of each touch count, those whose coarse V_rel ranks highest on average over the compared designs), then the
   others ordered by :func:`~latticeopt.study.multilevel.sampling_order` (touch counts, and within each its shallow
   and deep presses, ``multilevel.depth_split_mm``, interleaved): the fine subset of a design is a prefix of that one
   order, so it is nested and common to all designs.
3. The take-all phantoms and a pilot on the fine mesh (the study's own settings), then, per design, longer prefixes
   (:func:`~latticeopt.study.multilevel.next_fine_count`) until the two-level SE is within ``se_factor`` of the
   estimated plain fine SE or every phantom is fine (the SE of the estimate with ``multilevel.control``'s
   coefficient). Designs asking for the same prefix are evaluated together.

Both levels go through :func:`~latticeopt.study.engine.evaluate_designs` into the one store, each under its own
settings key (the key hashes the mesh): an interrupted run started again reads everything stored, makes the
same decisions from the same numbers and computes only what is missing. Failures follow the plain sweep's rule:
a phantom that any compared design failed, at either level, is left out for every design (at both levels); the
order is then rebuilt over the remaining phantoms and any phantom that enters a prefix is evaluated. A fine
failure of a phantom outside every design's subset cannot be seen: the estimate is of the mean over the
phantoms that every design solved at the coarse level and, where run, at the fine one.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .config import Study
from .engine import evaluate_designs, run_prefixes
from .multilevel import (
    MultilevelEstimate,
    depth_parts,
    multilevel_estimate,
    next_fine_count,
    sampling_order,
    take_all_mask,
)
from .settings import EvalSettings, coarse_level_settings
from .store import Evaluation

__all__ = ["MultilevelRun", "run_multilevel"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class MultilevelRun:
    """What a two-level sweep evaluated and estimated.

    Attributes
    ----------
    coarse_settings, fine_settings
        The settings (and so store keys) of the two levels.
    coarse
        One coarse evaluation per task, in task order (design-major).
    fine
        ``(design position, phantom position) -> Evaluation`` of every fine evaluation made or read.
    used
        Phantom positions every compared design solved (both levels where run), in sequence order.
    order
        ``used`` in fine order, the take-all phantoms first: design ``i``'s fine subset is ``order[:n_fine[i]]``.
    take_all
        The take-all phantoms (positions in the study's phantoms), the first ``len(take_all)`` of :attr:`order`.
    deep
        The sampled phantoms (positions in the study's phantoms) of the deep parts (``multilevel.depth_split_mm``;
        empty without a split).
    n_fine
        Prefix length per design (0 for a design not compared).
    estimates
        Per design the :class:`~latticeopt.study.multilevel.MultilevelEstimate`, ``None`` if not compared.
    compared
        Positions of the designs with at least one coarse success.
    computed_coarse, computed_fine
        Evaluations computed now (the rest came from the store).
    """

    coarse_settings: EvalSettings
    fine_settings: EvalSettings
    coarse: tuple[Evaluation, ...]
    fine: dict
    used: tuple[int, ...]
    order: tuple[int, ...]
    take_all: tuple[int, ...]
    deep: tuple[int, ...]
    n_fine: tuple[int, ...]
    estimates: tuple[MultilevelEstimate | None, ...]
    compared: tuple[int, ...]
    computed_coarse: int
    computed_fine: int

    def level_arrays(self, study: Study, design: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(coarse, fine, strata, take_all)`` over :attr:`used` for one design; fine is NaN outside its prefix,
        take_all marks the take-all phantoms."""
        return (*_arrays(study, self.coarse, self.fine, list(self.used), list(self.order), design,
                         self.n_fine[design]), self.take_all_mask())

    def take_all_mask(self) -> np.ndarray:
        """:attr:`take_all` as a mask over :attr:`used`."""
        return np.isin(np.array(self.used, dtype=int), np.array(self.take_all, dtype=int))

    def parts(self) -> np.ndarray:
        """The sampling part over :attr:`used`: 1 for a phantom of :attr:`deep`, else 0 (the estimates' ``parts``)."""
        return np.isin(np.array(self.used, dtype=int), np.array(self.deep, dtype=int)).astype(int)


def _arrays(study, coarse, fine, used, order, i, n):
    nph = len(study.phantoms)
    pos = {j: k for k, j in enumerate(used)}
    c = np.array([coarse[i * nph + j].v_rel for j in used], dtype=float)
    f = np.full(len(used), np.nan)
    for j in order[:n]:
        f[pos[j]] = fine[(i, j)].v_rel
    strata = np.array([study.phantoms[j].n_touches for j in used])
    return c, f, strata


def _take_all(study, coarse, used, compared, strata, share) -> np.ndarray:
    """The take-all phantoms over ``used``: per touch count the ``share`` whose coarse V_rel ranks highest, on
    average over the compared designs (ranks, not values: designs respond on different scales)."""
    if not used or share <= 0:
        return np.zeros(len(used), dtype=bool)
    nph = len(study.phantoms)
    ranks = np.zeros(len(used))
    for i in compared:
        c = np.array([coarse[i * nph + j].v_rel for j in used])
        for k in np.unique(strata):
            sel = np.flatnonzero(strata == k)
            ranks[sel] += np.argsort(np.argsort(c[sel], kind="stable"), kind="stable")
    return take_all_mask(ranks, strata, share)


def run_multilevel(study: Study, settings: EvalSettings, out_dir, evaluate: Callable, *, jobs: int = 1,
                   backend: str = "local", scheduler=None, progress: bool = False,
                   retry_failed: bool = False) -> MultilevelRun:
    """Evaluate ``study`` at both levels through the store in ``out_dir`` (module docstring).

    Parameters
    ----------
    study
        A study with ``study.multilevel`` set.
    settings
        The fine level's settings (the study's, with the model :func:`~.sweep.run_sweep` resolved).
    out_dir, evaluate, jobs, backend, scheduler, progress, retry_failed
        As in :func:`latticeopt.study.engine.evaluate_designs`.
    """
    ml = study.multilevel
    coarse_settings = coarse_level_settings(settings, ml)
    run = dict(evaluate=evaluate, jobs=jobs, backend=backend, scheduler=scheduler, progress=progress,
               retry_failed=retry_failed)
    coarse, computed_coarse = evaluate_designs(study.designs, study.phantoms, coarse_settings, out_dir,
                                               label=f"{study.name} (coarse)", **run)
    nd, nph = len(study.designs), len(study.phantoms)
    compared = [i for i in range(nd) if any(coarse[i * nph + j].ok for j in range(nph))]
    fine: dict = {}
    n = dict.fromkeys(compared, 0)
    computed_fine = 0
    while True:
        used = [j for j in range(nph)
                if all(coarse[i * nph + j].ok and (fine[(i, j)].ok if (i, j) in fine else True) for i in compared)]
        strata = np.array([study.phantoms[j].n_touches for j in used])
        tail = _take_all(study, coarse, used, compared, strata, ml.take_all)
        deepest = [max(t.depth_mm for t in study.phantoms[j].touches) for j in used]
        parts = depth_parts(deepest, strata, ml.depth_split_mm, tail)
        rest = np.flatnonzero(~tail)
        # positions in ``used`` of the phantoms not taken whole, touch counts and depth parts interleaved
        sampled_order = rest[sampling_order(strata[rest], parts[rest])]
        order = [used[k] for k in np.flatnonzero(tail)] + [used[k] for k in sampled_order]
        n_tail = int(tail.sum())
        want: dict[int, int] = {}
        for i in compared:
            if not used:
                break
            n[i] = min(n[i], len(used))
            if any((i, j) not in fine for j in order[:n[i]]):  # exclusions moved a new phantom into the prefix
                want[i] = n[i]
                continue
            c, f, s = _arrays(study, coarse, fine, used, order, i, n[i])
            sampled = max(n[i] - n_tail, 0)
            nxt = n_tail + next_fine_count(c, f, s, sampled, pilot=ml.pilot, se_factor=ml.se_factor,
                                           control=ml.control, take_all=tail, order=sampled_order, parts=parts)
            if nxt != n[i]:
                want[i] = nxt
        if not want:
            break
        computed_fine += run_prefixes(study.designs, study.phantoms, want, order, settings, out_dir, fine, n, run,
                                      label=lambda m: f"{study.name} (fine, {m} phantoms)")
        log.info("%s: fine phantoms per design %s", study.name, sorted(set(n.values())))
    estimates: list[MultilevelEstimate | None] = [None] * nd
    for i in compared:
        if used and n[i]:
            estimates[i] = multilevel_estimate(*_arrays(study, coarse, fine, used, order, i, n[i]),
                                               control=ml.control, take_all=tail, parts=parts)
    return MultilevelRun(coarse_settings=coarse_settings, fine_settings=settings, coarse=coarse, fine=fine,
                         used=tuple(used), order=tuple(order), take_all=tuple(order[:n_tail]),
                         deep=tuple(used[k] for k in np.flatnonzero((parts > 0) & ~tail)),
                         n_fine=tuple(n.get(i, 0) for i in range(nd)),
                         estimates=tuple(estimates), compared=tuple(compared), computed_coarse=computed_coarse,
                         computed_fine=computed_fine)
