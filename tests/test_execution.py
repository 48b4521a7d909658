"""``run_tasks``: every task once, workers reused only while the environment holds, early stop kills them."""

from __future__ import annotations

import contextlib
import os
import time
import warnings

import numpy as np
import pytest

from latticeopt.execution import run_tasks

ENV = "LATTICEOPT_TEST_EXECUTION"


#: when this module was imported: in a worker, when that worker took its first task of this module
_BORN = time.time()


def _square(x: int) -> tuple[int, int, str | None, float]:
    return x * x, os.getpid(), os.environ.get(ENV), _BORN


def _sleep(seconds: float) -> int:
    time.sleep(seconds)
    return os.getpid()


#: What a worker keeps between tasks (a sweep worker keeps its last design's model)
_KEPT: dict = {}


def _keep(megabytes: int) -> int:
    _KEPT["model"] = np.ones(megabytes * 131072)  # float64: 131072 per MB
    time.sleep(1.1)  # loky checks a worker's memory at most once a second, after a task
    return os.getpid()


def _raise(x: int) -> int:
    raise IndexError(f"task {x}")


def _collect(fn, args, jobs):
    out = {}
    with contextlib.closing(run_tasks(fn, ((i, a) for i, a in enumerate(args)), jobs=jobs)) as results:
        for tag, result in results:
            assert tag not in out
            out[tag] = result
    return out


def _gone(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] == "Z"
    except FileNotFoundError:
        return True


def test_every_task_once_in_workers_as_inline():
    args = [(x,) for x in range(20)]
    inline = _collect(_square, args, 1)
    pooled = _collect(_square, args, 2)
    assert {k: v[0] for k, v in pooled.items()} == {k: v[0] for k, v in inline.items()} == {
        i: i * i for i in range(20)}
    assert {v[1] for v in inline.values()} == {os.getpid()}
    assert os.getpid() not in {v[1] for v in pooled.values()}


def test_workers_are_reused_while_the_environment_holds_and_restarted_when_it_changes(monkeypatch):
    # judged by when each worker was born, not by which pids the first call happened to use: on a loaded machine
    # one worker can take all of a call's quick tasks while the other is still starting
    monkeypatch.setenv(ENV, "a")
    first = _collect(_square, [(x,) for x in range(8)], 2)
    t_again = time.time()
    again = _collect(_square, [(x,) for x in range(8)], 2)
    assert {v[1] for v in again.values()} & {v[1] for v in first.values()}
    assert max(v[3] for v in again.values()) < t_again  # no worker started for the second call
    assert {v[2] for v in again.values()} == {"a"}
    monkeypatch.setenv(ENV, "b")  # a worker started before cannot see it: fresh workers
    t_changed = time.time()
    changed = _collect(_square, [(x,) for x in range(8)], 2)
    assert {v[2] for v in changed.values()} == {"b"}
    assert min(v[3] for v in changed.values()) > t_changed
    assert not {v[1] for v in changed.values()} & {v[1] for v in [*first.values(), *again.values()]}


def test_stopping_early_kills_the_running_workers():
    gen = run_tasks(_sleep, ((i, a) for i, a in enumerate([(0.0,), (60.0,), (60.0,), (60.0,)])), jobs=2)
    _, pid = next(gen)
    t0 = time.monotonic()
    gen.close()
    while not _gone(pid) and time.monotonic() - t0 < 20:
        time.sleep(0.05)
    assert _gone(pid) and time.monotonic() - t0 < 20  # not after its 60 s task


@pytest.mark.parametrize("jobs", [1, 2])
def test_a_task_exception_reaches_the_caller_with_its_type(jobs):
    with pytest.raises(IndexError, match="task"):
        _collect(_raise, [(x,) for x in range(4)], jobs)


def test_a_worker_replaced_for_its_kept_memory_loses_no_task_and_warns_nothing():
    # loky replaces a worker whose memory grew 300 MB past its size after its first task; with tasks queued it
    # warned "A worker stopped while some jobs were given to the executor" (a sweep's worker growing from a
    # coarse-level model to a fine one did so between rounds): routine, so not shown
    sizes = [0, 0] + [400] * 6
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        pids = _collect(_keep, [(mb,) for mb in sizes], 2)
    assert sorted(pids) == list(range(len(sizes)))
    assert len(set(pids.values())) > 2  # a worker was replaced: the situation loky warns about arose
    assert not [w for w in caught if "A worker stopped" in str(w.message)]
