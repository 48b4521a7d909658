"""The probe grid of density studies: the uniformity gradient through the whole model, the symmetric images that
let only one probe per orbit be solved, the min_uniformity constraint, the front's CLI surface and bad input."""

import json

import numpy as np
import pytest

from latticeopt import LatticeDesign, MeshSettings
from latticeopt.cli import main
from latticeopt.coupled import PhysicsSettings
from latticeopt.optimize.graded import GradedConfig
from latticeopt.optimize.probes import ProbeGrid, uniformity_constraint

DESIGN = LatticeDesign(thickness_mm=3.0)
PROBES = dict(probes=True, probe_grid=3, probe_radius_mm=12.0, probe_depth_mm=2.5)


@pytest.fixture(scope="module")
def model():
    from latticeopt.density import DensityModel

    return DensityModel(DESIGN, 10, MeshSettings(size_mm=8.0), PhysicsSettings(mechanics_rtol=1e-10))


def test_uniformity_gradient_through_the_model(model):
    """d uniformity / d (line widths) through the graded density, the probes' adjoints and their mirror images,
    against central differences of the whole model."""
    from latticeopt.density.graded import GradedSquare

    param = GradedSquare(DESIGN, 10, "mirror", smoothing_mm=1.0, samples=2)
    probes = ProbeGrid(DESIGN, GradedConfig(cells=10, **PROBES))
    x = np.linspace(3.0, 5.0, param.n_variables)
    pe = probes.solve(model, param.density(x))
    assert pe.solved == 4  # 3 x 3 probes under the two mirrors: corner, two edges, centre
    g = param.gradient(x, None, pe.d_uniformity)
    d = np.cos(np.arange(param.n_variables))
    h = 1e-4
    fd = (probes.solve(model, param.density(x + h * d), gradient=False).uniformity
          - probes.solve(model, param.density(x - h * d), gradient=False).uniformity) / (2 * h)
    assert abs(g @ d - fd) <= 1e-4 * abs(fd)
    # the constraint nlopt gets: floor - uniformity, gradient its negative
    grad = np.empty(param.n_variables)
    value = uniformity_constraint(lambda xv, beta: (None, pe), param, None, 0.5)(x, grad)
    assert value == pytest.approx(0.5 - pe.uniformity) and np.allclose(grad, -g)


def test_symmetric_images_agree_on_the_density_mesh(model):
    """On a D4-symmetric layout the probes solved one per orbit, their images filled in, give what solving every
    probe gives: V_rel, uniformity and its gradient (the mesh's own asymmetry is below the solver tolerance)."""
    rng = np.random.default_rng(4)
    r = rng.random((10, 10))
    r = (r + r[::-1] + r[:, ::-1] + r[::-1, ::-1]) / 4
    rho = 0.2 + 0.8 * (r + r.T) / 2
    orbits = ProbeGrid(DESIGN, GradedConfig(cells=10, **PROBES)).solve(model, rho)
    every = ProbeGrid(DESIGN, GradedConfig(cells=10, probe_orbits=False, **PROBES)).solve(model, rho)
    assert (orbits.solved, every.solved) == (3, 9)
    assert np.max(np.abs(orbits.v_rel - every.v_rel) / every.v_rel) < 1e-5
    assert orbits.uniformity == pytest.approx(every.uniformity, rel=1e-5)
    scale = np.abs(every.d_uniformity).max()
    assert np.abs(orbits.d_uniformity - every.d_uniformity).max() < 1e-4 * scale
    # a layout graded along x keeps only the mirror in y: 6 of the 9 probes solved
    assert ProbeGrid(DESIGN, GradedConfig(cells=10, **PROBES)).solve(model, rho * np.linspace(0.9, 1, 10),
                                                                    gradient=False).solved == 6


def test_electrodes_decide_the_symmetries_used():
    shifted = LatticeDesign(thickness_mm=3.0, electrode_positions_mm=(10.0, 37.5, 62.5, 87.5))
    # positions run counter-clockwise on every side: the quarter and half turns keep them, no mirror does
    grid = ProbeGrid(shifted, GradedConfig(**PROBES))
    assert grid._ops == (0, 3, 5, 6)
    rep, _ = grid.plan(grid._ops)
    assert len(set(rep.tolist())) == 3 and rep[2] == rep[8] == rep[6] == rep[0]
    assert ProbeGrid(DESIGN, GradedConfig(**PROBES))._ops == tuple(range(8))


