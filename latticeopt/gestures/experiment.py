"""The paper's classification experiment (§VII) on simulated gestures, and classification of recordings.

:func:`train_gesture_models` trains the CNN and the LSTM of :mod:`latticeopt.learn.classifiers` on a
:class:`~latticeopt.gestures.simulate.GestureDataset` split 8:2 per class (training / validation, the best
validation epoch kept) and evaluates both on a separately generated test set, writing model files,
confusion-matrix PNGs and per-class precision/recall tables. :func:`classify_sequences` applies a saved model
to sequences of shape ``(n, 15, 104)``.

Torch is imported inside the functions, so importing this module does not need it.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from .. import _validate as v
from .._jsonout import dumps
from ..errors import ParameterError
from .trajectories import GESTURES, N_FRAMES

log = logging.getLogger(__name__)

#: The paper's accuracies on its real test recordings (1200 sequences).
PAPER_ACCURACY = {"cnn": 0.985, "lstm": 0.996}
MODEL_NAMES = {"cnn": "GestureCNN", "lstm": "GestureLSTM"}
N_MEAS = 104
#: Frame convention written into model files and checked nowhere else: keep recordings in this form.
FRAME_CONVENTION = ("relative change (V - V_ref) / V_ref of the 104 reciprocity-independent adjacent-protocol "
                    "measurements, V_ref a no-touch reference of the same sensor")


def check_sequences(frames, source: str = "frames", n_frames: int = N_FRAMES, n_meas: int = N_MEAS,
                    name: str = "frames") -> np.ndarray:
    """Return ``frames`` as float32 ``(n, n_frames, n_meas)`` or raise a one-line :class:`ParameterError`
    naming ``name`` (the parameter or CLI flag) and ``source`` (where the array came from)."""
    a = np.asarray(frames)
    if a.ndim != 3 or a.shape[0] < 1 or a.shape[1:] != (n_frames, n_meas):
        raise ParameterError(name, f"an array of shape (n, {n_frames}, {n_meas}) (n sequences of {n_frames} "
                             f"frames x {n_meas} measurements)", f"{source}: shape {a.shape}")
    if not np.issubdtype(a.dtype, np.number) or not np.all(np.isfinite(a)):
        raise ParameterError(name, "finite numbers", f"{source}: dtype {a.dtype} or NaN/infinite values")
    return a.astype(np.float32)


def relative_to_reference(frames: np.ndarray, reference, name: str = "reference") -> np.ndarray:
    """Raw voltages ``(n, T, 104)`` to relative changes against a no-touch reference ``(104,)`` or ``(k, 104)``
    (averaged over ``k``)."""
    ref = np.asarray(reference, dtype=float)
    if ref.ndim == 2:
        ref = ref.mean(axis=0)
    if ref.shape != (frames.shape[-1],) or not np.all(np.isfinite(ref)) or np.any(ref == 0):
        raise ParameterError(name, f"non-zero finite no-touch voltages of shape ({frames.shape[-1]},) or "
                             f"(k, {frames.shape[-1]})", f"shape {np.shape(reference)}")
    return ((frames - ref) / ref).astype(np.float32)


def _table(report: dict) -> str:
    lines = ["| class | precision | recall | F1 | support |", "|---|---:|---:|---:|---:|"]
    for i, name in enumerate(report["class_names"]):
        p, r, f = (report[k][i] for k in ("precision", "recall", "f1"))
        lines.append(f"| {name} | {p:.3f} | {r:.3f} | {f:.3f} | {int(report['support'][i])} |")
    return "\n".join(lines)


def accuracy_table(summary: dict) -> str:
    """Markdown table of the simulated test accuracies beside the paper's real-data figures."""
    lines = ["| model | simulated test accuracy (this run) | paper, real recordings |", "|---|---:|---:|"]
    for key in ("cnn", "lstm"):
        if key in summary["models"]:
            acc = summary["models"][key]["test_accuracy"]
            lines.append(f"| {key.upper()} | {100 * acc:.1f} % | {100 * PAPER_ACCURACY[key]:.1f} % |")
    return "\n".join(lines)


