"""Adaptive phantom counts (``[phantoms] target_se``): stopping rule, common prefix, resume, outputs, schema, CLI.

The model is a TEST DOUBLE (``fake_spread``): a cheap deterministic function of design and phantom whose spread
over phantoms is set by the design's channel width (w = 2: tiny, w = 3: moderate, w = 4: large). It exercises the
machinery, not physics.
"""

from __future__ import annotations

import csv
import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from doubles import logged_calls, record_call, run_cli

from latticeopt.errors import ConvergenceError, ParameterError
from latticeopt.study.adaptive_sweep import next_count
from latticeopt.study.config import load_study
from latticeopt.study.multilevel import fine_order
from latticeopt.study.settings import AdaptiveSettings
from latticeopt.study.sweep import run_sweep

LOG_ENV = "LATTICEOPT_TEST_AD_LOG"
STOP_ENV = "LATTICEOPT_TEST_AD_STOP"  # interrupt (KeyboardInterrupt) once this many calls are logged
SPREAD = {2: 0.001, 3: 0.012, 4: 0.05}  # amplitude of the per-phantom noise by width_mm
TARGET, MIN, BATCH, TOTAL = 0.002, 6, 5, 36


def _noise(phantom) -> float:
    """A fixed pseudo-random number in [-1, 1) per phantom."""
    x = math.sin(12.9898 * phantom.index + 78.233 * phantom.n_touches) * 43758.5453
    return 2.0 * (x - math.floor(x)) - 1.0


def _value(design, phantom) -> float:
    return 0.02 + 0.002 * design.width_mm + SPREAD[int(design.width_mm)] * _noise(phantom)


def fake_spread(design, phantom, settings) -> dict:
    """TEST DOUBLE: V_rel with a design-dependent spread over phantoms; logs every call."""
    record_call(f"{design.content_hash()} {phantom.key}", LOG_ENV, STOP_ENV)
    return {"v_rel": _value(design, phantom)}


def fake_spread_failing(design, phantom, settings) -> dict:
    """TEST DOUBLE: as fake_spread, but the w = 2 design fails on 2-touch phantom 0."""
    if design.width_mm == 2 and phantom.n_touches == 2 and phantom.index == 0:
        raise ConvergenceError("fake: the mechanics did not converge")
    return fake_spread(design, phantom, settings)


STUDY = """
name = "ad"
out = "{out}"
[design]
thickness_mm = 3.0
[grid]
width_mm = [2, 3, 4]
[phantoms]
seed = 3
counts = {{ 1 = 12, 2 = 12, 3 = 12 }}
{extra}
"""


def _study(tmp_path: Path, out="out", overrides=(), extra=None, tail=""):
    if extra is None:
        extra = f"target_se = {TARGET}\nmin_per_design = {MIN}\nbatch_size = {BATCH}\n"
    path = tmp_path / "study.toml"
    path.write_text(STUDY.format(out=(tmp_path / out).as_posix(), extra=extra) + tail)
    return load_study(path, overrides)


def _se(x) -> float:
    return float(np.std(x, ddof=1) / math.sqrt(len(x)))


def _expected_count(values) -> int:
    """The rule, written out independently: MIN first, BATCH more while the SE is above TARGET, at most all."""
    n = MIN
    while n < len(values) and _se(values[:n]) > TARGET:
        n = min(len(values), n + BATCH)
    return n