TINY = ["--set", "mesh.size_mm=8", "--set", "graded.cells=8", "--set", "graded.iterations=3",
        "--set", "phantoms.counts={1=1}", "--set", "graded.probe_grid=3", "--set", "graded.probe_radius_mm=12",
        "--set", "graded.probe_depth_mm=2.5", "--quiet"]


def _history(out):
    return [json.loads(x) for x in (out / "history.jsonl").read_text().splitlines()]


def test_min_uniformity_is_honoured(tmp_path, monkeypatch):
    """Maximizing V_rel alone lowers the uniformity of the start layout; with the start's uniformity as the floor
    the run ends at or above it, and the report states the final layout's uniformity."""
    monkeypatch.chdir(__import__("pathlib").Path(__file__).resolve().parents[1])
    assert main(["optimize", "studies/optimize_graded.toml", "--out", str(tmp_path / "free"), *TINY,
                 "--set", "graded.probes=true"]) == 0
    free = _history(tmp_path / "free")
    start, end = free[0]["uniformity"], json.loads((tmp_path / "free" / "final.json").read_text())["uniformity"]
    assert end < start - 1e-4  # the floor below will be active
    floor = round(start, 4)
    assert main(["optimize", "studies/optimize_graded.toml", "--out", str(tmp_path / "floor"), *TINY,
                 "--set", f"graded.min_uniformity={floor}"]) == 0
    final = json.loads((tmp_path / "floor" / "final.json").read_text())
    assert final["uniformity"] >= floor - 1e-4 and final["uniformity"] > end
    assert all("uniformity" in h and h["probes_solved"] == 3 for h in _history(tmp_path / "floor"))
    report = (tmp_path / "floor" / "report.txt").read_text()
    assert f"uniformity (1 - CV) {final['uniformity']:.4f}" in report and f"uniformity floor {floor:g}: met" in report


@pytest.mark.parametrize("override, key", [
    ("graded.min_uniformity=1.5", "graded.min_uniformity"),
    ("graded.probe_radius_mm=7.5", "graded.probe_radius_mm"),
    ("graded.probe_grid=1", "graded.probe_grid"),
    ("graded.probe_depth_mm=9.5", "graded.probe_depth_mm"),
    ("graded.probes='yes'", "graded.probes"),
    ("graded.front=[0.5, 0.5]", "graded.front"),
    ("graded.front=0.5", "graded.front"),
])
def test_bad_probe_keys_are_one_line_before_any_work(tmp_path, override, key, capsys, monkeypatch):
    monkeypatch.chdir(__import__("pathlib").Path(__file__).resolve().parents[1])
    import latticeopt.density

    monkeypatch.setattr(latticeopt.density, "DensityModel", None)  # any model built would fail loudly
    extra = ["--set", "graded.probes=true"] if "probe_" in override else []
    status = main(["optimize", "studies/optimize_graded.toml", "--out", str(tmp_path), *extra, "--set", override])
    err = capsys.readouterr().err
    assert status == 2 and len(err.splitlines()) == 1 and key in err


