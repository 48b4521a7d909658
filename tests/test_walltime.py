"""``sweep --dry-run``'s wall-time estimate: measured per-phantom seconds from the store when it has rows with the
study's settings, else the documented figure scaled by mesh size; a range for the two-level estimator.

The model is a TEST DOUBLE (``slow_fake``): a constant V_rel after a short sleep, so the store records seconds.
"""

from __future__ import annotations

import statistics
import time
from pathlib import Path

from doubles import run_cli

from latticeopt.study.config import load_study
from latticeopt.study.estimators import estimator_for
from latticeopt.study.settings import coarse_level_settings
from latticeopt.study.store import ResultStore
from latticeopt.study.sweep import run_sweep
from latticeopt.study.walltime import SECONDS_AT_2MM, format_seconds, wall_time

STUDY = """
name = "walltime"
out = "{out}"
jobs = 2
[design]
thickness_mm = 3.0
[grid]
width_mm = {widths}
[phantoms]
seed = 3
counts = {{ 1 = 2, 2 = 2 }}
[mesh]
size_mm = {size}
{extra}
"""


def slow_fake(design, phantom, settings) -> dict:
    """TEST DOUBLE: V_rel from the width and the phantom, 20 ms of wall time each."""
    time.sleep(0.02)
    return {"v_rel": 0.01 * (1 + design.width_mm) + 1e-3 * phantom.index}


def _study(tmp_path: Path, widths="[0, 2]", size=5.0, extra="", model=None):
    text = STUDY.format(out=(tmp_path / "out").as_posix(), widths=widths, size=size, extra=extra)
    if model:
        text = f'model = "{model}"\n' + text
    (tmp_path / "study.toml").write_text(text)
    return load_study(tmp_path / "study.toml")


def _estimate(study, workers=None):
    tasks = [(d.content_hash(), p.key) for d, p in study.tasks()]
    return wall_time(estimator_for(study).levels(study.settings), tasks, study.out_dir,
                     study.jobs if workers is None else workers)


def test_without_a_store_the_documented_cost_scaled_by_mesh_size(tmp_path):
    at_2 = _estimate(_study(tmp_path, size=2.0))
    at_4 = _estimate(_study(tmp_path, size=4.0))
    assert at_2.least_s == at_2.most_s == 8 * SECONDS_AT_2MM / 2  # 2 designs x 4 phantoms on 2 workers
    assert at_4.most_s == at_2.most_s / 8
    assert _estimate(_study(tmp_path, size=2.0), workers=1).most_s == 2 * at_2.most_s
    line = at_4.line()
    assert line.startswith(f"estimated wall time: {format_seconds(at_4.most_s)} on 2 workers; 8 to run")
    assert "estimated: " in line and "docs/performance.md x (2 / 4)^3" in line and "no stored rows" in line
    # finer than 2 mm the factorization's n^2 work takes over: 1.4 mm runs took about 8x their 2 mm seconds
    at_14 = _estimate(_study(tmp_path, size=1.4))
    assert 8.0 < at_14.most_s / at_2.most_s < 9.0
    assert "x (2 / 1.4)^6" in at_14.line()


def test_stored_rows_give_the_measured_seconds_and_only_what_is_missing_counts(tmp_path):
    run_sweep(_study(tmp_path), slow_fake, progress=False, outputs=False)
    study = _study(tmp_path, widths="[0, 2, 4]", model="test_walltime:slow_fake")  # one design more
    with ResultStore(study.out_dir, readonly=True) as store:
        seconds = [e.seconds for e in store.rows(settings_key=study.settings.key)]
    assert len(seconds) == 8 and min(seconds) >= 0.02
    est = _estimate(study)
    (level,) = est.levels
    assert level.measured_rows == 8 and level.to_run == (4, 4)
    assert abs(est.most_s - 4 * statistics.fmean(seconds) / 2) < 1e-9
    assert "measured: mean of 8 stored rows" in est.line() and "docs/performance.md" not in est.line()


def test_other_settings_do_not_count_as_measured(tmp_path):
    run_sweep(_study(tmp_path), slow_fake, progress=False, outputs=False)
    est = _estimate(_study(tmp_path, size=4.0, model="test_walltime:slow_fake"))  # another mesh: another key
    assert est.levels[0].measured_rows == 0 and est.levels[0].to_run == (8, 8)
    assert "the cost of latticeopt.coupled:evaluate_phantom, not of test_walltime:slow_fake" in est.line()


def test_two_level_is_a_range_from_the_pilot_to_every_phantom(tmp_path):
    study = _study(tmp_path, size=2.0, extra="[multilevel]\npilot = 2\ntake_all = 0\ncoarse = { size_mm = 4.0 }")
    coarse, fine = est_levels = _estimate(study).levels
    assert [lv.name for lv in est_levels] == ["coarse", "fine"]
    assert coarse.to_run == (8, 8) and coarse.mesh_mm == 4.0 and fine.to_run == (2 * 2, 8)
    # the take-all phantoms come on top of the pilot: ceil(0.05 x 2) = 1 of each of the two touch counts
    with_take_all = _study(tmp_path, size=2.0, extra="[multilevel]\npilot = 2\ncoarse = { size_mm = 4.0 }")
    assert _estimate(with_take_all).levels[1].to_run == (2 * (2 + 2), 8)
    est = _estimate(study)
    assert est.least_s == (8 * coarse.seconds + 4 * fine.seconds) / 2
    assert est.most_s == (8 * coarse.seconds + 8 * fine.seconds) / 2
    assert f"{format_seconds(est.least_s)} to {format_seconds(est.most_s)}" in est.line()
    assert coarse_level_settings(study.settings, study.multilevel).key != study.settings.key


def test_cli_dry_run_prints_the_estimate_and_where_it_comes_from(tmp_path):
    _study(tmp_path)
    args = ("sweep", str(tmp_path / "study.toml"), "--evaluate", "test_walltime:slow_fake", "--no-progress")
    before = run_cli(*args, "--dry-run", "--jobs", "1")
    assert before.returncode == 0, before.stderr
    assert "estimated wall time:" in before.stdout and "on 1 worker;" in before.stdout
    assert "no stored rows with these settings" in before.stdout
    assert not (tmp_path / "out").exists()  # a dry run writes nothing
    assert run_cli(*args, "--jobs", "1").returncode == 0
    after = run_cli(*args, "--dry-run")
    assert after.returncode == 0, after.stderr
    assert "estimated wall time: 0 s on 2 workers; 0 to run" in after.stdout
    assert "measured: mean of 8 stored rows" in after.stdout
