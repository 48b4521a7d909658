"""The sweep engine: evaluate designs on phantoms through the results store, in parallel, resumably.

Every estimator (:mod:`latticeopt.study.estimators`: plain, two-level, adaptive) and the optimizer run their
evaluations through :func:`evaluate_designs`; this module imports none of them.

The model is a picklable top-level function ``evaluate(design, phantom, settings) -> dict`` (default: the
study's ``model``, ``latticeopt.coupled:evaluate_phantom``, found by :func:`resolve_model`); see
:func:`~latticeopt.study.worker.result_to_evaluation` for the keys it returns. Workers only compute; the parent
process is the store's single writer and commits each result in its own transaction the moment it arrives, so a
run killed at any point resumes where it stopped and recomputes nothing stored. Tasks go out design-major (all
phantoms of one design, then the next) through a window of a few tasks per worker, so each worker keeps meeting
the design whose mesh and reference it has just loaded.

Failures. A :class:`~latticeopt.errors.ModelFailure` (:class:`ConvergenceError`, :class:`MeshError`, or a
custom model's own subclass), a PARDISO factorization that hit a zero pivot or a singular matrix, or a
non-finite ``V_rel`` is a *failed phantom*: stored as a ``'failed'`` row with its message and traceback, and
the run goes on. Any other exception (``ValueError``, ``IndexError``, ``NotImplementedError``, a model
returning no ``v_rel``, a broken worker pool, ...) is a bug, not a property of the design: recording it as a
failure would bias every comparison, so the engine stores what has arrived, appends the traceback to
``error.log`` in the output folder and raises :class:`~latticeopt.errors.ModelBugError` with a one-line
message.

Backends (joblib, :mod:`latticeopt.execution`). ``"local"``: with ``jobs == 1`` the tasks run in this
process; with more, in loky worker processes started with ``OMP/MKL/OPENBLAS_NUM_THREADS=1``, so BLAS/MKL
start single-threaded in every worker (each result records the thread counts the worker's loaded BLAS/OpenMP
libraries report; more than one is logged as a warning), and kept for the next run of this process.
``"dask"``: joblib's dask backend on the cluster at ``scheduler`` (an address or a ``Client``); without one, a
local cluster of ``jobs`` single-threaded worker processes.
"""

from __future__ import annotations

import contextlib
import importlib
import logging
import signal
import threading
import time
import traceback
from collections.abc import Callable
from pathlib import Path

from ..errors import LatticeoptError, ModelBugError, ParameterError
from ..execution import BACKENDS, run_tasks
from .settings import EvalSettings
from .store import Evaluation, ResultStore, folder_lock
from .worker import evaluate_chunk, forget_prepared, result_to_evaluation

__all__ = ["BACKENDS", "CHUNK_PHANTOMS", "ERROR_LOG", "check_run_args", "evaluate_designs", "model_name",
           "resolve_model", "run_prefixes", "write_error_log"]

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


def model_name(fn: Callable) -> str:
    return f"{fn.__module__}:{fn.__qualname__}"


def write_error_log(out_dir: Path, header: str, text: str) -> Path:
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
    path = write_error_log(out_dir, f"model {settings.model}, {what}, worker {worker.get('host', '?')}:"
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


def check_run_args(jobs, backend, scheduler) -> None:
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

    What every estimator and the optimizer run: a design already evaluated (same
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
        As in :func:`~latticeopt.study.sweep.run_sweep`.
    label
        Name used in log messages.

    Returns
    -------
    evaluations : tuple of Evaluation
        One per (design, phantom), design-major.
    computed : int
        How many were computed now (the rest came from the store).
    """
    check_run_args(jobs, backend, scheduler)
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


def run_prefixes(designs, phantoms, want: dict, order, settings: EvalSettings, out_dir, into: dict, n, run: dict,
                 label: Callable[[int], str]) -> int:
    """Evaluate design ``i`` on the first ``want[i]`` phantoms of ``order`` for every ``i`` in ``want``.

    The step the two-level and the adaptive estimators repeat. Designs asking for the same prefix run together
    (one :func:`evaluate_designs` call: phantoms already stored are read, the rest computed). Each evaluation
    goes to ``into[(i, j)]`` (position in ``designs``, position in ``phantoms``) and the prefix length to
    ``n[i]``; ``run`` holds the other arguments of :func:`evaluate_designs` and ``label(m)`` names the progress
    bar of an ``m``-phantom prefix. Returns how many evaluations were computed.
    """
    computed = 0
    for m in sorted(set(want.values())):
        group = [i for i in want if want[i] == m]
        rows, done = evaluate_designs([designs[i] for i in group], [phantoms[j] for j in order[:m]],
                                      settings, out_dir, label=label(m), **run)
        computed += done
        for g, i in enumerate(group):
            for k, j in enumerate(order[:m]):
                into[(i, j)] = rows[g * m + k]
            n[i] = m
    return computed


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
        path = write_error_log(store.path.parent, f"sweep stopped: model {settings.model}", traceback.format_exc())
        first = (f"{type(exc).__name__}: {exc}".splitlines() or [""])[0]
        raise ModelBugError(f"sweep stopped by {first} ({stored} results stored this run); traceback in "
                            f"{path}") from None
    finally:
        bar.close()
        if jobs <= 1 and backend != "dask":
            forget_prepared()  # the chunks ran in this process: free the last design's model
