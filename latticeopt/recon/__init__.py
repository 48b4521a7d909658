"""Tactile image reconstruction from an exported sensor model (paper §V).

>>> import numpy as np
>>> from latticeopt import LatticeDesign, MeshSettings
>>> from latticeopt.sensor_model import SensorSimulator, build_sensor_model, load_sensor_model
>>> from latticeopt.recon import LinearReconstructor, read_frames, relative_change, render_touches
>>> model = build_sensor_model(LatticeDesign(), MeshSettings(size_mm=6), cache_dir=False)
>>> disc = render_touches(np.array([[30.0, 65.0, 20.0, 0.3]]), model.sigma0_S_per_m, model.n_pixels)
>>> y = relative_change(SensorSimulator(model).voltages(disc), model.v_ref)   # one simulated frame
>>> LinearReconstructor(model, "noser").reconstruct(y).shape
(1, 48, 48)

Real data: ``model = load_sensor_model("sensor.npz")`` (written by ``latticeopt export``) and
``y = relative_change(read_frames("frames.csv", model.protocol), model.v_ref)``.

Modules: :mod:`.classical` (one-step Gauss-Newton / Tikhonov with identity, NOSER and Laplacian priors, GCV,
iterative Gauss-Newton), :mod:`.frames` (CSV/NPY frames of a real 16-electrode system), :mod:`.dataset`
(the paper's simulated training data), :mod:`.augment` (eight-fold symmetry of the square sensor), :mod:`.dnn`
(the learned reconstructor through :mod:`latticeopt.learn`; needs PyTorch), :mod:`.evaluate` (metrics per touch
count and comparison figures). Torch is imported only when a network is trained or applied.
"""

from .augment import SQUARE_GROUP, Symmetry, square_symmetries
from .classical import PRIORS, GaussNewton, LinearReconstructor
from .dataset import DatasetConfig, ReconDataset, add_noise, generate_dataset, relative_change, render_touches
from .frames import read_frames, reference_frame

__all__ = ["PRIORS", "SQUARE_GROUP", "DatasetConfig", "GaussNewton", "LinearReconstructor", "ReconDataset",
           "Symmetry", "add_noise", "generate_dataset", "read_frames", "reference_frame", "relative_change",
           "render_touches", "square_symmetries"]
