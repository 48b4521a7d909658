"""The sweep machinery: end to end, kill-and-resume, determinism, failures, dask.

The model here is a TEST DOUBLE (``fake_evaluate``): a cheap deterministic function of the design and the
phantom that exercises the runner, store and reports. It is not physics; the coupled model is tested in its
own modules.
"""

from __future__ import annotations

import builtins
import csv
import dataclasses
import os
import re
import signal
import sqlite3
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from latticeopt.errors import AllFailedError, ConvergenceError, FolderLockedError, LatticeoptError, ModelBugError
from latticeopt.study.config import load_study
from latticeopt.study.report import best_design
from latticeopt.study.store import ResultStore
from latticeopt.study.sweep import run_sweep

TESTS = Path(__file__).parent
LOG_ENV = "LATTICEOPT_TEST_EVAL_LOG"
DELAY_ENV = "LATTICEOPT_TEST_EVAL_DELAY"
#: "N:PATH": once N evaluations are in the log, every further one waits until PATH exists (a condition, not a
#: sleep: a run held this way cannot finish before the test interrupts it, however busy the machine)
GATE_ENV = "LATTICEOPT_TEST_EVAL_GATE"


def _fake_value(design, phantom) -> float:
    depth = sum(t.depth_mm * t.radius_mm for t in phantom.touches)
    return 1e-3 * depth * (1 + 0.05 * design.width_mm) / design.thickness_mm + 1e-4 * phantom.index


def fake_evaluate(design, phantom, settings) -> dict:
    """TEST DOUBLE of latticeopt.coupled.evaluate_phantom (machinery only, not physics)."""
    delay = float(os.environ.get(DELAY_ENV, "0"))
    if delay:
        time.sleep(delay)
    v = _fake_value(design, phantom)
    log = os.environ.get(LOG_ENV)
    gate = os.environ.get(GATE_ENV)
    if gate and log:
        n, _, release = gate.partition(":")
        logged = len(Path(log).read_text().splitlines()) if os.path.exists(log) else 0
        deadline = time.monotonic() + 900
        while logged >= int(n) and not os.path.exists(release) and time.monotonic() < deadline:
            time.sleep(0.05)
    if log:
        with open(log, "a") as fh:
            fh.write(f"{design.content_hash()} {phantom.key}\n")
    return {"v_rel": v, "voltages": np.linspace(1.0, 2.0, 208) * (1 + v),
            "forces_N": [t.depth_mm * 0.1 for t in phantom.touches], "timings": {"fake": 0.0}, "newton_steps": 3}


def fake_evaluate_failing(design, phantom, settings) -> dict:
    """TEST DOUBLE that fails (ConvergenceError) on phantom index 1 of the w = 2 design."""
    if design.width_mm == 2 and phantom.index == 1:
        raise ConvergenceError("fake: Newton did not converge at step 3")
    return fake_evaluate(design, phantom, settings)


def fake_evaluate_buggy(design, phantom, settings) -> dict:
    """TEST DOUBLE with a programming error on phantom index 2 (must stop the sweep)."""
    if phantom.index == 2:
        raise TypeError("fake bug")
    return fake_evaluate(design, phantom, settings)


STUDY = """
name = "tiny"
out = "{out}"
jobs = 1
[design]
thickness_mm = 3.0
[grid]
width_mm = [0, 2]
[phantoms]
seed = 7
counts = {{ 1 = {n1}, 2 = {n2} }}
[mesh]
size_mm = 5.0
"""


def _study(tmp_path: Path, n1=2, n2=1, name="study.toml", out="out"):
    path = tmp_path / name
    path.write_text(STUDY.format(out=(tmp_path / out).as_posix(), n1=n1, n2=n2))
    return load_study(path)


def _read_csv(path: Path, drop=("seconds",)) -> list[dict]:
    with open(path) as fh:
        return [{k: v for k, v in row.items() if k not in drop} for row in csv.DictReader(fh)]


