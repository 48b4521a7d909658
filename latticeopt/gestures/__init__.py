"""Touch-gesture sequences for the paper's classification experiment (§VII), simulated with a sensor model.

:mod:`.trajectories` draws the documented space-time trajectory of each of the 12 gestures (touch discs:
centres, radii, conductivity change per frame); :mod:`.simulate` turns them into 15-frame x 104-measurement
sequences through the exported sensor model's forward solve, with noise and slow baseline drift, and caches
datasets on disk (:func:`default_cache_dir`: the user cache folder). See ``docs/gestures.md``. No torch
here; the classifiers live in :mod:`latticeopt.learn`.
"""

from .simulate import (
    GestureDataset,
    MeasurementConfig,
    default_cache_dir,
    generate_gestures,
    measured_frames,
    sequence_images,
)
from .trajectories import GESTURES, MAX_TOUCHES, N_FRAMES, GestureConfig, Trajectory, envelope, trajectory

__all__ = ["GESTURES", "MAX_TOUCHES", "N_FRAMES", "GestureConfig", "GestureDataset", "MeasurementConfig",
           "Trajectory", "default_cache_dir", "envelope", "generate_gestures", "measured_frames", "sequence_images",
           "trajectory"]