def test_front_dry_run_lists_the_points(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(__import__("pathlib").Path(__file__).resolve().parents[1])
    assert main(["optimize", "studies/optimize_freeform.toml", "--out", str(tmp_path), "--set",
                 "freeform.front=[0.7, 0.5]", "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "3 optimizations" in out and not (tmp_path / "free").exists()
    points = [line.split()[1].rstrip(":") for line in out.splitlines() if line.strip().startswith("point")]
    assert points == ["free", "u0.500", "u0.700"]
    assert "square w1" in out and "diagonal w6" in out
    bad = main(["optimize", "studies/optimize_freeform.toml", "--out", str(tmp_path), "--set",
                "freeform.front=[0.5]", "--set", "freeform.min_uniformity=0.6", "--dry-run"])
    assert bad == 2 and "freeform.min_uniformity" in capsys.readouterr().err


def test_front_runs_resumes_and_plots(tmp_path, capsys, monkeypatch):
    """A tiny front end to end (two lattices as references): every point its own folder, the table and the plot;
    run again, nothing is solved (the points' final.json and references.json are read)."""
    monkeypatch.chdir(__import__("pathlib").Path(__file__).resolve().parents[1])
    import latticeopt.density
    import latticeopt.optimize.front as front

    monkeypatch.setattr(front, "REFERENCES", {"uniform": (0.0,), "square": (4.0,)})
    argv = ["optimize", "studies/optimize_graded.toml", "--out", str(tmp_path), *TINY[:-1],
            "--set", "graded.iterations=1", "--set", "graded.front=[0.5]"]
    assert main(argv) == 0
    first = capsys.readouterr().out
    assert "== front point free ==" in first and "== front point u0.500 ==" in first
    rows = (tmp_path / "front.csv").read_text().splitlines()
    assert rows[0].startswith("kind,label,v_rel,uniformity") and len(rows) == 1 + 2 + 2
    assert (tmp_path / "front.png").is_file() and (tmp_path / "u0.500" / "report.txt").is_file()
    floor = json.loads((tmp_path / "u0.500" / "state.json").read_text())["identity"]["config"]["min_uniformity"]
    assert floor == 0.5
    monkeypatch.setattr(latticeopt.density, "DensityModel", None)  # a second run must solve nothing
    assert main(argv) == 0
    second = capsys.readouterr().out
    assert "== front point" not in second and "done before" in second
    assert (tmp_path / "front.csv").read_text().splitlines() == rows
    assert main([*argv, "--dry-run"]) == 0
    assert capsys.readouterr().out.count("(done)") == 2


def test_runs_without_probes_keep_their_recorded_settings():
    """The probe keys at their defaults are not part of a run's identity: runs begun before them still resume."""
    from latticeopt.optimize.freeform import FreeformConfig
    from latticeopt.optimize.identity import run_identity
    from latticeopt.optimize.probes import PROBE_DEFAULTS

    ident = run_identity(DESIGN, [], MeshSettings(), PhysicsSettings(), FreeformConfig())
    assert not set(PROBE_DEFAULTS) & set(ident["config"]) and "cells" in ident["config"]
    ident = run_identity(DESIGN, [], MeshSettings(), PhysicsSettings(), FreeformConfig(min_uniformity=0.2))
    assert ident["config"]["min_uniformity"] == 0.2


def test_a_front_point_is_the_study_run_on_its_own(monkeypatch):
    """The point folders of a front hold what `--set graded.probes=true` (free) and `--set graded.min_uniformity=u`
    runs would: the documented loop of single runs and the front share their folders."""
    from latticeopt.optimize.freeform_study import freeform_from_dict
    from latticeopt.optimize.front import front_points
    from latticeopt.optimize.identity import run_identity
    from latticeopt.study.config import read_study_table

    def load(*sets):
        raw, keys = read_study_table("studies/optimize_graded.toml", list(sets), {})
        s = freeform_from_dict(raw, "studies/optimize_graded.toml", keys)
        return s, lambda cfg: run_identity(s.design, list(s.phantoms), s.mesh, s.physics, cfg)

    monkeypatch.chdir(__import__("pathlib").Path(__file__).resolve().parents[1])
    front, ident = load("graded.front=[0.3, 0.5]")
    points = dict(front_points(front.config))
    free, ident_free = load("graded.probes=true")
    floor, ident_floor = load("graded.min_uniformity=0.5")
    assert ident(points["free"]) == ident_free(free.config)
    assert ident(points["u0.500"]) == ident_floor(floor.config) != ident(points["u0.300"])


def test_dominated_points_are_named_and_left_off_the_line():
    """The model front of docs/results.md: the point with floor 0.30 came back to 0.342 after MMA overshot it, below
    the points of floors 0.35 and 0.40, which meet its floor and respond more; the others dominate no one."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from latticeopt.optimize.front import dominated_by, draw_front

    def row(label, v, u, met=True):
        return {"label": label, "v_rel": v, "uniformity": u, "floor_met": met}

    points = [row("free", 0.0829, 0.226, None), row("u0.250", 0.0807, 0.250), row("u0.300", 0.0735, 0.342),
              row("u0.350", 0.0767, 0.350), row("u0.400", 0.0745, 0.400)]
    refs = [row("square w8", 0.0734, 0.379, None), row("uniform", 0.0480, 0.47, None)]
    better = dict(zip([r["label"] for r in points + refs], dominated_by(points + refs)))
    assert better["u0.300"] == ["u0.350", "u0.400"]
    assert better["square w8"] == ["u0.400"]  # 0.0745 at 0.400 against 0.0734 at 0.379
    assert all(not better[k] for k in ("free", "u0.250", "u0.350", "u0.400", "uniform"))
    assert dominated_by([row("a", 0.1, 0.3), row("b", 0.1, 0.3)]) == [[], []]  # a tie dominates neither
    fig, ax = plt.subplots()
    draw_front(ax, points, refs, mark_dominated=True)
    line = next(ln for ln in ax.lines if ln.get_label() == "optimized (epsilon-constraint)")
    assert list(line.get_xdata()) == [0.226, 0.250, 0.350, 0.400]
    hollow = next(ln for ln in ax.lines if ln.get_label() == "dominated by another optimized point")
    assert list(hollow.get_xdata()) == [0.342]
    plt.close(fig)


def test_round_off_rows_are_reported_and_recomputed_for_old_runs(tmp_path, capsys, monkeypatch):
    """The diagonal lattice at w = 2 hangs its corner electrodes on dead-end channels, so its untouched rows between
    them are round-off in the density model too (4 mm cells); the square lattice's and the optimized layouts' are
    not. The front names it in a warning, in front.csv and on the plot; a front run before final.json and
    references.json kept the smallest row recomputes it (one electrics solve each) to the same value."""
    monkeypatch.chdir(__import__("pathlib").Path(__file__).resolve().parents[1])
    import csv

    import latticeopt.optimize.front as front
    from latticeopt.metric import ROUND_OFF_REL

    monkeypatch.setattr(front, "REFERENCES", {"square": (4.0,), "diagonal": (2.0,)})
    argv = ["optimize", "studies/optimize_graded.toml", "--out", str(tmp_path), "--set", "mesh.size_mm=4",
            "--set", "graded.cells=25", "--set", "graded.iterations=1", "--set", "phantoms.counts={1=1}",
            "--set", "graded.probe_grid=3", "--set", "graded.probe_radius_mm=12", "--set", "graded.probe_depth_mm=2.5",
            "--set", "graded.front=[0.9]", "--quiet"]

    def table():
        with open(tmp_path / "front.csv") as fh:
            return {r["label"]: r for r in csv.DictReader(fh)}

    assert main(argv) == 0
    out = capsys.readouterr().out
    warning = [line for line in out.splitlines() if line.startswith("warning: reference rows")]
    assert len(warning) == 1 and "(diagonal w2)" in warning[0]
    rows = table()
    assert {k for k, r in rows.items() if r["round_off"] == "True"} == {"diagonal w2"}
    smallest = {k: float(r["min_reference_rel"]) for k, r in rows.items()}
    assert smallest["diagonal w2"] < ROUND_OFF_REL < 1e-7 < min(v for k, v in smallest.items() if k != "diagonal w2")
    for path in (tmp_path / "free" / "final.json", tmp_path / "references.json"):
        stored = json.loads(path.read_text())
        for entry in stored["points"].values() if "points" in stored else [stored]:
            del entry["min_reference_rel"]
        path.write_text(json.dumps(stored))
    assert main(argv) == 0
    assert "(diagonal w2)" in capsys.readouterr().out
    again = {k: float(r["min_reference_rel"]) for k, r in table().items()}
    assert again == pytest.approx(smallest, rel=1e-6)
    assert "min_reference_rel" in json.loads((tmp_path / "references.json").read_text())["points"]["square w4"]
