"""Run a study: every (design, phantom) pair not yet in the store, in parallel, written as it finishes.

>>> from latticeopt.study.config import load_study
>>> from latticeopt.study.sweep import run_sweep
>>> result = run_sweep(load_study("studies/quick.toml"), jobs=2)  # doctest: +SKIP

The model is a picklable top-level function ``evaluate(design, phantom, settings) -> dict`` (default: the
study's ``model``, ``latticeopt.coupled:evaluate_phantom``); see :func:`result_to_evaluation` for the keys it
returns. Workers only compute; the parent process is the store's single writer and commits each result in its
own transaction the moment it arrives, so a sweep killed at any point resumes where it stopped and recomputes
nothing stored. Tasks go out design-major (all phantoms of one design, then the next) through a window of a
few tasks per worker, so each worker keeps meeting the design whose mesh and reference it has just loaded.

Failures. A :class:`~latticeopt.errors.ModelFailure` (:class:`ConvergenceError`, :class:`MeshError`, or a
custom model's own subclass), a PARDISO factorization that hit a zero pivot or a singular matrix, or a
non-finite ``V_rel`` is a *failed phantom*: stored as a ``'failed'`` row with its message and traceback, and
the sweep goes on. Any other exception (``ValueError``, ``IndexError``, ``NotImplementedError``, a model
returning no ``v_rel``, a broken worker pool, ...) is a bug, not a property of the design: recording it as a
failure would bias every comparison, so the sweep stores what has arrived, appends the traceback to
``error.log`` in the output folder and raises :class:`~latticeopt.errors.ModelBugError` with a one-line
message. How failed phantoms enter the tables: :mod:`latticeopt.study.report`.

Backends (joblib, :mod:`latticeopt.study.execution`). ``"local"``: with ``jobs == 1`` the tasks run in this
process; with more, in loky worker processes started with ``OMP/MKL/OPENBLAS_NUM_THREADS=1``, so BLAS/MKL
start single-threaded in every worker (each result records the thread counts the worker's loaded BLAS/OpenMP
libraries report; more than one is logged as a warning), and kept for the next run of this process.
``"dask"``: joblib's dask backend on the cluster at ``scheduler`` (an address or a ``Client``); without one, a
local cluster of ``jobs`` single-threaded worker processes.
"""

from __future__ import annotations

import contextlib
import dataclasses
import importlib
import json
import logging
import signal
import threading
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import AllFailedError, LatticeoptError, ModelBugError, ParameterError
from .config import Study
from .execution import BACKENDS, blas_threads, run_tasks
from .settings import EvalSettings
from .store import Evaluation, ResultStore, folder_lock
from .worker import FAILURE_TYPES, evaluate_chunk, is_model_failure, result_to_evaluation

__all__ = ["BACKENDS", "ERROR_LOG", "FAILURE_TYPES", "SweepResult", "blas_threads", "evaluate_designs",
           "is_model_failure", "resolve_model", "result_to_evaluation", "run_sweep"]

log = logging.getLogger(__name__)

#: File in the output folder that collects the tracebacks of exceptions that stopped a run.
ERROR_LOG = "error.log"
#: Phantoms per task for models with a ``prepare`` hook (see :func:`evaluate_chunk`).
CHUNK_PHANTOMS = 4


def _chunks(todo, tasks, size: int) -> list[list[int]]:
    """Split task indices into runs of at most ``size`` consecutive tasks of one design (tasks are design-major)."""
    out: list[list[int]] = []
    for i in todo:
        if out and len(out[-1]) < size and tasks[out[-1][0]][0] == tasks[i][0]:
            out[-1].append(i)
        else:
            out.append([i])
    return out


def resolve_model(name: str) -> Callable:
    """Import ``"module:function"`` (the study's ``model``)."""
    module, _, func = name.partition(":")
    try:
        return getattr(importlib.import_module(module), func)
    except (ImportError, AttributeError) as exc:
        raise ParameterError("model", "an importable 'module:function' evaluating one phantom",
                             f"{name} ({exc})") from None


def _model_name(fn: Callable) -> str:
    return f"{fn.__module__}:{fn.__qualname__}"


def _write_error_log(out_dir: Path, header: str, text: str) -> Path:
    """Append a stamped traceback to ``out_dir/error.log``; return its path."""
    path = Path(out_dir) / ERROR_LOG
    with open(path, "a") as fh:
        fh.write(f"--- {time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime())} {header}\n{text.rstrip()}\n\n")
    return path


