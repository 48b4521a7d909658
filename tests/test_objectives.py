"""The image-quality objective term ``image_cc`` (latticeopt.study.imaging, latticeopt.study.objectives).

``disc_evaluate`` below is a TEST DOUBLE of ``latticeopt.coupled.evaluate_phantom``: it models every touch as a
conductivity disc of the punch's footprint (no mechanics) and returns the voltages of the design's own forward
model, so the probe images are real one-step reconstructions of real (disc) frames at a fraction of the cost.
The run with the real coupled model is at the end of the file.
"""

from __future__ import annotations

import csv
import functools
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from latticeopt.design import LatticeDesign
from latticeopt.errors import LatticeoptError, ParameterError
from latticeopt.mesh import MeshSettings
from latticeopt.optimize import load_optimization, optimization_from_dict, run_optimization
from latticeopt.optimize.objectives import Objective
from latticeopt.recon.presses import PRESS_RATIO
from latticeopt.study.imaging import (
    ReconstructorCache,
    build_reconstructor,
    footprint_figures,
    footprints,
    probe_image_figures,
    probe_presses,
)
from latticeopt.study.settings import EvalSettings

TESTS = Path(__file__).parent
MESH = MeshSettings(mesher="grid", size_mm=4.0, channel_cells=1, layer_cells=2, cell_counts="fixed")
DESIGN = LatticeDesign(pitch_mm=12.5, width_mm=3.0, thickness_mm=3.0)
EXTENT = (0.0, 100.0, 0.0, 100.0)
PRESSES = np.array([[25.0, 25.0, 7.5, 2.0], [75.0, 25.0, 7.5, 2.0], [25.0, 75.0, 7.5, 2.0], [50.0, 60.0, 9.0, 2.0]])


@functools.lru_cache(maxsize=4)
def _simulator(design: LatticeDesign, settings: EvalSettings):
    from latticeopt.sensor_model import build_sensor_model
    from latticeopt.sensor_simulator import SensorSimulator

    # at sigma0 = 1 S/m, z_c = 2e-3 ohm m^2: the default [physics], the coupled model's reference state
    return SensorSimulator(build_sensor_model(design, settings.mesh, sigma_S_per_m=1.0))


def _disc_voltages(design: LatticeDesign, touches, settings: EvalSettings) -> tuple[np.ndarray, np.ndarray]:
    from latticeopt.recon.dataset import render_touches

    sim = _simulator(design, settings)
    model = sim.model
    rows = np.array([[t.x_mm, t.y_mm, 2 * t.radius_mm, PRESS_RATIO] for t in touches])
    sigma = render_touches(rows, model.sigma0_S_per_m, model.n_pixels, model.extent_mm)
    return sim.voltages(sigma[None])[0], model.v_ref


def disc_evaluate(design, phantom, settings) -> dict:
    """TEST DOUBLE of latticeopt.coupled.evaluate_phantom: every touch a half-conductivity disc of its footprint."""
    volts, ref = _disc_voltages(design, phantom.touches, settings)
    return {"v_rel": float(np.mean(np.abs(volts / ref - 1))), "voltages": volts}


def no_voltage_evaluate(design, phantom, settings) -> dict:
    """TEST DOUBLE: V_rel only, as a model that does not report voltages."""
    return {"v_rel": 0.01}


def corner_failing_evaluate(design, phantom, settings) -> dict:
    """TEST DOUBLE: as disc_evaluate, but the press nearest the origin fails (non-finite V_rel)."""
    t = phantom.touches[0]
    if phantom.kind == "press" and t.x_mm < 30 and t.y_mm < 30:
        return {"v_rel": math.nan}
    return disc_evaluate(design, phantom, settings)


STUDY = """
name = "img"
out = "{out}"
jobs = 1
[design]
pitch_mm = 12.5
thickness_mm = 3.0
[phantoms]
seed = 2025
counts = {{ 1 = 2 }}
[mesh]
mesher = "grid"
size_mm = 4.0
channel_cells = 1
layer_cells = 2
cell_counts = "fixed"
[optimize]
algorithm = "LN_BOBYQA"
objective = "image_cc"
max_evals = {max_evals}
xtol_abs_mm = 0.05
bootstrap = 200
[optimize.uniformity]
grid = 2
radius_mm = 7.5
depth_mm = 2.0
[optimize.variables]
width_mm = {{ lower = 1.0, upper = 8.0, start = 3.0 }}
"""


