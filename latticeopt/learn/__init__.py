"""Learning side of latticeopt: the reconstruction network, the gesture classifiers, training and metrics.

PyTorch is optional (``pip install "latticeopt[learn]"``). This package imports it lazily: ``import
latticeopt.learn`` and the torch-free modules (:mod:`.metrics`, :mod:`.splits`) work without it; the names
below that need torch import their module on first access and raise
:class:`~latticeopt.learn._torch.MissingDependencyError` with the install command when torch is missing.

Modules: :mod:`.recon_net` (MLP encoder + CNN decoder, paper §V), :mod:`.classifiers` (the paper's CNN and
LSTM, §VII), :mod:`.training` (:func:`train_model`, :class:`TrainConfig`, :class:`TrainResult`,
:func:`predict`), :mod:`.persist` (pickle-free :func:`save_model` / :func:`load_model`), :mod:`.metrics`
(CC, PSNR, SSIM, RE; confusion matrix, precision/recall; plot), :mod:`.splits` (seeded 7:2:1 / 8:2 splits).
"""

from __future__ import annotations

import importlib

from ._torch import MissingDependencyError, TrainingError

_LAZY = {
    "ReconNet": "recon_net",
    "GestureCNN": "classifiers", "GestureLSTM": "classifiers", "GESTURE_CLASSES": "classifiers",
    "channel_statistics": "layers",
    "TrainConfig": "training", "TrainResult": "training", "train_model": "training", "predict": "training",
    "seed_everything": "training",
    "save_model": "persist", "load_model": "persist",
    "evaluate_images": "metrics", "classification_report": "metrics", "confusion_matrix": "metrics",
    "plot_confusion_matrix": "metrics",
    "split_indices": "splits", "stratified_split": "splits", "RECON_SPLIT": "splits", "GESTURE_SPLIT": "splits",
}

__all__ = ["MissingDependencyError", "TrainingError", *sorted(_LAZY)]


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
