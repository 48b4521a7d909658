"""The two-level sweep: both levels through the store, the fine count per design, resume, outputs, CLI.

The model is a TEST DOUBLE (``fake_two_level``): a cheap deterministic function of design, phantom and mesh size
whose coarse value is a biased, noisy copy of the fine one. It exercises the machinery, not physics.
"""

from __future__ import annotations

import csv
import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from doubles import logged_calls, record_call, run_cli

from latticeopt.errors import ConvergenceError
from latticeopt.study.config import load_study
from latticeopt.study.multilevel import fine_order, multilevel_estimate, take_all_mask
from latticeopt.study.multilevel_report import model_seconds
from latticeopt.study.settings import coarse_level_settings
from latticeopt.study.store import ResultStore
from latticeopt.study.sweep import run_sweep

LOG_ENV = "LATTICEOPT_TEST_ML_LOG"
STOP_ENV = "LATTICEOPT_TEST_ML_STOP"  # interrupt (KeyboardInterrupt) once this many calls are logged


def _fine_value(design, phantom) -> float:
    load = sum(t.depth_mm * t.radius_mm for t in phantom.touches)
    return 1e-3 * load * (1 + 0.05 * design.width_mm) / design.thickness_mm


def _value(design, phantom, size_mm: float) -> float:
    f = _fine_value(design, phantom)
    if size_mm <= 3.0:
        return f
    return 0.9 * f - 2e-3 + 1e-3 * math.sin(7.0 * phantom.index + 3.0 * phantom.n_touches + design.width_mm)


def _size(settings) -> float:
    """Mesh size of the level's mechanics (the coarse level solves its mechanics on ``mechanics_mesh``)."""
    return (settings.mechanics_mesh or settings.mesh).size_mm


def fake_two_level(design, phantom, settings) -> dict:
    """TEST DOUBLE: fine (mesh <= 3 mm) and coarse values of one phantom; logs every call."""
    record_call(f"{_size(settings)} {design.content_hash()} {phantom.key}", LOG_ENV, STOP_ENV)
    return {"v_rel": _value(design, phantom, _size(settings))}


def fake_two_level_physics(design, phantom, settings) -> dict:
    """TEST DOUBLE: as fake_two_level, with the coarse value offset by the ``mechanics_rtol`` it was run with."""
    out = fake_two_level(design, phantom, settings)
    out["v_rel"] += settings.physics.get("mechanics_rtol", 0.0)
    return out


def fake_two_level_folding(design, phantom, settings) -> dict:
    """TEST DOUBLE: as fake_two_level; the coarse level's electrics "fell back" on 3-touch phantom 0."""
    out = fake_two_level(design, phantom, settings)
    if settings.mechanics_mesh is not None and phantom.n_touches == 3 and phantom.index == 0:
        out["electrics_mesh"] = "mechanics"
    return out


def fake_two_level_failing(design, phantom, settings) -> dict:
    """TEST DOUBLE: as fake_two_level, but the fine level of the w = 4 design fails on 2-touch phantom 0."""
    if _size(settings) <= 3.0 and design.width_mm == 4 and phantom.n_touches == 2 and phantom.index == 0:
        raise ConvergenceError("fake: the fine mechanics did not converge")
    return fake_two_level(design, phantom, settings)


STUDY = """
name = "ml"
out = "{out}"
[design]
thickness_mm = 3.0
[grid]
width_mm = [2, 4]
[phantoms]
seed = 3
counts = {{ 1 = 12, 2 = 12, 3 = 12 }}
[mesh]
size_mm = 2.0
[multilevel]
coarse = {{ size_mm = 4.0, channel_cells = 1 }}
pilot = {pilot}
se_factor = {factor}
take_all = {take_all}
"""


def _study(tmp_path: Path, pilot=6, factor=1.1, out="out", overrides=(), take_all=0.0):
    path = tmp_path / "study.toml"
    path.write_text(STUDY.format(out=(tmp_path / out).as_posix(), pilot=pilot, factor=factor, take_all=take_all))
    return load_study(path, overrides)