def _write(tmp_path: Path, max_evals: int = 4) -> Path:
    p = tmp_path / "img.toml"
    p.write_text(STUDY.format(out=(tmp_path / "out").as_posix(), max_evals=max_evals))
    return p


# -- the figures on known images ---------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def model():
    return build_reconstructor(DESIGN, EvalSettings(mesh=MESH), "laplacian")[0]


def test_perfect_image_scores_one_and_a_shifted_or_inverted_truth_less(model):
    assert model.extent_mm == EXTENT and model.n_pixels == 48
    truth = footprints(model, PRESSES)
    assert truth.shape == (4, 48, 48) and truth.min() == pytest.approx(PRESS_RATIO - 1) and truth.max() == 0
    # the disc's area on the grid is the punch's (sub-pixel coverage at the rim)
    area = -truth.sum(axis=(1, 2)) / (1 - PRESS_RATIO) * (100 / 48) ** 2
    assert area == pytest.approx(np.pi * PRESSES[:, 2] ** 2, rel=0.02)
    perfect = footprint_figures(truth, PRESSES, model)
    assert perfect["cc"] == pytest.approx(1.0, abs=1e-12)
    assert np.all(np.abs(perfect["position_error_mm"]) < 0.5) and np.all(perfect["position_offset_mm"] < 0.5)
    # any positive multiple of the truth plus a constant is as good (Pearson)
    assert footprint_figures(3 * truth + 0.2, PRESSES, model)["cc"] == pytest.approx(1.0, abs=1e-12)
    shifted = PRESSES + np.array([10.0, 0.0, 0.0, 0.0])
    moved = footprint_figures(footprints(model, shifted), PRESSES, model)
    assert np.all(moved["cc"] < 0.6) and moved["position_offset_mm"] == pytest.approx(10.0, abs=0.5)
    # a shift of a quarter radius lowers the correlation less than a shift of more than a radius
    small = footprint_figures(footprints(model, PRESSES + np.array([2.0, 0, 0, 0])), PRESSES, model)
    assert np.all(moved["cc"] < small["cc"]) and np.all(small["cc"] < 1 - 1e-3)
    # a press imaged as a conductivity increase is anti-correlated and has no lobe of the right sign to locate
    wrong = footprint_figures(-truth, PRESSES, model)
    assert wrong["cc"] == pytest.approx(-1.0, abs=1e-12) and np.all(np.isnan(wrong["position_error_mm"]))


def test_image_cc_term_score_standard_error_nan_and_paired_difference():
    rng = np.random.default_rng(4)
    cc = rng.uniform(0.3, 0.7, 400)
    vrel = np.full(400, 0.02)
    obj = Objective(weights=(("image_cc", 1.0),), bootstrap=400)
    assert obj.needs_probes and obj.needs_images and obj.probes(100.0)
    val = obj.evaluate([], vrel, cc)
    assert val.score == pytest.approx(cc.mean()) and val.terms == {"image_cc": pytest.approx(cc.mean())}
    assert val.se == pytest.approx(cc.std() / math.sqrt(cc.size), rel=0.15)  # bootstrap SE of a mean
    both = Objective(weights=(("mean", 1.0), ("image_cc", 0.1)), bootstrap=200)
    r = rng.normal(0.05, 0.01, 20)
    assert both.evaluate(r, vrel, cc).score == pytest.approx(r.mean() + 0.1 * cc.mean())
    for bad_cc, bad_v in ((np.where(np.arange(400) == 7, np.nan, cc), vrel), (cc, np.where(np.arange(400) == 3,
                                                                                             np.nan, vrel))):
        nan = obj.evaluate([], bad_v, bad_cc)
        assert math.isnan(nan.score) and math.isnan(nan.se) and math.isnan(nan.terms["image_cc"])
    with pytest.raises(ParameterError, match="probe_cc"):
        obj.evaluate([], vrel, cc[:-1])
    # paired over the same probes: the SE of the difference is far below the unpaired SE
    other = cc - 0.01 + rng.normal(0, 0.002, 400)
    d, se = obj.paired_difference(([], vrel, cc), ([], vrel, other))
    assert d == pytest.approx(np.mean(cc - other)) and se < 0.2 * val.se
    assert se == pytest.approx(np.std(cc - other) / math.sqrt(400), rel=0.2)
    assert "image CC (laplacian, lambda 0.001)" in obj.describe()


