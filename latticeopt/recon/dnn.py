"""The learned reconstructor: glue between the simulated dataset and :mod:`latticeopt.learn`.

The network (:class:`latticeopt.learn.ReconNet`, MLP encoder and CNN decoder after dong2025data) maps relative
changes ``y = (V - V_ref) / V_ref`` of all rows (208) to the normalized change image ``(sigma - sigma0) /
sigma0`` (48 x 48). Training uses :func:`latticeopt.learn.train_model` (Adam, MSE, best validation epoch) on
:func:`~latticeopt.recon.dataset.training_arrays` (eight-fold augmented, noisy; with the dataset's coupled presses
if it holds any) and the clean validation part.
The saved network file (:func:`latticeopt.learn.save_model`, no pickles) records the sensor model's
fingerprint so it is never applied to frames of another sensor model by mistake.
"""

from __future__ import annotations

import logging
import sys
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from .. import _validate as v
from ..errors import ParameterError
from ..sensor_model import SensorModel
from .dataset import PAPER_SNR_DB, ReconDataset, part_arrays, training_arrays

log = logging.getLogger(__name__)

INPUT_KIND = "relative_change_all_rows"


@dataclass(frozen=True)
class ReconTrainConfig:
    """Training settings for the reconstructor.

    Parameters
    ----------
    epochs, batch_size, learning_rate, patience, seed, num_threads
        Passed to :class:`latticeopt.learn.TrainConfig` (loss MSE). The paper keeps dong2025data's settings,
        which we do not have; Adam with 1e-3 and batch 256 is our choice.
    augment
        Eight-fold symmetry augmentation with noise (paper); False trains on the clean training part only.
    snr_db
        SNR of the seven augmented copies.
    hidden, latent_channels, decoder_channels, dropout
        Architecture of :class:`latticeopt.learn.ReconNet` (defaults: its defaults).
    progress
        tqdm progress bar over epochs.
    """

    epochs: int = 100
    batch_size: int = 256
    learning_rate: float = 1e-3
    patience: int | None = 15
    seed: int = 0
    num_threads: int | None = None
    augment: bool = True
    snr_db: tuple = PAPER_SNR_DB
    hidden: tuple = (512, 512)
    latent_channels: int = 32
    decoder_channels: tuple = (32, 16, 8)
    dropout: float = 0.0
    progress: bool = False

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "epochs", v.integer("epochs", self.epochs, lo=1))
        set_(self, "batch_size", v.integer("batch_size", self.batch_size, lo=1))
        set_(self, "learning_rate", v.real("learning_rate", self.learning_rate, lo=0, lo_open=True))
        set_(self, "snr_db", tuple(v.real("snr_db", s) for s in self.snr_db))
        set_(self, "hidden", tuple(v.integer("hidden", h, lo=1) for h in self.hidden))
        set_(self, "decoder_channels", tuple(v.integer("decoder_channels", c, lo=1) for c in self.decoder_channels))


def train_reconstructor(data: ReconDataset, model: SensorModel, config: ReconTrainConfig | None = None):
    """Train the MLP-CNN reconstructor on ``data``.

    Returns
    -------
    net : latticeopt.learn.ReconNet
        The network holding the best validation epoch's weights.
    result : latticeopt.learn.TrainResult
    metadata : dict
        What :func:`save_reconstructor` stores with the weights.
    """
    from ..learn import ReconNet, TrainConfig, channel_statistics, seed_everything, train_model

    cfg = config or ReconTrainConfig()
    data.check_model(model)
    n_presses = 0 if data.presses is None else int(data.presses.solved.sum())
    if cfg.progress:  # the augmentation takes seconds before the epoch bar appears
        print(f"preparing {len(data.train)} training samples{f' + {n_presses} presses' if n_presses else ''}"
              f"{' x 8 (symmetries with noise)' if cfg.augment else ''}", file=sys.stderr, flush=True)
    x_tr, y_tr = training_arrays(data, model, cfg.snr_db, augment=cfg.augment)
    x_va, y_va, _ = part_arrays(data, model, "val")
    mean, std = channel_statistics(x_tr)
    seed_everything(cfg.seed)
    net = ReconNet(model.n_rows, image_size=model.n_pixels, hidden=cfg.hidden, latent_channels=cfg.latent_channels,
                   decoder_channels=cfg.decoder_channels, dropout=cfg.dropout, input_mean=mean, input_std=std)
    tcfg = TrainConfig(loss="mse", epochs=cfg.epochs, batch_size=cfg.batch_size, learning_rate=cfg.learning_rate,
                       patience=cfg.patience, seed=cfg.seed, num_threads=cfg.num_threads, progress=cfg.progress)
    log.info("training on %d samples (%s augmentation), validating on %d", len(x_tr),
             "eight-fold" if cfg.augment else "no", len(x_va))
    result = train_model(net, (x_tr, y_tr), (x_va.astype(np.float32), y_va), tcfg)
    meta = {"input": INPUT_KIND, "target": "normalized_change", "sensor_model_fingerprint": model.fingerprint,
            "n_pixels": model.n_pixels, "sigma0_S_per_m": model.sigma0_S_per_m,
            "train_config": {k: list(x) if isinstance(x, tuple) else x for k, x in asdict(cfg).items()},
            "train_result": result.to_dict(), "n_train": int(len(x_tr)), "n_val": int(len(x_va)),
            "dataset": asdict(data.config),
            "train_presses": None if data.presses is None else {"n": len(data.presses.presses),
                                                                 "solved": n_presses, "seed": data.presses.seed}}
    return net, result, meta


def save_reconstructor(path: str | Path, net, metadata: dict) -> Path:
    from ..learn import save_model

    return save_model(path, net, metadata=metadata)


class DNNReconstructor:
    """A trained network file applied to relative changes (checks it belongs to ``model``).

    Parameters
    ----------
    path
        Network file from ``latticeopt recon-train`` / :func:`save_reconstructor`.
    model
        The sensor model the frames belong to.
    """

    def __init__(self, path: str | Path, model: SensorModel):
        from ..learn import load_model

        self.net, self.metadata = load_model(path)
        if self.metadata.get("input") != INPUT_KIND:
            raise ParameterError("--net", "a reconstruction network trained by latticeopt recon-train",
                                 f"{path} (input {self.metadata.get('input')!r})")
        fp = self.metadata.get("sensor_model_fingerprint")
        if fp != model.fingerprint:
            raise ParameterError("--net", f"a network trained for sensor model {model.fingerprint}",
                                 f"{path} (trained for {fp})")
        self.model = model

    def reconstruct(self, y: np.ndarray) -> np.ndarray:
        """Images ``(k, n, n)`` of the normalized change from relative changes ``(k, n_rows)``."""
        from ..learn import predict

        y = np.atleast_2d(np.asarray(y, dtype=float))
        if y.shape[1] != self.model.n_rows:
            raise ParameterError("y", f"relative changes of shape (k, {self.model.n_rows})", y.shape)
        return predict(self.net, y.astype(np.float32)).astype(np.float64)
