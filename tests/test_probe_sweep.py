"""``kind = "probes"`` sweeps: the loader's checks as one-line CLI errors, ``--set probes.*``, the report against
the stored probe V_rel (a test double for the report's logic, failures included), and the coupled model on a
coarse mesh, whose probe map keeps the symmetric lattice's mirror symmetry."""

from __future__ import annotations

import csv
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from latticeopt.errors import ConvergenceError
from latticeopt.study.config import load_study
from latticeopt.study.sweep import run_sweep

STUDY = """
name = "probes"
kind = "probes"
out = "{out}"
[design]
thickness_mm = 3.0
[grid]
width_mm = [2, 4]
[probes]
grid = 3
radius_mm = 10.0
[mesh]
size_mm = 8.0
channel_cells = 1
layer_cells = 1
[physics]
mechanics_rtol = 1e-8
"""
#: The square's symmetries on (row, column) arrays: both mirrors, the half turn and the four with a transpose.
MIRRORS = (lambda a: a[::-1], lambda a: a[:, ::-1], lambda a: a[::-1, ::-1], lambda a: a.T, lambda a: a[::-1].T,
           lambda a: a[:, ::-1].T, lambda a: a[::-1, ::-1].T)


def _write(tmp_path: Path, text: str = STUDY, name: str = "probes.toml") -> Path:
    path = tmp_path / name
    path.write_text(text.format(out=(tmp_path / "out").as_posix()))
    return path


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "latticeopt", "sweep", *args], capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": os.pathsep.join(
                              [str(Path(__file__).parent), os.environ.get("PYTHONPATH", "")])}, timeout=300)


def _read_csv(path: Path) -> list[dict]:
    with open(path) as fh:
        return list(csv.DictReader(fh))


@pytest.mark.parametrize("edit, extra, key, fragments", [
    (("grid = 3", "grid = 11"), [], "probes.grid", ["2 to 10", "got 11"]),
    (("grid = 3", "grid = 3.5"), [], "probes.grid", ["2 to 10", "got 3.5"]),
    (("radius_mm = 10.0", "radius_mm = 17.0"), [], "probes.radius_mm", ["<= L / (2 grid) = 16.6667 mm", "got 17"]),
    (("radius_mm = 10.0", "radius_mm = 10.0\ndepth_mm = 9.0"), [], "probes.depth_mm", ["< 9 mm", "got 9"]),
    # against every design's stack: the thinner of two
    (("width_mm = [2, 4]", "total_thickness_mm = [9.0, 7.0]"), ["--set", "probes.depth_mm=8"],
     "--set probes.depth_mm", ["< 7 mm", "got 8"]),
    (("radius_mm = 10.0", "radius_mm = 10.0\nspacing_mm = 3"), [], "probes.spacing_mm",
     ["one of grid, radius_mm, depth_mm", "got 'spacing_mm'"]),
    (("[mesh]", "[phantoms]\nseed = 1\n[mesh]"), [], "phantoms", ["no [phantoms] table in a kind = 'probes' study",
                                                                  "use [probes]"]),
    (("[mesh]", "[press]\nx_mm = 30\n[mesh]"), [], "press", ["no [press] table in a kind = 'probes' study"]),
    (("[mesh]", "[multilevel]\npilot = 4\n[mesh]"), [], "multilevel", ["kind = 'probes'",
                                                                        "the probe grid is not a random sample"]),
    (('kind = "probes"', 'kind = "grid"'), [], "probes", ["no [probes] table in a kind = 'grid' study",
                                                          "use [phantoms]"]),
    (("", ""), ["--set", "probes.grid=1"], "--set probes.grid", ["2 to 10", "got 1"]),
    (("", ""), ["--set", "probes.radius_mm=0"], "--set probes.radius_mm", ["0 < radius_mm", "got 0"]),
])
def test_bad_probe_studies_are_one_line_before_any_work(tmp_path, capsys, edit, extra, key, fragments):
    from latticeopt.cli import main

    path = _write(tmp_path, STUDY.replace(*edit) if edit[0] else STUDY)
    code = main(["sweep", str(path), *extra])  # in-process: the same error path, without a fresh interpreter
    err = capsys.readouterr().err
    assert code == 2, err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    named = key if key.startswith("--set") else f"{path}: {key}:"
    assert named in err, err
    for fragment in fragments:
        assert fragment in err, err
    assert not (tmp_path / "out").exists()