@pytest.mark.parametrize("change, key", [
    ({"objective": {"image_cc": -1}}, "optimize.objective.image_cc"),
    ({"objective": "image"}, "optimize.objective"),
    ({"image": {"prior": "tv"}}, "optimize.image.prior"),
    ({"image": {"lambda": 0}}, "optimize.image.lambda"),
    ({"image": {"lambda": "lcurve"}}, "optimize.image.lambda"),
    ({"image": {"lambda": 20.0}}, "optimize.image.lambda"),
    ({"image": {"bogus": 1}}, "optimize.image.bogus"),
    ({"image": 0.01}, "optimize.image"),
    ({"objective": "image_cc", "uniformity": {"grid": 5, "radius_mm": 12.0}}, "optimize.uniformity"),
])
def test_bad_image_keys_are_rejected_in_one_line_naming_the_key(change, key):
    raw = {"design": {"width_mm": 3.0}, "phantoms": {"counts": {"1": 1}},
           "optimize": {"variables": {"width_mm": [1, 5]}, **change}}
    with pytest.raises(ParameterError) as exc:
        optimization_from_dict(raw, source="f.toml")
    assert exc.value.name == f"f.toml: {key}", str(exc.value)
    assert "\n" not in str(exc.value)


def test_image_keys_reach_the_objective():
    raw = {"design": {"width_mm": 3.0}, "phantoms": {"counts": {"1": 1}},
           "optimize": {"variables": {"width_mm": [1, 5]}, "objective": {"mean": 1.0, "image_cc": 0.05},
                        "image": {"prior": "noser", "lambda": 0.01}, "uniformity": {"grid": 2}}}
    opt = optimization_from_dict(raw)
    obj = opt.config.objective
    assert (obj.image_prior, obj.image_lambda, dict(obj.weights)) == ("noser", 0.01, {"mean": 1.0, "image_cc": 0.05})
    assert len(opt.probes) == 4 and probe_presses(opt.probes)[:, 2].tolist() == [7.5] * 4
    assert Objective().image_prior == "laplacian" and Objective().image_lambda == 1e-3


# -- reference voltages, reconstruction, cache -----------------------------------------------------------------
@pytest.mark.parametrize("physics", [{}, {"sigma_S_per_m": 0.5, "contact_impedance_ohm_m2": 5e-3,
                                         "current_A": 2e-3}])
def test_sensor_model_reference_is_the_coupled_models_untouched_voltages(physics):
    from latticeopt.coupled import CoupledModel, PhysicsSettings
    from latticeopt.touches import Touch

    settings = EvalSettings(mesh=MESH, physics_items=tuple(physics.items()))
    model, lin = build_reconstructor(DESIGN, settings, "laplacian")
    coupled = CoupledModel(DESIGN, MESH, PhysicsSettings.from_dict(physics), cache_dir=False)
    assert model.n_rows == 208 and lin.n == 48
    np.testing.assert_allclose(model.v_ref, coupled.reference_voltages, rtol=1e-10, atol=0)
    assert model.mesh.n_nodes == coupled.reference.mesh.n_nodes
    if not physics:  # a real press: its image is negative at the press and correlates with its footprint
        res = coupled.simulate([Touch(x_mm=50.0, y_mm=50.0, radius_mm=7.5, depth_mm=2.0)])
        press = np.array([[50.0, 50.0, 7.5, 2.0]])
        figs = probe_image_figures(model, lin, [res.voltages], press, 1e-3)
        assert figs["cc"][0] > 0.3 and abs(figs["position_error_mm"][0]) < 4.0


def test_probe_images_nan_where_a_probe_failed_and_the_cache_builds_once():
    settings = EvalSettings(mesh=MESH)
    cache = ReconstructorCache(size=2)
    model, lin = cache.get(DESIGN, settings, "laplacian")
    assert cache.get(DESIGN, settings, "laplacian")[1] is lin and cache.built == 1
    volts = [_disc_voltages(DESIGN, [_touch(p)], settings)[0] for p in PRESSES]
    full = probe_image_figures(model, lin, volts, PRESSES, 1e-3)
    assert np.all(full["cc"] > 0.4) and np.all(np.isfinite(full["position_error_mm"]))
    # the same result computed directly from the pieces it reuses
    from latticeopt.learn.metrics import correlation_coefficient

    y = np.stack(volts) / model.v_ref - 1
    images = lin.solve(y, 1e-3 * lin.eigenvalues.max())[0].reshape(4, 48, 48)
    np.testing.assert_allclose(full["cc"], correlation_coefficient(images, footprints(model, PRESSES)))
    part = probe_image_figures(model, lin, [volts[0], None, volts[2], volts[3]], PRESSES, 1e-3)
    assert np.isnan(part["cc"][1]) and np.isnan(part["position_error_mm"][1])
    np.testing.assert_allclose(part["cc"][[0, 2, 3]], full["cc"][[0, 2, 3]])
    assert np.all(np.isnan(probe_image_figures(model, lin, [None] * 4, PRESSES, 1e-3)["cc"]))
    with pytest.raises(LatticeoptError, match="208 finite touched voltages"):
        probe_image_figures(model, lin, [volts[0][:100]] + volts[1:], PRESSES, 1e-3)
    # a different design or prior is a different entry; the oldest falls out beyond `size`
    cache.get(DESIGN, settings, "noser")
    cache.get(LatticeDesign(pitch_mm=12.5, width_mm=5.0, thickness_mm=3.0), settings, "laplacian")
    assert cache.built == 3
    cache.get(DESIGN, settings, "laplacian")
    assert cache.built == 4