def test_estimates_match_the_statistics_and_meet_the_criterion(tmp_path, monkeypatch):
    monkeypatch.setenv(LOG_ENV, str(tmp_path / "calls.log"))
    study = _study(tmp_path)
    res = run_sweep(study, fake_two_level, progress=False)
    ml = res.multilevel
    nph = len(study.phantoms)
    strata = np.array([p.n_touches for p in study.phantoms])
    order = fine_order(strata)
    assert list(ml.order) == [int(j) for j in order]  # nothing failed: every phantom is used
    calls = logged_calls(tmp_path / "calls.log")
    assert len(calls) == len(set(calls)) == 2 * nph + sum(ml.n_fine)  # every evaluation once
    with open(res.outputs["summary"]) as fh:
        summary = list(csv.DictReader(fh))
    for i, design in enumerate(study.designs):
        n = ml.n_fine[i]
        assert 6 <= n < nph  # the coarse level is informative here: fewer than all fine
        c = np.array([_value(design, p, 4.0) for p in study.phantoms])
        f = np.full(nph, np.nan)
        f[order[:n]] = [_fine_value(design, study.phantoms[j]) for j in order[:n]]
        want = multilevel_estimate(c, f, strata)
        assert ml.estimates[i] == want
        assert want.se <= 1.1 * want.plain_fine_se
        row = summary[i]
        assert float(row["v_rel_mean"]) == pytest.approx(want.mean, rel=1e-12)
        assert float(row["v_rel_se"]) == pytest.approx(want.se, rel=1e-12)
        assert (int(row["n_fine"]), int(row["n_coarse"])) == (n, nph)
        assert float(row["plain_fine_se_est"]) == pytest.approx(want.plain_fine_se, rel=1e-12)
        # the estimate is close to the true fine mean of these phantoms (within 3 SE)
        true = np.mean([_fine_value(design, p) for p in study.phantoms])
        assert abs(want.mean - true) < 3 * want.se
    with ResultStore(res.out_dir, readonly=True) as store:
        assert len(store.done_keys(ml.coarse_settings.key)) == 2 * nph
        assert len(store.done_keys(ml.fine_settings.key)) == sum(ml.n_fine)
    assert ml.coarse_settings.key != ml.fine_settings.key
    report = (res.out_dir / "report.txt").read_text()
    assert "two-level estimator" in report and "best minus runner-up" in report and "model time:" in report
    cost = model_seconds(study, ml)  # the all-fine cost: each design's mean fine seconds times its phantoms
    want = sum(nph * np.mean([e.seconds for (d, _), e in ml.fine.items() if d == i]) for i in range(2))
    assert cost["plain"] == pytest.approx(want, rel=1e-12) and cost["plain"] > cost["fine"]
    again = run_sweep(_study(tmp_path), fake_two_level, progress=False)
    assert again.computed == 0 and len(logged_calls(tmp_path / "calls.log")) == len(calls)
    assert again.multilevel.estimates == ml.estimates


def test_take_all_phantoms_come_first_for_every_design_and_enter_the_estimate(tmp_path, monkeypatch):
    """multilevel.take_all: per touch count the phantoms whose coarse V_rel ranks highest on average over the
    designs get the fine level first, for every design; the estimate treats them as measured, not sampled."""
    monkeypatch.setenv(LOG_ENV, str(tmp_path / "calls.log"))
    study = _study(tmp_path, take_all=0.25)
    ml = run_sweep(study, fake_two_level, progress=False).multilevel
    strata = np.array([p.n_touches for p in study.phantoms])
    coarse = np.array([[_value(d, p, 4.0) for p in study.phantoms] for d in study.designs])
    ranks = np.zeros(strata.size)  # each design's coarse rank within the touch count, summed
    for c in coarse:
        for k in (1, 2, 3):
            idx = np.flatnonzero(strata == k)
            ranks[idx] += np.argsort(np.argsort(c[idx]))
    want = set(np.flatnonzero(take_all_mask(ranks, strata, 0.25)).tolist())
    assert len(want) == 9 and set(ml.take_all) == want  # ceil(0.25 * 12) of each touch count
    assert set(ml.order[:9]) == want
    for i, design in enumerate(study.designs):
        n = ml.n_fine[i]
        assert n >= 9 + 6  # the take-all phantoms and the pilot
        f = np.full(strata.size, np.nan)
        f[list(ml.order[:n])] = [_fine_value(design, study.phantoms[j]) for j in ml.order[:n]]
        mask = np.isin(np.arange(strata.size), list(want))
        assert ml.estimates[i] == multilevel_estimate(coarse[i], f, strata, take_all=mask)
        assert ml.estimates[i] != multilevel_estimate(coarse[i], f, strata)  # the parts change the estimate


