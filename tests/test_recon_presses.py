"""Coupled press frames for reconstruction and their gap to conductivity discs."""

from __future__ import annotations

import json

import numpy as np
import pytest

from latticeopt.cli import main
from latticeopt.design import LatticeDesign
from latticeopt.mesh import MeshSettings
from latticeopt.recon.classical import LinearReconstructor
from latticeopt.recon.dataset import DatasetConfig, generate_dataset
from latticeopt.recon.presses import disc_frames, press_frames, press_gap, random_presses
from latticeopt.sensor_model import build_sensor_model, save_sensor_model


@pytest.fixture(scope="module")
def model():
    return build_sensor_model(LatticeDesign(width_mm=4.0, thickness_mm=3.0), MeshSettings(size_mm=6.0),
                              n_pixels=16, cache_dir=False)


def test_random_presses_keep_the_punch_on_the_sensor_and_are_reproducible():
    p = random_presses(200, 100.0, seed=3)
    x, y, r, d = p.T
    assert np.all(x - r >= 0) and np.all(x + r <= 100) and np.all(y - r >= 0) and np.all(y + r <= 100)
    assert np.all((r >= 6.25) & (r <= 8.75)) and np.all((d >= 1) & (d <= 4))
    np.testing.assert_array_equal(p, random_presses(200, 100.0, seed=3))


def test_press_frames_zero_depth_is_silent_and_a_press_raises_the_voltages(model):
    y = press_frames(model, np.array([[50.0, 50.0, 8.75, 0.0], [50.0, 50.0, 8.75, 3.0]]))
    assert np.max(np.abs(y[0])) < 1e-12
    # thinner channels under the punch: more resistance, the mean measured voltage rises
    assert np.mean(y[1]) > 0


def test_press_gap_of_discs_against_themselves_is_exact(model):
    p = random_presses(3, 100.0, seed=1)
    lin = LinearReconstructor(model, "laplacian")
    fns = {"tikhonov": lambda yy: lin.solve(yy, 1e-3)[0].reshape(len(yy), 16, 16)}
    discs = disc_frames(model, p, 0.5)
    discs_with_failure = np.vstack([discs, np.full((1, model.n_rows), np.nan)])
    p4 = np.vstack([p, p[:1]])
    g = press_gap(model, p4, fns, discs_with_failure)["tikhonov"]
    assert g["n"] == 3 and g["cc"] == pytest.approx(1.0, abs=1e-12)
    assert g["press"] == pytest.approx(g["disc"], rel=1e-12)


def test_recon_eval_reports_the_press_gap(model, tmp_path, capsys):
    path = save_sensor_model(model, tmp_path / "s.npz")
    ds = tmp_path / "ds.npz"
    generate_dataset(model, DatasetConfig(per_count=10, touch_counts=(1,))).save(ds)
    assert main(["recon-eval", "--model", str(path), "--dataset", str(ds), "--methods", "background,tikhonov",
                 "--prior", "laplacian", "--presses", "2", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    gap = out["presses"]["tikhonov/laplacian"]
    assert gap["n"] == 2 and -1 <= gap["cc"] <= 1 and gap["press"]["resolution"] > 0
    assert main(["recon-eval", "--model", str(path), "--dataset", str(ds), "--presses", "-1"]) == 2
    assert "--presses" in capsys.readouterr().err
    assert main(["recon-eval", "--model", str(path), "--dataset", str(ds), "--presses", "1", "--press-seed",
                 "-1"]) == 2
    assert "--press-seed" in capsys.readouterr().err
