"""Building blocks shared by the networks: input standardization stored with the weights.

EIT voltage changes are small numbers (relative changes of order 1e-3) whose spread differs by orders of
magnitude between channels (adjacent-electrode measurements change far more than opposite ones). Networks train
badly on such inputs, so every model standardizes its input per measurement channel with a mean and standard
deviation computed once from the training set and stored as buffers: they travel with the ``state_dict``, so a
saved model applies exactly the scaling it was trained with.
"""

from __future__ import annotations

import numpy as np

from ..errors import ParameterError
from ._torch import require_torch

torch = require_torch()
nn = torch.nn

#: Channels whose standard deviation is below this fraction of the largest one are treated as constant.
RELATIVE_STD_FLOOR = 1e-8


def channel_statistics(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-channel mean and standard deviation over every axis but the last.

    Parameters
    ----------
    x
        Training inputs, shape ``(n, n_meas)`` or ``(n, n_frames, n_meas)``.

    Returns
    -------
    mean, std
        Float arrays of shape ``(n_meas,)``. Constant channels get ``std = 1`` so they map to zero
        instead of dividing by zero.
    """
    x = np.asarray(x, dtype=np.float64)
    if x.ndim < 2 or x.shape[0] == 0 or not np.all(np.isfinite(x)):
        raise ParameterError("x", "a finite array of shape (n >= 1, ..., n_meas)", getattr(x, "shape", x))
    flat = x.reshape(-1, x.shape[-1])
    mean = flat.mean(axis=0)
    std = flat.std(axis=0)
    floor = RELATIVE_STD_FLOOR * max(float(std.max()), np.finfo(float).tiny)
    std = np.where(std > floor, std, 1.0)
    return mean, std


class Standardize(nn.Module):
    """``(x - mean) / std`` over the last axis with ``mean`` and ``std`` kept as buffers.

    Parameters
    ----------
    n_features
        Length of the last input axis.
    mean, std
        Arrays of shape ``(n_features,)``; ``None`` means 0 and 1 (identity), the usual choice when the
        buffers will be overwritten by :meth:`torch.nn.Module.load_state_dict`.
    """

    def __init__(self, n_features: int, mean: np.ndarray | None = None, std: np.ndarray | None = None):
        super().__init__()
        mean = np.zeros(n_features) if mean is None else np.asarray(mean, dtype=np.float64)
        std = np.ones(n_features) if std is None else np.asarray(std, dtype=np.float64)
        for name, arr in (("input_mean", mean), ("input_std", std)):
            if arr.shape != (n_features,) or not np.all(np.isfinite(arr)):
                raise ParameterError(name, f"a finite array of shape ({n_features},)", arr.shape)
        if np.any(std <= 0):
            raise ParameterError("input_std", "positive values", float(std.min()))
        self.register_buffer("mean", torch.as_tensor(mean, dtype=torch.float32))
        self.register_buffer("std", torch.as_tensor(std, dtype=torch.float32))

    def forward(self, x):
        return (x - self.mean) / self.std


def check_input(x, expected_tail: tuple[int, ...], what: str) -> None:
    """Raise :class:`ParameterError` unless ``x.shape == (batch, *expected_tail)``."""
    if tuple(x.shape[1:]) != tuple(expected_tail) or x.ndim != len(expected_tail) + 1:
        raise ParameterError(what, "shape (batch, " + ", ".join(map(str, expected_tail)) + ")", tuple(x.shape))
