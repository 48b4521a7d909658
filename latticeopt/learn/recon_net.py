"""The learned tactile reconstructor: an MLP encoder and a CNN decoder (paper §V, after dong2025data).

The paper reconstructs touch images with "the deep neural network (DNN) architecture in [dong2025data]": a
multilayer perceptron (MLP) that extracts *global* features of the voltage vector followed by a convolutional
neural network (CNN) that extracts *fine-grained local* patterns; the original network outputs a 64 x 64 image
and the paper appends an upsampling layer that rescales it to the 48 x 48 grid of its sensor.

Reference: H. Dong, R. B. Liu, L. Micklem, P. E, F. Giorgio-Serchi and Y. Yang, "Data-efficient tactile sensing
with electrical impedance tomography" (cited as dong2025data in the paper; arXiv:2411.12658).

That reference's layer table was not available to us (only its abstract, which confirms "a DNN with an MLP
encoder and a CNN decoder"), so the layer sizes below are our reconstruction from the description above, not
a copy of the original; every size is a constructor argument:

====================  ==========================================================================================
stage                 layers (defaults)
====================  ==========================================================================================
input scaling         per-channel ``(v - mean) / std`` with training-set statistics stored as buffers
MLP encoder           ``n_meas -> 512 -> 512`` (Linear + ReLU, optional dropout): each hidden unit sees every
                      measurement, i.e. global features of the frame
latent                Linear ``512 -> 32 * 8 * 8`` + ReLU, reshaped to a 32-channel 8 x 8 feature map
CNN decoder           three stages ``8 -> 16 -> 32 -> 64`` px, each a 4 x 4 stride-2 transposed convolution
                      (kernel divisible by the stride: even overlap, fewer checkerboard artefacts) and a
                      3 x 3 convolution, both with batch normalization and ReLU; channels 32 -> 32 -> 16 -> 8
output                3 x 3 convolution to one channel, *no* activation (conductivity changes may be negative
                      or positive: the paper's touches span 0.05 to 2 sigma0), giving the 64 x 64 image
resize                bilinear ``nn.Upsample`` to ``image_size`` (48 x 48), the paper's appended "upsampling"
                      layer (for 64 -> 48 it actually shrinks the image)
====================  ==========================================================================================

Default size: about 1.46 M parameters (208 inputs). The network maps whatever image the training targets
contain; we recommend the normalized change ``(sigma - sigma0) / sigma0`` so targets are of order one, and
relative voltage changes ``(v - v_ref) / v_ref`` as inputs: training runs in float32, where absolute voltages
would spend most of the 7 significant digits on the reference level.
"""

from __future__ import annotations

import numpy as np

from .. import _validate as v
from ..errors import ParameterError
from ._torch import require_torch
from .layers import Standardize, check_input

torch = require_torch()
nn = torch.nn

#: Measurement counts of a 16-electrode adjacent protocol: all 208 or the 104 independent ones.
SUPPORTED_N_MEAS = (208, 104)


def _positive_ints(name: str, values, *, allow_empty: bool = False) -> tuple[int, ...]:
    try:
        vals = tuple(values)
    except TypeError:
        raise ParameterError(name, "a sequence of positive integers", values) from None
    if not vals and not allow_empty:
        raise ParameterError(name, "a non-empty sequence of positive integers", values)
    return tuple(v.integer(name, x, lo=1, expected="a sequence of positive integers") for x in vals)