def test_depth_parts_split_the_sampled_phantoms_and_enter_the_estimate(tmp_path, monkeypatch):
    """multilevel.depth_split_mm: each touch count's sampled phantoms (not take-all) are shallow or deep by their
    deepest touch; the order interleaves both in proportion and the estimate takes each as a part of its own."""
    monkeypatch.setenv(LOG_ENV, str(tmp_path / "calls.log"))
    path = tmp_path / "study.toml"
    path.write_text(STUDY.format(out=(tmp_path / "out").as_posix(), pilot=6, factor=1.1, take_all=0.1)
                    .replace("counts = { 1 = 12, 2 = 12, 3 = 12 }", "counts = { 1 = 30, 2 = 30, 3 = 30 }"))
    deepest = np.array([max(t.depth_mm for t in p.touches) for p in load_study(path).phantoms])
    split = float(np.median(deepest))
    study = load_study(path, [f"multilevel.depth_split_mm={split}"])
    res = run_sweep(study, fake_two_level, progress=False)
    ml = res.multilevel
    strata = np.array([p.n_touches for p in study.phantoms])
    tail = np.isin(np.arange(strata.size), list(ml.take_all))
    want = {j for j in range(strata.size) if deepest[j] > split and not tail[j]
            and min(np.sum((strata == strata[j]) & ~tail & (deepest > split)),
                    np.sum((strata == strata[j]) & ~tail & (deepest <= split))) >= 10}
    assert want and set(ml.deep) == want
    assert f"shallow and deep parts, {len(want)} deeper than {split:g} mm" in (res.out_dir / "report.txt").read_text()
    sampled = list(ml.order[len(ml.take_all):])
    for n in (6, 20, 40):  # every prefix holds each touch count's deep share within a phantom or two
        for k in (1, 2, 3):
            cell = [j for j in sampled if strata[j] == k]
            share = np.mean([j in want for j in cell])
            got = sum(j in want for j in sampled[:n] if strata[j] == k)
            assert abs(got - share * sum(strata[j] == k for j in sampled[:n])) <= 1.5
    coarse = np.array([[_value(d, p, 4.0) for p in study.phantoms] for d in study.designs])
    parts = np.isin(np.arange(strata.size), list(want)).astype(int)
    for i, design in enumerate(study.designs):
        n = ml.n_fine[i]
        f = np.full(strata.size, np.nan)
        f[list(ml.order[:n])] = [_fine_value(design, study.phantoms[j]) for j in ml.order[:n]]
        assert ml.estimates[i] == multilevel_estimate(coarse[i], f, strata, take_all=tail, parts=parts)
        assert ml.estimates[i] != multilevel_estimate(coarse[i], f, strata, take_all=tail)


