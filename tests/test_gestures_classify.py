"""Both classifiers learn simulated gestures well above chance; the classify-train / classify commands."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("torch")

from latticeopt.cli import main  # noqa: E402
from latticeopt.design import LatticeDesign  # noqa: E402
from latticeopt.gestures import generate_gestures  # noqa: E402
from latticeopt.gestures.experiment import PAPER_ACCURACY, classify_sequences, train_gesture_models  # noqa: E402
from latticeopt.gestures.trajectories import GESTURES  # noqa: E402
from latticeopt.mesh import MeshSettings  # noqa: E402
from latticeopt.sensor_model import SensorSimulator, export_sensor_model, load_sensor_model  # noqa: E402

PER_CLASS, TEST_PER_CLASS = 3, 1
#: A tiny learnable subset: a stationary contact, a large one, and two swipes that differ only by direction.
SUBSET = ("no contact", "fist press", "finger swipe left", "finger swipe right")


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    """A coarse sensor model, the data `classify-train --per-class 3 --test-per-class 1` uses (cached), and
    both models trained on a tiny subset of the classes."""
    import torch

    torch.set_num_threads(1)
    tmp = tmp_path_factory.mktemp("classify")
    sensor = export_sensor_model(LatticeDesign(width_mm=4, thickness_mm=3), tmp / "sensor.npz",
                                 MeshSettings(size_mm=5), cache_dir=tmp / "meshes")
    model = load_sensor_model(sensor)
    sim = SensorSimulator(model)
    cache = tmp / "cache"
    data = generate_gestures(model, PER_CLASS, seed=0, cache_dir=cache, simulator=sim)
    test = generate_gestures(model, TEST_PER_CLASS, seed=0, pool="test", cache_dir=cache, simulator=sim)
    out = tmp / "out"
    summary = train_gesture_models(data, test, out, epochs=2)
    classes = [GESTURES.index(n) for n in SUBSET]
    sub = generate_gestures(model, 16, seed=0, simulator=sim, classes=classes)
    sub_test = generate_gestures(model, 5, seed=0, pool="test", simulator=sim, classes=classes)
    sub_summary = train_gesture_models(sub, sub_test, tmp / "subset", epochs=40, batch_size=16, learning_rate=1e-3)
    return dict(tmp=tmp, sensor=sensor, model=model, sim=sim, cache=cache, data=data, test=test, out=out,
                summary=summary, sub_summary=sub_summary)


def test_outputs_of_a_training_run(setup):
    s = setup["summary"]
    assert s["n_train"] == 2 * 12 and s["n_val"] == 1 * 12 and s["n_test"] == TEST_PER_CLASS * 12
    for key in ("cnn", "lstm"):
        e = s["models"][key]
        assert 1 <= e["best_epoch"] <= 2
        for f in (e["model_file"], e["confusion_png"]):
            assert (setup["out"] / f).stat().st_size > 0
    report = (setup["out"] / "report.md").read_text()
    assert "SIMULATED" in report and "98.5 %" in report and "99.6 %" in report
    assert all(name in report for name in GESTURES)
    assert json.loads((setup["out"] / "summary.json").read_text())["simulation"] is True


def test_both_models_learn_a_tiny_subset_well_above_chance(setup):
    s = setup["sub_summary"]
    assert s["n_test"] == 20
    for key in ("cnn", "lstm"):
        acc = s["models"][key]["test_accuracy"]
        assert acc >= 0.5, (key, acc)  # chance is 0.25


@pytest.mark.slow
def test_both_models_learn_all_twelve_gestures_well_above_chance(setup, tmp_path):
    model, sim = setup["model"], setup["sim"]
    data = generate_gestures(model, 40, seed=1, simulator=sim)
    test = generate_gestures(model, 10, seed=1, pool="test", simulator=sim)
    s = train_gesture_models(data, test, tmp_path, epochs=40, batch_size=32, learning_rate=1e-3)
    for key in ("cnn", "lstm"):
        acc = s["models"][key]["test_accuracy"]
        assert acc > 3 / 12, (key, acc)  # chance is 1/12


def test_classify_sequences_reproduces_the_reported_test_accuracy(setup):
    test = setup["test"]
    for key in ("cnn", "lstm"):
        labels, prob, meta = classify_sequences(setup["out"] / f"gesture_{key}.npz", test.frames)
        assert prob.shape == (len(test), 12) and np.allclose(prob.sum(axis=1), 1)
        assert np.mean(labels == test.labels) == pytest.approx(setup["summary"]["models"][key]["test_accuracy"])
        assert meta["classes"] == list(GESTURES) and "relative change" in meta["frame"]


def test_classify_cli_prints_one_class_per_sequence(setup, tmp_path, capsys):
    frames = setup["test"].frames[:5]
    np.save(tmp_path / "f.npy", frames)
    assert main(["classify", "--model", str(setup["out"] / "gesture_lstm.npz"), "--frames",
                 str(tmp_path / "f.npy")]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    expected, _, _ = classify_sequences(setup["out"] / "gesture_lstm.npz", frames)
    assert [ln.split("\t")[1] for ln in lines] == [GESTURES[k] for k in expected]
    # raw voltages with a no-touch reference give the same predictions
    ref = np.abs(setup["model"].v_ref[setup["model"].independent])
    np.save(tmp_path / "raw.npy", ref * (1 + frames.astype(float)))
    np.save(tmp_path / "ref.npy", np.tile(ref, (3, 1)))
    assert main(["classify", "--model", str(setup["out"] / "gesture_lstm.npz"), "--frames",
                 str(tmp_path / "raw.npy"), "--reference", str(tmp_path / "ref.npy"), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert [p["class"] for p in out["predictions"]] == [GESTURES[k] for k in expected]


@pytest.mark.parametrize("shape", [(5, 14, 104), (5, 15, 208), (15, 104), (2, 3, 15, 104)])
def test_classify_cli_rejects_other_shapes(setup, tmp_path, capsys, shape):
    np.save(tmp_path / "f.npy", np.zeros(shape, np.float32))
    code = main(["classify", "--model", str(setup["out"] / "gesture_cnn.npz"), "--frames", str(tmp_path / "f.npy")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1
    assert "--frames" in err and "(n, 15, 104)" in err and str(shape) in err and "Traceback" not in err


def test_classify_cli_rejects_bad_files(setup, tmp_path, capsys):
    np.save(tmp_path / "f.npy", setup["test"].frames[:2])
    cases = [["--model", str(tmp_path / "missing.npz"), "--frames", str(tmp_path / "f.npy")],
             ["--model", str(setup["sensor"]), "--frames", str(tmp_path / "f.npy")],  # not a classifier file
             ["--model", str(setup["out"] / "gesture_cnn.npz"), "--frames", str(tmp_path / "nope.npy")],
             ["--model", str(setup["out"] / "gesture_cnn.npz"), "--frames", str(tmp_path / "f.npy"),
              "--reference", str(tmp_path / "f.npy")]]
    for args in cases:
        assert main(["classify", *args]) == 2, args
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "Traceback" not in err


def test_classify_train_cli_writes_models_and_reports(setup, tmp_path, capsys):
    out = tmp_path / "run"
    code = main(["classify-train", "--model", str(setup["sensor"]), "--per-class", str(PER_CLASS),
                 "--test-per-class", str(TEST_PER_CLASS), "--epochs", "1", "--out", str(out),
                 "--cache-dir", str(setup["cache"]), "--no-progress"])
    text = capsys.readouterr().out
    assert code == 0
    assert "SIMULATED" in text and f"{100 * PAPER_ACCURACY['cnn']:.1f} %" in text and "99.6 %" in text
    for f in ("gesture_cnn.npz", "gesture_lstm.npz", "confusion_cnn.png", "confusion_lstm.png", "report.md",
              "summary.json"):
        assert (out / f).is_file(), f
    s = json.loads((out / "summary.json").read_text())
    assert s["train_config"]["batch_size"] == 256 and s["train_config"]["learning_rate"] == 1e-4
    assert s["data"]["key"] == setup["data"].info["key"]  # the cached data were reused


@pytest.mark.parametrize("args, flag", [(["--per-class", "0"], "--per-class"), (["--epochs", "0"], "--epochs"),
                                        (["--snr", "60", "40"], "--snr")])
def test_classify_train_cli_rejects_bad_values(setup, capsys, args, flag):
    code = main(["classify-train", "--model", str(setup["sensor"]), *args, "--no-cache", "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and flag in err and err.count("\n") == 1


def test_classify_train_cli_rejects_a_bad_sensor_model(tmp_path, capsys):
    (tmp_path / "bad.npz").write_bytes(b"garbage")
    assert main(["classify-train", "--model", str(tmp_path / "bad.npz"), "--no-progress"]) == 2
    assert "--model" in capsys.readouterr().err


def _reject_constant(name):
    raise ValueError(f"not JSON: {name}")


def test_classify_train_cli_caches_in_the_user_cache_folder_only(setup, tmp_path, monkeypatch, capsys):
    work, cache_home = tmp_path / "work", tmp_path / "xdg"
    work.mkdir()
    monkeypatch.chdir(work)
    monkeypatch.setenv("XDG_CACHE_HOME", str(cache_home))
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    code = main(["classify-train", "--model", str(setup["sensor"]), "--per-class", str(PER_CLASS),
                 "--test-per-class", str(TEST_PER_CLASS), "--epochs", "1", "--out", str(tmp_path / "run"),
                 "--no-progress"])
    capsys.readouterr()
    assert code == 0
    assert list(work.iterdir()) == []  # no ./gesture_cache, no temporary files
    cached = sorted(p.name for p in (cache_home / "latticeopt" / "gestures").iterdir())
    assert len(cached) == 2 and all(n.startswith("gestures-") and n.endswith(".npz") for n in cached)
    # summary.json is strict JSON (null, never NaN)
    json.loads((tmp_path / "run" / "summary.json").read_text(), parse_constant=_reject_constant)


def test_classify_train_help_states_the_cache_folder(monkeypatch, tmp_path, capsys):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    with pytest.raises(SystemExit):
        main(["classify-train", "--help"])
    text = "".join(capsys.readouterr().out.split())  # argparse wraps lines at spaces, never inside a path
    assert str(tmp_path / "xdg" / "latticeopt" / "gestures") in text


def test_training_summary_writes_null_for_undefined_metrics(tmp_path):
    from latticeopt._jsonout import dumps

    text = dumps({"val_accuracy": float("nan"), "history": [1.0, float("inf")], "n": np.int64(2)}, indent=1)
    assert json.loads(text, parse_constant=_reject_constant) == {"val_accuracy": None, "history": [1.0, None],
                                                                  "n": 2}