class ReconNet(nn.Module):
    """Voltage frame -> tactile image: MLP encoder, CNN decoder, resize (see the module docstring).

    Parameters
    ----------
    n_meas
        Measurements per frame: 208 (all adjacent-adjacent voltages) or 104 (the independent half), see
        :data:`SUPPORTED_N_MEAS`. Any positive integer is accepted so other protocols can be tried; the
        measurement order must be the one used in training.
    image_size
        Side of the output image in pixels (paper: 48).
    hidden
        Widths of the encoder's hidden layers.
    latent_channels, latent_size
        The encoder's last layer is reshaped to ``(latent_channels, latent_size, latent_size)``.
    decoder_channels
        Output channels of the decoder stages; each stage doubles the side, so the native output side is
        ``latent_size * 2 ** len(decoder_channels)`` (default 64, as in dong2025data).
    dropout
        Dropout probability after each hidden encoder layer (0 disables it).
    input_mean, input_std
        Per-measurement standardization, shape ``(n_meas,)``, e.g. from
        :func:`latticeopt.learn.layers.channel_statistics` on the training inputs; ``None`` = identity.

    Notes
    -----
    ``forward`` takes a float tensor of shape ``(batch, n_meas)`` and returns ``(batch, image_size,
    image_size)``.
    """

    def __init__(self, n_meas: int = 208, *, image_size: int = 48, hidden=(512, 512), latent_channels: int = 32,
                 latent_size: int = 8, decoder_channels=(32, 16, 8), dropout: float = 0.0,
                 input_mean: np.ndarray | None = None, input_std: np.ndarray | None = None):
        super().__init__()
        n_meas = v.integer("n_meas", n_meas, lo=1)
        image_size = v.integer("image_size", image_size, lo=1)
        hidden = _positive_ints("hidden", hidden, allow_empty=True)
        latent_channels = v.integer("latent_channels", latent_channels, lo=1)
        latent_size = v.integer("latent_size", latent_size, lo=1)
        decoder_channels = _positive_ints("decoder_channels", decoder_channels, allow_empty=True)
        dropout = v.real("dropout", dropout, lo=0.0, hi=1.0, hi_open=True)
        self._config = dict(n_meas=n_meas, image_size=image_size, hidden=list(hidden),
                            latent_channels=latent_channels, latent_size=latent_size,
                            decoder_channels=list(decoder_channels), dropout=dropout)
        self.n_meas = n_meas
        self.image_size = image_size
        self.native_size = latent_size * 2 ** len(decoder_channels)
        self._latent_shape = (latent_channels, latent_size, latent_size)

        self.standardize = Standardize(n_meas, input_mean, input_std)
        layers: list = []
        width = n_meas
        for h in hidden:
            layers += [nn.Linear(width, h), nn.ReLU()]
            if dropout > 0:
                layers.append(nn.Dropout(dropout))
            width = h
        layers += [nn.Linear(width, latent_channels * latent_size ** 2), nn.ReLU()]
        self.encoder = nn.Sequential(*layers)

        stages: list = []
        c_in = latent_channels
        for c_out in decoder_channels:
            stages += [
                nn.ConvTranspose2d(c_in, c_out, kernel_size=4, stride=2, padding=1, bias=False),
                nn.BatchNorm2d(c_out), nn.ReLU(),
                nn.Conv2d(c_out, c_out, kernel_size=3, padding=1, bias=False),
                nn.BatchNorm2d(c_out), nn.ReLU(),
            ]
            c_in = c_out
        stages.append(nn.Conv2d(c_in, 1, kernel_size=3, padding=1))
        self.decoder = nn.Sequential(*stages)
        # The paper's appended layer: rescale the native (64 x 64) output to the sensor's image grid.
        self.resize = (nn.Identity() if image_size == self.native_size else
                       nn.Upsample(size=(image_size, image_size), mode="bilinear", align_corners=False))

    def config(self) -> dict:
        """Constructor arguments (JSON-serializable) that rebuild this architecture; the buffers
        ``input_mean``/``input_std`` travel with the ``state_dict``."""
        return dict(self._config)

    def forward(self, x):
        check_input(x, (self.n_meas,), "frames")
        z = self.encoder(self.standardize(x))
        # Channels-last activations let oneDNN pick its fast kernels for these few-channel convolutions:
        # 2.5x faster training on this CPU than the default layout (benchmarks/bench_learn.py); same results.
        img = self.decoder(z.view(-1, *self._latent_shape).contiguous(memory_format=torch.channels_last))
        return self.resize(img)[:, 0]