def test_se_factor_one_runs_every_phantom_fine_and_equals_the_plain_sweep(tmp_path):
    study = _study(tmp_path, factor=1.0)
    ml = run_sweep(study, fake_two_level, progress=False).multilevel
    assert ml.n_fine == (len(study.phantoms),) * 2
    plain = dataclasses.replace(study, multilevel=None)  # the plain estimator on the fine mesh
    res = run_sweep(plain, fake_two_level, progress=False, out_dir=tmp_path / "plain")
    with open(res.outputs["summary"]) as fh:
        rows = list(csv.DictReader(fh))
    for e, row in zip(ml.estimates, rows):
        assert e.mean == pytest.approx(float(row["v_rel_mean"]), rel=1e-12)
    # every phantom fine: the all-fine cost the report extrapolates is exactly the fine seconds spent
    cost = model_seconds(study, ml)
    assert cost["plain"] == pytest.approx(cost["fine"], rel=1e-12) and cost["fine"] > 0
    assert cost["two_level"] == pytest.approx(cost["coarse"] + cost["fine"], rel=1e-12)
    assert cost["coarse"] == pytest.approx(sum(e.seconds for e in ml.coarse), rel=1e-12)


def test_interrupted_run_resumes_without_recomputing(tmp_path, monkeypatch):
    log = tmp_path / "calls.log"
    monkeypatch.setenv(LOG_ENV, str(log))
    ref = run_sweep(_study(tmp_path, out="ref"), fake_two_level, progress=False).multilevel
    log.unlink()
    total = 2 * 36 + sum(ref.n_fine)
    stop = 2 * 36 + 3  # past the coarse level, inside the fine pilot
    monkeypatch.setenv(STOP_ENV, str(stop))
    with pytest.raises(KeyboardInterrupt):
        run_sweep(_study(tmp_path), fake_two_level, progress=False)
    assert len(logged_calls(log)) == stop
    monkeypatch.delenv(STOP_ENV)
    res = run_sweep(_study(tmp_path), fake_two_level, progress=False)
    calls = logged_calls(log)
    assert len(calls) == len(set(calls)) == total  # nothing computed twice
    assert res.computed == total - stop
    assert res.multilevel.estimates == ref.estimates and res.multilevel.n_fine == ref.n_fine


def _cli(tmp_path: Path, *extra: str):
    return run_cli("sweep", str(tmp_path / "study.toml"), "--evaluate", "test_multilevel_sweep:fake_two_level",
                   "--no-progress", "--jobs", "1", *extra)


@pytest.mark.parametrize("setting, key", [("multilevel.pilot=1", "--set multilevel.pilot"),
                                          ("multilevel.se_factor=0.5", "--set multilevel.se_factor"),
                                          ("multilevel.coarse.size_mm=-4", "--set multilevel.coarse.size_mm"),
                                          ("multilevel.coarse_physics.mechanics_rtol=2",
                                           "multilevel.coarse_physics.mechanics_rtol"),
                                          ("multilevel.coarse_physics.gel=2", "multilevel.coarse_physics"),
                                          ("multilevel.coarse_physics=3", "multilevel.coarse_physics"),
                                          ("multilevel.coarse_electrics=both", "multilevel.coarse_electrics"),
                                          ("multilevel.control=best", "--set multilevel.control"),
                                          ("multilevel.take_all=0.6", "--set multilevel.take_all"),
                                          ("multilevel.take_all='all'", "--set multilevel.take_all"),
                                          ("multilevel.depth_split_mm=-1", "--set multilevel.depth_split_mm"),
                                          ("multilevel.depth_split_mm=inf", "--set multilevel.depth_split_mm")])
def test_cli_bad_values_exit_2_with_one_line_naming_the_key(tmp_path, setting, key):
    _study(tmp_path)
    done = _cli(tmp_path, "--set", setting)
    assert done.returncode == 2
    err = done.stderr.strip().splitlines()
    assert len(err) == 1 and key in err[0]
    assert not (tmp_path / "out" / "results.sqlite").exists()  # refused before any work


def test_cli_bad_control_names_the_key_the_allowed_values_and_what_arrived(tmp_path):
    _study(tmp_path)
    done = _cli(tmp_path, "--set", "multilevel.control=beta1")
    assert done.returncode == 2 and "Traceback" not in done.stderr
    (line,) = done.stderr.strip().splitlines()
    assert "multilevel.control" in line and "'fixed'" in line and "'fitted'" in line and "beta1" in line