def _model_bug(out_dir: Path, settings: EvalSettings, stored: int, design, phantom, payload: dict) -> ModelBugError:
    """Log a bug payload's traceback and build the one-line error that stops the run."""
    if payload.get("where") == "prepare":
        what = f"preparing {design.describe()} (the model's per-design set-up)"
    else:
        where = "checking the result of" if payload.get("where") == "result" else "evaluating"
        what = f"{where} phantom {phantom.index} ({phantom.n_touches} touches) of {design.describe()}"
    first = (payload["error"].splitlines() or [""])[0]
    worker = payload.get("worker", {})
    path = _write_error_log(out_dir, f"model {settings.model}, {what}, worker {worker.get('host', '?')}:"
                                     f"{worker.get('pid', '?')}", payload.get("traceback") or payload["error"])
    return ModelBugError(f"{first} while {what} (model {settings.model}): not a ModelFailure, so a bug; the run "
                         f"stopped with {stored} results stored this run; traceback in {path}")


@contextlib.contextmanager
def _sigterm_as_interrupt():
    """Let ``kill PID`` stop a sweep like Ctrl-C does (in the main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        raise KeyboardInterrupt(f"signal {signum}")

    old = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


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
        Write CSV tables and figures at the end (:func:`latticeopt.study.report.write_outputs`).
    """
    t_start = time.perf_counter()
    settings = study.settings
    if evaluate is None:
        evaluate = resolve_model(settings.model)
    else:
        settings = dataclasses.replace(settings, model=_model_name(evaluate))
    out = Path(study.out_dir if out_dir is None else out_dir)
    _check_run_args(study.jobs if jobs is None else jobs, backend, scheduler)
    with folder_lock(out):  # one run per folder: a second one refuses rather than compute the same phantoms
        (out / "study.json").write_text(json.dumps({**study.as_dict(), "settings": settings.as_dict(),
                                                    "settings_key": settings.key}, indent=1, default=str))
        run = dict(jobs=study.jobs if jobs is None else jobs, backend=backend, scheduler=scheduler,
                   progress=progress, retry_failed=retry_failed)
        ml = ad = None
        if study.multilevel is not None:  # coarse on every phantom, fine on a nested subset
            from .multilevel_sweep import run_multilevel

            ml = run_multilevel(study, settings, out, evaluate, **run)
            evaluations, computed = ml.coarse, ml.computed_coarse + ml.computed_fine
        elif study.adaptive is not None:  # per design a prefix of one common order, until its SE meets the target
            from .adaptive_sweep import run_adaptive

            ad = run_adaptive(study, settings, out, evaluate, **run)
            evaluations, computed = ad.rows(), ad.computed
        else:
            evaluations, computed = evaluate_designs(study.designs, study.phantoms, settings, out, evaluate,
                                                     label=study.name, **run)
        files, report = {}, ()
        if outputs and ml is not None:
            from .multilevel_report import write_multilevel_outputs

            files, report = write_multilevel_outputs(study, ml, out)
        elif outputs and ad is not None:
            from .adaptive_report import write_adaptive_outputs

            files, report = write_adaptive_outputs(study, ad, out)
        elif outputs:
            from .report import write_outputs

            files, report = write_outputs(study, evaluations, out)
    total = len(evaluations) + (len(ml.fine) if ml is not None else 0)
    result = SweepResult(study=study, settings=settings, out_dir=out, evaluations=evaluations, computed=computed,
                         skipped=total - computed, seconds=time.perf_counter() - t_start, outputs=files,
                         report=tuple(report), multilevel=ml, adaptive=ad)
    if evaluations and result.failed == len(evaluations):
        raise AllFailedError(all_failed_message(evaluations, computed, out, "results.csv" if outputs else None),
                             result)
    return result


def all_failed_message(evaluations, computed: int, out: Path, table: str | None) -> str:
    """One line for a run in which every evaluation failed: how many, the first error, where the rest are."""
    first = next(((e.error or "").splitlines()[:1] for e in evaluations), [""])
    where = f"every error is in {Path(out) / table}" if table else f"every error is in {Path(out) / 'results.sqlite'}"
    return (f"every one of the {len(evaluations)} evaluations failed ({computed} computed now, the rest read from "
            f"the store), so there is nothing to compare; the first: {first[0] if first else ''}; {where} "
            "(--retry-failed runs them again)")


def _check_run_args(jobs, backend, scheduler) -> None:
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise ParameterError("jobs", "an integer >= 1", jobs)
    if backend not in BACKENDS:
        raise ParameterError("backend", "one of " + ", ".join(map(repr, BACKENDS)), backend)
    if backend == "local" and scheduler is not None:
        raise ParameterError("scheduler", "no scheduler with backend 'local' (use backend 'dask')", scheduler)


