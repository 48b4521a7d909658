"""Where a sweep's tasks run: in this process, in a local process pool, or on a dask.distributed cluster.

:func:`run_tasks` is the one loop every parallel stage uses (sweeps, the sensor model's pixel solves, the
gesture frames): it keeps a window of tasks in flight, hands back results as they finish, and stops the workers
when the caller stops early or fails. Each backend under it offers ``submit(fn, *args) -> future``,
``wait_any(pending) -> done futures``, ``window`` (tasks worth keeping in flight) and
``close(abort)``; :func:`make_backend` picks one. Local worker processes are started fresh (``spawn``) while
``OMP/MKL/OPENBLAS_NUM_THREADS=1`` is set in the environment they inherit, so their BLAS/MKL libraries load
single-threaded; :func:`blas_threads` asks the loaded libraries what they actually use, so the runner can check.
Dask's nanny starts its workers with the same variables set to 1 (``distributed.nanny.pre-spawn-environ``).
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import ctypes
import logging
import multiprocessing
import os
import re
import signal
from pathlib import Path

from ..errors import LatticeoptError, ParameterError

__all__ = ["BACKENDS", "blas_threads", "make_backend", "run_tasks"]

BACKENDS = ("local", "dask")
#: Tasks kept in flight per worker: one running, one queued so the worker never waits for the parent.
_INFLIGHT_PER_WORKER = 2
_THREAD_VARS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "VECLIB_MAXIMUM_THREADS",
                "NUMEXPR_NUM_THREADS")
_BLAS_GETTERS = ("scipy_openblas_get_num_threads64_", "scipy_openblas_get_num_threads", "openblas_get_num_threads64_",
                 "openblas_get_num_threads", "MKL_Get_Max_Threads", "omp_get_max_threads")


def blas_threads() -> dict[str, int]:
    """Thread counts reported by the BLAS/MKL/OpenMP libraries loaded in this process (Linux; else ``{}``).

    Returns
    -------
    dict
        ``"library:getter" -> threads`` for every loaded OpenBLAS, MKL runtime and OpenMP runtime.
    """
    maps = Path("/proc/self/maps")
    if not maps.exists():
        return {}
    out: dict[str, int] = {}
    paths = {line.split()[-1] for line in maps.read_text().splitlines() if len(line.split()) >= 6}
    for path in sorted(paths):
        if not re.search(r"openblas|mkl_rt|libgomp|libiomp|libomp", os.path.basename(path)):
            continue
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for sym in _BLAS_GETTERS:
            fn = getattr(lib, sym, None)
            if fn is not None:
                fn.restype = ctypes.c_int
                out[f"{os.path.basename(path)}:{sym}"] = int(fn())
                break
    return out


def _worker_init() -> None:
    # Ctrl-C goes to the whole process group; only the parent should react (it stops the workers itself).
    signal.signal(signal.SIGINT, signal.SIG_IGN)


@contextlib.contextmanager
def _single_thread_env():
    """Set the BLAS/OpenMP thread variables to 1 while worker processes are started (they inherit them)."""
    saved = {k: os.environ.get(k) for k in _THREAD_VARS}
    os.environ.update({k: "1" for k in _THREAD_VARS})
    try:
        yield
    finally:
        for k, val in saved.items():
            if val is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = val


def _pid(_: object) -> int:
    return os.getpid()


class _Inline:
    """jobs == 1: run each task in this process when its result is asked for."""

    window = 1  # each task runs when submitted: one at a time keeps every result handed back at once

    def submit(self, fn, *args):
        fut: cf.Future = cf.Future()
        fut.set_result(fn(*args))
        return fut

    def wait_any(self, pending):
        return set(pending)

    def close(self, abort: bool) -> None:
        pass


class _Pool:
    def __init__(self, jobs: int):
        self.window = _INFLIGHT_PER_WORKER * jobs
        with _single_thread_env():
            self._ex = cf.ProcessPoolExecutor(max_workers=jobs, mp_context=multiprocessing.get_context("spawn"),
                                              initializer=_worker_init)
            # start the workers now, while the environment says one thread
            list(self._ex.map(_pid, range(jobs)))

    def submit(self, fn, *args):
        return self._ex.submit(fn, *args)

    def wait_any(self, pending):
        return cf.wait(pending, return_when=cf.FIRST_COMPLETED).done

    def close(self, abort: bool) -> None:
        if abort:
            procs = list(getattr(self._ex, "_processes", {}).values())  # no public way to stop running tasks
            manager = getattr(self._ex, "_executor_manager_thread", None)  # shutdown() forgets it
            self._ex.shutdown(wait=False, cancel_futures=True)
            for p in procs:
                p.terminate()
            for p in procs:
                p.join(5)
            if manager is not None:
                # CPython 3.11's exit hook can write to this thread's wakeup pipe while the thread closes it (a
                # stray "Bad file descriptor" traceback after Ctrl-C, seen once in CI): let it finish first
                manager.join(5)
        else:
            self._ex.shutdown(wait=True)


class _Dask:
    def __init__(self, jobs: int, scheduler):
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
        self._own = []
        if scheduler is None:
            cluster = LocalCluster(n_workers=jobs, threads_per_worker=1, processes=True, dashboard_address=None)
            self._own.append(cluster)
            self.client = Client(cluster)
            self._own.insert(0, self.client)
        elif isinstance(scheduler, str):
            try:
                self.client = Client(scheduler, timeout="30s")
            except (OSError, TimeoutError) as exc:
                raise LatticeoptError(f"cannot reach the dask scheduler at {scheduler!r}: {exc}") from None
            self._own.append(self.client)
        else:
            self.client = scheduler
        n = sum(w.get("nthreads", 1) for w in self.client.scheduler_info()["workers"].values())
        self.window = _INFLIGHT_PER_WORKER * max(n, 1)

    def submit(self, fn, *args):
        return self.client.submit(fn, *args, pure=False)

    def wait_any(self, pending):
        from distributed import wait

        return wait(list(pending), return_when="FIRST_COMPLETED").done

    def close(self, abort: bool) -> None:
        for obj in self._own:
            obj.close()


def make_backend(backend: str, jobs: int, scheduler):
    if backend == "dask":
        return _Dask(jobs, scheduler)
    return _Inline() if jobs == 1 else _Pool(jobs)


def run_tasks(fn, tasks, *, backend: str = "local", jobs: int = 1, scheduler=None):
    """Run ``fn(*args)`` for every ``(tag, args)`` of ``tasks`` and yield the results as they finish.

    Parameters
    ----------
    fn
        A picklable top-level function.
    tasks
        Iterable of ``(tag, args)``, consumed lazily: at most the backend's ``window`` tasks are in flight
        (two per worker; one in this process with ``jobs == 1``), so a long task list is never all queued
        and a killed run loses only the tasks in flight.
    backend, jobs, scheduler
        As for :func:`make_backend`.

    Yields
    ------
    list of (tag, result)
        The tasks that finished since the last yield, all of them, so a caller that must stop (a bug in one
        result) can still keep the others.

    Notes
    -----
    Use it as ``with contextlib.closing(run_tasks(...)) as batches:``: leaving the block early (an exception,
    Ctrl-C, ``break``) stops the workers at once; a worker's exception is raised from ``fut.result()`` here,
    after which the workers are stopped as well.
    """
    runner = make_backend(backend, jobs, scheduler)
    queue = iter(tasks)
    pending: dict = {}
    aborted = True
    try:
        while True:
            while len(pending) < runner.window:
                item = next(queue, None)
                if item is None:
                    break
                tag, args = item
                pending[runner.submit(fn, *args)] = tag
            if not pending:
                break
            done = runner.wait_any(pending)
            yield [(pending.pop(fut), fut.result()) for fut in done]
        aborted = False
    finally:
        runner.close(abort=aborted)