def test_fitted_control_reuses_every_stored_row_and_reports_its_beta(tmp_path, monkeypatch):
    # the store holds per-phantom values, which the estimator does not change: the same study with
    # control = "fitted" reads every coarse row and the fine rows it shares, and runs only the fine phantoms
    # its own stopping rule asks for beyond them
    log = tmp_path / "calls.log"
    monkeypatch.setenv(LOG_ENV, str(log))
    fixed = run_sweep(_study(tmp_path), fake_two_level, progress=False)
    assert "control fixed: beta = 1" in (fixed.out_dir / "report.txt").read_text()
    before = len(logged_calls(log))
    study = _study(tmp_path, overrides=["multilevel.control=fitted"])
    res = run_sweep(study, fake_two_level, progress=False)
    ml, ref = res.multilevel, fixed.multilevel
    assert (ml.coarse_settings.key, ml.fine_settings.key) == (ref.coarse_settings.key, ref.fine_settings.key)
    assert ml.computed_coarse == 0
    assert ml.computed_fine == sum(max(0, a - b) for a, b in zip(ml.n_fine, ref.n_fine))
    assert len(logged_calls(log)) == before + ml.computed_fine
    with open(res.outputs["summary"]) as fh:
        summary = list(csv.DictReader(fh))
    report = (res.out_dir / "report.txt").read_text()
    assert "control fitted" in report
    for i in range(len(study.designs)):
        want = multilevel_estimate(*ml.level_arrays(study, i), control="fitted")
        assert ml.estimates[i] == want and abs(want.beta - 1) > 0.05  # the fake coarse level is 0.9 F + ...
        assert want.se <= 1.1 * want.plain_fine_se
        assert float(summary[i]["beta"]) == pytest.approx(want.beta, rel=1e-12)
        assert f"fitted beta {want.beta:.3f}" in report
        assert multilevel_estimate(*ml.level_arrays(study, i)).beta == 1.0


def test_cli_set_pilot_runs_and_prints_the_report(tmp_path):
    _study(tmp_path)
    done = _cli(tmp_path, "--set", "multilevel.pilot=9")
    assert done.returncode == 0, done.stderr
    assert "two-level estimator" in done.stdout and "pilot 9" in done.stdout


def test_cli_dry_run_counts_what_each_level_has_stored(tmp_path):
    study = _study(tmp_path, overrides=['model = "test_multilevel_sweep:fake_two_level"'])  # as --evaluate sets it
    before = _cli(tmp_path, "--dry-run")
    assert before.returncode == 0, before.stderr
    assert "72 evaluations, 0 stored" in before.stdout and "0 of 72 stored" in before.stdout
    assert not (tmp_path / "out" / "results.sqlite").exists()
    assert _cli(tmp_path).returncode == 0
    with ResultStore(study.out_dir, readonly=True) as store:
        n_fine = len(store.done_keys(study.settings.key))
        n_coarse = len(store.done_keys(coarse_level_settings(study.settings, study.multilevel).key))
    assert n_coarse == 72 and 2 * 6 <= n_fine < 72
    after = _cli(tmp_path, "--dry-run")
    assert f"72 evaluations, {n_fine} stored" in after.stdout and "72 of 72 stored" in after.stdout


def test_a_fine_failure_leaves_the_phantom_out_for_every_design_at_both_levels(tmp_path):
    study = _study(tmp_path)
    res = run_sweep(study, fake_two_level_failing, progress=False)
    ml = res.multilevel
    bad = next(j for j, p in enumerate(study.phantoms) if p.n_touches == 2 and p.index == 0)
    assert bad in fine_order(np.array([p.n_touches for p in study.phantoms]))[:6]  # it was in the pilot
    assert not ml.fine[(1, bad)].ok and bad not in ml.used and len(ml.used) == len(study.phantoms) - 1
    for i, design in enumerate(study.designs):
        prefix = ml.order[:ml.n_fine[i]]
        assert bad not in prefix and all(ml.fine[(i, j)].ok for j in prefix)
        c, f, s, whole = ml.level_arrays(study, i)
        want = multilevel_estimate(c, f, s, whole)
        assert ml.estimates[i] == want and want.n_coarse == len(study.phantoms) - 1
        kept = [study.phantoms[j] for j in ml.used]
        assert c.tolist() == [_value(design, p, 4.0) for p in kept]
    with open(res.outputs["summary"]) as fh:
        assert [int(r["failed_fine"]) for r in csv.DictReader(fh)] == [0, 1]
    report = (study.out_dir / "report.txt").read_text()
    assert "failed: 0 coarse and 1 fine evaluations, on 1 of 36 phantoms" in report
    assert "failed phantom 2:0 (2 touches, index 0): fine, width = 4 mm: ConvergenceError" in report
    assert """--set 'phantoms.only=["2:0"]'""" in report