def train_gesture_models(data, test, out_dir: str | Path, *, epochs: int = 100, seed: int = 0,
                         num_threads: int | None = 1, patience: int | None = None, progress: bool = False,
                         models=("cnn", "lstm"), description: dict | None = None, batch_size: int = 256,
                         learning_rate: float = 1e-4) -> dict:
    """Train the paper's CNN and LSTM on ``data`` (8:2 split per class) and test them on ``test``.

    Parameters
    ----------
    data, test
        :class:`~latticeopt.gestures.simulate.GestureDataset` for training/validation and for testing.
    out_dir
        Folder for ``gesture_<model>.npz``, ``confusion_<model>.png``, ``report.md`` and ``summary.json``.
    epochs, seed, num_threads, patience, progress, batch_size, learning_rate
        :class:`~latticeopt.learn.training.TrainConfig` settings (Adam and cross-entropy always; the defaults
        batch 256 and learning rate 1e-4 are the paper's); ``seed`` also seeds the split and the initial
        weights.
    models
        Which of ``"cnn"``, ``"lstm"`` to train.
    description
        Extra JSON-serializable facts for the summary and the model files (e.g. the sensor model's path).

    Returns
    -------
    dict
        ``summary.json``'s content: data sizes, the split, per model the training history summary, best epoch,
        validation and test accuracy and the per-class report.
    """
    from ..learn.classifiers import GestureCNN, GestureLSTM
    from ..learn.layers import channel_statistics
    from ..learn.metrics import classification_report, plot_confusion_matrix
    from ..learn.persist import save_model
    from ..learn.splits import GESTURE_SPLIT, stratified_split
    from ..learn.training import TrainConfig, predict, seed_everything, train_model

    models = tuple(v.choice("models", m, tuple(MODEL_NAMES)) for m in models)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    x = check_sequences(data.frames, "training data")
    x_te = check_sequences(test.frames, "test data")
    tr, va = stratified_split(data.labels, GESTURE_SPLIT, seed)
    mean, std = channel_statistics(x[tr])
    config = TrainConfig(epochs=epochs, seed=seed, num_threads=num_threads, patience=patience, progress=progress,
                         batch_size=batch_size, learning_rate=learning_rate)
    classes = {"cnn": GestureCNN, "lstm": GestureLSTM}
    summary: dict = {"simulation": True, "classes": list(GESTURES), "frame": FRAME_CONVENTION,
                     "n_train": int(len(tr)), "n_val": int(len(va)), "n_test": int(len(x_te)),
                     "per_class": data.info.get("per_class"), "test_per_class": test.info.get("per_class"),
                     "train_config": config.to_dict(), "data": data.info, "test_data": test.info,
                     "description": description or {}, "paper_accuracy_real_data": PAPER_ACCURACY, "models": {}}
    for key in models:
        seed_everything(seed)
        net = classes[key](input_mean=mean, input_std=std)
        result = train_model(net, (x[tr], data.labels[tr]), (x[va], data.labels[va]), config)
        val_pred = predict(net, x[va]).argmax(axis=1)
        test_pred = predict(net, x_te).argmax(axis=1)
        val_rep = classification_report(val_pred, data.labels[va], GESTURES)
        rep = classification_report(test_pred, test.labels, GESTURES)
        entry = {"model_class": MODEL_NAMES[key], "best_epoch": result.best_epoch, "epochs_run": result.epochs_run,
                 "train_seconds": result.seconds, "seconds_per_epoch": result.seconds_per_epoch,
                 "val_accuracy": val_rep["accuracy"], "test_accuracy": rep["accuracy"],
                 "val_accuracy_history": list(result.val_accuracy or ()),
                 "test_report": {k: np.asarray(x_).tolist() if isinstance(x_, np.ndarray) else x_
                                 for k, x_ in rep.items()},
                 "model_file": f"gesture_{key}.npz", "confusion_png": f"confusion_{key}.png"}
        save_model(out / entry["model_file"], net, metadata={
            "task": "gesture classification", "classes": list(GESTURES), "frame": FRAME_CONVENTION,
            "n_frames": N_FRAMES, "n_meas": N_MEAS, "trained_on": "simulated sequences",
            "train_config": config.to_dict(), "train_result": result.to_dict(),
            "test_accuracy_simulated": rep["accuracy"], "data_key": data.info.get("key"),
            "description": description or {}})
        plot_confusion_matrix(rep["confusion_matrix"], GESTURES, out / entry["confusion_png"],
                              title=f"{key.upper()}, simulated test set ({rep['n']} sequences), accuracy "
                                    f"{100 * rep['accuracy']:.1f} %")
        summary["models"][key] = entry
        log.info("%s: best epoch %d, validation accuracy %.4f, test accuracy %.4f", key, result.best_epoch,
                 val_rep["accuracy"], rep["accuracy"])
    (out / "summary.json").write_text(dumps(summary, indent=1, default=float))
    (out / "report.md").write_text(report_markdown(summary))
    return summary


def report_markdown(summary: dict) -> str:
    """The accuracy comparison and per-class precision/recall tables (simulation, clearly labelled)."""
    parts = ["# Gesture classification on SIMULATED data", "",
             f"Training/validation: {summary['n_train']} / {summary['n_val']} simulated sequences "
             f"({summary['per_class']} per class, 8:2 split); test: {summary['n_test']} sequences generated "
             f"separately ({summary['test_per_class']} per class). Adam, learning rate "
             f"{summary['train_config']['learning_rate']:g}, batch {summary['train_config']['batch_size']}, "
             f"{summary['train_config']['epochs']} epochs at most, best validation epoch kept.", "",
             "The paper's accuracies are on real recordings and are quoted for reference only; simulated "
             "accuracy is not a prediction of real-data accuracy.", "", accuracy_table(summary)]
    for key, entry in summary["models"].items():
        parts += ["", f"## {key.upper()} (best epoch {entry['best_epoch']} of {entry['epochs_run']}, "
                      f"{entry['seconds_per_epoch']:.1f} s per epoch)", "", _table(entry["test_report"])]
    return "\n".join(parts) + "\n"


def classify_sequences(model_path: str | Path, frames) -> tuple[np.ndarray, np.ndarray, dict]:
    """Predicted class of every sequence.

    Parameters
    ----------
    model_path
        A model file written by :func:`train_gesture_models` (``gesture_cnn.npz`` or ``gesture_lstm.npz``).
    frames
        Relative changes, shape ``(n, 15, 104)`` (see :data:`FRAME_CONVENTION`).

    Returns
    -------
    labels : ndarray of int, shape (n,)
    probabilities : ndarray, shape (n, 12)
        Softmax of the model's scores.
    metadata : dict
        The model file's metadata.
    """
    from ..learn.persist import load_model
    from ..learn.training import predict

    x = check_sequences(frames)
    net, meta = load_model(model_path)
    if type(net).__name__ not in MODEL_NAMES.values():
        raise ParameterError("--model", "a gesture classifier file (GestureCNN or GestureLSTM)",
                             f"{model_path}: {type(net).__name__}")
    scores = predict(net, x).astype(np.float64)
    p = np.exp(scores - scores.max(axis=1, keepdims=True))
    p /= p.sum(axis=1, keepdims=True)
    return scores.argmax(axis=1), p, meta
