"""Run a study: every (design, phantom) pair not yet in the store, in parallel, written as it finishes.

>>> from latticeopt.study.config import load_study
>>> from latticeopt.study.sweep import run_sweep
>>> result = run_sweep(load_study("studies/quick.toml"), jobs=2)  # doctest: +SKIP

How: :func:`~latticeopt.study.estimators.estimator_for` picks the study's estimator once (plain, two-level or
adaptive), whose ``run()`` evaluates through the engine (:mod:`latticeopt.study.engine`: the store, the
workers, failures and bugs, backends) and whose ``write_outputs()`` writes the tables, figures and
``report.txt``. The parent process is the store's single writer and commits each result the moment it arrives,
so a sweep killed at any point (Ctrl-C, ``kill PID``) resumes where it stopped and recomputes nothing stored.
How failed phantoms enter the tables: :mod:`latticeopt.study.report`.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import AllFailedError
from ..execution import blas_threads
from .config import Study
from .engine import (
    BACKENDS,
    CHUNK_PHANTOMS,
    ERROR_LOG,
    check_run_args,
    evaluate_designs,
    model_name,
    resolve_model,
)
from .estimators import estimator_for
from .settings import EvalSettings
from .store import Evaluation, folder_lock
from .worker import FAILURE_TYPES, is_model_failure, result_to_evaluation

# the engine's names stay importable from here, where they were first defined
__all__ = ["BACKENDS", "CHUNK_PHANTOMS", "ERROR_LOG", "FAILURE_TYPES", "SweepResult", "blas_threads",
           "evaluate_designs", "is_model_failure", "resolve_model", "result_to_evaluation", "run_sweep"]


# -- the runner -------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SweepResult:
    """What a sweep did and where its outputs are.

    ``evaluations`` is in task order (:meth:`Study.tasks`), one stored row per task.
    """

    study: Study
    settings: EvalSettings
    out_dir: Path
    evaluations: tuple[Evaluation, ...]
    computed: int
    skipped: int
    seconds: float
    outputs: dict = field(default_factory=dict)
    report: tuple[str, ...] = ()
    multilevel: object = None  # a MultilevelRun when the study has [multilevel]; evaluations are then coarse
    adaptive: object = None  # an AdaptiveRun when [phantoms] has target_se; evaluations are then those made

    @property
    def failed(self) -> int:
        return sum(not e.ok for e in self.evaluations)


def run_sweep(study: Study, evaluate: Callable | None = None, *, jobs: int | None = None, backend: str = "local",
              scheduler=None, progress: bool = True, retry_failed: bool = False, out_dir: str | Path | None = None,
              outputs: bool = True) -> SweepResult:
    """Evaluate every (design, phantom) pair of ``study`` that the store does not hold yet.

    Parameters
    ----------
    study
        The validated study.
    evaluate
        Top-level, picklable ``evaluate(design, phantom, settings) -> dict``; ``None`` imports the study's
        ``model``. A given function replaces ``settings.model`` (its ``module:qualname``), which is part of
        the settings key, so different models never share rows.
    jobs
        Worker processes (default: the study's ``jobs``).
    backend
        ``"local"`` or ``"dask"``.
    scheduler
        Dask scheduler address (``"tcp://host:8786"``) or a ``distributed.Client``; ``None`` with
        ``backend="dask"`` starts a local cluster.
    progress
        Show a tqdm progress bar with ETA on stderr.
    retry_failed
        Re-run phantoms whose stored row is ``'failed'`` (a success then replaces the failure).
    out_dir
        Output folder (default: the study's ``out``); holds ``results.sqlite`` and the reports.
    outputs
        Write the tables, figures and ``report.txt`` at the end (the estimator's ``write_outputs()``).
    """
    t_start = time.perf_counter()
    settings = study.settings
    if evaluate is None:
        evaluate = resolve_model(settings.model)
    else:
        settings = dataclasses.replace(settings, model=model_name(evaluate))
    out = Path(study.out_dir if out_dir is None else out_dir)
    check_run_args(study.jobs if jobs is None else jobs, backend, scheduler)
    estimator = estimator_for(study)
    with folder_lock(out):  # one run per folder: a second one refuses rather than compute the same phantoms
        (out / "study.json").write_text(json.dumps({**study.as_dict(), "settings": settings.as_dict(),
                                                    "settings_key": settings.key}, indent=1, default=str))
        outcome = estimator.run(settings, out, evaluate, jobs=study.jobs if jobs is None else jobs,
                                backend=backend, scheduler=scheduler, progress=progress, retry_failed=retry_failed)
        files, report = estimator.write_outputs(outcome, out) if outputs else ({}, ())
    evaluations = outcome.evaluations
    result = SweepResult(study=study, settings=settings, out_dir=out, evaluations=evaluations,
                         computed=outcome.computed, skipped=outcome.total - outcome.computed,
                         seconds=time.perf_counter() - t_start, outputs=files, report=tuple(report),
                         multilevel=outcome.multilevel, adaptive=outcome.adaptive)
    if evaluations and result.failed == len(evaluations):
        raise AllFailedError(all_failed_message(evaluations, outcome.computed, out,
                                                "results.csv" if outputs else None), result)
    return result


def all_failed_message(evaluations, computed: int, out: Path, table: str | None) -> str:
    """One line for a run in which every evaluation failed: how many, the first error, where the rest are."""
    first = next(((e.error or "").splitlines()[:1] for e in evaluations), [""])
    where = f"every error is in {Path(out) / table}" if table else f"every error is in {Path(out) / 'results.sqlite'}"
    return (f"every one of the {len(evaluations)} evaluations failed ({computed} computed now, the rest read from "
            f"the store), so there is nothing to compare; the first: {first[0] if first else ''}; {where} "
            "(--retry-failed runs them again)")