def _touch(row):
    from latticeopt.touches import Touch

    x, y, r, d = row
    return Touch(x_mm=x, y_mm=y, radius_mm=r, depth_mm=d)


# -- optimizer runs ----------------------------------------------------------------------------------------------
def test_image_objective_run_through_the_api(tmp_path, monkeypatch):
    import latticeopt.study.imaging as imaging

    builds = []
    original = imaging.build_reconstructor
    monkeypatch.setattr(imaging, "build_reconstructor",
                        lambda design, *a: builds.append(design.content_hash()) or original(design, *a))
    opt = load_optimization(_write(tmp_path))
    assert opt.config.objective.weights == (("image_cc", 1.0),) and len(opt.probes) == 4
    res = run_optimization(opt, disc_evaluate)
    fresh = [s for s in res.history if not s.repeat]
    assert len(builds) == len(set(builds)) == len({s.assessment.design_key for s in fresh})  # one per design
    for s in fresh:
        a = s.assessment
        assert len(a.probe_cc) == 4 and len(a.probe_v) == 4 and a.n_failed == 0
        assert a.score == pytest.approx(np.mean(a.probe_cc)) and a.terms["image_cc"] == a.score
        assert 0 < a.se < 0.5 and math.isfinite(a.image_figures["position_error_mm"])
    # the best design's score recomputed from scratch: its own Jacobian, its probes' disc voltages
    best = res.best
    design = LatticeDesign(pitch_mm=12.5, thickness_mm=3.0, width_mm=best.x["width_mm"])
    settings = res.settings
    model, lin = original(design, settings, "laplacian")
    presses = probe_presses(opt.probes)
    volts = [_disc_voltages(design, [_touch(p)], settings)[0] for p in presses]
    assert best.score == pytest.approx(np.mean(probe_image_figures(model, lin, volts, presses, 1e-3)["cc"]),
                                       rel=1e-9)
    assert best.score >= res.optimum.start_step.score and res.paired is not None and math.isfinite(res.paired[1])
    rows = list(csv.DictReader(open(res.outputs["history"])))
    assert {"term_image_cc", "image_position_error_mm", "image_position_offset_mm"} <= set(rows[0])
    assert "image CC" in "\n".join(res.report) and "mean position error" in "\n".join(res.report)
    # a second run reads every phantom from the store and builds each design once again (a per-run cache)
    builds.clear()
    again = run_optimization(load_optimization(_write(tmp_path)), disc_evaluate, outputs=False)
    assert again.computed == 0 and [(s.x, s.score) for s in again.history] == [(s.x, s.score) for s in res.history]
    assert len(builds) == len(set(builds))


def test_image_objective_needs_voltages_and_a_failed_probe_makes_the_design_infeasible(tmp_path):
    with pytest.raises(LatticeoptError, match="no 'voltages'.*image_cc"):
        run_optimization(load_optimization(_write(tmp_path), ["out=" + (tmp_path / "a").as_posix()]),
                         no_voltage_evaluate, outputs=False)
    res = run_optimization(load_optimization(_write(tmp_path, max_evals=2), ["out=" + (tmp_path / "b").as_posix()]),
                           corner_failing_evaluate, outputs=False)
    a = res.history[0].assessment
    assert a.n_failed == 1 and math.isnan(a.score) and math.isnan(a.probe_cc[0])
    assert all(math.isfinite(c) for c in a.probe_cc[1:]) and res.best is None
    assert "infeasible" in res.history[0].note


