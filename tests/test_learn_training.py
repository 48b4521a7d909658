"""The training loop, best-epoch selection and pickle-free model files, on tiny learnable synthetic tasks."""

from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from latticeopt.errors import ParameterError  # noqa: E402
from latticeopt.learn import persist  # noqa: E402
from latticeopt.learn.classifiers import GestureCNN, GestureLSTM  # noqa: E402
from latticeopt.learn.layers import channel_statistics  # noqa: E402
from latticeopt.learn.metrics import classification_report, evaluate_images  # noqa: E402
from latticeopt.learn.persist import load_model, save_model  # noqa: E402
from latticeopt.learn.recon_net import ReconNet  # noqa: E402
from latticeopt.learn.training import TrainConfig, predict, seed_everything, train_model  # noqa: E402

torch.set_num_threads(1)
QUIET = dict(progress=False, num_threads=1)


def gesture_like(n_per_class: int, seed: int, n_classes: int = 12):
    """Sequences (n, 15, 104): a noisy Gaussian bump along the channels whose start (4 values) and speed
    (-2, 0, +2 channels per frame) depend on the class; position jitter, amplitude and noise are random."""
    rng = np.random.default_rng(seed)
    ch = np.arange(104)
    x, y = [], []
    for c in range(n_classes):
        start, speed = (20, 40, 60, 80)[c % 4], (-2.0, 0.0, 2.0)[c // 4]
        for _ in range(n_per_class):
            centre = start + rng.uniform(-3, 3) + speed * np.arange(15)[:, None]
            bump = rng.uniform(0.7, 1.3) * np.exp(-0.5 * ((ch - centre) / 4.0) ** 2)
            x.append(bump + rng.standard_normal((15, 104)))
            y.append(c)
    return np.asarray(x, np.float32), np.asarray(y)


def blob_frames(n: int, seed: int, side: int = 24, n_meas: int = 104):
    """Disc images (n, side, side) on a zero background and measurements through a fixed random linear map."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:side, 0:side] + 0.5
    c = rng.uniform(4, side - 4, (n, 2))
    r = rng.uniform(3, 6, n)
    amp = rng.uniform(0.5, 1.5, n)
    img = amp[:, None, None] * ((xx - c[:, 0, None, None]) ** 2 + (yy - c[:, 1, None, None]) ** 2
                                < r[:, None, None] ** 2)
    forward = np.random.default_rng(12345).standard_normal((n_meas, side * side)) / side
    frames = img.reshape(n, -1) @ forward.T + 0.01 * rng.standard_normal((n, n_meas))
    return frames.astype(np.float32), img.astype(np.float32)


@pytest.mark.parametrize("cls, epochs", [(GestureCNN, 4), (GestureLSTM, 6)])
def test_classifiers_learn_synthetic_gestures_well_above_chance(cls, epochs):
    x_tr, y_tr = gesture_like(40, seed=1)
    x_va, y_va = gesture_like(8, seed=2)
    x_te, y_te = gesture_like(10, seed=3)
    mean, std = channel_statistics(x_tr)
    seed_everything(0)
    model = cls(input_mean=mean, input_std=std)
    result = train_model(model, (x_tr, y_tr), (x_va, y_va),
                         TrainConfig(epochs=epochs, batch_size=32, learning_rate=1e-3, **QUIET))
    report = classification_report(predict(model, x_te).argmax(axis=1), y_te, [str(k) for k in range(12)])
    assert report["accuracy"] > 0.8  # chance is 1/12
    assert result.val_accuracy is not None and len(result.val_accuracy) == epochs
    assert result.best_epoch == int(np.argmin(result.val_loss)) + 1


def test_recon_net_learns_blobs_and_beats_the_background_prediction():
    v_tr, i_tr = blob_frames(600, seed=1)
    v_va, i_va = blob_frames(100, seed=2)
    v_te, i_te = blob_frames(100, seed=3)
    mean, std = channel_statistics(v_tr)
    seed_everything(0)
    # A small net of the same structure: 4 x 4 latent, three doubling stages to 32 x 32, resized to 24 x 24.
    model = ReconNet(104, image_size=24, hidden=(128,), latent_channels=16, latent_size=4,
                     decoder_channels=(16, 8, 8), input_mean=mean, input_std=std)
    result = train_model(model, (v_tr, i_tr), (v_va, i_va),
                         TrainConfig(loss="mse", epochs=6, batch_size=32, learning_rate=3e-3, **QUIET))
    assert result.val_accuracy is None
    pred = predict(model, v_te)
    assert pred.shape == i_te.shape
    mse = np.mean((pred - i_te) ** 2)
    assert mse < 0.4 * np.mean(i_te ** 2)  # the all-background (zero) image
    assert mse < 0.4 * np.mean((i_tr.mean(axis=0) - i_te) ** 2)  # the mean training image
    assert evaluate_images(pred, i_te)["mean"]["cc"] > 0.75


def _overfitting_regression():
    rng = np.random.default_rng(0)
    w = rng.standard_normal(8)

    def data(n):
        x = rng.standard_normal((n, 8)).astype(np.float32)
        return x, (x @ w + rng.standard_normal(n)).astype(np.float32)[:, None]

    return data(24), data(200)


def _mlp():
    return torch.nn.Sequential(torch.nn.Linear(8, 128), torch.nn.ReLU(), torch.nn.Linear(128, 1))


def test_best_epoch_is_the_validation_minimum_and_its_weights_are_kept():
    train, val = _overfitting_regression()
    seed_everything(0)
    model = _mlp()
    cfg = TrainConfig(loss="mse", epochs=30, batch_size=8, learning_rate=1e-2, **QUIET)
    result = train_model(model, train, val, cfg)
    assert result.epochs_run == 30 and not result.stopped_early
    assert result.best_epoch == int(np.argmin(result.val_loss)) + 1
    assert result.best_epoch < 30  # the task overfits, so restoring weights is exercised
    pred = predict(model, val[0])
    assert np.mean((pred - val[1]) ** 2) == pytest.approx(result.best_val_loss, rel=1e-5)
    assert len(result.epoch_seconds) == 30 and result.seconds >= sum(result.epoch_seconds)
    json.dumps(result.to_dict())  # serializable for model metadata


def test_patience_stops_after_no_improvement():
    train, val = _overfitting_regression()
    seed_everything(0)
    result = train_model(_mlp(), train, val,
                         TrainConfig(loss="mse", epochs=200, batch_size=8, learning_rate=1e-2, patience=5, **QUIET))
    assert result.stopped_early
    assert result.epochs_run == result.best_epoch + 5
    assert result.best_epoch == int(np.argmin(result.val_loss)) + 1


def test_training_is_deterministic_for_a_seed_and_leaves_global_rng_alone():
    train, val = _overfitting_regression()
    runs = []
    for _ in range(2):
        seed_everything(3)
        model = torch.nn.Sequential(torch.nn.Linear(8, 32), torch.nn.ReLU(), torch.nn.Dropout(0.3),
                                    torch.nn.Linear(32, 1))
        torch.manual_seed(99)
        before = torch.rand(1)
        torch.manual_seed(99)
        result = train_model(model, train, val, TrainConfig(loss="mse", epochs=4, batch_size=8, seed=5, **QUIET))
        assert torch.equal(torch.rand(1), before)  # training forked the global generator
        runs.append((result.train_loss, result.val_loss, [p.detach().clone() for p in model.parameters()]))
    assert runs[0][0] == runs[1][0] and runs[0][1] == runs[1][1]
    assert all(torch.equal(a, b) for a, b in zip(runs[0][2], runs[1][2]))


def test_config_and_input_validation():
    for bad in (dict(loss="l1"), dict(epochs=0), dict(batch_size=-1), dict(learning_rate=0.0),
                dict(patience=0), dict(num_threads=0), dict(device="tpu"), dict(progress="yes")):
        with pytest.raises(ParameterError, match=next(iter(bad))):
            TrainConfig(**bad)
    assert TrainConfig().learning_rate == 1e-4 and TrainConfig().batch_size == 256
    x, y = gesture_like(2, seed=0)
    model = GestureLSTM()
    cfg = TrainConfig(epochs=1, **QUIET)
    with pytest.raises(ParameterError, match="targets"):
        train_model(model, (x, y + 12), (x, y), cfg)  # label 12+ with 12 classes
    with pytest.raises(ParameterError, match="train_arrays"):
        train_model(model, (x, y[:-1]), (x, y), cfg)
    with pytest.raises(ParameterError, match="train_arrays"):
        train_model(model, (x, y.astype(float)), (x, y), cfg)
    with pytest.raises(ParameterError, match="val_arrays"):
        train_model(model, (x, y), (x[:, :, :50], y), cfg)
    with pytest.raises(ParameterError, match="targets"):
        train_model(ReconNet(104, image_size=24, hidden=(8,), latent_channels=2, latent_size=4,
                             decoder_channels=(2, 2, 2)),
                    (x[:, 0], np.zeros((len(x), 48, 48), np.float32)),
                    (x[:, 0], np.zeros((len(x), 48, 48), np.float32)), TrainConfig(loss="mse", **QUIET))


def _models():
    rng = np.random.default_rng(7)
    torch.manual_seed(7)
    recon = ReconNet(208, input_mean=rng.normal(size=208), input_std=rng.uniform(0.5, 2, 208))
    recon.train()(torch.randn(8, 208))  # move the batch-norm running statistics off their defaults
    cnn = GestureCNN(input_mean=rng.normal(size=104), input_std=rng.uniform(0.5, 2, 104))
    lstm = GestureLSTM(input_mean=rng.normal(size=104), input_std=rng.uniform(0.5, 2, 104))
    return [(recon.eval(), torch.randn(4, 208)), (cnn.eval(), torch.randn(4, 15, 104)),
            (lstm.eval(), torch.randn(4, 15, 104))]


def test_save_load_round_trip_gives_identical_outputs(tmp_path):
    for model, x in _models():
        meta = {"class_names": ["a", "b"], "train_config": TrainConfig(**QUIET).to_dict()}
        path = save_model(tmp_path / f"{type(model).__name__}.npz", model, metadata=meta)
        loaded, got = load_model(path)
        assert type(loaded) is type(model) and not loaded.training
        assert torch.equal(loaded(x), model(x))
        assert got["class_names"] == ["a", "b"] and got["train_config"]["learning_rate"] == 1e-4
        assert got["_file"]["format_version"] == persist.FORMAT_VERSION
        with np.load(path, allow_pickle=False) as npz:  # readable by numpy alone, no pickle
            assert npz["state/standardize.mean"].shape in ((208,), (104,))


def test_bad_model_files_give_clear_errors(tmp_path):
    model, _ = _models()[2]
    good = save_model(tmp_path / "m.npz", model)
    data = good.read_bytes()
    truncated = tmp_path / "truncated.npz"
    truncated.write_bytes(data[: len(data) // 2])
    with pytest.raises(ParameterError, match="unreadable"):
        load_model(truncated)

    with np.load(good, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    meta = json.loads(arrays["__meta__"].tobytes())

    def write(name, meta_change=None, **extra):
        m = dict(meta, **(meta_change or {}))
        out = dict(arrays, __meta__=np.frombuffer(json.dumps(m).encode(), np.uint8), **extra)
        np.savez(tmp_path / name, **out)
        return tmp_path / name

    with pytest.raises(ParameterError, match="newer"):
        load_model(write("newer.npz", {"format_version": persist.FORMAT_VERSION + 1}))
    with pytest.raises(ParameterError, match="unknown model_class"):
        load_model(write("cls.npz", {"model_class": "os.system"}))
    with pytest.raises(ParameterError, match="do not fit"):
        load_model(write("arch.npz", {"model_config": dict(meta["model_config"], hidden_size=32)}))
    # An object array would need unpickling: refused, never executed.
    with pytest.raises(ParameterError, match="unreadable"):
        load_model(write("pickle.npz", **{"state/evil": np.array([{"a": 1}], dtype=object)}))
    with pytest.raises(ParameterError, match="existing"):
        load_model(tmp_path / "missing.npz")
    assert zipfile.is_zipfile(good)
