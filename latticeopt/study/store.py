"""The results store: one SQLite file per output folder, one row per evaluation.

An *evaluation* is one (design, phantom, settings) triple; its identity is the triple of content hashes
``(design_key, phantom_key, settings_key)`` (:meth:`LatticeDesign.content_hash`, :attr:`Phantom.key`,
:attr:`EvalSettings.key`), so the same triple computed by a sweep, an optimizer or by hand lands in the same
row, and anything that has it can look it up.

Crash safety. The file is in WAL mode with ``synchronous=FULL`` and every row is written in its own
transaction the moment its result arrives: a process killed at any instant (SIGKILL included) leaves every
committed row intact and no half row; SQLite rolls back the unfinished transaction on the next open.

Write semantics (:meth:`ResultStore.put`). ``UNIQUE(design_key, phantom_key, settings_key)``:

- no row yet -> inserted;
- an ``'ok'`` row exists -> left untouched (INSERT OR IGNORE semantics; a finished result is never
  overwritten, so a repeated or concurrent run cannot change it);
- a ``'failed'`` row exists -> replaced by the new row (REPLACE semantics for failures only), which is how
  ``--retry-failed`` turns a failure into a result.

Voltages are stored as a little-endian float64 blob (``np.frombuffer(blob, '<f8')``); forces, timings,
design, phantom and settings as JSON text. The store is meant to have one writer at a time (the sweep's
parent process); any number of readers may read while it writes.

One writer per folder (:func:`folder_lock`). A sweep or optimization holds an exclusive ``flock`` on
``latticeopt.lock`` in its output folder for the whole run, so a second run started on the same folder refuses
at once (:class:`~latticeopt.errors.FolderLockedError`, naming the folder and the PID holding it) instead of
computing every phantom the first one is computing. The kernel drops the lock when the process ends, however it
ends, so a killed run never leaves a stale lock. ``flock`` is local to one machine: two hosts writing one folder
over a network file system are not kept apart.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import socket
import sqlite3
import threading
import time
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._jsonout import jsonable
from ..errors import FolderLockedError, LatticeoptError

__all__ = ["LOCK_NAME", "STATUSES", "STORE_NAME", "Evaluation", "ResultStore", "folder_lock"]

STORE_NAME = "results.sqlite"
LOCK_NAME = "latticeopt.lock"
STATUSES = ("ok", "failed")
SCHEMA_VERSION = 1

_SCHEMA = """
CREATE TABLE IF NOT EXISTS evaluations (
    id            INTEGER PRIMARY KEY,
    design_key    TEXT NOT NULL,
    phantom_key   TEXT NOT NULL,
    settings_key  TEXT NOT NULL,
    status        TEXT NOT NULL CHECK (status IN ('ok', 'failed')),
    v_rel         REAL,
    forces_json   TEXT,
    seconds       REAL,
    timings_json  TEXT,
    extra_json    TEXT,
    voltages      BLOB,
    error         TEXT,
    design_json   TEXT NOT NULL,
    phantom_json  TEXT NOT NULL,
    settings_json TEXT NOT NULL,
    host          TEXT,
    created_utc   TEXT NOT NULL,
    UNIQUE (design_key, phantom_key, settings_key)
);
CREATE INDEX IF NOT EXISTS evaluations_by_settings_design ON evaluations (settings_key, design_key);
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
"""

_COLUMNS = ("design_key", "phantom_key", "settings_key", "status", "v_rel", "forces_json", "seconds",
            "timings_json", "extra_json", "voltages", "error", "design_json", "phantom_json", "settings_json",
            "host", "created_utc")

# An 'ok' row is final; a 'failed' row gives way to whatever is written next for the same key.
_PUT = (f"INSERT INTO evaluations ({', '.join(_COLUMNS)}) VALUES ({', '.join('?' * len(_COLUMNS))}) "
        "ON CONFLICT (design_key, phantom_key, settings_key) DO UPDATE SET "
        + ", ".join(f"{c} = excluded.{c}" for c in _COLUMNS[3:])
        + " WHERE evaluations.status = 'failed'")


def _to_json(obj) -> str:
    return json.dumps(jsonable(obj), sort_keys=True, allow_nan=True)


@dataclass(frozen=True)
class Evaluation:
    """One stored evaluation (a row of the store).

    Parameters
    ----------
    design_key, phantom_key, settings_key
        Content hashes identifying the evaluation.
    status
        ``'ok'`` or ``'failed'``.
    v_rel
        Mean relative voltage change (dimensionless); ``None`` when failed.
    forces_N
        Reaction force per touch (N), in the phantom's touch order; empty if the model gave none.
    seconds
        Wall time of the evaluation in its worker (s).
    timings
        The model's own breakdown, name -> seconds.
    voltages
        Touched voltages, shape ``(n_measurements,)`` (V), float64; ``None`` if not stored.
    error
        ``"ExceptionType: message"`` plus traceback for failures, else ``None``.
    design, phantom, settings
        The JSON-decoded descriptions (``LatticeDesign.as_dict()``, ``Phantom.as_dict()``,
        ``EvalSettings.as_dict()``).
    extra
        Any further keys the model returned (solver statistics, ...) and worker information.
    host, created_utc
        Where and when (ISO 8601, UTC) the row was written.
    """

    design_key: str
    phantom_key: str
    settings_key: str
    status: str
    v_rel: float | None = None
    forces_N: tuple[float, ...] = ()
    seconds: float | None = None
    timings: dict = field(default_factory=dict)
    voltages: np.ndarray | None = None
    error: str | None = None
    design: dict = field(default_factory=dict)
    phantom: dict = field(default_factory=dict)
    settings: dict = field(default_factory=dict)
    extra: dict = field(default_factory=dict)
    host: str | None = None
    created_utc: str | None = None

    def __post_init__(self) -> None:
        if self.status not in STATUSES:
            raise ValueError(f"status: expected one of {STATUSES}, got {self.status!r}")
        if self.status == "ok" and (self.v_rel is None or not math.isfinite(self.v_rel)):
            raise ValueError(f"v_rel: expected a finite number for an 'ok' evaluation, got {self.v_rel!r}")

    @property
    def key(self) -> tuple[str, str, str]:
        return self.design_key, self.phantom_key, self.settings_key

    @property
    def ok(self) -> bool:
        return self.status == "ok"


def _row_values(e: Evaluation) -> tuple:
    volts = None if e.voltages is None else np.ascontiguousarray(e.voltages, dtype="<f8").tobytes()
    return (e.design_key, e.phantom_key, e.settings_key, e.status,
            None if e.v_rel is None else float(e.v_rel), _to_json(list(e.forces_N)),
            None if e.seconds is None else float(e.seconds), _to_json(e.timings), _to_json(e.extra), volts,
            e.error, _to_json(e.design), _to_json(e.phantom), _to_json(e.settings),
            e.host or socket.gethostname(),
            e.created_utc or time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()))


def _from_row(row: sqlite3.Row) -> Evaluation:
    blob = row["voltages"]
    return Evaluation(
        design_key=row["design_key"], phantom_key=row["phantom_key"], settings_key=row["settings_key"],
        status=row["status"], v_rel=row["v_rel"], forces_N=tuple(json.loads(row["forces_json"] or "[]")),
        seconds=row["seconds"], timings=json.loads(row["timings_json"] or "{}"),
        voltages=None if blob is None else np.frombuffer(blob, dtype="<f8").copy(), error=row["error"],
        design=json.loads(row["design_json"]), phantom=json.loads(row["phantom_json"]),
        settings=json.loads(row["settings_json"]), extra=json.loads(row["extra_json"] or "{}"),
        host=row["host"], created_utc=row["created_utc"])


class ResultStore:
    """An open results store (SQLite) — the connection is the reused state.

    Parameters
    ----------
    path
        The ``.sqlite`` file, or a folder (then ``folder/results.sqlite``). Created with its folder unless
        ``readonly``.
    readonly
        Open an existing store for reading only (safe while a sweep writes to it).

    Use as a context manager, or call :meth:`close`.
    """

    def __init__(self, path: str | Path, *, readonly: bool = False):
        p = Path(path)
        if p.is_dir() or not p.suffix:
            p = p / STORE_NAME
        self.path = p
        self.readonly = readonly
        if readonly:
            if not p.exists():
                raise LatticeoptError(f"no results store at {p}")
            self._db = sqlite3.connect(f"{p.resolve().as_uri()}?mode=ro", uri=True, timeout=60)
        else:
            p.parent.mkdir(parents=True, exist_ok=True)
            # isolation_level=None (autocommit): every write statement is one transaction of its own.
            self._db = sqlite3.connect(p, timeout=60, isolation_level=None)
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute("PRAGMA synchronous=FULL")
            self._db.executescript(_SCHEMA)
            self._db.execute("INSERT OR IGNORE INTO meta VALUES ('schema_version', ?)", (str(SCHEMA_VERSION),))
        self._db.row_factory = sqlite3.Row
        got = self._db.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone()
        if got is None or int(got["value"]) != SCHEMA_VERSION:
            raise LatticeoptError(f"{p}: results store schema {got and got['value']!r}, this latticeopt reads "
                                  f"{SCHEMA_VERSION}")

    # -- context manager ---------------------------------------------------------------------------
    def close(self) -> None:
        self._db.close()

    def __enter__(self) -> ResultStore:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- writing -----------------------------------------------------------------------------------
    def put(self, evaluation: Evaluation) -> bool:
        """Write one evaluation in its own transaction; see the module docstring for the semantics.

        Returns
        -------
        bool
            True if a row was inserted or a failed row replaced, False if an ``'ok'`` row was already there.
        """
        # Autocommit connection: this single statement is its own transaction, committed on return.
        cur = self._db.execute(_PUT, _row_values(evaluation))
        return cur.rowcount > 0

    # -- reading -----------------------------------------------------------------------------------
    def __len__(self) -> int:
        return self._db.execute("SELECT COUNT(*) FROM evaluations").fetchone()[0]

    def done_keys(self, settings_key: str | None = None, *, include_failed: bool = True) -> set[tuple[str, str, str]]:
        """Keys ``(design_key, phantom_key, settings_key)`` already stored (``'ok'``, and failed unless not)."""
        sql = "SELECT design_key, phantom_key, settings_key FROM evaluations WHERE 1"
        args: list = []
        if settings_key is not None:
            sql += " AND settings_key = ?"
            args.append(settings_key)
        if not include_failed:
            sql += " AND status = 'ok'"
        return {tuple(r) for r in self._db.execute(sql, args)}

    def seconds(self, settings_key: str) -> dict[tuple[str, str], float]:
        """``(design_key, phantom_key) -> seconds`` of every row under one settings key (ok and failed)."""
        sql = "SELECT design_key, phantom_key, seconds FROM evaluations WHERE settings_key = ?"
        return {(d, p): float(t) for d, p, t in self._db.execute(sql, (settings_key,)) if t is not None}

    def get(self, design_key: str, phantom_key: str, settings_key: str) -> Evaluation | None:
        """The evaluation with these keys, or ``None``."""
        row = self._db.execute("SELECT * FROM evaluations WHERE design_key = ? AND phantom_key = ? AND "
                               "settings_key = ?", (design_key, phantom_key, settings_key)).fetchone()
        return None if row is None else _from_row(row)

    def rows(self, *, design_key: str | None = None, settings_key: str | None = None,
             status: str | None = None) -> list[Evaluation]:
        """Stored evaluations, optionally filtered, in insertion order."""
        sql, args = "SELECT * FROM evaluations WHERE 1", []
        for col, val in (("design_key", design_key), ("settings_key", settings_key), ("status", status)):
            if val is not None:
                sql += f" AND {col} = ?"
                args.append(val)
        return [_from_row(r) for r in self._db.execute(sql + " ORDER BY id", args)]

    def lookup(self, keys: Iterable[tuple[str, str, str]]) -> dict[tuple[str, str, str], Evaluation]:
        """Stored evaluations for the given keys (missing keys are absent from the result)."""
        wanted = set(keys)
        by_group: dict[tuple[str, str], set[str]] = {}
        for d, p, s in wanted:
            by_group.setdefault((s, d), set()).add(p)
        out = {}
        for (s, d), phantoms in by_group.items():
            for row in self._db.execute("SELECT * FROM evaluations WHERE settings_key = ? AND design_key = ?",
                                        (s, d)):
                if row["phantom_key"] in phantoms:
                    e = _from_row(row)
                    out[e.key] = e
        return out

    def evaluations_for(self, design, settings_key: str,
                        phantom_keys: Sequence[str] | None = None) -> list[Evaluation]:
        """A design's stored evaluations under one settings key (the optimizer's look-up).

        Parameters
        ----------
        design
            A :class:`~latticeopt.design.LatticeDesign` or its content hash.
        settings_key
            :attr:`EvalSettings.key` of the settings the values must have been computed with.
        phantom_keys
            If given, only these phantoms, returned in this order (missing ones skipped).
        """
        dkey = design if isinstance(design, str) else design.content_hash()
        rows = self.rows(design_key=dkey, settings_key=settings_key)
        if phantom_keys is None:
            return rows
        by_phantom = {r.phantom_key: r for r in rows}
        return [by_phantom[k] for k in phantom_keys if k in by_phantom]

    def integrity_check(self) -> str:
        """SQLite's ``PRAGMA integrity_check`` result (``'ok'`` when healthy)."""
        return self._db.execute("PRAGMA integrity_check").fetchone()[0]