def test_low_spread_stops_early_high_spread_runs_to_the_maximum(tmp_path, monkeypatch):
    monkeypatch.setenv(LOG_ENV, str(tmp_path / "calls.log"))
    study = _study(tmp_path)
    res = run_sweep(study, fake_spread, progress=False)
    ad = res.adaptive
    order = [int(j) for j in fine_order(np.array([p.n_touches for p in study.phantoms]))]
    assert list(ad.order) == order and ad.excluded == ()
    assert ad.n[0] == MIN  # tiny spread: the first SE check passes
    assert ad.n[2] == TOTAL  # large spread: never meets the target
    assert MIN < ad.n[1] < TOTAL  # moderate spread: stops in between
    for i, design in enumerate(study.designs):
        values = [_value(design, study.phantoms[j]) for j in order]
        assert ad.n[i] == _expected_count(values)
    calls = logged_calls(tmp_path / "calls.log")
    assert len(calls) == len(set(calls)) == sum(ad.n) == res.computed  # every evaluation once, nothing extra
    with open(res.outputs["summary"]) as fh:
        summary = list(csv.DictReader(fh))
    for i, design in enumerate(study.designs):
        values = [_value(design, study.phantoms[j]) for j in order[:ad.n[i]]]
        row = summary[i]
        assert int(row["n"]) == ad.n[i] and int(row["n_max"]) == TOTAL
        assert float(row["v_rel_mean"]) == pytest.approx(np.mean(values), rel=1e-12)
        assert float(row["v_rel_se"]) == pytest.approx(_se(values), rel=1e-12)
        assert row["target_met"] == str(_se(values) <= TARGET)
    assert [r["target_met"] for r in summary] == ["True", "True", "False"]
    report = (res.out_dir / "report.txt").read_text()
    assert "target NOT met" in report and report.count("target met") == 2
    assert f"n = {MIN} of {TOTAL}" in report and f"n = {TOTAL} of {TOTAL}" in report


def test_designs_run_a_common_balanced_prefix_and_pair_on_the_shared_part(tmp_path):
    study = _study(tmp_path)
    res = run_sweep(study, fake_spread, progress=False)
    ad = res.adaptive
    order = [int(j) for j in fine_order(np.array([p.n_touches for p in study.phantoms]))]
    for i in range(len(study.designs)):
        ran = sorted(j for (d, j) in ad.evaluations if d == i)
        assert ran == sorted(order[:ad.n[i]])  # a prefix of the one common order
    first = [study.phantoms[j].n_touches for j in order[:MIN]]
    assert sorted(first) == [1, 1, 2, 2, 3, 3]  # touch counts interleaved, not the single touches first
    # best and runner-up by mean over each design's own prefix, paired over the shorter of their prefixes
    means = [np.mean([_value(d, study.phantoms[j]) for j in order[:ad.n[i]]]) for i, d in enumerate(study.designs)]
    a, b = np.argsort(means)[::-1][:2]
    m = min(ad.n[a], ad.n[b])
    assert m < max(ad.n[a], ad.n[b])  # the two ran different counts: the pairing is over the shared part
    diffs = [_value(study.designs[a], study.phantoms[j]) - _value(study.designs[b], study.phantoms[j])
             for j in order[:m]]
    line = next(s for s in res.report if s.startswith("best minus runner-up"))
    assert f"over the {m} phantoms both ran" in line
    assert f"{np.mean(diffs):.5f} ± {_se(diffs):.5f}" in line
    # the rows are the plain sweep's: running the study with every phantom computes only the rest
    plain = run_sweep(dataclasses.replace(study, adaptive=None), fake_spread, progress=False)
    assert plain.computed == 3 * TOTAL - sum(ad.n)


def test_interrupted_run_resumes_without_recomputing(tmp_path, monkeypatch):
    log = tmp_path / "calls.log"
    monkeypatch.setenv(LOG_ENV, str(log))
    ref = run_sweep(_study(tmp_path, out="ref"), fake_spread, progress=False).adaptive
    log.unlink()
    total = sum(ref.n)
    stop = 3 * MIN + 4  # past the first check, inside the later batches
    monkeypatch.setenv(STOP_ENV, str(stop))
    with pytest.raises(KeyboardInterrupt):
        run_sweep(_study(tmp_path), fake_spread, progress=False)
    assert len(logged_calls(log)) == stop
    monkeypatch.delenv(STOP_ENV)
    res = run_sweep(_study(tmp_path), fake_spread, progress=False)
    calls = logged_calls(log)
    assert len(calls) == len(set(calls)) == total  # nothing computed twice
    assert res.computed == total - stop
    assert res.adaptive.n == ref.n
    again = run_sweep(_study(tmp_path), fake_spread, progress=False)
    assert again.computed == 0 and len(logged_calls(log)) == total
    assert again.report[2:] == res.report[2:]  # the same numbers (line 2 counts what was computed now)


