"""The sensitivity runner on a model whose figures are known in closed form."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import pytest

from latticeopt.errors import ParameterError
from latticeopt.study.sensitivity import load_variants, parse_vary, plot_tornado, run_sensitivity, write_table
from latticeopt.study.sweep import run_sweep

STUDY = Path(__file__).resolve().parents[1] / "studies" / "sensitivity_press.toml"


def press_model(design, phantom, settings) -> dict:
    """TEST DOUBLE: V_rel = depth * (1 + w / 10) * mu_gel / 500 (+ 0.01 with a rim channel)."""
    mu = settings.physics.get("hydrogel_shear_kPa", 5.0)
    depth = phantom.touches[0].depth_mm
    v = depth * (1 + design.width_mm / 10) * mu / 500 + (0.01 * depth if design.rim == "channel" else 0.0)
    return {"v_rel": v, "forces_N": [0.0], "timings": {"double": 0.0}}


def test_each_run_moves_the_figures_as_the_model_says(tmp_path):
    runs = load_variants(STUDY, [parse_vary("hydrogel_shear_kPa=2,15"), parse_vary("rim=channel")],
                         [f"out={(tmp_path / 'o').as_posix()}"])
    assert [r[0] for r in runs] == ["baseline", "physics.hydrogel_shear_kPa=2", "physics.hydrogel_shear_kPa=15",
                                    "design.rim=channel"]
    rows = run_sensitivity(runs, lambda s: run_sweep(s, press_model, jobs=1, progress=False, outputs=False))
    for r, mu, rim in zip(rows, (5.0, 2.0, 15.0, 5.0), (0, 0, 0, 1)):
        v = {w: 4 * (1 + w / 10) * mu / 500 + 0.04 * rim for w in (0, 4, 6)}
        fig = r["figures"]
        assert fig["ratio w = 4 vs no lattice"][0] == pytest.approx(v[4] / v[0], rel=1e-12)
        assert fig["ratio w = 4 vs w = 6"][0] == pytest.approx(v[4] / v[6], rel=1e-12)
        assert math.isnan(fig["ratio w = 4 vs w = 6"][1])  # a press has no sampling error
    table = write_table(rows, tmp_path / "s.csv")
    with open(table) as fh:
        assert [row["run"] for row in csv.DictReader(fh)] == [r[0] for r in runs]
    assert plot_tornado(rows, tmp_path / "t.png").read_bytes()[:4] == b"\x89PNG"


@pytest.mark.parametrize("text, match", [("hydrogel_shear_kPa", "KEY=V1,V2"), ("colour=1", "a dotted study key"),
                                         ("rim=none,none", "distinct values")])
def test_bad_vary_arguments(text, match):
    with pytest.raises(ParameterError, match=match):
        parse_vary(text)


def test_bad_values_are_caught_before_any_run(tmp_path):
    with pytest.raises(ParameterError, match="--vary design.rim"):
        load_variants(STUDY, [parse_vary("rim=round")], [f"out={(tmp_path / 'o').as_posix()}"])
    assert not (tmp_path / "o").exists()


def test_a_probes_study_is_refused_naming_its_kind(tmp_path):
    probes = STUDY.parent / "uniformity_layouts.toml"
    with pytest.raises(ParameterError, match=r"layouts.toml: kind: expected 'grid' or 'press'.*got 'probes'"):
        load_variants(probes, [parse_vary("rim=channel")], [f"out={(tmp_path / 'o').as_posix()}"])
    assert not (tmp_path / "o").exists()


def failing_with_soft_gel(design, phantom, settings) -> dict:
    """TEST DOUBLE: every press fails when the gel is softer than 3 kPa (a ModelFailure, as the mechanics would)."""
    from latticeopt.errors import ConvergenceError

    if settings.physics.get("hydrogel_shear_kPa", 5.0) < 3:
        raise ConvergenceError("test double: no convergence")
    return press_model(design, phantom, settings)


def test_an_input_that_fails_every_press_is_reported_not_fatal(tmp_path):
    runs = load_variants(STUDY, [parse_vary("hydrogel_shear_kPa=2,15")], [f"out={(tmp_path / 'o').as_posix()}"])
    rows = run_sensitivity(runs, lambda s: run_sweep(s, failing_with_soft_gel, jobs=1, progress=False,
                                                     outputs=False))
    assert [r["failed"] for r in rows] == [0, 6, 0]  # 3 designs x 2 depths, all failed: the run goes on
    assert rows[1]["figures"] == {} and rows[2]["figures"]
    write_table(rows, tmp_path / "s.csv")
    plot_tornado(rows, tmp_path / "t.png")


def test_dry_run_prints_every_run_and_runs_none(tmp_path, capsys, monkeypatch):
    import latticeopt.study.sweep
    from latticeopt.cli import main

    def no_run(*args, **kwargs):
        raise AssertionError("a dry run ran a sweep")

    monkeypatch.setattr(latticeopt.study.sweep, "run_sweep", no_run)
    out = tmp_path / "o"
    argv = ["sensitivity", str(STUDY), "--vary", "hydrogel_shear_kPa=2,15", "--set", f"out={out.as_posix()!r}",
            "--dry-run"]
    assert main(argv) == 0
    text = capsys.readouterr().out
    runs = load_variants(STUDY, [parse_vary("hydrogel_shear_kPa=2,15")], [f"out={out.as_posix()!r}"])
    for label, _, _, study in runs:
        assert f"{label} " in text and f"= {study.n_tasks}; out {study.out_dir}" in text
    assert f"3 runs (the baseline and 2 variants), {sum(r[3].n_tasks for r in runs)} evaluations" in text
    assert f"would write {out / 'sensitivity' / 'sensitivity.csv'} and" in text
    assert not out.exists()  # nothing written
    assert main([*argv, "--json"]) == 0
    import json

    plan = json.loads(capsys.readouterr().out)
    assert [r["run"] for r in plan["runs"]] == [r[0] for r in runs] and plan["dry_run"] is True


def test_tornado_names_what_it_shows_and_keeps_labels_and_markers_clear(tmp_path, saved_figures):
    from test_report_plots import blank_border

    runs = load_variants(STUDY, [parse_vary("hydrogel_shear_kPa=4.99,5.01"), parse_vary("rim=channel")],
                         [f"out={(tmp_path / 'o').as_posix()}"])
    rows = run_sensitivity(runs, lambda s: run_sweep(s, press_model, jobs=1, progress=False, outputs=False))
    plot_tornado(rows, tmp_path / "t.png")
    fig, = saved_figures
    title = " ".join(fig._suptitle.get_text().split())
    assert "square lattice (p = 12.5 mm) and uniform layer, no rim channel, t = 3 mm" in title
    assert "one press, r = 8.75 mm at (50, 50) mm, figures at 4 mm deep" in title and "grid mesh, 2 mm" in title
    fig.canvas.draw()
    for ax in fig.axes:
        if not ax.get_visible():
            continue
        lo, hi = ax.get_xlim()
        for line in ax.lines:  # the markers (and the baseline) inside the frame, not cut by it
            x = [float(v) for v in line.get_xdata()]
            assert all(lo < v < hi for v in x), (ax.get_title(), x, (lo, hi))
        labels = [t for t in ax.texts if t.get_text() in ("4.99", "5.01")]
        assert len(labels) == 2
        a, b = (t.get_window_extent() for t in labels)
        assert not a.overlaps(b), ax.get_title()  # two values close together: labels apart
    assert blank_border(tmp_path / "t.png")
