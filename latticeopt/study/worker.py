"""The worker side of a sweep: run the model on phantoms of one design and return every outcome as data.

A :class:`~latticeopt.errors.ModelFailure` (:class:`ConvergenceError`, :class:`MeshError`, or a custom model's
own subclass), a PARDISO factorization that hit a zero pivot or a singular matrix, or a non-finite ``V_rel``
is a failed phantom; any other exception is a bug, returned with its traceback as text (not every exception
survives pickling) so the parent can log it and stop (:mod:`latticeopt.study.sweep`).
"""

from __future__ import annotations

import json
import math
import os
import socket
import threading
import time
import traceback
from collections.abc import Callable

import numpy as np

from .._jsonout import jsonable
from ..errors import LatticeoptError, ModelFailure
from ..execution import blas_threads
from .settings import EvalSettings
from .store import Evaluation

__all__ = ["FAILURE_TYPES", "evaluate_chunk", "forget_prepared", "is_model_failure", "result_to_evaluation"]

#: Exceptions that mean "this phantom failed" (recorded, sweep goes on); anything else is a bug and stops it.
FAILURE_TYPES: tuple[type[BaseException], ...] = (ModelFailure,)
#: PARDISO error codes of a numerically singular tangent (-4: zero pivot, -7: singular diagonal) -- what a
#: badly deformed state produces; the other codes (inconsistent input, out of memory, ...) are bugs.
_PARDISO_SINGULAR = (-4, -7)


def is_model_failure(exc: BaseException) -> bool:
    """Whether ``exc`` means "this phantom failed" (recorded as ``'failed'``) rather than a bug (stops the run).

    True for :data:`FAILURE_TYPES` and for a PARDISO error with a singular-matrix code (the wrapper raises a
    plain ``Exception`` subclass carrying PARDISO's code in ``.value``).
    """
    if isinstance(exc, FAILURE_TYPES):
        return True
    return type(exc).__name__ == "PyPardisoError" and getattr(exc, "value", None) in _PARDISO_SINGULAR


#: The last model a ``prepare`` hook built in this thread: ``(prepare, (design key, settings key), run)``. The executor
#: hands a design's chunks out in turn to the same few workers, so keeping it pays the set-up (meshes, symbolic
#: factorization, reference voltages: about 1.2 s on the paper map's coarse level, 2-6 s on its fine one) once
#: per design and worker instead of once per chunk. Per thread: a dask worker may run two chunks at once.
_last = threading.local()


def forget_prepared() -> None:
    """Drop the model kept for the next chunk of the same design (frees its meshes and factorization)."""
    _last.entry = None


def _prepared(prepare: Callable, design, settings: EvalSettings) -> Callable:
    """``prepare(design, settings)``, or the run kept from the previous chunk of the same design and settings."""
    key = (design.content_hash(), settings.key)
    entry = getattr(_last, "entry", None)
    if entry is not None and entry[0] is prepare and entry[1] == key:
        return entry[2]
    forget_prepared()  # before building the next one: never two models in memory at once
    run = prepare(design, settings)
    _last.entry = (prepare, key, run)
    return run


def _bug_payload(exc: Exception, worker: dict, where: str) -> dict:
    return {"status": "bug", "error": f"{type(exc).__name__}: {exc}", "traceback": traceback.format_exc(),
            "where": where, "worker": worker}


