"""Frames of real presses for reconstruction: the coupled simulation of the exported design, against the
conductivity discs the training data and the paper's data set model a touch as.

A press changes the voltages through the deformed channels; a disc through a changed conductivity. For each
reconstructor :func:`press_gap` reconstructs both at the same places (a disc of the punch's diameter) and
reports the GREIT figures of each and the correlation between the two images: how far what a method learned or
assumes from discs carries over to presses.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .. import _validate as v
from ..learn.metrics import correlation_coefficient
from ..sensor_model import SensorModel
from .merit import greit_figures


def random_presses(n: int, size_mm: float, seed: int = 0, radius_mm=(6.25, 8.75), depth_mm=(1.0, 4.0)
                   ) -> np.ndarray:
    """``n`` single presses ``(x_mm, y_mm, radius_mm, depth_mm)`` with the punch inside the sensor, shape (n, 4);
    radius and depth uniform in the given ranges (the paper's punch radii and depths by default)."""
    n = v.integer("presses", n, lo=1, hi=10_000)
    rng = np.random.default_rng(seed)
    r = rng.uniform(*radius_mm, n)
    xy = rng.uniform(r[:, None], size_mm - r[:, None], (n, 2))
    return np.column_stack([xy, r, rng.uniform(*depth_mm, n)])


def press_frames(model: SensorModel, presses: np.ndarray, physics=None, progress: bool = False
                 ) -> np.ndarray:
    """Relative voltage changes ``V / V_ref - 1`` of each press (coupled mechanics and electrics on the
    design's mesh at the model's mesh settings), shape (k, n_rows); rows of failed presses are NaN.

    The relative change does not depend on the background conductivity (the export keeps ``z_c sigma``), so
    these frames go with the sensor model's Jacobian as they are.
    """
    from ..coupled import CoupledModel
    from ..errors import ModelFailure
    from ..mesh import MeshSettings
    from ..touches import Touch

    cm = CoupledModel(model.design, MeshSettings(**model.mesh_settings), physics)
    out = np.full((len(presses), model.n_rows), np.nan)
    it = range(len(presses))
    if progress:
        from tqdm import tqdm

        it = tqdm(it, desc="coupled presses", unit="press")
    for i in it:
        x, y, r, d = presses[i]
        try:
            res = cm.simulate([Touch(x_mm=x, y_mm=y, radius_mm=r, depth_mm=d)])
        except ModelFailure:
            continue
        out[i] = res.voltages / res.reference_voltages - 1
    return out


def disc_frames(model: SensorModel, presses: np.ndarray, ratio: float) -> np.ndarray:
    """Relative changes of a conductivity disc of each punch's footprint (``ratio`` sigma0), shape (k, n_rows)."""
    from ..sensor_simulator import SensorSimulator
    from .dataset import relative_change, render_touches

    sigma = np.stack([render_touches(np.array([[x, y, 2 * r, ratio]]), model.sigma0_S_per_m, model.n_pixels,
                                     model.extent_mm) for x, y, r, _ in presses])
    return relative_change(SensorSimulator(model).voltages(sigma), model.v_ref)


def press_gap(model: SensorModel, presses: np.ndarray, reconstructors: dict[str, Callable], press_y: np.ndarray,
              ratio: float = 0.5) -> dict:
    """GREIT figures of press and disc images per reconstructor, and their image correlation.

    Parameters
    ----------
    reconstructors
        name -> function of relative changes ``(k, n_rows)`` returning images ``(k, n, n)``.
    press_y
        :func:`press_frames` of ``presses`` (NaN rows are left out).
    ratio
        The discs' conductivity over sigma0; the sign of ``ratio - 1`` orients the press images as well (a
        press thins the channels, which acts like a less conductive disc).

    Returns
    -------
    dict
        name -> ``{"press": mean figures, "disc": mean figures, "cc": mean correlation, "n": presses}``.
    """
    ok = np.all(np.isfinite(press_y), axis=1)
    p, yp = presses[ok], press_y[ok]
    yd = disc_frames(model, p, ratio)
    out = {}
    for name, fn in reconstructors.items():
        ip, idisc = fn(yp), fn(yd)
        cc = correlation_coefficient(ip, idisc)
        out[name] = {"n": int(len(p)), "cc": float(np.nanmean(cc)) if np.isfinite(cc).any() else float("nan")}
        for label, images in (("press", ip), ("disc", idisc)):
            if not np.any(images):
                out[name][label] = {}
                continue
            figs = greit_figures(images, p[:, :2], model.extent_mm, contrast=ratio - 1)
            out[name][label] = {k: float(np.nanmean(f)) for k, f in figs.items()}
    return out
