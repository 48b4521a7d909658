"""The categorical outer loop of the optimizer (layout family x rim) on a model with known optima."""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from latticeopt.design import LatticeDesign
from latticeopt.errors import ParameterError
from latticeopt.fabrication import narrowest_features
from latticeopt.optimize import load_categories, run_optimization

TESTS = Path(__file__).resolve().parent
#: Known optimum of each combination: the peak V_rel and the width where it lies.
PEAK = {("square", "none"): (0.05, 4.0), ("square", "channel"): (0.03, 3.0),
        ("hexagonal", "none"): (0.06, 2.5), ("hexagonal", "channel"): (0.02, 5.0)}


def family_evaluate(design, phantom, settings) -> dict:
    """TEST DOUBLE of the coupled model: V_rel = peak - 0.002 (w - w*)^2 per (pattern, rim)."""
    peak, w_opt = PEAK[(design.pattern, design.rim)]
    return {"v_rel": peak - 0.002 * (design.width_mm - w_opt) ** 2, "forces_N": [0.1] * phantom.n_touches,
            "timings": {"double": 0.0}}


STUDY = """
name = "families"
out = "{out}"
jobs = 1
[design]
thickness_mm = 3.0
[phantoms]
seed = 3
counts = {{ 1 = 2 }}
[optimize]
algorithm = "LN_BOBYQA"
max_evals = 25
xtol_abs_mm = 0.001
[optimize.variables]
width_mm = {{ lower = 1.0, upper = 6.0, start = 3.5 }}
[optimize.categories]
pattern = ["square", "hexagonal"]
rim = ["none", "channel"]
"""


def _study(tmp_path: Path) -> Path:
    p = tmp_path / "families.toml"
    p.write_text(STUDY.format(out=(tmp_path / "out").as_posix()))
    return p


def test_every_combination_finds_its_own_optimum(tmp_path):
    runs = load_categories(_study(tmp_path))
    assert [dict(r.values) for r in runs] == [{"pattern": p, "rim": r} for p in ("square", "hexagonal")
                                             for r in ("none", "channel")]
    assert len({r.optimization.study.out_dir for r in runs}) == 4  # one store and report per combination
    for run in runs:
        res = run_optimization(run.optimization, family_evaluate, outputs=False)
        peak, w_opt = PEAK[(dict(run.values)["pattern"], dict(run.values)["rim"])]
        assert res.best.x["width_mm"] == pytest.approx(w_opt, abs=0.01)
        assert res.best.score == pytest.approx(peak, abs=1e-6)


