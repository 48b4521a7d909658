"""Free-form layouts: the parametrization's chain rule and symmetry, outlines that can be cast, and a coarse
optimization run from the command line that resumes after a crash and writes its layout."""

import json

import numpy as np
import pytest

from latticeopt import LatticeDesign, MeshSettings
from latticeopt.cli import main
from latticeopt.density.outline import density_outline
from latticeopt.density.projection import FreeForm
from latticeopt.layout_files import read_geojson

DESIGN = LatticeDesign(thickness_mm=3.0)


@pytest.mark.parametrize("symmetry", ["none", "mirror", "d4"])
def test_parametrization_chain_rule_symmetry_and_pads(symmetry):
    ff = FreeForm(DESIGN, 16, symmetry, min_feature_mm=15.0, pad_mm=4.0)
    rng = np.random.default_rng(2)
    x, g, d = rng.random(ff.n_variables), rng.normal(size=(16, 16)), rng.normal(size=ff.n_variables)
    h = 1e-6
    fd = (np.sum(g * ff.density(x + h * d, 4.0)) - np.sum(g * ff.density(x - h * d, 4.0))) / (2 * h)
    assert abs(ff.gradient(x, 4.0, g) @ d - fd) <= 1e-7 * abs(fd)
    rho = ff.density(x, 4.0)
    if symmetry != "none":
        assert np.allclose(rho, rho[::-1]) and np.allclose(rho, rho[:, ::-1])
    assert np.allclose(rho, rho.T) == (symmetry == "d4")
    # a pad at every electrode: the cell under each electrode's centre is gel
    for cx, cy, *_ in DESIGN.electrodes():
        i, j = min(int(cy / 100 * 16), 15), min(int(cx / 100 * 16), 15)
        assert rho[i, j] == 1.0
    assert {"none": 256, "mirror": 64, "d4": 36}[symmetry] == ff.n_variables


def test_outline_drops_floating_gel_and_round_trips(tmp_path):
    d = np.zeros((10, 10))
    d[1, :] = 1.0       # a channel along y = 10..20 mm: reaches the electrodes at y = 12.5 on both sides
    d[5, 4:6] = 1.0     # an island in the middle: touches no electrode
    geom, report = density_outline(DESIGN, d, smooth_mm=1.0)
    assert report["pieces"] == 1 and report["pieces_dropped"] == 1 and report["dropped_area_mm2"] > 150
    from latticeopt.layout_files import write_geojson

    write_geojson(geom, tmp_path / "l.geojson")
    back = read_geojson(tmp_path / "l.geojson")
    assert len(back) == 1
    pytest.importorskip("ezdxf")
    from latticeopt.layout_dxf import read_dxf, write_dxf

    write_dxf(geom, tmp_path / "l.dxf")
    area = sum(abs(np.sum(p[0][:, 0] * np.roll(p[0][:, 1], -1) - np.roll(p[0][:, 0], -1) * p[0][:, 1])) / 2
               for p in [tuple(np.asarray(r) for r in poly) for poly in read_dxf(tmp_path / "l.dxf")])
    assert abs(area - geom.area) < 1e-6 * geom.area


SMALL = ["--set", "mesh.size_mm=8", "--set", "freeform.cells=8", "--set", "phantoms.counts={1=1}",
         "--set", "freeform.betas=[1, 4]", "--set", "freeform.min_feature_mm=13"]


class Crash(Exception):
    pass