def test_end_to_end_two_designs_three_phantoms(tmp_path, monkeypatch):
    monkeypatch.setenv(LOG_ENV, str(tmp_path / "evals.log"))
    study = _study(tmp_path)
    res = run_sweep(study, fake_evaluate, progress=False)
    assert (res.computed, res.skipped, res.failed) == (6, 0, 0)
    rows = _read_csv(res.outputs["results"])
    assert len(rows) == 6
    expected = [(w, i, k) for w in ("0.0", "2.0") for i, k in (("0", "1"), ("1", "1"), ("0", "2"))]
    assert [(r["width_mm"], r["phantom_index"], r["n_touches"]) for r in rows] == expected
    summary = _read_csv(res.outputs["summary"])
    for s, design in zip(summary, study.designs):
        vals = [_fake_value(design, p) for p in study.phantoms]
        assert float(s["v_rel_mean"]) == pytest.approx(statistics.mean(vals), rel=1e-12)
        assert float(s["v_rel_se"]) == pytest.approx(statistics.stdev(vals) / np.sqrt(3), rel=1e-12)
        assert (s["n"], s["failed"]) == ("3", "0")
    best = best_design(study, res.evaluations)
    assert best["design"].width_mm == 2.0  # the double rises with w
    assert "best design: width = 2" in res.report[1]
    for key in ("lines_plot", "heatmap"):
        if key in res.outputs:
            assert res.outputs[key].read_bytes()[:4] == b"\x89PNG"
    assert "lines_plot" in res.outputs
    # a second run reads everything from the store
    again = run_sweep(study, fake_evaluate, progress=False)
    assert (again.computed, again.skipped) == (0, 6)
    assert len((tmp_path / "evals.log").read_text().splitlines()) == 6
    stored = again.evaluations[0]
    assert stored.voltages.shape == (208,) and stored.extra["newton_steps"] == 3


def test_process_pool_matches_inline_and_single_blas_thread(tmp_path):
    study = _study(tmp_path, n1=2, n2=2)
    inline = run_sweep(study, fake_evaluate, progress=False, out_dir=tmp_path / "a", outputs=False)
    pooled = run_sweep(study, fake_evaluate, jobs=2, progress=False, out_dir=tmp_path / "b", outputs=False)
    assert [e.v_rel for e in pooled.evaluations] == [e.v_rel for e in inline.evaluations]
    pids = {e.extra["worker"]["pid"] for e in pooled.evaluations}
    assert os.getpid() not in pids
    threads = [n for e in pooled.evaluations for n in e.extra["worker"]["blas_threads"].values()]
    assert threads and max(threads) == 1


def test_determinism_two_runs_identical(tmp_path):
    study = _study(tmp_path, n1=3, n2=2)
    a = run_sweep(study, fake_evaluate, progress=False, out_dir=tmp_path / "a")
    b = run_sweep(load_study(tmp_path / "study.toml"), fake_evaluate, progress=False, out_dir=tmp_path / "b")
    assert _read_csv(a.outputs["results"]) == _read_csv(b.outputs["results"])
    assert _read_csv(a.outputs["summary"]) == _read_csv(b.outputs["summary"])


def test_failures_recorded_counted_not_averaged_then_retried(tmp_path):
    study = _study(tmp_path)
    res = run_sweep(study, fake_evaluate_failing, progress=False)
    assert res.failed == 1 and res.computed == 6
    failed = [e for e in res.evaluations if not e.ok]
    assert "ConvergenceError: fake: Newton did not converge" in failed[0].error
    summary = {r["width_mm"]: r for r in _read_csv(res.outputs["summary"])}
    w2 = study.designs[1]
    ok_vals = [_fake_value(w2, p) for p in study.phantoms if p.index != 1 or p.n_touches != 1]
    assert (summary["2.0"]["n"], summary["2.0"]["failed"]) == ("2", "1")
    assert float(summary["2.0"]["v_rel_mean"]) == pytest.approx(statistics.mean(ok_vals), rel=1e-12)
    assert "1 failed" in res.report[0]
    # a plain re-run keeps the stored failure; retry_failed runs exactly the failed phantom again
    assert run_sweep(study, fake_evaluate_failing, progress=False).computed == 0
    retried = run_sweep(study, fake_evaluate_failing, progress=False, retry_failed=True)
    assert retried.computed == 1 and retried.failed == 1


RAISE_ENV = "LATTICEOPT_TEST_RAISE"


def fake_evaluate_raising(design, phantom, settings) -> dict:
    """TEST DOUBLE raising the builtin exception named by ``$LATTICEOPT_TEST_RAISE`` on phantom index 2."""
    if phantom.index == 2:
        raise getattr(builtins, os.environ[RAISE_ENV])("fake bug in the model")
    return fake_evaluate(design, phantom, settings)