def test_cli_ranks_the_combinations(tmp_path):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(TESTS), os.environ.get("PYTHONPATH", "")])}
    cmd = [sys.executable, "-m", "latticeopt", "optimize", str(_study(tmp_path)), "--quiet",
           "--evaluate", "test_optimize_categories:family_evaluate"]
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    ranked = [line.split(":")[0].strip() for line in done.stdout.split("categories ranked")[1].splitlines()[1:]
              if line.startswith("  ")]
    assert ranked == ["pattern-hexagonal_rim-none", "pattern-square_rim-none", "pattern-square_rim-channel",
                      "pattern-hexagonal_rim-channel"]
    with open(tmp_path / "out" / "categories.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert {r["category"] for r in rows} == set(ranked)
    for r in rows:  # the double gives every press the same V_rel: the median is the mean, each press half the sum
        assert float(r["v_rel_median"]) == pytest.approx(float(r["score"]), rel=1e-12)
        assert float(r["v_rel_max_share"]) == pytest.approx(0.5, rel=1e-12)
    assert "median press" in done.stdout
    # the optimum's layout measured on its footprint: the square lattice's channel w and island p - w, its
    # rim channel w / 2; the honeycomb at w = 2.5 leaves a silicone sliver where the sensor's edge clips a cell
    square = {r["rim"]: r for r in rows if r["pattern"] == "square"}
    assert float(square["none"]["narrowest_gel_mm"]) == pytest.approx(4.0, abs=1e-6)
    assert float(square["none"]["narrowest_silicone_mm"]) == pytest.approx(12.5 - 4.0, abs=1e-2)
    assert float(square["channel"]["narrowest_gel_mm"]) == pytest.approx(3.0 / 2, abs=1e-6)
    hex_report = (tmp_path / "out" / "pattern-hexagonal_rim-none" / "families_report.txt").read_text()
    assert "BELOW the fabrication limits" in hex_report and "< min_island_mm = 1" in hex_report
    assert "BELOW" not in (tmp_path / "out" / "pattern-square_rim-none" / "families_report.txt").read_text()
    # ... and the widths whose honeycomb meets both limits everywhere: each interval's ends pass, the grid
    # widths just outside them (in the bounds 1-6 mm) fail, measured one by one on the footprint
    result = json.loads((tmp_path / "out" / "pattern-hexagonal_rim-none" / "families_result.json").read_text())
    spans = result["castable_widths_mm"]
    assert spans and "widths whose layout meets both limits everywhere" in hex_report

    def castable(w):
        f = narrowest_features(LatticeDesign(pattern="hexagonal", width_mm=w, thickness_mm=3.0).footprint(), 100.0)
        return f.gel_mm >= 0.5 - 1e-3 and f.silicone_mm >= 1.0 - 1e-3  # min_channel_mm, min_island_mm defaults

    for a, b in spans:
        assert castable(a) and castable(b)
        assert all(not castable(round(w, 1)) for w in (a - 0.1, b + 0.1) if 1.0 <= round(w, 1) <= 6.0)
    hex_row = next(r for r in rows if r["category"] == "pattern-hexagonal_rim-none")
    assert hex_row["castable_widths_mm"] == ", ".join(f"{a:g}" if a == b else f"{a:g}-{b:g}" for a, b in spans)
    square_result = (tmp_path / "out" / "pattern-square_rim-none" / "families_result.json").read_text()
    assert json.loads(square_result)["castable_widths_mm"] is None  # nothing broken: no scan
    assert f"wrote figure: {tmp_path / 'out' / 'categories.png'}" in done.stdout  # every path on one axis
    assert (tmp_path / "out" / "categories.png").stat().st_size > 10_000


def test_check_castable_scores_the_castable_width_nearest_the_optimum_in_each_interval(tmp_path):
    """The honeycomb's optimum (w = 2.5) breaks a limit at the edge; with check_castable the nearest castable
    width of each interval is scored like a call: the double's V_rel there, and minus the optimum's, paired."""
    runs = load_categories(_study(tmp_path), ["optimize.check_castable=true",
                                              'optimize.categories.pattern=["hexagonal"]',
                                              'optimize.categories.rim=["none"]'])
    res = run_optimization(runs[0].optimization, family_evaluate)
    spans = res.castable_widths
    w_opt = res.best.x["width_mm"]
    want = [min(max(w_opt, a), b) for a, b in spans]
    assert [c.width_mm for c in res.castable_checks] == pytest.approx(want)
    for c in res.castable_checks:
        exact = 0.06 - 0.002 * (c.width_mm - 2.5) ** 2
        assert c.assessment.score == pytest.approx(exact, rel=1e-12)
        assert c.minus_optimum[0] == pytest.approx(exact - res.best.score, abs=1e-12)
    assert sum("castable: width = " in line for line in res.report) == len(want)
    n_ph = len(runs[0].optimization.study.phantoms)
    assert f"then {len(want)} castable width(s) x {n_ph} phantoms: {len(want) * n_ph} computed, 0 failed" \
        in res.report[0]
    payload = json.loads(res.outputs["result"].read_text())
    assert [c["width_mm"] for c in payload["castable_checks"]] == pytest.approx(want)
    # the checked designs are stored: a re-run reads them back instead of computing them again
    again = run_optimization(runs[0].optimization, family_evaluate)
    assert again.computed == 0 and [c.assessment.computed for c in again.castable_checks] == [0] * len(want)


def test_the_summary_names_a_castable_width_that_could_not_be_scored(tmp_path):
    """A castable width whose check failed a phantom has no score: the summary's best castable width is the best
    of the scored ones, and the unscored width is named beside it rather than dropped."""
    from latticeopt.optimize.categories import write_summary

    runs = load_categories(_study(tmp_path), ["optimize.check_castable=true",
                                              'optimize.categories.pattern=["hexagonal"]',
                                              'optimize.categories.rim=["none"]'])
    res = run_optimization(runs[0].optimization, family_evaluate, outputs=False)
    assert len(res.castable_checks) >= 2
    best = max(res.castable_checks, key=lambda c: c.assessment.score)
    failed = dataclasses.replace(best, assessment=dataclasses.replace(best.assessment, score=math.nan, n_failed=1),
                                 minus_optimum=None)
    res = dataclasses.replace(res, castable_checks=tuple(failed if c is best else c for c in res.castable_checks))
    write_summary([(runs[0], res)], tmp_path / "summary.csv")
    row = next(csv.DictReader(open(tmp_path / "summary.csv")))
    rest = max((c for c in res.castable_checks if c is not failed), key=lambda c: c.assessment.score)
    assert float(row["castable_width_mm"]) == pytest.approx(rest.width_mm)
    assert row["castable_unscored_mm"] == f"{best.width_mm:g}"


def test_the_figure_needs_one_shared_variable(tmp_path):
    import matplotlib.image

    from latticeopt.optimize.categories import plot_categories

    p = _study(tmp_path)
    runs = load_categories(p)
    pairs = [(r, run_optimization(r.optimization, family_evaluate, outputs=False)) for r in runs[:2]]
    assert plot_categories(pairs, tmp_path / "one.png") == tmp_path / "one.png"
    assert matplotlib.image.imread(tmp_path / "one.png").ndim == 3
    p.write_text(p.read_text().replace("[optimize.categories]", "thickness_mm = { lower = 2.0, upper = 4.0, "
                                       "start = 3.0 }\n[optimize.categories]").replace("thickness_mm = 3.0\n", ""))
    runs = load_categories(p)
    pairs = [(r, run_optimization(r.optimization, family_evaluate, outputs=False)) for r in runs[:2]]
    assert plot_categories(pairs, tmp_path / "two.png") is None and not (tmp_path / "two.png").exists()


@pytest.mark.parametrize("change, match", [
    ('pattern = ["square", "round"]', "optimize.categories.pattern: expected a list of distinct values"),
    ('colour = ["red"]', "optimize.categories.colour: expected a categorical design field"),
    ('pattern = []', "optimize.categories.pattern"),
])
def test_bad_categories_are_rejected_naming_the_key(tmp_path, change, match):
    p = _study(tmp_path)
    p.write_text(p.read_text().replace('pattern = ["square", "hexagonal"]', change))
    with pytest.raises(ParameterError, match=match):
        load_categories(p)


def test_a_category_fixed_in_the_design_is_rejected(tmp_path):
    p = _study(tmp_path)
    p.write_text(p.read_text().replace("thickness_mm = 3.0", 'thickness_mm = 3.0\nrim = "none"'))
    with pytest.raises(ParameterError, match="optimize.categories.rim: expected a field not also fixed"):
        load_categories(p)