def evaluate_designs(designs, phantoms, settings: EvalSettings, out_dir: str | Path, evaluate: Callable | None = None,
                     *, jobs: int = 1, backend: str = "local", scheduler=None, progress: bool = False,
                     retry_failed: bool = False, label: str = "evaluate") -> tuple[tuple[Evaluation, ...], int]:
    """Evaluate every design on every phantom through the store in ``out_dir``; compute only what is missing.

    The engine under :func:`run_sweep`, also meant for the optimizer: a design already evaluated (same
    design, phantom and settings keys) is read from the store, not recomputed.

    Parameters
    ----------
    designs, phantoms
        Sequences of :class:`LatticeDesign` and :class:`Phantom`; tasks run design-major.
    settings
        The evaluation settings; ``settings.model`` must name ``evaluate`` when that is given (its key is
        stored with every row).
    out_dir
        Folder of the results store.
    evaluate
        The model; ``None`` imports ``settings.model``.
    jobs, backend, scheduler, progress, retry_failed
        As in :func:`run_sweep`.
    label
        Name used in log messages.

    Returns
    -------
    evaluations : tuple of Evaluation
        One per (design, phantom), design-major.
    computed : int
        How many were computed now (the rest came from the store).
    """
    _check_run_args(jobs, backend, scheduler)
    if evaluate is None:
        evaluate = resolve_model(settings.model)
    tasks = [(d, p) for d in designs for p in phantoms]
    dkeys = [d.content_hash() for d in designs]
    skey = settings.key
    keys = [(dk, p.key, skey) for dk in dkeys for p in phantoms]
    with folder_lock(out_dir), ResultStore(out_dir) as store:
        done = store.done_keys(settings.key, include_failed=not retry_failed)
        todo, seen = [], set(done)
        for i, k in enumerate(keys):
            if k not in seen:  # a task listed twice is computed once
                todo.append(i)
                seen.add(k)
        log.info("%s: %d tasks, %d stored, %d to run", label, len(tasks), len(tasks) - len(todo), len(todo))
        if todo:
            _execute(tasks, todo, evaluate, settings, store, backend, jobs, scheduler, progress)
        stored = store.lookup(keys)
    missing = sum(k not in stored for k in keys)
    if missing:  # only possible if the store was changed under us
        raise LatticeoptError(f"{missing} evaluations missing from {store.path} after the run; run it again")
    return tuple(stored[k] for k in keys), len(todo)


def _execute(tasks, todo, evaluate, settings, store, backend, jobs, scheduler, progress) -> None:
    from tqdm.auto import tqdm

    bar = tqdm(total=len(tasks), initial=len(tasks) - len(todo), unit="phantom", disable=not progress,
               dynamic_ncols=True, desc="sweep")
    # Phantoms of one design go to a worker together so the model's per-design set-up is paid once per chunk;
    # small chunks keep the store fresh (a kill loses at most the chunks in flight).
    chunk_size = CHUNK_PHANTOMS if getattr(evaluate, "prepare", None) is not None else 1
    chunks = ((chunk, (evaluate, tasks[chunk[0]][0], [tasks[i][1] for i in chunk], settings))
              for chunk in _chunks(todo, tasks, chunk_size))
    failed = stored = 0
    warned_threads = False
    try:
        with _sigterm_as_interrupt(), contextlib.closing(run_tasks(evaluate_chunk, chunks, backend=backend,
                                                                   jobs=jobs, scheduler=scheduler)) as results:
            for chunk, payloads in results:
                # The chunk's phantoms before a bug are stored before it stops the sweep.
                bug = None
                for i, payload in zip(chunk, payloads):  # a bug payload ends its chunk early
                    design, phantom = tasks[i]
                    if payload["status"] == "bug":
                        bug = (design, phantom, payload)
                        break
                    try:
                        row = result_to_evaluation(payload, design, phantom, settings)
                    except LatticeoptError as exc:  # the model broke its contract: a bug as well
                        bug = (design, phantom, {"error": str(exc), "where": "result",
                                                 "traceback": traceback.format_exc()})
                        break
                    store.put(row)
                    stored += 1
                    failed += not row.ok
                    if not row.ok:
                        log.warning("phantom %d of %s failed: %s", phantom.index, design.describe(),
                                    (row.error or "").splitlines()[0])
                    many = {k: n for k, n in payload["worker"]["blas_threads"].items() if n > 1}
                    if many and (jobs > 1 or backend == "dask") and not warned_threads:
                        log.warning("worker %s runs BLAS/OpenMP with more than one thread: %s",
                                    payload["worker"]["pid"], many)
                        warned_threads = True
                    bar.update(1)
                    bar.set_postfix(failed=failed, refresh=False)
                if bug is not None:
                    raise _model_bug(store.path.parent, settings, stored, *bug)
    except KeyboardInterrupt:
        log.warning("interrupted: every finished phantom is stored in %s; run the same command to resume",
                    store.path)
        raise
    except ModelBugError:
        raise
    except Exception as exc:  # the machinery itself (a worker killed, a result that does not unpickle, ...)
        path = _write_error_log(store.path.parent, f"sweep stopped: model {settings.model}", traceback.format_exc())
        first = (f"{type(exc).__name__}: {exc}".splitlines() or [""])[0]
        raise ModelBugError(f"sweep stopped by {first} ({stored} results stored this run); traceback in "
                            f"{path}") from None
    finally:
        bar.close()