def test_image_objective_through_the_cli(tmp_path):
    path = _write(tmp_path, max_evals=3)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(TESTS), os.environ.get("PYTHONPATH", "")])}
    cmd = [sys.executable, "-m", "latticeopt", "optimize", str(path), "--evaluate", "test_objectives:disc_evaluate"]
    bad = subprocess.run(cmd + ["--set", "optimize.image.prior=tv"], env=env, capture_output=True, text=True)
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "--set optimize.image.prior" in bad.stderr
    done = subprocess.run(cmd + ["--quiet"], env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "image CC" in done.stdout and "optimum:" in done.stdout
    rows = list(csv.DictReader(open(tmp_path / "out" / "img_history.csv")))
    assert len(rows) == 3 and all(0 < float(r["term_image_cc"]) <= 1 for r in rows)


REAL = """
name = "real_image"
out = "{out}"
jobs = 1
[design]
pitch_mm = 12.5
thickness_mm = 3.0
[phantoms]
seed = 2025
counts = {{ 1 = 1 }}
[mesh]
mesher = "grid"
size_mm = 10.0
channel_cells = 1
layer_cells = 1
cell_counts = "fixed"
[optimize]
objective = {{ mean = 1.0, image_cc = 0.01 }}
max_evals = 2
bootstrap = 200
[optimize.uniformity]
grid = 2
depth_mm = 2.0
[optimize.variables]
width_mm = {{ lower = 1.0, upper = 7.0, start = 3.0 }}
"""


def test_real_coupled_presses_give_images_that_correlate_with_their_footprints(tmp_path):
    path = tmp_path / "real.toml"
    path.write_text(REAL.format(out=(tmp_path / "out").as_posix()))
    res = run_optimization(load_optimization(path), jobs=1, outputs=False)
    for s in res.history:
        a = s.assessment
        assert a.n_failed == 0 and all(c > 0 for c in a.probe_cc)
        assert a.score == pytest.approx(np.mean(a.random_v) + 0.01 * np.mean(a.probe_cc))


def test_shipped_optimize_image_study_matches_the_square_study_but_for_the_objective():
    path = TESTS.parent / "studies" / "optimize_image.toml"
    img = load_optimization(path)
    square = load_optimization(TESTS.parent / "studies" / "optimize_square.toml")
    assert img.config.objective.weights == (("image_cc", 1.0),) and len(img.probes) == 9
    assert (img.config.objective.image_prior, img.config.objective.image_lambda) == ("laplacian", 1e-3)
    assert img.study.phantoms == square.study.phantoms and img.study.settings.key == square.study.settings.key
    assert img.config.names == ("width_mm",) and img.study.designs[0].thickness_mm == 3.0
    mean = load_optimization(path, ["optimize.objective=mean", "name=optimize_image_mean"])
    assert mean.config.objective.weights == (("mean", 1.0),) and mean.probes == ()
    assert mean.study.settings.key == img.study.settings.key and mean.study.phantoms == img.study.phantoms


@pytest.mark.parametrize("weights", [(("mean", 1.0),), (("robust", 1.0),), (("uniformity", 1.0),),
                                     (("mean", 1.0), ("uniformity", 0.05))])
def test_term_gradients_against_differences(weights):
    """Every term with a gradient: per-phantom V_rel linear in a parameter vector, the score's gradient from the
    term table against central differences of the score."""
    rng = np.random.default_rng(3)
    A, B = rng.random((12, 5)), rng.random((9, 5))  # V_rel of 12 phantoms and 9 probes, linear in theta
    theta = rng.random(5)
    obj = Objective(weights=weights, quantile=0.3)

    def score(t):
        return obj.evaluate(A @ t, B @ t).score

    g = obj.gradient(A @ theta, B @ theta, A, B)
    for k in range(5):
        e = np.zeros(5)
        e[k] = 1e-6
        assert g[k] == pytest.approx((score(theta + e) - score(theta - e)) / 2e-6, rel=1e-5, abs=1e-9)


def test_term_table_names_every_term_and_refuses_image_gradients():
    with pytest.raises(ParameterError) as exc:
        Objective(weights=(("uniformty", 1.0),))
    for name in ("mean", "robust", "uniformity", "image_cc"):
        assert name in str(exc.value)
    with pytest.raises(ParameterError, match="adjoint gradients"):
        Objective(weights=(("image_cc", 1.0),)).gradient([0.1], [0.1], np.ones((1, 2)), np.ones((1, 2)))