def test_a_failed_phantom_is_left_out_for_every_design(tmp_path):
    study = _study(tmp_path)
    res = run_sweep(study, fake_spread_failing, progress=False)
    ad = res.adaptive
    bad = next(j for j, p in enumerate(study.phantoms) if p.n_touches == 2 and p.index == 0)
    order = [int(j) for j in fine_order(np.array([p.n_touches for p in study.phantoms]))]
    assert bad in order[:MIN] and ad.excluded == (bad,) and bad not in ad.order
    assert ad.n[2] == TOTAL - 1  # the maximum is every phantom not excluded
    for i in range(len(study.designs)):
        prefix = ad.order[:ad.n[i]]
        assert all(ad.evaluations[(i, j)].ok for j in prefix)
        assert len(prefix) >= MIN  # the replacement phantom was run
    assert "1 phantoms excluded" in "\n".join(res.report)
    assert "excluded phantom 2:0 (2 touches)" in "\n".join(res.report)
    assert """--set 'phantoms.only=["2:0"]'""" in res.report[-1]


@pytest.mark.parametrize("extra, key", [
    ("target_se = 0", "phantoms.target_se"),
    ("target_se = -0.1", "phantoms.target_se"),
    ("target_se = 'small'", "phantoms.target_se"),
    ("target_se = true", "phantoms.target_se"),
    ("target_se = inf", "phantoms.target_se"),
    ("target_se = 0.01\nmin_per_design = 1", "phantoms.min_per_design"),
    ("target_se = 0.01\nmin_per_design = 2.5", "phantoms.min_per_design"),
    ("target_se = 0.01\nmin_per_design = 37", "phantoms.min_per_design"),
    ("target_se = 0.01\nbatch_size = 0", "phantoms.batch_size"),
    ("min_per_design = 10", "phantoms.min_per_design"),
    ("batch_size = 3", "phantoms.batch_size"),
    ("target_se = 0.01\nbatch = 3", "phantoms.batch"),
])
def test_bad_values_name_the_key(tmp_path, extra, key):
    with pytest.raises(ParameterError) as exc:
        _study(tmp_path, extra=extra)
    assert f": {key}" in str(exc.value) and len(str(exc.value).splitlines()) == 1


def test_target_se_with_multilevel_is_refused_naming_both(tmp_path):
    tail = "[mesh]\nsize_mm = 2.0\n[multilevel]\ncoarse = { size_mm = 4.0, channel_cells = 1 }\n"
    with pytest.raises(ParameterError) as exc:
        _study(tmp_path, tail=tail)
    text = str(exc.value)
    assert "phantoms.target_se" in text and "[multilevel]" in text and len(text.splitlines()) == 1


def test_settings_defaults_and_checks():
    s = AdaptiveSettings(target_se=1)
    assert (s.target_se, s.min_per_design, s.batch_size) == (1.0, 30, 15)
    with pytest.raises(ParameterError, match="batch_size"):
        AdaptiveSettings(target_se=0.1, batch_size=True)
    ad = AdaptiveSettings(target_se=0.5, min_per_design=3, batch_size=4)
    assert next_count([], 10, ad) == 3
    assert next_count([0.0, 1.0, 2.0], 10, ad) == 7  # SE 0.577 > 0.5: one batch more
    assert next_count([0.0, 0.1, 0.2], 10, ad) == 3  # SE 0.058: done
    assert next_count([0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0], 10, ad) == 10  # capped at the maximum
    assert next_count([0.0, 9.0], 2, ad) == 2  # every phantom run: done whatever the SE


def _cli(tmp_path: Path, *extra: str):
    return run_cli("sweep", str(tmp_path / "study.toml"), "--evaluate", "test_adaptive_sweep:fake_spread",
                   "--no-progress", "--jobs", "1", *extra)


@pytest.mark.parametrize("setting, key", [("phantoms.target_se=-1", "--set phantoms.target_se"),
                                          ("phantoms.min_per_design=0", "--set phantoms.min_per_design"),
                                          ("phantoms.batch_size=[1]", "--set phantoms.batch_size")])
