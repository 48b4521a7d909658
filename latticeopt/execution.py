"""Where parallel tasks run: joblib, with loky worker processes here or a dask.distributed cluster.

:func:`run_tasks` is the one loop every parallel stage uses (sweeps, the sensor model's pixel solves, the
gesture frames): :class:`joblib.Parallel` hands back results as they finish, keeps two tasks per worker
dispatched, and stops the workers when the caller stops early or a task fails. Local workers are loky processes,
kept for the next run while this process's environment is unchanged (the one thing they inherit at start), started
with ``OMP/MKL/OPENBLAS_NUM_THREADS=1`` (``inner_max_num_threads=1``), so their BLAS/MKL libraries load
single-threaded, and ignoring Ctrl-C, which the parent handles; :func:`blas_threads` asks the loaded libraries
what they actually use, so the runner can check. Dask's nanny starts its workers with the same variables set
to 1 (``distributed.nanny.pre-spawn-environ``).

It sits beside the physics core, not in :mod:`latticeopt.study`, so the sensor simulator and the gesture
frames use it without importing the orchestration.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import signal
import warnings

from .errors import LatticeoptError, ParameterError

__all__ = ["BACKENDS", "blas_threads", "dask_client", "run_tasks"]

BACKENDS = ("local", "dask")
#: Tasks kept in flight per worker: one running, one queued so the worker never waits for the parent.
_INFLIGHT_PER_WORKER = 2
#: What loky says when it replaces a worker whose memory grew 300 MB past its size after its first task while
#: tasks were queued. A sweep worker keeps the last design's model (:mod:`latticeopt.study.worker`), which can
#: outgrow that (a fine-level model after a coarse one): loky's guard then starts a fresh worker, no task is lost,
#: and the new worker builds the model again (a few seconds; 11 replacements in the paper map's 2 h fine pass).
#: That is routine, not a fault to warn about.
_LOKY_REPLACED_WORKER = "A worker stopped while some jobs were given to the executor"


def blas_threads() -> dict[str, int]:
    """Thread counts reported by the BLAS/MKL/OpenMP libraries loaded in this process (threadpoolctl).

    Returns
    -------
    dict
        ``"library file:internal API" -> threads`` (``"libmkl_rt.so.3:mkl" -> 1``) for every loaded OpenBLAS,
        MKL, BLIS and OpenMP runtime.
    """
    from threadpoolctl import threadpool_info

    return {f"{os.path.basename(lib['filepath'])}:{lib['internal_api']}": int(lib["num_threads"])
            for lib in threadpool_info()}


def _worker_init(environment: str) -> None:
    """Start a loky worker; ``environment`` is the parent's :func:`_environment_key` (loky reuses its workers
    for later runs only while their start arguments, and so the environment they inherited, are the same)."""
    # Ctrl-C goes to the whole process group; only the parent should react (it stops the workers itself).
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _environment_key() -> str:
    return hashlib.sha256(repr(sorted(os.environ.items())).encode()).hexdigest()


def _tagged(fn, tag, args):
    return tag, fn(*args)


@contextlib.contextmanager
def dask_client(jobs: int, scheduler):
    """A dask.distributed client and its worker thread count; closes what it started.

    Parameters
    ----------
    jobs
        Workers of the local cluster started when ``scheduler`` is ``None``.
    scheduler
        ``None`` (a local cluster), a scheduler address (``"tcp://host:8786"``) or a ``distributed.Client``.

    Yields
    ------
    (distributed.Client, int)
    """
    try:
        from distributed import Client, LocalCluster
    except ImportError as exc:
        raise ParameterError("backend", "'local', or 'dask' with dask.distributed installed "
                             "(pip install 'dask[distributed]')", f"dask ({exc})") from None
    # distributed sets its loggers to INFO when imported: some 30 lines of scheduler and nanny chatter per
    # run. They follow this process's level instead (WARNING unless `latticeopt -v`).
    if not logging.getLogger().isEnabledFor(logging.INFO):
        for name in ("distributed", "dask"):
            logging.getLogger(name).setLevel(logging.WARNING)
    with contextlib.ExitStack() as own:
        if scheduler is None:
            cluster = own.enter_context(LocalCluster(n_workers=jobs, threads_per_worker=1, processes=True,
                                                     dashboard_address=None))
            client = own.enter_context(Client(cluster))
        elif isinstance(scheduler, str):
            try:
                client = own.enter_context(Client(scheduler, timeout="30s"))
            except (OSError, TimeoutError) as exc:
                raise LatticeoptError(f"cannot reach the dask scheduler at {scheduler!r}: {exc}") from None
        else:
            client = scheduler
        yield client, sum(w.get("nthreads", 1) for w in client.scheduler_info()["workers"].values())


def run_tasks(fn, tasks, *, backend: str = "local", jobs: int = 1, scheduler=None):
    """Run ``fn(*args)`` for every ``(tag, args)`` of ``tasks`` and yield the results as they finish.

    Parameters
    ----------
    fn
        A picklable top-level function.
    tasks
        Iterable of ``(tag, args)``, consumed lazily: at most two tasks per worker are dispatched at a time (one
        with ``jobs == 1``, which runs each task in this process), so a long task list is never all queued
        and a killed run loses only the tasks in flight.
    backend
        ``"local"``: ``jobs`` loky worker processes (none for ``jobs == 1``); ``"dask"``: the workers of
        ``scheduler`` (:func:`dask_client`).
    jobs, scheduler
        Worker processes; dask scheduler (``None``: a local cluster of ``jobs`` workers).

    Yields
    ------
    (tag, result)
        Each task as it finishes.

    Notes
    -----
    Use it as ``with contextlib.closing(run_tasks(...)) as results:``: leaving the block early (an exception,
    Ctrl-C, ``break``) stops the workers at once (loky kills its processes, dask cancels the tasks); a worker's
    exception is raised here with its type, after which the workers are stopped as well.
    """
    import joblib

    with contextlib.ExitStack() as stack:
        if backend == "dask":
            client, n = stack.enter_context(dask_client(jobs, scheduler))
            stack.enter_context(joblib.parallel_config(backend="dask", client=client))
        else:
            n = jobs
            # loky's manager thread warns in this process; one filter, replaced (not stacked) on every call
            warnings.filterwarnings("ignore", message=_LOKY_REPLACED_WORKER, category=UserWarning)
            stack.enter_context(joblib.parallel_config(backend="loky", inner_max_num_threads=1,
                                                       initializer=_worker_init, initargs=(_environment_key(),),
                                                       max_nbytes=None))
        n = max(n, 1)
        parallel = joblib.Parallel(n_jobs=n, return_as="generator_unordered", batch_size=1,
                                   pre_dispatch=str(_INFLIGHT_PER_WORKER * n))
        outputs = parallel(joblib.delayed(_tagged)(fn, tag, args) for tag, args in tasks)
        try:
            # not `yield from`: closing would then close joblib's generator before the warning filter below
            for result in outputs:  # noqa: UP028
                yield result
        finally:
            with warnings.catch_warnings():
                # joblib warns that closing early cancels the running tasks: stopping them is the point
                warnings.simplefilter("ignore")
                outputs.close()
