"""``latticeopt classify-train`` and ``latticeopt classify``: the paper's gesture classification (§VII)."""

from __future__ import annotations

import time
from pathlib import Path

DEFAULT_EPOCHS = 100


def register(sub) -> None:
    p = sub.add_parser(
        "classify-train", help="simulate the 12 touch gestures with a sensor model and train the CNN and LSTM",
        description="Simulate gesture sequences (15 frames x 104 measurements) with an exported sensor model, "
                    "train the paper's CNN and LSTM (Adam 1e-4, cross-entropy, batch 256, best validation "
                    "epoch; 8:2 split per class) and test them on a separately generated set. Writes into --out "
                    "(default gestures_out under the working directory): gesture_cnn.npz and gesture_lstm.npz "
                    "(the models), confusion_cnn.png, confusion_lstm.png, report.md and summary.json; the "
                    "simulated sequences are cached in --cache-dir. Accuracies are on SIMULATED data.")
    p.add_argument("--model", required=True, metavar="SENSOR.npz", help="sensor model from `latticeopt export`")
    p.add_argument("--per-class", type=int, default=1000,
                   help="training + validation sequences per class (paper: 1000)")
    p.add_argument("--test-per-class", type=int, default=None,
                   help="test sequences per class, generated separately (default: per-class / 10; paper: 100)")
    p.add_argument("--epochs", type=int, default=DEFAULT_EPOCHS,
                   help=f"maximum epochs per model (paper: 200; default {DEFAULT_EPOCHS}, see docs/gestures.md)")
    p.add_argument("--patience", type=int, default=None,
                   help="stop a model after this many epochs without validation improvement (default: never)")
    p.add_argument("--out", default="gestures_out", metavar="DIR", help="output folder (default gestures_out)")
    p.add_argument("--seed", type=int, default=0, help="seed of data, split and weights (default 0)")
    p.add_argument("--snr", type=float, nargs=2, default=None, metavar=("LO", "HI"),
                   help="measurement SNR range in dB (default 40 60)")
    p.add_argument("--jobs", "-j", type=int, default=1, help="simulation worker processes (default 1)")
    p.add_argument("--threads", type=int, default=1, help="torch threads while training (default 1)")
    p.add_argument("--cache-dir", type=Path, default=None,
                   help="folder of cached simulated datasets, keyed by content hash (default "
                        f"{_default_cache_dir()}: the user cache folder, never the working directory)")
    p.add_argument("--no-cache", action="store_true", help="neither read nor write the dataset cache")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.set_defaults(func=run_classify_train)

    c = sub.add_parser(
        "classify", help="classify recorded gesture sequences with a trained CNN or LSTM",
        description="Print the predicted gesture of every sequence in a .npy array of shape (n, 15, 104): "
                    "relative changes (V - V_ref) / V_ref of the 104 independent adjacent-protocol measurements "
                    "(pyEIT 'std' order), or raw voltages together with --reference.")
    c.add_argument("--model", required=True, metavar="MODEL.npz",
                   help="classifier file from classify-train (gesture_cnn.npz or gesture_lstm.npz)")
    c.add_argument("--frames", required=True, metavar="F.npy", help="sequences, shape (n, 15, 104)")
    c.add_argument("--reference", default=None, metavar="R.npy",
                   help="no-touch voltages (104,) or (k, 104): --frames are then raw voltages in the same unit")
    c.add_argument("--json", action="store_true", help="print one JSON object instead of lines")
    c.set_defaults(func=run_classify)


def _default_cache_dir() -> Path:
    from ..gestures.simulate import default_cache_dir

    return default_cache_dir()


def _load_npy(path: str, flag: str):
    import numpy as np

    from ..errors import ParameterError
    from ._common import check_input_file

    p = check_input_file(flag, path, (".npy",))
    try:
        a = np.load(p, allow_pickle=False)
    except (OSError, ValueError, EOFError) as exc:
        raise ParameterError(flag, "a numeric .npy array (no pickles)", f"{path}: {exc}") from None
    if np.iscomplexobj(a):  # the models take real relative changes; casting would drop the imaginary part
        raise ParameterError(flag, "real values (for complex recordings save np.abs(...), the magnitude)",
                             f"{path}: dtype {a.dtype}")
    return a


def _sensor_model(path: str):
    from ..errors import ParameterError
    from ..sensor_model import SensorModelError, load_sensor_model
    from ._common import check_input_file

    check_input_file("--model", path, (".npz",), "an existing sensor-model file (latticeopt export)")
    try:
        return load_sensor_model(path)
    except SensorModelError as exc:
        raise ParameterError("--model", "a sensor-model file written by `latticeopt export`", str(exc)) from None


