"""Coupled press frames for reconstruction and their gap to conductivity discs."""

from __future__ import annotations

import json

import numpy as np
import pytest

import latticeopt.recon.presses as presses_module
from latticeopt._npzfile import save_npz
from latticeopt.cli import main
from latticeopt.design import LatticeDesign
from latticeopt.mesh import MeshSettings
from latticeopt.recon.augment import square_symmetries
from latticeopt.recon.classical import LinearReconstructor
from latticeopt.recon.dataset import (
    DATASET_FORMAT,
    DatasetConfig,
    ReconDataset,
    generate_dataset,
    part_arrays,
    render_touches,
    training_arrays,
)
from latticeopt.recon.presses import disc_frames, press_frames, press_gap, random_presses, with_presses
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


# -- presses mixed into the training part ------------------------------------------------------------------------

@pytest.fixture(scope="module")
def discs(model):
    return generate_dataset(model, DatasetConfig(per_count=10, touch_counts=(1, 2), seed=4))


@pytest.fixture(scope="module")
def mixed(model, discs):
    return with_presses(discs, model, 3, seed=2)


def _no_solves(monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("press frames simulated again")

    monkeypatch.setattr(presses_module, "press_frames", refuse)


def test_presses_join_the_training_part_only_with_their_footprint_as_target(model, discs, mixed):
    p = mixed.presses
    np.testing.assert_array_equal(p.presses, random_presses(3, 100.0, seed=2))
    assert p.seed == 2 and p.y.shape == (3, model.n_rows) and p.images.shape == (3, 16, 16)
    # the coupled solve of the first press again (to solver rounding)
    np.testing.assert_allclose(p.y[:1], press_frames(model, p.presses[:1]), rtol=1e-6, atol=1e-9)
    s0 = model.sigma0_S_per_m
    for (x, y, r, _), img in zip(p.presses, p.images):
        disc = render_touches(np.array([[x, y, 2 * r, 0.5]]), s0, 16, model.extent_mm)
        np.testing.assert_allclose(img, (disc - s0) / s0, atol=1e-7)
        assert img.min() == pytest.approx(-0.5)
    assert discs.presses is None  # the input is left as it was
    for name in ("voltages", "images", "touches", "n_touches", "train", "val", "test"):
        assert getattr(mixed, name) is getattr(discs, name)
    for part in ("val", "test"):
        for a, b in zip(part_arrays(mixed, model, part), part_arrays(discs, model, part)):
            np.testing.assert_array_equal(a, b)
    y, img = training_arrays(mixed, model, augment=False)
    k = len(discs.train)
    assert len(y) == len(img) == k + 3
    np.testing.assert_allclose(y[k:], p.y, rtol=1e-6, atol=1e-12)
    np.testing.assert_array_equal(img[k:], p.images)
    np.testing.assert_array_equal(img[:k], discs.images[discs.train])


def test_failed_presses_are_left_out_of_training(model, mixed):
    from dataclasses import replace

    y = mixed.presses.y.copy()
    y[1] = np.nan
    failed = replace(mixed, presses=replace(mixed.presses, y=y))
    x, img = training_arrays(failed, model, augment=False)
    k = len(mixed.train)
    assert len(x) == k + 2 and np.isfinite(x).all()
    np.testing.assert_array_equal(img[k:], mixed.presses.images[[0, 2]])
    assert len(training_arrays(failed, model)[0]) == 8 * (k + 2)


def test_augmentation_moves_press_frames_and_targets_together(model, discs, mixed):
    x, img = training_arrays(mixed, model)
    x0, img0 = training_arrays(discs, model)
    k = len(discs.train)
    assert x.shape == (8 * (k + 3), model.n_rows) and img.shape == (8 * (k + 3), 16, 16)
    np.testing.assert_array_equal(x[:8 * k], x0)  # the disc rows do not change when presses are added
    np.testing.assert_array_equal(img[:8 * k], img0)
    p = mixed.presses
    syms = square_symmetries(model.design, model.protocol, 16)
    xp, ip = x[8 * k:].reshape(3, 8, -1), img[8 * k:].reshape(3, 8, 16, 16)
    np.testing.assert_allclose(xp[:, 0], p.y, rtol=1e-6, atol=1e-12)  # identity kept clean
    for g, sym in enumerate(syms):
        np.testing.assert_array_equal(ip[:, g], sym.images(p.images))
        # the target of the moved frame is the footprint of the moved press
        moved = np.column_stack([sym.points(p.presses[:, :2], 100.0), p.presses[:, 2:]])
        s0 = model.sigma0_S_per_m
        foot = [(render_touches(np.array([[x_, y_, 2 * r, 0.5]]), s0, 16, model.extent_mm) - s0) / s0
                for x_, y_, r, _ in moved]
        np.testing.assert_allclose(ip[:, g], foot, atol=1e-6)
        if g:  # the moved frame with noise of the paper's SNR on its absolute voltages
            V = model.v_ref * (1 + sym.relative(p.y))
            noise = (xp[:, g] - sym.relative(p.y)) * model.v_ref
            assert 10 * np.log10(np.mean(V ** 2) / np.mean(noise ** 2)) == pytest.approx(30 + 5 * g, abs=1.0)


def test_dataset_file_keeps_the_presses_and_older_files_still_load(model, discs, mixed, tmp_path):
    back = ReconDataset.load(mixed.save(tmp_path / "mixed.npz"))
    for name in ("presses", "y", "images"):
        np.testing.assert_array_equal(getattr(back.presses, name), getattr(mixed.presses, name))
    assert back.presses.seed == 2
    np.testing.assert_array_equal(back.test, mixed.test)
    assert ReconDataset.load(discs.save(tmp_path / "discs.npz")).presses is None
    # a version-1 file (before press samples existed) loads, without presses
    old = save_npz(tmp_path / "v1.npz", DATASET_FORMAT, 1, {"config": {"per_count": 10, "touch_counts": [1, 2],
                                                                    "seed": 4}, "model_fingerprint": model.fingerprint},
                   {"voltages": discs.voltages, "images": discs.images, "touches": discs.touches,
                    "n_touches": discs.n_touches, "train": discs.train, "val": discs.val, "test": discs.test})
    v1 = ReconDataset.load(old)
    assert v1.presses is None and v1.config == discs.config
    np.testing.assert_array_equal(v1.voltages, discs.voltages)


def test_a_rerun_reads_the_stored_presses(model, mixed, tmp_path, monkeypatch):
    back = ReconDataset.load(mixed.save(tmp_path / "mixed.npz"))
    _no_solves(monkeypatch)
    assert with_presses(back, model, 3, seed=2) is back
    assert with_presses(back, model, 0).presses is None  # discs only, without touching the file's presses
    with pytest.raises(AssertionError, match="simulated again"):
        with_presses(back, model, 3, seed=5)  # other presses are simulated
    with pytest.raises(AssertionError, match="simulated again"):
        with_presses(back, model, 4, seed=2)


def test_with_presses_refuses_bad_counts(model, discs):
    from latticeopt.errors import ParameterError

    for n in (-1, 10_001, 1.5):
        with pytest.raises(ParameterError, match="presses"):
            with_presses(discs, model, n)
    with pytest.raises(ParameterError, match="press_seed"):
        with_presses(discs, model, 1, seed=-1)


def test_recon_train_mixes_in_presses_once_and_recon_eval_refuses_their_seed(model, tmp_path, capsys, monkeypatch):
    pytest.importorskip("torch")
    path = save_sensor_model(model, tmp_path / "s.npz")
    ds, net = tmp_path / "ds.npz", tmp_path / "net.npz"
    base = ["recon-train", "--model", str(path), "--per-count", "10", "--touch-counts", "1", "--dataset", str(ds),
            "--epochs", "1", "--threads", "1", "-o", str(net)]
    assert main(base + ["--presses", "2", "--press-seed", "3", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["train_presses"] == {"n": 2, "solved": 2, "seed": 3}
    assert out["n_train_augmented"] == 8 * (7 + 2)
    stored = ReconDataset.load(ds).presses
    np.testing.assert_array_equal(stored.presses, random_presses(2, 100.0, seed=3))
    _no_solves(monkeypatch)
    assert main(base + ["--presses", "2", "--press-seed", "3"]) == 0
    captured = capsys.readouterr()
    assert "+ 2 coupled presses -> 72 augmented" in captured.out
    assert "preparing 7 training samples + 2 presses x 8" in captured.err
    assert main(base + ["--json"]) == 0  # --presses 0: discs only
    assert json.loads(capsys.readouterr().out)["train_presses"] is None
    assert ReconDataset.load(ds).presses is not None
    # the network trained on seed 3 is not scored on presses of seed 3
    assert main(base + ["--presses", "2", "--press-seed", "3", "--json"]) == 0
    capsys.readouterr()
    assert main(["recon-eval", "--model", str(path), "--dataset", str(ds), "--net", str(net), "--presses", "1",
                 "--press-seed", "3"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--press-seed" in err[0]