def test_a_bad_probe_study_from_the_command_line_exits_2_without_a_traceback(tmp_path):
    done = _cli(str(_write(tmp_path, STUDY.replace("grid = 3", "grid = 11"))))
    assert done.returncode == 2 and done.stderr.count("\n") == 1 and "Traceback" not in done.stderr, done.stderr
    assert "probes.grid" in done.stderr


def test_set_probes_keys_and_the_dry_run_count(tmp_path):
    path = _write(tmp_path)
    study = load_study(path, ["probes.grid=5", "probes.radius_mm=8"])
    assert (study.phantom_set.grid, study.phantom_set.radius_mm, len(study.phantoms)) == (5, 8.0, 25)
    assert study.n_tasks == 50 and study.phantom_set.depth_mm == 3.0  # the default
    done = _cli(str(path), "--dry-run", "--set", "probes.grid=5", "--set", "probes.radius_mm=8")
    assert done.returncode == 0, done.stderr
    assert "2 designs x 25 phantoms = 50 evaluations, 0 stored" in done.stdout
    assert "a 5 x 5 grid, one punch of radius 8 mm pressed 3 mm" in done.stdout
    assert not (tmp_path / "out").exists()


def probe_double(design, phantom, settings) -> dict:
    """TEST DOUBLE (not physics): V_rel rising with x and y, faster for wider channels; the w = 2 design fails its
    centre probe, as a press that does not converge would."""
    t = phantom.touches[0]
    if design.width_mm == 2 and (t.x_mm, t.y_mm) == (50.0, 50.0):
        raise ConvergenceError("test double: no convergence at the centre")
    return {"v_rel": 0.02 + 1e-4 * t.x_mm + 5e-5 * t.y_mm * design.width_mm, "forces_N": [1.0],
            "timings": {"double": 0.0}}


def test_report_uniformity_from_the_stored_probes_and_none_over_a_subset(tmp_path):
    study = load_study(_write(tmp_path), ["grid.width_mm=[2, 4, 6]"])
    res = run_sweep(study, probe_double, progress=False)
    assert (res.computed, res.failed) == (27, 1)
    rows = _read_csv(res.outputs["results"])
    summary = {s["width_mm"]: s for s in _read_csv(res.outputs["summary"])}
    for r in rows:  # probe i in column i % 3, row i // 3, at that cell's centre
        col, row = int(r["probe_col"]), int(r["probe_row"])
        assert int(r["phantom_index"]) == col + 3 * row
        x, y, *_ = eval(r["touches"])[0]
        assert (x, y) == ((col + 0.5) * 100 / 3, (row + 0.5) * 100 / 3)
    expected = {}
    for w in ("4.0", "6.0"):
        v = np.array([float(r["v_rel"]) for r in rows if r["width_mm"] == w])
        s = summary[w]
        expected[w] = 1 - np.std(v) / np.mean(v)
        assert float(s["uniformity"]) == pytest.approx(expected[w], rel=1e-12)
        assert float(s["worst_to_best"]) == pytest.approx(v.min() / v.max(), rel=1e-12)
        assert float(s["v_rel_mean"]) == pytest.approx(v.mean(), rel=1e-12)
        assert (s["solved"], s["failed"], s["weakest_probe"], s["weakest_col"], s["weakest_row"]) == (
            "9", "0", str(int(np.argmin(v))), "0", "0")
    assert expected["4.0"] > expected["6.0"]  # the double spreads more with wider channels
    assert (summary["4.0"]["rank"], summary["6.0"]["rank"]) == ("1", "2")
    # a failed probe: no uniformity over the other eight
    s2 = summary["2.0"]
    assert (s2["solved"], s2["failed"], s2["rank"], s2["weakest_probe"]) == ("8", "1", "", "")
    assert all(math.isnan(float(s2[k])) for k in ("uniformity", "worst_to_best", "v_rel_mean"))
    report = res.report
    ranked = [line for line in report if line.startswith("  1.") or line.startswith("  2.")]
    assert ranked[0].startswith("  1. width = 4 mm: uniformity " + f"{expected['4.0']:.4f}")
    assert ranked[1].startswith("  2. width = 6 mm: uniformity " + f"{expected['6.0']:.4f}")
    assert ("  not ranked: width = 2 mm: uniformity n/a, 1 of 9 probes failed (cells (1, 1); first error: "
            "ConvergenceError: test double: no convergence at the centre)") in report
    assert "weakest probe at (16.67, 16.67) mm (cell 0, 0)" in ranked[0]
    assert (study.out_dir / "report.txt").read_text().splitlines() == list(report)
    assert res.outputs["probes_plot"].name == "probes.png"
    assert res.outputs["probes_plot"].read_bytes()[:4] == b"\x89PNG"


