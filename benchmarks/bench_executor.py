"""Cost of the parallel executor itself (``latticeopt.execution.run_tasks``), apart from any model.

Prints, for ``--jobs`` local workers: the wall time of a fresh run whose tasks import the coupled model (worker
start and imports), the same for a second run straight after (reused workers start nothing), the dispatch
overhead per task (``--tiny`` tasks that return at once), the parallel efficiency on ``--busy`` tasks of fixed
CPU work, and the time from stopping a run early to its workers being gone. Operation counts (tasks, distinct worker
processes) are printed beside the times; this machine is noisy, so compare ratios within one run.

    python benchmarks/bench_executor.py --jobs 2
"""

from __future__ import annotations

import argparse
import contextlib
import os
import time

import numpy as np

from latticeopt.execution import run_tasks


def _pid() -> int:
    return os.getpid()


def _import_model() -> int:
    """What a sweep's worker does first: import the coupled model (scikit-fem, pypardiso, numba kernels)."""
    import latticeopt.coupled  # noqa: F401

    return os.getpid()


def _busy(seconds: float) -> int:
    """Fixed CPU work of about ``seconds`` (dense products; single-threaded BLAS in a worker)."""
    a = np.random.default_rng(0).random((200, 200))
    stop = time.process_time() + seconds
    while time.process_time() < stop:
        a = np.tanh(a @ a.T / 200.0)
    return os.getpid()


def _sleep(seconds: float) -> int:
    time.sleep(seconds)
    return os.getpid()


def _run(fn, args_list, jobs):
    t0 = time.perf_counter()
    with contextlib.closing(run_tasks(fn, ((i, a) for i, a in enumerate(args_list)), jobs=jobs)) as results:
        pids = [pid for _, pid in results]
    return time.perf_counter() - t0, len(pids), len(set(pids))


def _alive(pids) -> int:
    n = 0
    for pid in pids:
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.kill(pid, 0)
            with open(f"/proc/{pid}/stat") as fh:  # a zombie is gone for our purpose
                n += fh.read().split()[2] != "Z"
    return n


def _abort(jobs):
    """Start ``2 * jobs`` 30 s sleeps, stop after the first result of a quick task; time until workers die."""
    args = [(0.2,)] + [(30.0,)] * (2 * jobs)
    gen = run_tasks(_sleep, ((i, a) for i, a in enumerate(args)), jobs=jobs)
    pids = {next(gen)[1]}
    time.sleep(0.5)  # the sleeps are running now
    pids |= {int(p) for p in os.listdir("/proc") if p.isdigit() and _is_child(int(p))}
    t0 = time.perf_counter()
    gen.close()
    closed = time.perf_counter() - t0
    while _alive(pids) and time.perf_counter() - t0 < 60:
        time.sleep(0.01)
    return closed, time.perf_counter() - t0, len(pids)


def _is_child(pid: int) -> bool:
    """A worker of this process (its resource tracker, which lives as long as the process, does not count)."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            parent = int(fh.read().rsplit(")", 1)[1].split()[1])
        with open(f"/proc/{pid}/cmdline", "rb") as fh:
            tracker = b"resource_tracker" in fh.read()
    except (OSError, IndexError, ValueError):
        return False
    return parent == os.getpid() and not tracker


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--tiny", type=int, default=400, help="tasks that return at once")
    ap.add_argument("--busy", type=int, default=24, help="tasks of --busy-s CPU seconds each")
    ap.add_argument("--busy-s", type=float, default=0.5)
    args = ap.parse_args()
    j = args.jobs
    rows = []
    wall, n, procs = _run(_import_model, [()] * j, j)
    rows.append(("fresh run importing the model", f"{wall:.2f} s", f"{n} tasks, {procs} workers"))
    wall, n, procs = _run(_import_model, [()] * j, j)
    rows.append(("second run, the same", f"{wall:.3f} s", f"{n} tasks, {procs} workers"))
    wall, n, procs = _run(_pid, [()] * args.tiny, j)
    rows.append(("dispatch per tiny task", f"{1e3 * wall / n:.2f} ms", f"{n} tasks in {wall:.2f} s, {procs} workers"))
    t0 = time.process_time()
    _busy(args.busy_s)
    ideal = args.busy * (time.process_time() - t0) / j
    wall, n, procs = _run(_busy, [(args.busy_s,)] * args.busy, j)
    rows.append(("busy tasks: ideal / wall", f"{ideal / wall:.3f}", f"{n} x {args.busy_s} s CPU, wall {wall:.2f} s "
                 f"(ideal {ideal:.2f} s), {procs} workers"))
    closed, gone, n = _abort(j)
    rows.append(("stop early: close() returns", f"{closed:.3f} s", f"{n} worker processes"))
    rows.append(("stop early: children gone", f"{gone:.3f} s", "running 30 s sleeps killed"))
    width = max(len(r[0]) for r in rows)
    print(f"run_tasks, {j} local workers, load average {os.getloadavg()[0]:.2f}")
    for name, value, ops in rows:
        print(f"  {name:<{width}}  {value:>10}  {ops}")


if __name__ == "__main__":
    main()
