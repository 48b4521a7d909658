"""Frames of real presses for reconstruction: the coupled simulation of the exported design, against the
conductivity discs the training data and the paper's data set model a touch as.

A press changes the voltages through the deformed channels; a disc through a changed conductivity. For each
reconstructor :func:`press_gap` reconstructs both at the same places (a disc of the punch's diameter) and
reports the GREIT figures of each and the correlation between the two images: how far what a method learned or
assumes from discs carries over to presses. :func:`with_presses` adds such presses to a dataset's training part,
with that footprint disc as their target image, so that a network also learns from frames of real presses.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from .. import _validate as v
from ..learn.metrics import correlation_coefficient
from ..sensor_model import SensorModel
from .merit import greit_figures

log = logging.getLogger(__name__)

#: Conductivity over sigma0 of the disc that stands for a press (its footprint): the reference of
#: :func:`press_gap` and the target image of a press in training. A press thins the channels, which acts like a
#: less conductive disc.
PRESS_RATIO = 0.5


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


def footprint_sigma(model: SensorModel, presses: np.ndarray, ratio: float = PRESS_RATIO) -> np.ndarray:
    """Pixel conductivity (S/m) of a disc of each punch's footprint (its diameter, ``ratio`` sigma0) on the
    model's image grid, shape (k, n, n)."""
    from .dataset import render_touches

    return np.stack([render_touches(np.array([[x, y, 2 * r, ratio]]), model.sigma0_S_per_m, model.n_pixels,
                                    model.extent_mm) for x, y, r, _ in np.asarray(presses, dtype=float)])


def disc_frames(model: SensorModel, presses: np.ndarray, ratio: float) -> np.ndarray:
    """Relative changes of a conductivity disc of each punch's footprint (``ratio`` sigma0), shape (k, n_rows)."""
    from ..sensor_simulator import SensorSimulator
    from .dataset import relative_change

    return relative_change(SensorSimulator(model).voltages(footprint_sigma(model, presses, ratio)), model.v_ref)


def press_gap(model: SensorModel, presses: np.ndarray, reconstructors: dict[str, Callable], press_y: np.ndarray,
              ratio: float = PRESS_RATIO) -> dict:
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


def with_presses(data, model: SensorModel, n: int, seed: int = 0, *, progress: bool = False):
    """``data`` with ``n`` random single presses (:func:`random_presses` of ``seed``) in its training part.

    Each press is simulated once by :func:`press_frames` (the coupled model at its default physics) and its
    target image is the normalized change of its footprint disc (:func:`footprint_sigma`, :data:`PRESS_RATIO`),
    the disc :func:`press_gap` compares presses with. Validation and test parts stay discs only.

    Parameters
    ----------
    data : latticeopt.recon.dataset.ReconDataset
        Dataset simulated with ``model``.
    model
        The sensor model of ``data``.
    n
        Number of presses, ``0 <= n <= 10000``; 0 gives ``data`` without presses.
    seed
        Seed of the presses.
    progress
        tqdm progress bar over the coupled solves.

    Returns
    -------
    latticeopt.recon.dataset.ReconDataset
        ``data`` itself when it already holds exactly these presses (nothing is simulated again), else a copy
        with new :class:`~latticeopt.recon.dataset.PressSamples`.
    """
    from .dataset import PressSamples, normalized_change

    n = v.integer("presses", n, lo=0, hi=10_000)
    seed = v.integer("press_seed", seed, lo=0)
    data.check_model(model)
    if n == 0:
        return data if data.presses is None else replace(data, presses=None)
    wanted = random_presses(n, model.design.size_mm, seed)
    if data.presses is not None and np.array_equal(data.presses.presses, wanted):
        log.info("reusing the %d presses (seed %d) stored with the dataset", n, seed)
        return data
    y = press_frames(model, wanted, progress=progress)
    failed = int(np.sum(~np.all(np.isfinite(y), axis=1)))
    if failed:
        log.warning("%d of %d presses failed to solve; they are left out of training", failed, n)
    images = normalized_change(footprint_sigma(model, wanted), model.sigma0_S_per_m)
    return replace(data, presses=PressSamples(wanted, y, images, seed))