def test_layout_files_are_named_by_their_file_names(tmp_path):
    data = Path(__file__).resolve().parents[1] / "studies" / "data"
    files = [(data / "square_w4.geojson").as_posix(), (data / "graded_d4_t3.geojson").as_posix()]
    study = load_study(_write(tmp_path), [f"grid={{ layout = {files!r} }}".replace("'", '"'), "probes.grid=2"])
    res = run_sweep(study, probe_double, progress=False)
    names = [s["design"] for s in _read_csv(res.outputs["summary"])]
    assert names == ["square_w4.geojson", "graded_d4_t3.geojson"]
    for design, path in zip(study.designs, files):  # and the hash in results.csv is explained
        assert f"layout {design.content_hash()[:8]} = {path}" in res.report


def test_coupled_model_probe_sweep_is_symmetric_resumable_and_scored_from_its_rows(tmp_path):
    """A square lattice (D4, like the 16 evenly spaced electrodes) on a coarse mesh: 9 presses.

    The grid mesh of a square lattice is itself mirror-invariant (nodes and tetrahedra), so the probe map may differ
    from its mirror images only by the solver's tolerance. Measured on this mesh: 9e-10 of the largest probe
    V_rel at the default ``mechanics_rtol`` 1e-4 and 6e-12 at the 1e-8 used here; on the same lattice with 2 cells
    across a channel and through the layer, 9e-6 and 3e-9, falling with the tolerance as a solver's residue does and
    a geometric asymmetry would not. 1e-7 leaves four decades above what was measured and still catches a probe off
    its cell centre: moving the corner probe of w = 4 by 0.01 mm in x changes its V_rel by 4e-4 of itself.
    """
    path = _write(tmp_path)
    one = ["grid.width_mm=[4]"]  # one design: the test's cost is its presses
    study = load_study(path, one)
    res = run_sweep(study, progress=False)
    assert (res.computed, res.failed) == (9, 0)
    rows = _read_csv(res.outputs["results"])
    summary = _read_csv(res.outputs["summary"])
    for s in summary:
        mine = [r for r in rows if r["width_mm"] == s["width_mm"]]
        v = np.array([float(r["v_rel"]) for r in mine])
        assert float(s["uniformity"]) == pytest.approx(1 - np.std(v) / np.mean(v), rel=1e-12)
        assert float(s["worst_to_best"]) == pytest.approx(v.min() / v.max(), rel=1e-12)
        grid = np.full((3, 3), np.nan)
        for r in mine:
            grid[int(r["probe_row"]), int(r["probe_col"])] = float(r["v_rel"])
        asym = max(np.max(np.abs(op(grid) - grid)) for op in MIRRORS) / np.max(grid)
        assert asym < 1e-7, (s["width_mm"], asym)
        assert float(s["uniformity"]) < 0.9  # the probes are at different places: the map is not flat
    assert (tmp_path / "out" / "probes.png").read_bytes()[:4] == b"\x89PNG"
    again = run_sweep(study, progress=False)  # resumed: nothing recomputed, the same report
    assert (again.computed, again.skipped) == (0, 9) and again.report == res.report
    done = _cli(str(path), "--set", one[0], "--dry-run")
    assert done.returncode == 0 and "1 design x 9 phantoms = 9 evaluations, 9 stored" in done.stdout, done.stdout