# -- one writer per output folder -------------------------------------------------------------------------
_held: dict[str, list] = {}  # resolved folder -> [file descriptor, nesting depth] of the locks this process holds
_held_guard = threading.Lock()


@contextlib.contextmanager
def folder_lock(folder: str | Path) -> Iterator[Path]:
    """Hold the exclusive lock of an output folder while the block runs (see the module docstring).

    Re-entrant within a process: a run that holds the lock may call code that takes it again (the optimizer
    evaluates each design through :func:`latticeopt.study.sweep.evaluate_designs`, which locks too).

    Parameters
    ----------
    folder
        The output folder; created if missing.

    Yields
    ------
    Path
        The lock file (it holds ``PID host start-time`` of the holder while held).

    Raises
    ------
    FolderLockedError
        Another process holds the lock; the message names the folder and the holder's PID.
    """
    import fcntl

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / LOCK_NAME
    key = str(folder.resolve())
    with _held_guard:
        entry = _held.get(key)
        if entry is not None:
            entry[1] += 1
    if entry is None:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 400, 0).decode(errors="replace").split()
            os.close(fd)
            who = (f"PID {holder[0]} on {holder[1]} since {holder[2]}" if len(holder) >= 3
                   else "a process that is just starting")
            raise FolderLockedError("out", "an output folder no other latticeopt run is writing to (wait for it "
                                    "to finish or choose another --out)", f"{folder} (locked by {who})") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()} {socket.gethostname()} "
                      f"{time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime())}\n".encode(), 0)
        entry = [fd, 1]
        with _held_guard:
            _held[key] = entry
    try:
        yield path
    finally:
        with _held_guard:
            entry[1] -= 1
            last = entry[1] == 0
            if last:
                del _held[key]
        if last:
            os.ftruncate(entry[0], 0)  # no holder named once released
            os.close(entry[0])  # closing the only descriptor releases the flock
