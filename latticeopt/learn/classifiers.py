"""Gesture classifiers exactly as in the paper's Table "Model parameters" (§VII).

Both take a sequence of ``n_frames = 15`` voltage frames of ``n_meas = 104`` independent measurements, shape
``(batch, 15, 104)``, and return unnormalized class scores (logits) of shape ``(batch, 12)``; train them with
cross-entropy (:class:`latticeopt.learn.training.TrainConfig` ``loss="cross_entropy"``).

CNN (adapted by the paper from park2022biomimetic, yang2023robotic, yang2024body), input ``1 x 15 x 104``:

=======================  ===============================================================================
layer                    paper value / our choice
=======================  ===============================================================================
conv 1                   1 -> 32 channels, 5 x 5, **padding 2** ("same"), ReLU
max-pool 1               2 x 2, stride 2: 15 x 104 -> 7 x 52 (floor)
conv 2                   32 -> 16 channels, 5 x 5, padding 2, ReLU
max-pool 2               2 x 2, stride 2: 7 x 52 -> 3 x 26
flatten                  16 x 3 x 26 = **1248** (the table's flattened size; padding 0 would give 16 x 1 x 23)
FC 1, FC 2               1248 -> 128, ReLU; 128 -> 12
=======================  ===============================================================================

The table lists the convolutions and pools with one activation (ReLU); we apply it after each convolution
and fully connected hidden layer, before pooling.

LSTM, input ``15 x 104``: ``nn.LSTM(104, 64, num_layers=2, batch_first=True)`` and ``Linear(64, 12)`` on the
hidden state of the last time step (the table gives no dropout, so none is used).

Both standardize each of the ``n_meas`` channels with training-set statistics stored as buffers (see
:mod:`latticeopt.learn.layers`): a preprocessing step, not a layer of the paper's table.
"""

from __future__ import annotations

import numpy as np

from .. import _validate as v
from ..errors import ParameterError
from ._torch import require_torch
from .layers import Standardize, check_input

torch = require_torch()
nn = torch.nn

#: The paper's 12 gesture classes in label order.
GESTURE_CLASSES = (
    "no contact", "finger press", "four-finger scratch", "fist press", "finger double tap", "palm pat",
    "finger swipe up", "finger swipe down", "finger swipe left", "finger swipe right", "zoom-in", "zoom-out",
)


def _pooled(n: int) -> int:
    """Side after a 'same' 5 x 5 convolution and a 2 x 2 stride-2 max-pool (floor)."""
    return n // 2


class GestureCNN(nn.Module):
    """The paper's CNN gesture classifier (see the module docstring for the layer table).

    Parameters
    ----------
    n_frames, n_meas
        Input sequence shape (paper: 15 frames x 104 measurements).
    n_classes
        Number of gesture classes (paper: 12).
    input_mean, input_std
        Per-measurement standardization, shape ``(n_meas,)``; ``None`` = identity.

    Notes
    -----
    ``forward`` takes ``(batch, n_frames, n_meas)`` or ``(batch, 1, n_frames, n_meas)`` and returns logits
    ``(batch, n_classes)``.
    """

    def __init__(self, n_frames: int = 15, n_meas: int = 104, n_classes: int = 12, *,
                 input_mean: np.ndarray | None = None, input_std: np.ndarray | None = None):
        super().__init__()
        self.n_frames = v.integer("n_frames", n_frames, lo=4, expected="an integer >= 4 (two 2 x 2 pools)")
        self.n_meas = v.integer("n_meas", n_meas, lo=4, expected="an integer >= 4 (two 2 x 2 pools)")
        self.n_classes = v.integer("n_classes", n_classes, lo=2)
        self.standardize = Standardize(self.n_meas, input_mean, input_std)
        self.features = nn.Sequential(
            nn.Conv2d(1, 32, kernel_size=5, padding=2), nn.ReLU(), nn.MaxPool2d(2, stride=2),
            nn.Conv2d(32, 16, kernel_size=5, padding=2), nn.ReLU(), nn.MaxPool2d(2, stride=2),
            nn.Flatten(),
        )
        #: Length of the flattened feature vector (1248 at the paper's 15 x 104 input).
        self.flat_features = 16 * _pooled(_pooled(self.n_frames)) * _pooled(_pooled(self.n_meas))
        self.classifier = nn.Sequential(
            nn.Linear(self.flat_features, 128), nn.ReLU(), nn.Linear(128, self.n_classes))

    def config(self) -> dict:
        """Constructor arguments (JSON-serializable) that rebuild this architecture."""
        return dict(n_frames=self.n_frames, n_meas=self.n_meas, n_classes=self.n_classes)

    def forward(self, x):
        if x.ndim == 4:
            check_input(x, (1, self.n_frames, self.n_meas), "frames")
            x = x[:, 0]
        check_input(x, (self.n_frames, self.n_meas), "frames")
        return self.classifier(self.features(self.standardize(x).unsqueeze(1)))


class GestureLSTM(nn.Module):
    """The paper's LSTM gesture classifier: 2-layer LSTM (104 -> 64) and a linear head on the last step.

    Parameters
    ----------
    n_meas
        Measurements per frame (paper: 104), the LSTM input size.
    hidden_size, num_layers
        LSTM width and depth (paper: 64, 2).
    n_classes
        Number of gesture classes (paper: 12).
    input_mean, input_std
        Per-measurement standardization, shape ``(n_meas,)``; ``None`` = identity.

    Notes
    -----
    ``forward`` takes ``(batch, n_frames, n_meas)`` for any ``n_frames >= 1`` and returns logits
    ``(batch, n_classes)``.
    """

    def __init__(self, n_meas: int = 104, hidden_size: int = 64, num_layers: int = 2, n_classes: int = 12, *,
                 input_mean: np.ndarray | None = None, input_std: np.ndarray | None = None):
        super().__init__()
        self.n_meas = v.integer("n_meas", n_meas, lo=1)
        self.hidden_size = v.integer("hidden_size", hidden_size, lo=1)
        self.num_layers = v.integer("num_layers", num_layers, lo=1)
        self.n_classes = v.integer("n_classes", n_classes, lo=2)
        self.standardize = Standardize(self.n_meas, input_mean, input_std)
        self.lstm = nn.LSTM(self.n_meas, self.hidden_size, num_layers=self.num_layers, batch_first=True)
        self.head = nn.Linear(self.hidden_size, self.n_classes)

    def config(self) -> dict:
        """Constructor arguments (JSON-serializable) that rebuild this architecture."""
        return dict(n_meas=self.n_meas, hidden_size=self.hidden_size, num_layers=self.num_layers,
                    n_classes=self.n_classes)

    def forward(self, x):
        if x.ndim != 3 or x.shape[1] < 1 or x.shape[2] != self.n_meas:
            raise ParameterError("frames", f"shape (batch, n_frames >= 1, {self.n_meas})", tuple(x.shape))
        out, _ = self.lstm(self.standardize(x))
        return self.head(out[:, -1])