def test_coarse_mesh_changes_only_the_keys_given_and_keeps_the_rest_of_the_fine_mesh(tmp_path):
    fine = {"mesher": "grid", "size_mm": 2.0, "channel_cells": 2, "layer_cells": 3, "electrode_edges": False}
    tail = "\n".join(f"{k} = {str(v).lower() if isinstance(v, bool) else repr(v)}" for k, v in fine.items())
    text = STUDY.format(out=(tmp_path / "out").as_posix(), pilot=6, factor=1.1, take_all=0).replace(
        "[mesh]\nsize_mm = 2.0", "[mesh]\n" + tail.replace("'", '"'))
    path = tmp_path / "study.toml"
    path.write_text(text)
    ml = load_study(path).multilevel
    assert (ml.coarse.size_mm, ml.coarse.channel_cells) == (4.0, 1)
    assert (ml.coarse.mesher, ml.coarse.layer_cells, ml.coarse.electrode_edges) == ("grid", 3, False)
    path.write_text(text.replace("coarse = { size_mm = 4.0, channel_cells = 1 }", "coarse = { size_mm = 3.0 }"))
    ml = load_study(path).multilevel
    assert (ml.coarse.size_mm, ml.coarse.channel_cells, ml.coarse.layer_cells) == (3.0, 2, 3)
    path.write_text(text.replace("\n[multilevel]\n", "\n[multilevel]\n").replace(
        "coarse = { size_mm = 4.0, channel_cells = 1 }\n", ""))
    ml = load_study(path).multilevel  # no coarse key: 4 mm, 1 channel cell, the rest from [mesh]
    assert (ml.coarse.size_mm, ml.coarse.channel_cells, ml.coarse.layer_cells, ml.coarse.electrode_edges) == (
        4.0, 1, 3, False)


def test_coarse_physics_changes_the_coarse_level_only(tmp_path):
    study = _study(tmp_path, overrides=["physics.mechanics_rtol=1e-5", "multilevel.coarse_physics.mechanics_rtol=0.01"])
    assert study.multilevel.coarse_physics == (("mechanics_rtol", 0.01),)
    ml = run_sweep(study, fake_two_level_physics, progress=False).multilevel
    assert dict(ml.coarse_settings.physics_items)["mechanics_rtol"] == 0.01
    assert dict(ml.fine_settings.physics_items)["mechanics_rtol"] == 1e-5  # the fine level keeps [physics]
    assert ml.coarse_settings.key != dataclasses.replace(ml.coarse_settings, physics_items=()).key
    design, phantom = study.designs[0], study.phantoms[0]
    assert ml.coarse[0].v_rel == pytest.approx(_value(design, phantom, 4.0) + 0.01, rel=1e-12)
    fine = ml.fine[(0, ml.order[0])]
    assert fine.v_rel == pytest.approx(_fine_value(design, study.phantoms[ml.order[0]]) + 1e-5, rel=1e-12)