def test_cli_bad_values_exit_2_with_one_line_naming_the_key(tmp_path, setting, key):
    _study(tmp_path)
    done = _cli(tmp_path, "--set", setting)
    assert done.returncode == 2
    err = done.stderr.strip().splitlines()
    assert len(err) == 1 and key in err[0]
    assert not (tmp_path / "out" / "results.sqlite").exists()  # refused before any work


def test_cli_runs_and_prints_the_report(tmp_path):
    _study(tmp_path)
    done = _cli(tmp_path, "--set", "phantoms.batch_size=10")
    assert done.returncode == 0, done.stderr
    assert "adaptive counts" in done.stdout and "then 10 more at a time" in done.stdout
    dry = _cli(tmp_path, "--dry-run")
    assert dry.returncode == 0 and "adaptive: each design runs 6 phantoms" in dry.stdout


def test_optimization_and_sensitivity_studies_refuse_target_se(tmp_path):
    from latticeopt.optimize.load import optimization_from_dict
    from latticeopt.study.sensitivity import load_variants

    raw = {"design": {"pitch_mm": 12.5}, "phantoms": {"counts": {"1": 4}, "target_se": 0.01},
           "optimize": {"variables": {"width_mm": {"lower": 0.5, "upper": 8.0, "start": 2.0}}}}
    with pytest.raises(ParameterError, match="phantoms.target_se"):
        optimization_from_dict(raw)
    _study(tmp_path)
    with pytest.raises(ParameterError, match="phantoms.target_se"):
        load_variants(tmp_path / "study.toml", [])


def _adaptive_bias(rng, sample, sd: float, replicates: int = 1500) -> float:
    """Monte Carlo bias of the stopped mean in units of the plain SE at the mean stopping count (true mean 0.06)."""
    rule = AdaptiveSettings(target_se=sd / math.sqrt(60), min_per_design=30, batch_size=15)
    means, counts = np.empty(replicates), np.empty(replicates)
    for r in range(replicates):
        x, n = sample(rng), 0
        while (m := next_count(x[:n], len(x), rule)) != n:
            n = m
        means[r], counts[r] = x[:n].mean(), n
    return float((means.mean() - 0.06) / (sd / math.sqrt(counts.mean())))


def test_early_stopping_is_unbiased_for_normal_values_and_biased_low_for_right_skewed_ones():
    # the sample mean and variance of normal data are independent, so stopping on the spread cannot bias the mean;
    # for right-skewed data a prefix that missed the large values has a low mean and a low spread, and stops early
    # (benchmarks/adaptive_bias.py prints the full table; docs/studies.md quotes it)
    rng = np.random.default_rng(7)
    normal = _adaptive_bias(rng, lambda g: g.normal(0.06, 0.018, 300), 0.018)
    sig = math.sqrt(math.log(2.0))  # lognormal with mean 0.06 and coefficient of variation 1
    skewed = _adaptive_bias(rng, lambda g: g.lognormal(math.log(0.06) - sig * sig / 2, sig, 300), 0.06)
    assert abs(normal) < 0.12  # Monte Carlo SE of the estimate about 0.03
    assert -0.6 < skewed < -0.15


def fake_spread_dead_ends(design, phantom, settings) -> dict:
    """TEST DOUBLE: as fake_spread, and the w = 3 design reports reference rows at round-off (a dead end)."""
    return {**fake_spread(design, phantom, settings), "min_reference_rel": 1e-13 if design.width_mm == 3 else 0.01}


@pytest.mark.parametrize("floor", [0.0, 1e-4])
def test_report_warns_of_reference_rows_at_round_off(tmp_path, floor):
    study = _study(tmp_path, tail=f"[physics]\nmeasurement_floor_rel = {floor}\n")
    res = run_sweep(study, fake_spread_dead_ends, progress=False)
    lines = [line for line in res.report if line.startswith("warning:") and "round-off" in line]
    assert len(lines) == (floor == 0)  # a floor lifts the rows: nothing to warn of
    assert ("instrument floor of 0.0001" in res.report[1]) == (floor > 0)
    if lines:  # names only the design with the dead end, and the key that mends it
        assert "(width = 3 mm)" in lines[0] and "width = 2" not in lines[0] and "width = 4" not in lines[0]
        assert "1e-13" in lines[0] and "physics.measurement_floor_rel" in lines[0]
