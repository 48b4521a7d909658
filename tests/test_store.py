"""The SQLite results store: round trip, write semantics, uniqueness, WAL, readers, SIGKILL."""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from latticeopt.design import LatticeDesign
from latticeopt.errors import LatticeoptError
from latticeopt.study.store import Evaluation, ResultStore


def _ev(d="d1", p="p1", s="s1", status="ok", v_rel=0.05, **kw) -> Evaluation:
    return Evaluation(design_key=d, phantom_key=p, settings_key=s, status=status, v_rel=v_rel, **kw)


def test_round_trip_is_exact(tmp_path):
    volts = np.random.default_rng(0).normal(size=208)
    e = _ev(forces_N=(1.25, 0.5), seconds=3.5, timings={"mechanics": 2.0}, voltages=volts,
            design={"width_mm": 4.0}, phantom={"index": 3}, settings={"mesh": {"size_mm": 2}},
            extra={"newton_steps": np.int64(7), "stretch": np.float32(1.5)})
    with ResultStore(tmp_path) as store:
        assert store.put(e)
        got = store.get("d1", "p1", "s1")
    assert (tmp_path / "results.sqlite").exists()
    assert got.voltages.dtype == np.float64 and np.array_equal(got.voltages, volts)
    assert got.forces_N == (1.25, 0.5) and got.timings == {"mechanics": 2.0} and got.v_rel == 0.05
    assert got.extra == {"newton_steps": 7, "stretch": 1.5} and got.design == {"width_mm": 4.0}
    assert got.created_utc.endswith("Z") and got.host


def test_ok_rows_are_final_failed_rows_give_way(tmp_path):
    with ResultStore(tmp_path / "r.sqlite") as store:
        assert store.put(_ev(v_rel=0.1))
        assert not store.put(_ev(v_rel=0.2))  # OR IGNORE for a finished result
        assert store.get("d1", "p1", "s1").v_rel == 0.1
        assert store.put(_ev(p="p2", status="failed", v_rel=None, error="ConvergenceError: x"))
        assert store.put(_ev(p="p2", status="failed", v_rel=None, error="ConvergenceError: y"))
        assert store.get("d1", "p2", "s1").error.endswith("y")
        assert store.put(_ev(p="p2", v_rel=0.3))  # REPLACE a failure by a result
        assert store.get("d1", "p2", "s1").v_rel == 0.3
        assert not store.put(_ev(p="p2", status="failed", v_rel=None, error="late"))
        assert len(store) == 2 and store.done_keys() == {("d1", "p1", "s1"), ("d1", "p2", "s1")}


def test_unique_constraint_in_the_schema(tmp_path):
    with ResultStore(tmp_path) as store:
        store.put(_ev())
    con = sqlite3.connect(tmp_path / "results.sqlite")
    with pytest.raises(sqlite3.IntegrityError, match="UNIQUE"):
        con.execute("INSERT INTO evaluations (design_key, phantom_key, settings_key, status, design_json, "
                    "phantom_json, settings_json, created_utc) VALUES ('d1', 'p1', 's1', 'ok', '{}', '{}', '{}', 'x')")
    assert con.execute("PRAGMA journal_mode").fetchone()[0] == "wal"


def test_invalid_rows_rejected():
    with pytest.raises(ValueError, match="status"):
        _ev(status="done")
    with pytest.raises(ValueError, match="v_rel"):
        _ev(v_rel=float("nan"))


def test_queries_and_optimizer_lookup(tmp_path):
    design = LatticeDesign(width_mm=4, thickness_mm=3)
    dk = design.content_hash()
    with ResultStore(tmp_path) as store:
        for i in range(4):
            store.put(_ev(d=dk, p=f"p{i}", v_rel=0.01 * i))
        store.put(_ev(d=dk, p="p0", s="other", v_rel=9.0))
        store.put(_ev(d="x", p="p0", status="failed", v_rel=None, error="e"))
        assert [e.v_rel for e in store.evaluations_for(design, "s1", ["p3", "missing", "p1"])] == [0.03, 0.01]
        assert len(store.evaluations_for(dk, "s1")) == 4
        assert store.done_keys("s1", include_failed=False) == {(dk, f"p{i}", "s1") for i in range(4)}
        assert [e.design_key for e in store.rows(status="failed")] == ["x"]
        found = store.lookup([(dk, "p2", "s1"), (dk, "p0", "other"), ("nope", "p0", "s1")])
        assert {k: e.v_rel for k, e in found.items()} == {(dk, "p2", "s1"): 0.02, (dk, "p0", "other"): 9.0}
        # a reader sees committed rows while the writer is open
        with ResultStore(tmp_path, readonly=True) as reader:
            assert len(reader) == 6
            store.put(_ev(d=dk, p="p9"))
            assert len(reader) == 7
            with pytest.raises(sqlite3.OperationalError):
                reader._db.execute("DELETE FROM evaluations")


def test_readonly_missing_store(tmp_path):
    with pytest.raises(LatticeoptError, match="no results store"):
        ResultStore(tmp_path / "none", readonly=True)


WRITER = textwrap.dedent("""
    import sys
    import numpy as np
    from latticeopt.study.store import Evaluation, ResultStore
    store = ResultStore(sys.argv[1])
    i = 0
    while True:
        store.put(Evaluation(design_key="d", phantom_key=f"p{i}", settings_key="s", status="ok", v_rel=float(i),
                             voltages=np.full(208, float(i)), forces_N=(float(i),)))
        i += 1
""")


def test_store_survives_sigkill_mid_write(tmp_path):
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(tmp_path)])
    db = tmp_path / "results.sqlite"
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        if db.exists():
            try:
                with ResultStore(tmp_path, readonly=True) as r:
                    if len(r) >= 20:
                        break
            except (sqlite3.OperationalError, LatticeoptError):
                pass
        time.sleep(0.01)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    with ResultStore(tmp_path) as store:  # opening for writing recovers the WAL
        assert store.integrity_check() == "ok"
        rows = store.rows()
        assert len(rows) >= 20
        # every row is whole, and they form an unbroken prefix 0..n-1 (no row lost before a later one)
        assert sorted(int(e.phantom_key[1:]) for e in rows) == list(range(len(rows)))
        for e in rows:
            assert e.voltages.shape == (208,) and np.all(e.voltages == e.v_rel) and e.forces_N == (e.v_rel,)


def _try_lock_elsewhere(folder) -> subprocess.CompletedProcess:
    code = textwrap.dedent("""
        import sys
        from latticeopt.errors import FolderLockedError
        from latticeopt.study.store import folder_lock
        try:
            with folder_lock(sys.argv[1]):
                print("got it")
        except FolderLockedError as exc:
            print(exc)
    """)
    return subprocess.run([sys.executable, "-c", code, str(folder)], capture_output=True, text=True, timeout=60)


def test_folder_lock_is_exclusive_reentrant_and_released(tmp_path):
    from latticeopt.study.store import LOCK_NAME, folder_lock

    with folder_lock(tmp_path) as path:
        with folder_lock(tmp_path):  # the same process may take it again (the optimizer's sweeps do)
            assert path.read_text().split()[0] == str(os.getpid())
        other = _try_lock_elsewhere(tmp_path).stdout  # the outer hold still counts
        assert f"locked by PID {os.getpid()}" in other and str(tmp_path) in other
    assert path.read_text() == "" and path.name == LOCK_NAME
    assert _try_lock_elsewhere(tmp_path).stdout.strip() == "got it"