def test_coarse_electrics_fine_keeps_the_fine_mesh_and_solves_the_mechanics_on_the_coarse_one(tmp_path):
    study = _study(tmp_path)
    ml = study.multilevel
    assert ml.coarse_electrics == "fine"  # the default
    hybrid = coarse_level_settings(study.settings, ml)
    assert hybrid.mesh == study.settings.mesh and hybrid.mechanics_mesh == ml.coarse
    assert hybrid.key != study.settings.key and "mechanics_mesh" not in study.settings.as_dict()
    both = coarse_level_settings(study.settings, dataclasses.replace(ml, coarse_electrics="coarse"))
    assert both.mesh == ml.coarse and both.mechanics_mesh is None
    assert len({hybrid.key, both.key, study.settings.key}) == 3
    res = run_sweep(_study(tmp_path, overrides=["multilevel.coarse_electrics=coarse"]), fake_two_level,
                    progress=False)
    assert res.multilevel.coarse_settings.mesh.size_mm == 4.0
    assert "electrics on the coarse mesh" in (res.out_dir / "report.txt").read_text()


def test_coarse_evaluations_whose_electrics_fell_back_are_marked_and_counted(tmp_path):
    study = _study(tmp_path)
    res = run_sweep(study, fake_two_level_folding, progress=False)
    with open(res.outputs["results"]) as fh:
        rows = list(csv.DictReader(fh))
    marked = [(r["level"], int(r["n_touches"]), int(r["phantom_index"])) for r in rows if r["electrics_on"] == "coarse"]
    assert sorted(marked) == [("coarse", 3, 0)] * len(study.designs)
    assert {r["electrics_on"] for r in rows if r["level"] == "fine"} == {"fine"}
    assert "folded in 2 of 72 evaluations" in (res.out_dir / "report.txt").read_text()


def fake_two_level_dead_end(design, phantom, settings) -> dict:
    """TEST DOUBLE: as fake_two_level; the w = 4 design reports reference rows at round-off."""
    return {**fake_two_level(design, phantom, settings), "min_reference_rel": 1e-13 if design.width_mm == 4 else 1e-3}


@pytest.mark.parametrize("overrides, warned", [((), True), (("physics.measurement_floor_rel=1e-4",), False)])
def test_report_warns_of_rows_at_round_off_unless_a_floor_is_set(tmp_path, overrides, warned):
    res = run_sweep(_study(tmp_path, overrides=overrides), fake_two_level_dead_end, progress=False)
    lines = [x for x in res.report if x.startswith("warning:")]
    assert [("(width = 4 mm)" in x, "width = 2" in x) for x in lines] == ([(True, False)] if warned else [])
    assert ("instrument floor of 0.0001" in res.report[1]) == (not warned)


def test_the_figure_says_it_shows_a_two_level_estimate_and_how_many_fine_phantoms(tmp_path, saved_figures):
    study = _study(tmp_path)
    ml = run_sweep(study, fake_two_level, progress=False).multilevel
    title = " ".join(saved_figures[0].axes[0].get_title().split())  # the title wraps its lines
    lo, hi = min(ml.n_fine), max(ml.n_fine)
    span = f"{lo}-{hi}" if lo != hi else f"{lo}"
    assert f"two-level: {len(study.phantoms)} phantoms per design at the coarse level, {span} on this mesh" in title


def test_cli_two_level_on_the_quick_study_says_how_many_phantoms_and_how_to_raise_them(tmp_path):
    quick = str(Path(__file__).parents[1] / "studies" / "quick.toml")
    done = run_cli("sweep", quick, "--set", "multilevel.pilot=15", "--out", str(tmp_path / "q"), "--dry-run")
    assert done.returncode == 2
    err = done.stderr.strip().splitlines()
    assert len(err) == 1 and "phantoms.counts" in err[0]
    assert "got {1: 1, 2: 1, 3: 1}" in err[0]  # phantoms per touch count, not the touch counts
    assert "--set 'phantoms.counts={ 1 = 2, 2 = 2, 3 = 2 }'" in err[0]
    raised = run_cli("sweep", quick, "--set", "multilevel.pilot=15", "--set", "phantoms.counts={ 1 = 2, 2 = 2, 3 = 2 }",
                     "--out", str(tmp_path / "q"), "--dry-run")
    assert raised.returncode == 0, raised.stderr
    assert "two-level" in raised.stdout and not (tmp_path / "q" / "results.sqlite").exists()