def fake_evaluate_always_failing(design, phantom, settings) -> dict:
    """TEST DOUBLE whose every phantom fails (ConvergenceError)."""
    raise ConvergenceError(f"fake: phantom {phantom.index} did not converge")


FAIL_ENV = "LATTICEOPT_TEST_FAIL_PHANTOMS"


def fake_evaluate_fails_chosen(design, phantom, settings) -> dict:
    """TEST DOUBLE: ConvergenceError on the w = 0 design for the phantoms ``$LATTICEOPT_TEST_FAIL_PHANTOMS``
    lists as ``touches:index`` pairs (comma-separated)."""
    chosen = {tuple(int(x) for x in item.split(":")) for item in os.environ.get(FAIL_ENV, "").split(",") if item}
    if design.width_mm == 0 and (phantom.n_touches, phantom.index) in chosen:
        raise ConvergenceError("fake: the press was too hard")
    return fake_evaluate(design, phantom, settings)


def test_designs_are_compared_on_the_phantoms_every_design_solved(tmp_path, monkeypatch):
    study = _study(tmp_path, n1=4, n2=2)
    w0, w2 = study.designs
    # w = 2 reads more than w = 0 on every phantom; w = 0 fails exactly its two weakest phantoms
    assert all(_fake_value(w2, p) > _fake_value(w0, p) for p in study.phantoms)
    weakest = sorted(study.phantoms, key=lambda p: _fake_value(w0, p))[:2]
    monkeypatch.setenv(FAIL_ENV, ",".join(f"{p.n_touches}:{p.index}" for p in weakest))
    survivors = [p for p in study.phantoms if p not in weakest]
    # averaged over its own successes, w = 0 would look better than w = 2 over all six: the bias at stake
    assert statistics.mean(_fake_value(w0, p) for p in survivors) > statistics.mean(
        _fake_value(w2, p) for p in study.phantoms)
    res = run_sweep(study, fake_evaluate_fails_chosen, progress=False)
    assert res.failed == 2
    best = best_design(study, res.evaluations)
    assert best["design"] == w2 and best["runner_up"] == w0 and best["paired_n"] == 4
    assert best["paired_diff"] == pytest.approx(statistics.mean(
        _fake_value(w2, p) - _fake_value(w0, p) for p in survivors), rel=1e-12)
    summary = {r["width_mm"]: r for r in _read_csv(res.outputs["summary"])}
    assert [(summary[w]["n"], summary[w]["n_ok"], summary[w]["failed"]) for w in ("0.0", "2.0")] == [
        ("4", "4", "2"), ("4", "6", "0")]
    for w, design in (("0.0", w0), ("2.0", w2)):  # both means over the same four phantoms
        assert float(summary[w]["v_rel_mean"]) == pytest.approx(
            statistics.mean(_fake_value(design, p) for p in survivors), rel=1e-12)
    report = (study.out_dir / "report.txt").read_text()
    assert "best design: width = 2 mm" in report
    assert "compared on the 4 of 6 phantoms" in report and "2 excluded" in report
    for p in weakest:
        assert f"excluded phantom {p.n_touches}:{p.index} ({p.n_touches} touches): failed for width = 0 mm: " \
            "ConvergenceError" in report
    # the report's phantoms.only setting re-draws exactly the failed phantoms
    setting = re.search(r"--set '(phantoms\.only=.*)'", report).group(1)
    again = load_study(study.source, [setting])
    assert [p.touches for p in again.phantoms] == [p.touches for p in weakest]
    assert len(_read_csv(res.outputs["excluded"])) == 2
    # every design against the best, paired over the same survivors, overall and per touch count
    paired = _read_csv(res.outputs["paired"])
    assert [r["width_mm"] for r in paired] == ["2.0", "0.0"] and float(paired[0]["diff_to_best"]) == 0.0
    assert float(paired[1]["diff_to_best"]) == pytest.approx(-best["paired_diff"], rel=1e-12)
    for k in (1, 2):
        diffs = [_fake_value(w0, p) - _fake_value(w2, p) for p in survivors if p.n_touches == k]
        assert float(paired[1][f"diff_{k}_touch"]) == pytest.approx(statistics.mean(diffs), rel=1e-12)
    assert "paired difference to the best" in report and "width = 0 mm: -" in report
    compared = [(r["width_mm"], r["compared"]) for r in _read_csv(res.outputs["results"])]
    assert sum(c == "True" for _, c in compared) == 8
    # once the failures are retried successfully the full set is back and the stale list is gone
    monkeypatch.delenv(FAIL_ENV)
    again = run_sweep(study, fake_evaluate_fails_chosen, progress=False, retry_failed=True)
    assert again.failed == 0 and "excluded" not in again.outputs and not (study.out_dir / "excluded.csv").exists()
    assert "designs compared on all 6 phantoms" in again.report[-1]