def test_freeform_run_resumes_after_a_crash_and_writes_a_castable_layout(tmp_path, monkeypatch, capsys):
    out = tmp_path / "run"
    argv = ["optimize", "studies/optimize_freeform.toml", "--out", str(out), *SMALL,
            "--set", "freeform.iterations_per_beta=2"]
    import latticeopt.optimize.freeform as freeform

    calls = {"n": 0}
    original = freeform.json.dumps

    def crash_on_third_record(obj, *a, **k):  # the third evaluation's history line: a kill mid-run
        if isinstance(obj, dict) and "iteration" in obj:
            calls["n"] += 1
            if calls["n"] == 3:
                raise Crash
        return original(obj, *a, **k)

    monkeypatch.chdir(__import__("pathlib").Path(__file__).resolve().parents[1])
    monkeypatch.setattr(freeform.json, "dumps", crash_on_third_record)
    with pytest.raises(Crash):
        main(argv)
    monkeypatch.setattr(freeform.json, "dumps", original)
    state = json.loads((out / "state.json").read_text())
    assert (state["stage"], state["iterations"]) == (1, 0)  # stage 1 finished, nothing of stage 2 kept
    assert len((out / "history.jsonl").read_text().splitlines()) == 2
    capsys.readouterr()
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert "resuming" in text and "stage 2 of 2" in text
    history = [json.loads(x) for x in (out / "history.jsonl").read_text().splitlines()]
    assert [h["stage"] for h in history] == [0, 0, 1, 1]  # stage 1 was not run again
    assert all(h["isolation"] >= 1.0 for h in history)  # the bound's measure, on every evaluation
    final = json.loads((out / "final.json").read_text())  # the layout nlopt returned, which the outline is
    report = (out / "report.txt").read_text()
    assert f"final layout: mean V_rel {final['v_rel']:.5f}, isolation {final['isolation']:.4g} (bound 100)" in report
    assert final["isolation"] >= 1.0 and f"isolation {history[-1]['isolation']:.4g}" in report
    for name in ("layout.geojson", "density.npz", "convergence.png", "layout_stage1.png", "layout_stage2.png",
                 "report.txt", "stl/hydrogel.stl"):
        assert (out / name).is_file(), name
    assert main(["mesh", "--layout", str(out / "layout.geojson"), "--thickness", "3", "--size", "8", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["region_volumes_mm3"]["hydrogel"] > 0
    # the outline keys shape only the written layout: a finished run re-outlined without smoothing writes the
    # cell staircase (every edge axis-aligned, what the grid mesher meshes exactly) and computes no new iterate,
    # not even the final layout again: its V_rel comes from final.json (no density model is built)
    import latticeopt.density as density

    def no_model(*a, **k):
        raise AssertionError("a finished run built a density model")

    monkeypatch.setattr(density, "DensityModel", no_model)
    capsys.readouterr()
    assert main([*argv, "--set", "freeform.smooth_mm=0"]) == 0
    assert f"final layout read from {out / 'final.json'} (mean V_rel {final['v_rel']:.5f})" in capsys.readouterr().out
    assert f"final layout: mean V_rel {final['v_rel']:.5f}" in (out / "report.txt").read_text()
    assert len((out / "history.jsonl").read_text().splitlines()) == 4
    ring = json.loads((out / "layout.geojson").read_text())["features"][0]["geometry"]["coordinates"][0]
    assert all(a[0] == b[0] or a[1] == b[1] for a, b in zip(ring, ring[1:]))
    capsys.readouterr()
    # a key that moves the iterates still refuses the folder
    assert main([*argv, "--set", "freeform.start=0.4"]) == 2
    assert "choose another --out" in capsys.readouterr().err


def test_stages_appended_to_betas_continue_a_finished_run(tmp_path, monkeypatch, capsys):
    """A run whose layout is still grey can be sharpened further: the same study with stages appended to betas
    resumes from the last iterate (no stage run again); any other change of betas is refused."""
    monkeypatch.chdir(__import__("pathlib").Path(__file__).resolve().parents[1])
    out = tmp_path / "run"
    argv = ["optimize", "studies/optimize_freeform.toml", "--out", str(out), *SMALL,
            "--set", "freeform.iterations_per_beta=1"]
    assert main(argv) == 0
    first = (out / "history.jsonl").read_text().splitlines()
    assert [json.loads(x)["beta"] for x in first] == [1, 4]
    capsys.readouterr()
    assert main([*argv, "--set", "freeform.betas=[1, 4, 16]"]) == 0
    assert "extending the continuation" in capsys.readouterr().out
    history = (out / "history.jsonl").read_text().splitlines()
    assert history[:2] == first and [json.loads(x)["beta"] for x in history[2:]] == [16]
    assert json.loads((out / "state.json").read_text())["stage"] == 3
    assert main([*argv, "--set", "freeform.betas=[2, 4, 16, 32]"]) == 2  # not an extension of [1, 4, 16]
    assert "stages appended to betas" in capsys.readouterr().err


class ParkedOptimizer:
    """An nlopt.opt stand-in that asks for the start twice and then once more for the same point, as MMA does
    when parked on its bounds."""

    def __init__(self, algorithm, n):
        self.f = None

    def __getattr__(self, name):  # bounds, constraints, tolerances: accepted and ignored
        return lambda *a, **k: None

    def set_min_objective(self, f):
        self.f = f

    def optimize(self, x):
        for _ in range(3):
            self.f(np.asarray(x, dtype=float), np.empty(0))
        return x


def test_a_repeated_point_is_counted_but_not_timed(tmp_path, monkeypatch, capsys):
    import nlopt

    monkeypatch.chdir(__import__("pathlib").Path(__file__).resolve().parents[1])
    monkeypatch.setattr(nlopt, "opt", ParkedOptimizer)
    out = tmp_path / "run"
    assert main(["optimize", "studies/optimize_freeform.toml", "--out", str(out), *SMALL,
                 "--set", "freeform.betas=[1]", "--set", "freeform.iterations_per_beta=3"]) == 0
    history = [json.loads(x) for x in (out / "history.jsonl").read_text().splitlines()]
    assert [h["repeat"] for h in history] == [False, True, True]
    assert history[0]["seconds"] > 0 and history[0]["newton_steps"] > 0
    assert all(h["seconds"] == 0 and h["newton_steps"] == 0 for h in history[1:])
    assert history[1]["v_rel"] == history[0]["v_rel"]
    assert "3 evaluations (2 repeats of the point before, not solved again)" in (out / "report.txt").read_text()
    assert "(repeat of the previous point)" in capsys.readouterr().out


@pytest.mark.parametrize("override, key", [
    ("freeform.symmetry='c2'", "freeform.symmetry"),
    ("freeform.cells=2", "freeform.cells"),
    ("freeform.max_hydrogel_fraction=0", "freeform.max_hydrogel_fraction"),
    ("freeform.betas=[4, 1]", "freeform.betas"),
    ("freeform.bogus=1", "freeform.bogus"),
    ("freeform.isolation_sharpening=0.5", "freeform.isolation_sharpening"),
    ("freeform.isolation_threshold=1.5", "freeform.isolation_threshold"),
    ("freeform.max_isolation=0.5", "freeform.max_isolation"),
    ("mesh.mesher='tetwild'", "mesh.mesher"),
    ("physics.conductivity_law='linear'", "physics.conductivity_law"),
])
def test_bad_freeform_keys_are_one_line_before_any_work(tmp_path, override, key, capsys, monkeypatch):
    monkeypatch.chdir(__import__("pathlib").Path(__file__).resolve().parents[1])
    import latticeopt.density

    monkeypatch.setattr(latticeopt.density, "DensityModel", None)  # any model built would fail loudly
    status = main(["optimize", "studies/optimize_freeform.toml", "--out", str(tmp_path), "--set", override])
    err = capsys.readouterr().err
    assert status == 2 and len(err.splitlines()) == 1 and key in err


def test_graded_widths_gradient_through_the_model():
    """d mean V_rel / d (line widths) by the chain rule through the graded density, against central differences
    of the whole model over the widths."""
    from latticeopt import MeshSettings
    from latticeopt.coupled import PhysicsSettings
    from latticeopt.density import DensityModel
    from latticeopt.density.graded import GradedSquare
    from latticeopt.touches import Touch

    param = GradedSquare(LatticeDesign(thickness_mm=3.0), 10, "mirror", smoothing_mm=1.0, samples=2)
    model = DensityModel(DESIGN, 10, MeshSettings(size_mm=8.0), PhysicsSettings(mechanics_rtol=1e-10))
    press = [[Touch(45.0, 55.0, 12.0, 2.5)]]
    x = np.linspace(3.0, 5.0, param.n_variables)
    ev = model.evaluate(param.density(x), press)
    g = param.gradient(x, None, ev.dv_rel_ddensity)
    d = np.cos(np.arange(param.n_variables))
    h = 1e-4
    fd = (model.evaluate(param.density(x + h * d), press, gradient=False).v_rel
          - model.evaluate(param.density(x - h * d), press, gradient=False).v_rel) / (2 * h)
    assert abs(g @ d - fd) <= 1e-4 * abs(fd)
    # the exact outline is the union of the channel rectangles
    widths = param.widths(x)
    assert param.polygons(x).area == pytest.approx(
        100 * widths.sum() - sum(a * b for a in widths[:7] for b in widths[7:]), rel=1e-9)


def test_graded_study_writes_an_exact_layout(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(__import__("pathlib").Path(__file__).resolve().parents[1])
    out = tmp_path / "graded"
    assert main(["optimize", "studies/optimize_graded.toml", "--out", str(out), "--set", "mesh.size_mm=8",
                 "--set", "graded.cells=8", "--set", "graded.iterations=2", "--set", "phantoms.counts={1=1}",
                 "--quiet"]) == 0
    widths = json.loads((out / "widths.json").read_text())
    assert len(widths["widths_along_x_mm"]) == 7 and widths["widths_along_x_mm"] == widths["widths_along_y_mm"]
    assert all(1.0 <= w <= 10.5 for w in widths["variables_mm"])
    # the outline's narrowest gel, measured on it, is the narrowest line the optimizer chose
    report = (out / "report.txt").read_text()
    assert f"narrowest gel {min(widths['variables_mm']):.3g} mm" in report
    capsys.readouterr()
    assert main(["mesh", "--layout", str(out / "layout.geojson"), "--mesher", "grid", "--thickness", "3",
                 "--size", "8", "--json"]) == 0  # axis-aligned: the exact grid mesher takes it
    assert (out / "stl" / "hydrogel.stl").is_file()
    bad = main(["optimize", "studies/optimize_graded.toml", "--out", str(tmp_path / "b"), "--set",
                "graded.min_island_mm=12"])
    assert bad == 2 and "graded.min_island_mm" in capsys.readouterr().err


def test_a_minimum_channel_narrower_than_two_density_elements_is_warned(caplog):
    from latticeopt.optimize.freeform import warn_if_unresolved

    with caplog.at_level("WARNING", logger="latticeopt.optimize.freeform"):
        assert not warn_if_unresolved("graded.min_width_mm", 4.0, None)  # two elements of the default 2 mm mesh
        assert not warn_if_unresolved("freeform.min_feature_mm", 2.0, MeshSettings(size_mm=1.0))
        assert not caplog.records
        assert warn_if_unresolved("graded.min_width_mm", 1.0, MeshSettings(size_mm=2.0))
    record, = caplog.records
    assert "graded.min_width_mm = 1 mm" in record.message and "2 mm density mesh" in record.message
    assert "mesh.size_mm <= 0.5" in record.message


def test_worker_processes_follow_the_same_path(tmp_path, monkeypatch, capsys):
    """--jobs presses each iterate's phantoms in worker processes: the same iterates as one process, and not part
    of the run's identity (a folder made with one worker resumes with two)."""
    monkeypatch.chdir(__import__("pathlib").Path(__file__).resolve().parents[1])
    small = ["--set", "mesh.size_mm=8", "--set", "graded.cells=8", "--set", "graded.iterations=2",
             "--set", "phantoms.counts={1=2,2=1}", "--quiet"]
    one, two = tmp_path / "one", tmp_path / "two"
    assert main(["optimize", "studies/optimize_graded.toml", "--out", str(one), *small]) == 0
    assert main(["optimize", "studies/optimize_graded.toml", "--out", str(two), *small, "--jobs", "2"]) == 0
    h1, h2 = ([json.loads(x) for x in (d / "history.jsonl").read_text().splitlines()] for d in (one, two))
    assert len(h1) == len(h2) == 2
    for a, b in zip(h1, h2):
        assert b["v_rel"] == pytest.approx(a["v_rel"], rel=1e-9) and b["newton_steps"] == a["newton_steps"]
    capsys.readouterr()
    assert main(["optimize", "studies/optimize_graded.toml", "--out", str(one), *small[:-1], "--jobs", "2"]) == 0
    assert "every stage done" in capsys.readouterr().out


def test_a_layout_in_separate_pieces_is_flagged(tmp_path):
    """Two channels that each join two electrodes but not each other: no current flows between them in a cast
    sensor, so the report must say so rather than present the density model's reading."""
    from latticeopt.optimize.freeform import FreeformConfig
    from latticeopt.optimize.layout_outputs import write_outputs

    d = np.zeros((10, 10))
    d[1, :] = 1.0   # y = 10..20 mm: electrodes at y = 12.5 on both sides
    d[8, :] = 1.0   # y = 80..90 mm: electrodes at y = 87.5
    write_outputs(DESIGN, d, FreeformConfig(cells=10, smooth_mm=0.0), tmp_path, [])
    report = (tmp_path / "report.txt").read_text()
    assert "WARNING: the layout is 2 separate pieces" in report
    d[:, 1] = 1.0   # joined by a channel along x = 10..20 mm: one piece, no warning
    write_outputs(DESIGN, d, FreeformConfig(cells=10, smooth_mm=0.0), tmp_path, [])
    assert "WARNING" not in (tmp_path / "report.txt").read_text()


def test_isolation_bound_reads_the_layout_as_cast():
    """Bridges below the cast's threshold conduct in the model at the stage's sharpness, and bridges parked just
    below it still conduct at any finite sharpness (what an optimizer bounded there did): the bound reads the
    layout sharpened with the stage and eroded to isolation_threshold, where only solid bridges join."""
    import dataclasses

    from latticeopt import MeshSettings
    from latticeopt.density import DensityModel
    from latticeopt.optimize.freeform import FreeformConfig

    cfg = FreeformConfig()
    assert cfg.isolation_sharpness(16.0) == 16.0 * cfg.isolation_sharpening == 128.0
    assert FreeformConfig(isolation_sharpening=1.0).isolation_sharpness(4.0) == 4.0  # the stage's own layout
    n = 20
    model = DensityModel(DESIGN, n, MeshSettings(size_mm=6.0))
    ff = FreeForm(DESIGN, n, "none", min_feature_mm=0.0, pad_mm=0.0)  # the density is the projected variables
    eroded = dataclasses.replace(ff, eta=cfg.isolation_threshold)
    x = np.zeros((n, n))
    x[:, [7, 12]] = x[[7, 12], :] = 1.0
    x[:4, :4] = x[:4, -4:] = x[-4:, :4] = x[-4:, -4:] = 1.0  # corner pieces, each with two electrodes

    def bridged(value):
        b = x.copy()
        b[2, 4:7] = b[2, 13:16] = b[17, 4:7] = b[17, 13:16] = value
        return b.ravel()

    sharp = cfg.isolation_sharpness(16.0)
    assert model.isolation(ff.density(bridged(0.48), 16.0))[0] < cfg.max_isolation
    assert model.isolation(ff.density(bridged(0.48), sharp))[0] > 100 * cfg.max_isolation
    assert model.isolation(ff.density(bridged(0.495), sharp))[0] < cfg.max_isolation
    assert model.isolation(eroded.density(bridged(0.495), sharp))[0] > 100 * cfg.max_isolation
    assert model.isolation(eroded.density(bridged(0.7), sharp))[0] < 10.0  # a solid bridge joins