def evaluate_chunk(evaluate: Callable, design, phantoms, settings: EvalSettings) -> list[dict]:
    """Worker side: run the model on phantoms of one design; failures and bugs come back as data.

    A model may expose ``evaluate.prepare(design, settings) -> callable(phantom) -> dict`` to build its
    per-design state (mesh, factorizations, reference) once instead of once per phantom: the callable is kept
    for the next chunk of the same design and settings in this thread (:data:`_last`), so the set-up is paid
    once per worker and design; the callable must give a phantom the same result whatever ran before it. Plain
    functions are called per phantom. If ``prepare`` itself fails, every phantom of the chunk is recorded as
    failed with that error. An exception that is not a model failure (:func:`is_model_failure`) ends the chunk
    with a ``"bug"`` payload carrying its traceback (as text: not every exception survives pickling).
    """
    worker = {"host": socket.gethostname(), "pid": os.getpid(), "blas_threads": blas_threads()}
    t0 = time.perf_counter()
    prepare = getattr(evaluate, "prepare", None)
    try:
        run = _prepared(prepare, design, settings) if prepare is not None else (
            lambda ph: evaluate(design, ph, settings))
        setup_error = None
    except Exception as exc:
        if not is_model_failure(exc):
            return [_bug_payload(exc, worker, "prepare")]
        setup_error = f"{type(exc).__name__}: {exc}\n{traceback.format_exc()}"
    setup = time.perf_counter() - t0
    payloads = []
    for k, phantom in enumerate(phantoms):
        t1 = time.perf_counter()
        if setup_error is not None:
            result, status, error = {}, "failed", setup_error
        else:
            try:
                result = run(phantom)
                status, error = "ok", None
            except Exception as exc:
                if not is_model_failure(exc):
                    payloads.append(_bug_payload(exc, worker, "evaluate"))
                    forget_prepared()  # a model a bug interrupted is not reused
                    break
                result, status = {}, "failed"
                error = f"{type(exc).__name__}: {exc}\n{traceback.format_exc()}"
        # the set-up (when this chunk paid it) is charged to its first phantom, so summed seconds stay the real cost
        seconds = time.perf_counter() - t1 + (setup if k == 0 else 0.0)
        payloads.append({"status": status, "result": result, "error": error, "seconds": seconds,
                         "worker": worker})
    return payloads


def result_to_evaluation(payload: dict, design, phantom, settings: EvalSettings) -> Evaluation:
    """Turn a worker's payload into a store row, checking the model's return value.

    The model returns a dict with ``v_rel`` (float, required) and optionally ``voltages`` (array, V),
    ``forces_N`` (one per touch, N), ``timings`` (name -> s); any other keys are kept in ``extra``. A
    non-finite ``v_rel`` makes the row ``'failed'``; a missing ``v_rel`` or a non-dict is a bug
    (:class:`LatticeoptError`).
    """
    common = dict(design_key=design.content_hash(), phantom_key=phantom.key, settings_key=settings.key,
                  seconds=payload["seconds"], design=design.as_dict(), phantom=phantom.as_dict(),
                  settings=settings.as_dict(), host=payload["worker"]["host"])
    if payload["status"] == "failed":
        return Evaluation(status="failed", error=payload["error"], extra={"worker": payload["worker"]}, **common)
    res = payload["result"]
    if not isinstance(res, dict) or "v_rel" not in res:
        raise LatticeoptError(f"model {settings.model} returned {type(res).__name__} without 'v_rel' for "
                              f"phantom {phantom.index} of {design.describe()}")
    extra = {k: _jsonable_or_note(val) for k, val in res.items() if k not in ("v_rel", "voltages", "forces_N",
                                                                             "timings")}
    extra["worker"] = payload["worker"]
    forces = tuple(float(f) for f in np.atleast_1d(np.asarray(res.get("forces_N", ()), dtype=float)))
    volts = res.get("voltages")
    volts = None if volts is None else np.asarray(volts, dtype=float).ravel()
    v_rel = float(res["v_rel"])
    if not math.isfinite(v_rel):
        return Evaluation(status="failed", error=f"non-finite v_rel {v_rel!r}", forces_N=forces,
                          timings=dict(res.get("timings", {})), voltages=volts, extra=extra, **common)
    return Evaluation(status="ok", v_rel=v_rel, forces_N=forces, timings=dict(res.get("timings", {})),
                      voltages=volts, extra=extra, **common)


def _jsonable_or_note(value):
    """Keep JSON-able extras (numpy scalars/arrays included); note, do not store, anything else."""
    try:
        json.dumps(jsonable(value))
    except (TypeError, ValueError):
        return f"<not stored: {type(value).__name__}>"
    return jsonable(value)
