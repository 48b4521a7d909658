"""A generic, reusable training loop for the reconstruction network and the gesture classifiers.

:func:`train_model` trains any ``torch.nn.Module`` on in-memory numpy arrays with Adam (paper: learning rate
1e-4, batch 256), cross-entropy (classification) or mean squared error (reconstruction), evaluates the
validation set after every epoch and leaves the model holding the weights of the epoch with the lowest
validation loss (the paper's "epoch of best model"), as :class:`TrainResult` reports.

Reproducibility: shuffling uses a ``torch.Generator`` seeded with ``TrainConfig.seed``, and dropout draws from
the global torch generator re-seeded with the same seed inside :func:`torch.random.fork_rng`, so training does
not disturb the caller's random state. The initial weights are drawn when the model is *constructed*: call
:func:`seed_everything` before building it. With the same seed, initial weights, data and thread count, two
runs on the same machine give identical histories.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import random
import time
from dataclasses import dataclass

import numpy as np

from .. import _validate as v
from ..errors import ParameterError
from ._torch import TrainingError, require_torch
from .splits import GESTURE_SPLIT, RECON_SPLIT, split_indices, stratified_split

torch = require_torch()

log = logging.getLogger(__name__)

LOSSES = ("cross_entropy", "mse")
DEVICES = ("cpu", "cuda")

__all__ = ["GESTURE_SPLIT", "LOSSES", "RECON_SPLIT", "TrainConfig", "TrainResult", "predict", "seed_everything",
           "split_indices", "stratified_split", "train_model"]


@dataclass(frozen=True)
class TrainConfig:
    """How to train (paper §VII table: Adam, 1e-4, cross-entropy, batch 256, 200 epochs, best on validation).

    Parameters
    ----------
    loss
        ``"cross_entropy"`` (classification; targets are integer labels) or ``"mse"`` (reconstruction; targets
        have the model's output shape).
    epochs
        Maximum number of passes over the training set.
    batch_size
        Samples per Adam step (the last batch of an epoch may be smaller).
    learning_rate
        Adam step size.
    weight_decay
        Adam L2 penalty (0 = none, as in the paper).
    patience
        Stop when the validation loss has not improved for this many epochs; ``None`` runs all ``epochs``.
    seed
        Seed of shuffling and dropout (see the module docstring).
    num_threads
        Torch intra-op threads while training (restored afterwards); ``None`` keeps the current setting.
        Use 1 inside parallel workers.
    device
        ``"cpu"`` or ``"cuda"``.
    progress
        Show a tqdm progress bar over epochs.
    """

    loss: str = "cross_entropy"
    epochs: int = 200
    batch_size: int = 256
    learning_rate: float = 1e-4
    weight_decay: float = 0.0
    patience: int | None = None
    seed: int = 0
    num_threads: int | None = None
    device: str = "cpu"
    progress: bool = True

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "loss", v.choice("loss", self.loss, LOSSES))
        set_(self, "epochs", v.integer("epochs", self.epochs, lo=1))
        set_(self, "batch_size", v.integer("batch_size", self.batch_size, lo=1))
        set_(self, "learning_rate", v.real("learning_rate", self.learning_rate, lo=0, lo_open=True))
        set_(self, "weight_decay", v.real("weight_decay", self.weight_decay, lo=0))
        if self.patience is not None:
            set_(self, "patience", v.integer("patience", self.patience, lo=1,
                                             expected="None (no early stopping) or an integer >= 1"))
        set_(self, "seed", v.integer("seed", self.seed, lo=0))
        if self.num_threads is not None:
            set_(self, "num_threads", v.integer("num_threads", self.num_threads, lo=1,
                                                expected="None (keep torch's setting) or an integer >= 1"))
        set_(self, "device", v.choice("device", self.device, DEVICES))
        if not isinstance(self.progress, bool):
            raise ParameterError("progress", "True or False", self.progress)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class TrainResult:
    """What happened during :func:`train_model`; epochs are numbered from 1.

    Attributes
    ----------
    train_loss, val_loss
        Mean loss per sample of each epoch run (training loss averaged over the epoch's steps in training
        mode; validation loss in evaluation mode after the epoch).
    val_accuracy
        Validation accuracy per epoch for ``loss="cross_entropy"``, else ``None``.
    epoch_seconds
        Wall time of each epoch (training and validation).
    best_epoch
        The epoch (1-based) of the lowest validation loss, the first one on ties; the model holds its weights.
    seconds
        Total wall time.
    stopped_early
        True when ``patience`` ended training before ``epochs``.
    """

    train_loss: tuple[float, ...]
    val_loss: tuple[float, ...]
    val_accuracy: tuple[float, ...] | None
    epoch_seconds: tuple[float, ...]
    best_epoch: int
    seconds: float
    stopped_early: bool

    @property
    def epochs_run(self) -> int:
        return len(self.train_loss)

    @property
    def best_val_loss(self) -> float:
        return self.val_loss[self.best_epoch - 1]

    @property
    def seconds_per_epoch(self) -> float:
        return self.seconds / max(self.epochs_run, 1)

    def to_dict(self) -> dict:
        """JSON-serializable summary (for model metadata and reports)."""
        d = dataclasses.asdict(self)
        d.update(epochs_run=self.epochs_run, best_val_loss=self.best_val_loss)
        return {k: list(x) if isinstance(x, tuple) else x for k, x in d.items()}


def seed_everything(seed: int) -> None:
    """Seed torch's, Python's and numpy's global generators (for scripts, before building a model)."""
    seed = v.integer("seed", seed, lo=0)
    torch.manual_seed(seed)
    random.seed(seed)
    np.random.seed(seed % 2 ** 32)


def _as_tensors(name: str, arrays, loss: str):
    if not isinstance(arrays, tuple | list) or len(arrays) != 2:
        raise ParameterError(name, "a pair (inputs, targets) of numpy arrays", type(arrays).__name__)
    x, y = (np.asarray(a) for a in arrays)
    if x.ndim < 2 or x.shape[0] == 0 or not np.issubdtype(x.dtype, np.number):
        raise ParameterError(f"{name}[0]", "numeric inputs of shape (n >= 1, ...)", f"{x.dtype} {x.shape}")
    if y.shape[:1] != x.shape[:1]:
        raise ParameterError(f"{name}[1]", f"one target per input ({x.shape[0]})", y.shape)
    if not np.all(np.isfinite(x)):
        raise ParameterError(f"{name}[0]", "finite inputs", "NaN or infinite values")
    if loss == "cross_entropy":
        if y.ndim != 1 or not np.issubdtype(y.dtype, np.integer) or y.min() < 0:
            raise ParameterError(f"{name}[1]", "non-negative integer class labels of shape (n,)",
                                 f"{y.dtype} {y.shape}")
        yt = torch.as_tensor(y.astype(np.int64))
    else:
        if not np.issubdtype(y.dtype, np.number) or not np.all(np.isfinite(y)):
            raise ParameterError(f"{name}[1]", "finite numeric targets", f"{y.dtype} {y.shape}")
        yt = torch.as_tensor(np.ascontiguousarray(y, dtype=np.float32))
    return torch.as_tensor(np.ascontiguousarray(x, dtype=np.float32)), yt


def _check_model_output(model, x, y, loss: str, device) -> None:
    """One forward pass on one sample so shape mistakes fail with a clear message before training."""
    model.eval()
    with torch.no_grad():
        out = model(x[:1].to(device))
    if loss == "cross_entropy":
        if out.ndim != 2:
            raise ParameterError("model", "class scores of shape (batch, n_classes) for cross_entropy",
                                 tuple(out.shape))
        if int(y.max()) >= out.shape[1]:
            raise ParameterError("targets", f"labels in 0..{out.shape[1] - 1} (model outputs {out.shape[1]} "
                                            "classes)", int(y.max()))
    elif tuple(out.shape[1:]) != tuple(y.shape[1:]):
        raise ParameterError("targets", f"the model's output shape per sample {tuple(out.shape[1:])}",
                             tuple(y.shape[1:]))


def _train_epoch(model, x, y, loss_fn, optimizer, batch_size: int, device, generator) -> float:
    """One shuffled pass of Adam steps; returns the mean training loss per sample."""
    model.train()
    perm = torch.randperm(len(x), generator=generator)
    total = 0.0
    for start in range(0, len(x), batch_size):
        idx = perm[start:start + batch_size]
        xb, yb = x[idx].to(device), y[idx].to(device)
        optimizer.zero_grad(set_to_none=True)
        loss = loss_fn(model(xb), yb)
        loss.backward()
        optimizer.step()
        total += float(loss.detach()) * len(idx)
    return total / len(x)


def _evaluate(model, x, y, loss_fn, batch_size: int, device, classify: bool) -> tuple[float, float | None]:
    model.eval()
    total, correct = 0.0, 0
    with torch.no_grad():
        for start in range(0, len(x), batch_size):
            xb, yb = x[start:start + batch_size].to(device), y[start:start + batch_size].to(device)
            out = model(xb)
            total += float(loss_fn(out, yb)) * len(xb)
            if classify:
                correct += int((out.argmax(dim=1) == yb).sum())
    return total / len(x), (correct / len(x) if classify else None)


def train_model(model, train_arrays, val_arrays, config: TrainConfig | None = None) -> TrainResult:
    """Train ``model`` in place and leave it holding the best validation epoch's weights.

    Parameters
    ----------
    model
        A ``torch.nn.Module`` mapping a float batch ``(batch, ...)`` to class scores ``(batch, n_classes)``
        (cross-entropy) or to outputs shaped like the targets (MSE), e.g. :class:`~.recon_net.ReconNet`,
        :class:`~.classifiers.GestureCNN`, :class:`~.classifiers.GestureLSTM`.
    train_arrays, val_arrays
        ``(inputs, targets)`` numpy pairs with one row per sample: inputs float ``(n, ...)``; targets
        int labels ``(n,)`` for cross-entropy or float arrays for MSE.
    config
        :class:`TrainConfig`; default ``TrainConfig()``.

    Returns
    -------
    TrainResult
        Per-epoch losses, the best epoch (1-based), timings.

    Raises
    ------
    ParameterError
        Arrays or model outputs of the wrong shape or type.
    TrainingError
        The training loss became NaN or infinite (lower ``learning_rate``).
    """
    from tqdm import tqdm

    cfg = TrainConfig() if config is None else config
    if not isinstance(cfg, TrainConfig):
        raise ParameterError("config", "a TrainConfig", type(cfg).__name__)
    if not isinstance(model, torch.nn.Module):
        raise ParameterError("model", "a torch.nn.Module", type(model).__name__)
    if cfg.device == "cuda" and not torch.cuda.is_available():
        raise ParameterError("device", "'cpu' (CUDA is not available on this machine)", cfg.device)
    x_tr, y_tr = _as_tensors("train_arrays", train_arrays, cfg.loss)
    x_va, y_va = _as_tensors("val_arrays", val_arrays, cfg.loss)
    if x_tr.shape[1:] != x_va.shape[1:]:
        raise ParameterError("val_arrays[0]", f"inputs shaped like the training inputs (n, "
                                              f"{', '.join(map(str, x_tr.shape[1:]))})", tuple(x_va.shape))
    device = torch.device(cfg.device)
    classify = cfg.loss == "cross_entropy"
    loss_fn = torch.nn.CrossEntropyLoss() if classify else torch.nn.MSELoss()
    model.to(device)

    old_threads = torch.get_num_threads()
    if cfg.num_threads is not None:
        torch.set_num_threads(cfg.num_threads)
    t_start = time.perf_counter()
    train_hist, val_hist, acc_hist, sec_hist = [], [], [], []
    best_epoch, best_loss, best_state = 0, math.inf, None
    stopped_early = False
    try:
        _check_model_output(model, x_tr, y_tr, cfg.loss, device)
        _check_model_output(model, x_va, y_va, cfg.loss, device)
        optimizer = torch.optim.Adam(model.parameters(), lr=cfg.learning_rate, weight_decay=cfg.weight_decay)
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(cfg.seed)
            shuffle = torch.Generator().manual_seed(cfg.seed)
            with tqdm(range(1, cfg.epochs + 1), desc=f"training {type(model).__name__}", unit="epoch",
                      disable=not cfg.progress, leave=False) as bar:
                for epoch in bar:
                    t_epoch = time.perf_counter()
                    train_loss = _train_epoch(model, x_tr, y_tr, loss_fn, optimizer, cfg.batch_size, device,
                                              shuffle)
                    if not math.isfinite(train_loss):
                        raise TrainingError(f"training loss became {train_loss} at epoch {epoch} "
                                            f"(learning_rate={cfg.learning_rate:g}); try a smaller learning rate")
                    val_loss, val_acc = _evaluate(model, x_va, y_va, loss_fn, cfg.batch_size, device, classify)
                    train_hist.append(train_loss)
                    val_hist.append(val_loss)
                    if classify:
                        acc_hist.append(val_acc)
                    sec_hist.append(time.perf_counter() - t_epoch)
                    if val_loss < best_loss:
                        best_epoch, best_loss = epoch, val_loss
                        best_state = {k: t.detach().clone() for k, t in model.state_dict().items()}
                    bar.set_postfix(train=f"{train_loss:.4g}", val=f"{val_loss:.4g}", best=best_epoch)
                    log.debug("epoch %d: train %.6g, val %.6g%s", epoch, train_loss, val_loss,
                              f", val accuracy {val_acc:.4f}" if classify else "")
                    if cfg.patience is not None and epoch - best_epoch >= cfg.patience:
                        stopped_early = epoch < cfg.epochs
                        break
    finally:
        torch.set_num_threads(old_threads)
    if best_state is None:
        raise TrainingError("the validation loss was never finite; no epoch can be selected")
    model.load_state_dict(best_state)
    model.eval()
    seconds = time.perf_counter() - t_start
    log.info("trained %s: %d epochs in %.1f s, best epoch %d (validation loss %.6g)",
             type(model).__name__, len(train_hist), seconds, best_epoch, best_loss)
    return TrainResult(train_loss=tuple(train_hist), val_loss=tuple(val_hist),
                       val_accuracy=tuple(acc_hist) if classify else None, epoch_seconds=tuple(sec_hist),
                       best_epoch=best_epoch, seconds=seconds, stopped_early=stopped_early)


def predict(model, inputs: np.ndarray, *, batch_size: int = 1024, device: str = "cpu") -> np.ndarray:
    """Model outputs for ``inputs`` in evaluation mode, as a float32 numpy array.

    Parameters
    ----------
    model
        A trained ``torch.nn.Module``.
    inputs
        Float array ``(n, ...)`` shaped as in training.
    batch_size
        Samples per forward pass (memory only; results do not depend on it).
    device
        ``"cpu"`` or ``"cuda"``.

    Returns
    -------
    ndarray
        ``(n, ...)`` outputs: class scores (take ``argmax(axis=1)`` for labels) or images.
    """
    batch_size = v.integer("batch_size", batch_size, lo=1)
    dev = torch.device(v.choice("device", device, DEVICES))
    x = np.asarray(inputs)
    if x.ndim < 2 or x.shape[0] == 0 or not np.issubdtype(x.dtype, np.number) or not np.all(np.isfinite(x)):
        raise ParameterError("inputs", "a finite numeric array of shape (n >= 1, ...)", f"{x.dtype} {x.shape}")
    xt = torch.as_tensor(np.ascontiguousarray(x, dtype=np.float32))
    model.to(dev)
    model.eval()
    outs = []
    with torch.no_grad():
        for start in range(0, len(xt), batch_size):
            outs.append(model(xt[start:start + batch_size].to(dev)).cpu().numpy())
    return np.concatenate(outs)