def test_a_design_that_failed_everything_is_not_compared(tmp_path, monkeypatch):
    study = _study(tmp_path, n1=2, n2=1)
    monkeypatch.setenv(FAIL_ENV, ",".join(f"{p.n_touches}:{p.index}" for p in study.phantoms))
    res = run_sweep(study, fake_evaluate_fails_chosen, progress=False)
    assert res.failed == 3
    assert best_design(study, res.evaluations)["design"].width_mm == 2.0
    assert "designs compared on all 3 phantoms" in "\n".join(res.report)
    assert any(line.startswith("not compared: width = 0 mm: every phantom failed") for line in res.report)


def test_model_bug_stops_sweep_keeping_stored_rows(tmp_path):
    study = _study(tmp_path, n1=3, n2=0)
    with pytest.raises(ModelBugError, match="TypeError: fake bug") as info:
        run_sweep(study, fake_evaluate_buggy, progress=False)
    assert "\n" not in str(info.value) and str(study.out_dir / "error.log") in str(info.value)
    with ResultStore(study.out_dir, readonly=True) as store:
        assert len(store) == 2  # phantoms 0 and 1 of the first design, each committed as it finished


@pytest.mark.parametrize("name, jobs", [("IndexError", 1), ("ValueError", 1), ("NotImplementedError", 1),
                                        ("RuntimeError", 1), ("IndexError", 2)])
def test_non_model_failures_stop_the_sweep_with_the_traceback_logged(tmp_path, monkeypatch, name, jobs):
    monkeypatch.setenv(RAISE_ENV, name)
    study = _study(tmp_path, n1=3, n2=0)
    with pytest.raises(ModelBugError) as info:
        run_sweep(study, fake_evaluate_raising, jobs=jobs, progress=False)
    msg = str(info.value)
    assert msg.startswith(f"{name}: fake bug in the model while evaluating phantom 2") and "\n" not in msg
    text = (study.out_dir / "error.log").read_text()
    assert "Traceback (most recent call last)" in text and "in fake_evaluate_raising" in text
    assert f"{name}: fake bug in the model" in text
    with ResultStore(study.out_dir, readonly=True) as store:
        rows = store.rows()
        # nothing recorded as a failed phantom; with one worker, phantoms 0 and 1 were stored before it stopped
        assert all(e.ok for e in rows) and {int(e.phantom["index"]) for e in rows} <= {0, 1}
        assert len(rows) == 2 or jobs > 1


def test_model_failures_and_singular_factorizations_are_phantom_failures():
    from pypardiso.pardiso_wrapper import PyPardisoError

    from latticeopt.errors import MeshError, ModelFailure
    from latticeopt.study.worker import is_model_failure

    assert is_model_failure(ConvergenceError("x")) and is_model_failure(MeshError("x"))
    assert is_model_failure(ModelFailure("a custom model's own failure"))
    assert is_model_failure(PyPardisoError(-4)) and is_model_failure(PyPardisoError(-7))
    for bug in (PyPardisoError(-1), PyPardisoError(-2), ValueError("x"), RuntimeError("x"), IndexError("x"),
                NotImplementedError("x"), FloatingPointError("x"), MemoryError(), LatticeoptError("x")):
        assert not is_model_failure(bug), bug


def _cli(tmp_path: Path, model: str, *extra: str, env_extra: dict | None = None) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(TESTS), os.environ.get("PYTHONPATH", "")]),
           **(env_extra or {})}
    cmd = [sys.executable, "-m", "latticeopt", "sweep", str(tmp_path / "study.toml"), "--evaluate", model,
           "--no-progress", "--jobs", "1", *extra]
    return subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=120)


def test_cli_bug_exits_non_zero_with_one_line_and_the_traceback_in_the_log(tmp_path):
    study = _study(tmp_path, n1=3, n2=0)
    done = _cli(tmp_path, "test_sweep:fake_evaluate_raising", env_extra={RAISE_ENV: "IndexError"})
    assert done.returncode == 1 and done.stderr.count("\n") == 1, done.stderr
    assert "Traceback" not in done.stderr and "IndexError" in done.stderr and "error.log" in done.stderr
    assert "in fake_evaluate_raising" in (study.out_dir / "error.log").read_text()