def run_classify_train(args) -> int:
    from .. import _validate as v
    from .._extras import require_extra
    from ..errors import ParameterError
    from ..gestures import MeasurementConfig, generate_gestures
    from ..gestures.experiment import accuracy_table, train_gesture_models
    from ._common import check_output_path

    t0 = time.perf_counter()
    per_class = v.integer("--per-class", args.per_class, lo=3,
                          expected="an integer >= 3 (the 8:2 split must leave one per class for validation)")
    test_per = max(1, per_class // 10) if args.test_per_class is None else v.integer(
        "--test-per-class", args.test_per_class, lo=1)
    epochs = v.integer("--epochs", args.epochs, lo=1)
    if args.patience is not None:
        v.integer("--patience", args.patience, lo=1)
    seed = v.integer("--seed", args.seed, lo=0)
    jobs = v.integer("--jobs", args.jobs, lo=1)
    threads = v.integer("--threads", args.threads, lo=1)
    if args.snr is None:
        measurement = MeasurementConfig()
    else:
        # below -40 dB the noise is 100 times the signal; above 200 dB it is below double-precision rounding
        lo, hi = (v.real("--snr", x, lo=-40, hi=200) for x in args.snr)
        if hi < lo:
            raise ParameterError("--snr", "LO HI in dB with -40 <= LO <= HI <= 200", f"{lo:g} {hi:g}")
        measurement = MeasurementConfig(snr_db=(lo, hi))
    check_output_path("--out", args.out, kind="dir")
    if not args.no_cache:
        check_output_path("--cache-dir", args.cache_dir, kind="dir")
    require_extra("learn", "classify-train trains the classifiers with it", modules=("torch",))
    model = _sensor_model(args.model)
    cache = None if args.no_cache else (args.cache_dir or _default_cache_dir())
    progress = not args.no_progress
    data = generate_gestures(model, per_class, seed=seed, pool="trainval", measurement=measurement, jobs=jobs,
                             progress=progress, cache_dir=cache)
    test = generate_gestures(model, test_per, seed=seed, pool="test", measurement=measurement, jobs=jobs,
                             progress=progress, cache_dir=cache)
    t_data = time.perf_counter() - t0
    summary = train_gesture_models(data, test, args.out, epochs=epochs, seed=seed, num_threads=threads,
                                   patience=args.patience, progress=progress,
                                   description={"sensor_model": str(args.model), "fingerprint": model.fingerprint})
    print("Gesture classification on SIMULATED sequences (the paper's figures are on real recordings):")
    print(accuracy_table(summary))
    for key, e in summary["models"].items():
        print(f"{key.upper()}: best epoch {e['best_epoch']}/{e['epochs_run']}, validation accuracy "
              f"{100 * e['val_accuracy']:.1f} %, {e['train_seconds']:.0f} s training")
    print(f"data: {summary['n_train']} train / {summary['n_val']} validation / {summary['n_test']} test sequences "
          f"in {t_data:.0f} s ({data.info['forward_solves'] + test.info['forward_solves']} forward solves "
          "this run or when first cached)")
    print(f"wrote {Path(args.out) / 'report.md'} (per-class precision/recall), confusion_*.png, gesture_*.npz, "
          f"summary.json; total {time.perf_counter() - t0:.0f} s")
    return 0


def run_classify(args) -> int:
    import sys

    import numpy as np

    from .._extras import require_extra
    from ..gestures.experiment import check_sequences, classify_sequences, relative_to_reference
    from ..gestures.trajectories import GESTURES

    require_extra("learn", "classify runs the classifier with it", modules=("torch",))
    frames = check_sequences(_load_npy(args.frames, "--frames"), source=args.frames, name="--frames")
    if args.reference is not None:
        frames = relative_to_reference(frames, _load_npy(args.reference, "--reference"), name="--reference")
    elif np.median(np.abs(frames)) > 0.5:
        print("latticeopt classify: warning: the frames look like raw voltages (median |value| > 0.5); the "
              "models expect relative changes: pass --reference", file=sys.stderr)
    from ._common import check_input_file

    model_path = check_input_file("--model", args.model, (".npz",),
                                  "an existing classifier file (gesture_cnn.npz or gesture_lstm.npz)")
    labels, prob, _ = classify_sequences(model_path, frames)
    if args.json:
        from ._common import emit_json

        emit_json({"predictions": [{"sequence": i, "label": int(k), "class": GESTURES[k],
                                    "probability": float(prob[i, k])} for i, k in enumerate(labels)]})
    else:
        for i, k in enumerate(labels):
            print(f"{i}\t{GESTURES[k]}\t{prob[i, k]:.3f}")
    return 0