def test_every_evaluation_failed_is_an_error(tmp_path):
    study = _study(tmp_path)
    with pytest.raises(AllFailedError, match="every one of the 6 evaluations failed") as info:
        run_sweep(study, fake_evaluate_always_failing, progress=False)
    assert info.value.result.failed == 6 and "\n" not in str(info.value)
    assert (study.out_dir / "results.csv").exists()  # the errors are written out before the run reports failure
    done = _cli(tmp_path, "test_sweep:fake_evaluate_always_failing")
    assert done.returncode == 1 and done.stderr.count("\n") == 1, done.stderr
    assert "every one of the 6 evaluations failed" in done.stderr and "ConvergenceError" in done.stderr
    # one phantom that succeeds is enough for a normal exit
    assert run_sweep(study, fake_evaluate, progress=False, retry_failed=True).failed == 0


def test_second_run_on_a_locked_folder_refuses(tmp_path):
    study = _study(tmp_path)
    holder = subprocess.Popen([sys.executable, "-c", "import sys\nfrom latticeopt.study.store import folder_lock\n"
                               "with folder_lock(sys.argv[1]):\n    print('locked', flush=True)\n    sys.stdin.read()",
                               str(study.out_dir)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(FolderLockedError) as info:
            run_sweep(study, fake_evaluate, progress=False)
        assert str(study.out_dir) in str(info.value) and f"PID {holder.pid}" in str(info.value)
        done = _cli(tmp_path, "test_sweep:fake_evaluate")
        assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
        assert str(study.out_dir) in done.stderr and f"PID {holder.pid}" in done.stderr
        with ResultStore(study.out_dir) as store:
            assert len(store) == 0  # neither run computed anything
    finally:
        holder.communicate("", timeout=30)
    assert run_sweep(study, fake_evaluate, progress=False).computed == 6  # released when its holder ended


def _store_keys(path: Path) -> set[tuple[str, str]]:
    with ResultStore(path, readonly=True) as store:
        return {(e.design_key, e.phantom_key) for e in store.rows()}


def _start_cli_and_wait_for_rows(tmp_path: Path, out: Path, n_rows: int, log: str):
    """Start ``latticeopt sweep`` (2 workers, test double held after ``n_rows`` evaluations until a file that
    is never made appears) in its own session; return once ``n_rows`` rows are stored. Waits on conditions only."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(TESTS), os.environ.get("PYTHONPATH", "")]),
           DELAY_ENV: "0", LOG_ENV: str(tmp_path / log), GATE_ENV: f"{n_rows}:{tmp_path / 'never_released'}"}
    cmd = [sys.executable, "-m", "latticeopt", "sweep", str(tmp_path / "study.toml"), "--evaluate",
           "test_sweep:fake_evaluate", "--jobs", "2", "--no-progress", "--out", str(out)]
    # A shell that runs the tests as a background job starts them with SIGINT ignored, and a child would inherit
    # that; give the CLI the disposition a terminal's foreground job has.
    proc = subprocess.Popen(cmd, env=env, start_new_session=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    db = out / "results.sqlite"
    deadline = time.monotonic() + 600  # generous: a busy machine starts the workers slowly
    while time.monotonic() < deadline and proc.poll() is None:
        if db.exists():
            try:
                n = sqlite3.connect(f"{db.as_uri()}?mode=ro", uri=True).execute(
                    "SELECT COUNT(*) FROM evaluations").fetchone()[0]
            except sqlite3.OperationalError:
                n = 0
            if n >= n_rows:
                break
        time.sleep(0.02)
    assert proc.poll() is None, proc.communicate()
    return proc, cmd, env


def test_sigkill_mid_run_then_resume(tmp_path):
    study_path = tmp_path / "study.toml"
    _study(tmp_path, n1=5, n2=3)
    out = tmp_path / "killed"
    proc, cmd, env = _start_cli_and_wait_for_rows(tmp_path, out, 4, "run1.log")
    os.killpg(proc.pid, signal.SIGKILL)  # the CLI and its workers, at once
    proc.wait()
    first = _store_keys(out)
    assert 4 <= len(first) < 16
    with ResultStore(out, readonly=True) as store:
        assert store.integrity_check() == "ok"

    env.update({DELAY_ENV: "0", LOG_ENV: str(tmp_path / "run2.log")})
    del env[GATE_ENV]
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    recomputed = {tuple(line.split()) for line in (tmp_path / "run2.log").read_text().splitlines()}
    assert not recomputed & first  # nothing stored was computed again
    assert recomputed | first == _store_keys(out) and len(_store_keys(out)) == 16
    con = sqlite3.connect(out / "results.sqlite")
    assert con.execute("SELECT COUNT(*), COUNT(DISTINCT design_key || phantom_key || settings_key) "
                       "FROM evaluations").fetchone() == (16, 16)
    reference = run_sweep(load_study(study_path), fake_evaluate, progress=False, out_dir=tmp_path / "clean")
    assert _read_csv(out / "results.csv") == _read_csv(reference.outputs["results"])
    assert _read_csv(out / "summary.csv") == _read_csv(reference.outputs["summary"])


def _live_processes_in_group(pgid: int, wait_s: float = 5.0) -> list[str]:
    """Processes of a process group that are still running (zombies awaiting a reaper do not count)."""
    deadline = time.monotonic() + wait_s
    while True:
        ps = subprocess.run(["ps", "-o", "stat=,cmd=", "-g", str(pgid)], capture_output=True, text=True).stdout
        live = [line for line in ps.splitlines() if line.strip() and not line.strip().startswith("Z")]
        if not live or time.monotonic() > deadline:
            return live
        time.sleep(0.1)


def test_ctrl_c_stops_workers_and_leaves_store_consistent(tmp_path):
    _study(tmp_path, n1=5, n2=3)
    out = tmp_path / "interrupted"
    proc, cmd, env = _start_cli_and_wait_for_rows(tmp_path, out, 2, "run1.log")
    os.killpg(proc.pid, signal.SIGINT)  # what a terminal sends to the foreground group on Ctrl-C
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 130 and "interrupted" in err and "Traceback" not in err
    assert _live_processes_in_group(proc.pid, wait_s=60) == []  # no worker left behind
    with ResultStore(out, readonly=True) as store:
        assert store.integrity_check() == "ok" and 2 <= len(store) < 16
    del env[GATE_ENV]
    assert subprocess.run(cmd, env=env, capture_output=True, timeout=600).returncode == 0
    assert len(_store_keys(out)) == 16


def test_dask_local_cluster_equals_local_run(tmp_path):
    distributed = pytest.importorskip("distributed")
    study = _study(tmp_path, n1=2, n2=2)
    local = run_sweep(study, fake_evaluate, progress=False, out_dir=tmp_path / "local")
    # a real TCP scheduler on loopback; its worker runs in this process (threads), which is enough here
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False, host="127.0.0.1",
                                  protocol="tcp://", dashboard_address=None) as cluster:
        assert cluster.scheduler_address.startswith("tcp://127.0.0.1:")
        remote = run_sweep(study, fake_evaluate, backend="dask", scheduler=cluster.scheduler_address,
                           progress=False, out_dir=tmp_path / "dask")
    assert remote.computed == local.computed == 8
    assert _read_csv(remote.outputs["results"]) == _read_csv(local.outputs["results"])


def test_cli_rejects_bad_study_before_any_work(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(STUDY.format(out=(tmp_path / "never").as_posix(), n1=1, n2=1).replace("[0, 2]", "[0, 12.5]"))
    done = subprocess.run([sys.executable, "-m", "latticeopt", "sweep", str(bad)], capture_output=True, text=True)
    assert done.returncode == 2
    assert done.stderr.count("\n") == 1 and "grid.width_mm" in done.stderr and str(bad) in done.stderr
    assert not (tmp_path / "never").exists()


def test_model_return_contract():
    from latticeopt.design import LatticeDesign
    from latticeopt.study.config import EvalSettings
    from latticeopt.study.phantoms import random_phantom
    from latticeopt.study.worker import result_to_evaluation

    design, phantom, settings = LatticeDesign(), random_phantom(100.0, 2, 0, seed=0), EvalSettings()
    worker = {"host": "h", "pid": 1, "blas_threads": {}}

    def payload(result):
        return {"status": "ok", "result": result, "error": None, "seconds": 1.5, "worker": worker}

    e = result_to_evaluation(payload({"v_rel": np.float64(0.02), "forces_N": np.array([1.0, 2.0]),
                                      "voltages": np.ones(208), "timings": {"mechanics": 1.0},
                                      "newton_steps": np.int64(4), "mesh": object()}), design, phantom, settings)
    assert e.ok and e.v_rel == 0.02 and e.forces_N == (1.0, 2.0) and e.seconds == 1.5
    assert e.extra["newton_steps"] == 4 and e.extra["mesh"].startswith("<not stored")
    assert e.key == (design.content_hash(), phantom.key, settings.key)
    nan = result_to_evaluation(payload({"v_rel": float("nan")}), design, phantom, settings)
    assert not nan.ok and "non-finite" in nan.error
    with pytest.raises(LatticeoptError, match="without 'v_rel'"):
        result_to_evaluation(payload({"V_rel": 0.1}), design, phantom, settings)


def _prepare_fake(design, settings):
    """TEST DOUBLE of a per-design set-up hook: logs each preparation, then evaluates like fake_evaluate."""
    log = os.environ.get(LOG_ENV)
    if log:
        with open(log + ".prepare", "a") as fh:
            fh.write(f"{design.content_hash()}\n")
    return lambda phantom: fake_evaluate(design, phantom, settings)


def fake_evaluate_prepared(design, phantom, settings) -> dict:
    """TEST DOUBLE exposing the ``prepare`` hook the coupled model uses."""
    return _prepare_fake(design, settings)(phantom)


fake_evaluate_prepared.prepare = _prepare_fake


def _prepare_buggy(design, settings):
    if design.width_mm == 2:
        return settings.no_such_setting  # AttributeError: a bug in the set-up, not a failed phantom
    return _prepare_fake(design, settings)


def fake_evaluate_prepare_buggy(design, phantom, settings) -> dict:
    """TEST DOUBLE whose ``prepare`` hook has a programming error for the w = 2 design."""
    return _prepare_buggy(design, settings)(phantom)


fake_evaluate_prepare_buggy.prepare = _prepare_buggy


def test_a_bug_in_the_prepare_hook_stops_the_sweep(tmp_path):
    study = _study(tmp_path)
    with pytest.raises(ModelBugError, match="^AttributeError: ") as info:
        run_sweep(study, fake_evaluate_prepare_buggy, progress=False)
    assert f"while preparing {study.designs[1].describe()} " in str(info.value) and "\n" not in str(info.value)
    assert "in _prepare_buggy" in (study.out_dir / "error.log").read_text()
    with ResultStore(study.out_dir, readonly=True) as store:
        assert len(store) == 3 and all(e.ok for e in store.rows())  # the w = 0 design, none recorded as failed


@pytest.mark.parametrize("jobs", [1, 2])
def test_prepare_hook_runs_once_per_design_and_worker(tmp_path, monkeypatch, jobs):
    """A design's later chunks reuse the model its worker prepared for an earlier one (never another design's)."""
    from latticeopt.study.sweep import CHUNK_PHANTOMS

    monkeypatch.setenv(LOG_ENV, str(tmp_path / "evals.log"))
    study = _study(tmp_path, n1=10, n2=6)  # 16 phantoms per design, 2 designs
    assert 16 // CHUNK_PHANTOMS >= 3  # several chunks per design, so the count below shows the reuse
    plain = run_sweep(study, fake_evaluate, progress=False, out_dir=tmp_path / "plain", outputs=False)
    prepared = run_sweep(study, fake_evaluate_prepared, jobs=jobs, progress=False, out_dir=tmp_path / "prep",
                         outputs=False)
    assert [e.v_rel for e in prepared.evaluations] == [e.v_rel for e in plain.evaluations]
    preps = (tmp_path / "evals.log.prepare").read_text().splitlines()
    hashes = [d.content_hash() for d in study.designs]
    # each worker takes the chunks in task order (design-major), so it prepares each design at most once
    assert sorted(set(preps)) == sorted(hashes) and all(preps.count(h) <= jobs for h in hashes)
    if jobs == 1:
        assert preps == hashes


def test_a_kept_model_is_dropped_for_another_design_or_settings(tmp_path):
    from latticeopt.study import worker

    study = _study(tmp_path, n1=1, n2=1)
    built = []

    def prepare(design, settings):
        built.append((design.width_mm, settings.key))
        return lambda phantom: {"v_rel": design.width_mm + 1.0}

    other = dataclasses.replace(study.settings, mesh=dataclasses.replace(study.settings.mesh, size_mm=3.0))
    assert other.key != study.settings.key
    worker.forget_prepared()
    for design, settings in [(study.designs[0], study.settings), (study.designs[0], study.settings),
                             (study.designs[1], study.settings), (study.designs[1], other),
                             (study.designs[1], other)]:
        assert worker._prepared(prepare, design, settings)(None) == {"v_rel": design.width_mm + 1.0}
    assert built == [(study.designs[0].width_mm, study.settings.key), (study.designs[1].width_mm, study.settings.key),
                     (study.designs[1].width_mm, other.key)]
    worker.forget_prepared()
    worker._prepared(prepare, study.designs[1], other)
    assert len(built) == 4  # forgotten: built again


def test_a_model_that_a_bug_interrupted_is_built_again(tmp_path):
    from latticeopt.study import worker

    study = _study(tmp_path, n1=2, n2=1)
    built = []

    def evaluate(design, phantom, settings):  # plain calls are not used: the hook below is
        raise AssertionError

    def prepare(design, settings):
        built.append(design.width_mm)

        def run(phantom):
            if phantom.index == 1:
                raise KeyError("a bug, not a failed phantom")
            return {"v_rel": 0.1}
        return run

    evaluate.prepare = prepare
    worker.forget_prepared()
    design, phantoms = study.designs[0], study.phantoms
    assert [p["status"] for p in worker.evaluate_chunk(evaluate, design, phantoms[:1], study.settings)] == ["ok"]
    assert [p["status"] for p in worker.evaluate_chunk(evaluate, design, phantoms[1:2], study.settings)] == ["bug"]
    assert [p["status"] for p in worker.evaluate_chunk(evaluate, design, phantoms[:1], study.settings)] == ["ok"]
    assert built == [design.width_mm, design.width_mm]  # kept after the first chunk, built again after the bug
    worker.forget_prepared()


def test_a_grid_of_layout_files_says_which_hash_is_which_file(tmp_path):
    from latticeopt.study.config import study_from_dict

    data = TESTS.parent / "studies" / "data"
    files = [(data / "square_w4.geojson").as_posix(), (data / "graded_d4_t3.geojson").as_posix()]
    study = study_from_dict({"out": (tmp_path / "out").as_posix(), "design": {"thickness_mm": 3.0},
                             "grid": {"layout": files}, "phantoms": {"seed": 7, "counts": {"1": 2}},
                             "mesh": {"size_mm": 5.0}, "model": "tests.test_sweep:fake_evaluate"})
    res = run_sweep(study, fake_evaluate, progress=False)
    report = (study.out_dir / "report.txt").read_text()
    for design, path in zip(study.designs, files):
        assert f"layout {design.content_hash()[:8]} = {path}" in report
    assert study.designs[0].content_hash() != study.designs[1].content_hash() and res.failed == 0
    assert (study.out_dir / "layouts.png").is_file()  # the outlines beside their means: which hash looks how
    (tmp_path / "plain").mkdir()
    plain = _study(tmp_path / "plain", n1=1, n2=1)
    run_sweep(plain, fake_evaluate, progress=False)
    assert not (plain.out_dir / "layouts.png").exists()  # a grid over widths has no layout files to draw


def fake_evaluate_dead_ends(design, phantom, settings) -> dict:
    """TEST DOUBLE whose w = 2 design reports reference rows at round-off (a dead-end channel)."""
    return {**fake_evaluate(design, phantom, settings), "min_reference_rel": 1e-12 if design.width_mm == 2 else 0.01}


@pytest.mark.parametrize("floor, warned", [(0.0, True), (1e-4, False)])
def test_report_warns_of_reference_rows_at_round_off(tmp_path, floor, warned):
    path = tmp_path / "study.toml"
    path.write_text(STUDY.format(out=(tmp_path / "out").as_posix(), n1=2, n2=0)
                    + f"[physics]\nmeasurement_floor_rel = {floor}\n")
    res = run_sweep(load_study(path), fake_evaluate_dead_ends, progress=False)
    lines = [line for line in res.report if line.startswith("warning:") and "round-off" in line]
    assert len(lines) == int(warned)
    assert ("instrument floor of 0.0001" in res.report[0]) == (floor > 0)  # the report says which V_rel it read
    if warned:  # names the design with the dead end, not the other, and the key that mends it
        assert "(width = 2 mm)" in lines[0] and "width = 0" not in lines[0]
        assert "1e-12" in lines[0] and "physics.measurement_floor_rel" in lines[0]
