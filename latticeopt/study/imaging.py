"""The ``image_cc`` objective term: one-step images of the probe presses against their footprints.

What a user of the sensor finally sees is an image, so besides V_rel statistics a design can be scored on the
images its presses give. For each probe press (:meth:`latticeopt.optimize.objectives.Objective.probes`: one punch
per cell of an ``n x n`` grid, simulated by the coupled model through the results store like any phantom):

1. the relative change ``y = V / V_ref - 1`` of the press's stored touched voltages ``V``;
2. its one-step Tikhonov image (:class:`latticeopt.recon.classical.LinearReconstructor`) with the design's own
   pixel Jacobian (:func:`latticeopt.sensor_model.build_sensor_model` of the design at the study's mesh settings,
   48 x 48 pixels over the sensor);
3. its true image, the press's footprint: a disc of the punch radius at the press centre, as a conductivity
   *decrease* (a press thins the channels under it, which acts like a less conductive disc: the disc
   :func:`latticeopt.recon.presses.footprint_sigma` that ``press_gap`` and ``recon-train --presses`` use; the
   correlation does not depend on the disc's level, only on its sign);
4. the Pearson correlation of the two (:func:`latticeopt.learn.metrics.correlation_coefficient`) and, beside it,
   GREIT's position error in mm (:func:`latticeopt.recon.merit.greit_figures`, signed: positive when the image
   sits towards the centre) and the plain distance between footprint centre and image centroid.

Reference voltages. ``V_ref`` must be the untouched voltages of the *same* mesh as the coupled solve, or ``y``
holds mesh differences rather than the press. The sensor model is built from the same design, the same
:class:`~latticeopt.mesh.MeshSettings` and the study's own ``[physics]`` conductivity, contact impedance and
current, so its ``v_ref`` is the coupled model's ``reference_voltages`` (the same forward model on the same
hydrogel mesh; ``tests/test_imaging.py`` checks they agree).

Regularization: a *fixed* lambda relative to the largest eigenvalue of the design's ``A P^-1 A^T``
(:attr:`Objective.image_lambda`, default 1e-3; prior :attr:`Objective.image_prior`, default ``"laplacian"``).

* Fixed, not the L-curve per frame: on the noise-free probe frames of one design (w = 3, t = 3 mm, 4 mm mesh,
  3 x 3 probes) the L-curve corner ranged over four decades (1e-8.7 to 1e-4.4 of the largest eigenvalue, with
  the Laplacian prior) from one probe to the next, and it moves on a discrete grid; the score would then measure
  where a corner rule lands and jump as a design moves, a poor objective for a local optimizer and an unequal
  treatment of designs. A fixed value applies the same filter to every design.
* Relative, not absolute: a design whose sensitivities were all twice as large gets the same images, so
  ``image_cc`` scores the *pattern* of sensitivity (what the image can resolve) and leaves its magnitude to
  the V_rel terms, instead of counting it twice.
* 1e-3: with 40 dB noise on those frames (the low end of the paper's 35-65 dB) the L-curve corner lay at
  1e-3.0 to 1e-2.8 on every probe, so the score is that of the images a real measurement supports. Noise-free
  frames would favour ever smaller lambda; the frames are noise-free here so the score is deterministic.

The sensor model and reconstructor of a design are built once per run (:class:`ReconstructorCache`, about
1 s at the 4 mm mesh), not once per evaluation.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Sequence

import numpy as np

from ..design import LatticeDesign
from ..errors import LatticeoptError
from .phantoms import Phantom
from .settings import EvalSettings

__all__ = ["FIGURES", "ReconstructorCache", "build_reconstructor", "footprint_figures", "footprints",
           "probe_image_figures", "probe_presses"]

#: Figures reported beside ``image_cc`` (means over the probes, mm).
FIGURES = ("position_error_mm", "position_offset_mm")


def probe_presses(probes: Sequence[Phantom]) -> np.ndarray:
    """``(x_mm, y_mm, radius_mm, depth_mm)`` of every single-touch probe, shape ``(m, 4)``."""
    rows = []
    for p in probes:
        if p.n_touches != 1:
            raise LatticeoptError(f"image_cc scores single presses; probe {p.index} has {p.n_touches} touches")
        t = p.touches[0]
        rows.append((t.x_mm, t.y_mm, t.radius_mm, t.depth_mm))
    return np.asarray(rows, dtype=float).reshape(-1, 4)


def footprints(model, presses: np.ndarray) -> np.ndarray:
    """True images of presses on ``model``'s pixel grid: the normalized change ``(sigma - sigma0) / sigma0`` of
    :func:`latticeopt.recon.presses.footprint_sigma` (``PRESS_RATIO - 1`` over a disc of each punch radius at
    its centre, 0 elsewhere, sub-pixel coverage at the rim), shape ``(m, n_pixels, n_pixels)``, row ``iy``."""
    from ..recon.presses import footprint_sigma

    return footprint_sigma(model, np.asarray(presses, dtype=float).reshape(-1, 4)) / model.sigma0_S_per_m - 1.0


def footprint_figures(images: np.ndarray, presses: np.ndarray, model) -> dict[str, np.ndarray]:
    """Correlation with the footprint and GREIT position figures of each press image.

    Parameters
    ----------
    images : array, shape (m, n, n)
        Reconstructed normalized changes on ``model``'s pixel grid, finite.
    presses : array, shape (m, 4)
        ``(x_mm, y_mm, radius_mm, depth_mm)`` of each press.
    model
        The :class:`~latticeopt.sensor_model.SensorModel` whose grid the images are on.

    Returns
    -------
    dict
        ``"cc"`` (Pearson correlation with :func:`footprints`, NaN for a constant image) and :data:`FIGURES`
        (mm, NaN when the image has no lobe of the footprint's sign), each of shape ``(m,)``.
    """
    from ..learn.metrics import correlation_coefficient
    from ..recon.merit import greit_figures
    from ..recon.presses import PRESS_RATIO

    images = np.asarray(images, dtype=float)
    presses = np.asarray(presses, dtype=float).reshape(-1, 4)
    truth = footprints(model, presses)
    figs = greit_figures(images, presses[:, :2], model.extent_mm, contrast=PRESS_RATIO - 1)
    return {"cc": correlation_coefficient(images, truth), **{k: figs[k] for k in FIGURES}}


def build_reconstructor(design: LatticeDesign, settings: EvalSettings, prior: str):
    """The design's sensor model at the study's mesh and ``[physics]`` electrics, and its one-step reconstructor.

    Returns
    -------
    (SensorModel, LinearReconstructor)
        ``model.v_ref`` equals :class:`~latticeopt.coupled.CoupledModel` ``reference_voltages`` of the same
        design and settings (module docstring).
    """
    from ..recon.classical import LinearReconstructor
    from ..sensor_model import build_sensor_model

    phys = settings.physics_settings
    model = build_sensor_model(design, settings.mesh, sigma_S_per_m=phys.sigma_S_per_m,
                               contact_impedance_ohm_m2=phys.contact_impedance_ohm_m2, current_A=phys.current_A,
                               cache_dir=settings.cache_dir)
    return model, LinearReconstructor(model, prior)


class ReconstructorCache:
    """The last ``size`` designs' :func:`build_reconstructor` results, keyed by design, settings and prior.

    One lives for one optimization run, so a design assessed again (a replay after resuming, a repeated
    point) does not rebuild its Jacobian; ``built`` counts the builds.
    """

    def __init__(self, size: int = 4):
        self.size = size
        self.built = 0
        self._items: OrderedDict[tuple[str, str, str], tuple] = OrderedDict()

    def get(self, design: LatticeDesign, settings: EvalSettings, prior: str) -> tuple:
        key = (design.content_hash(), settings.key, prior)
        if key in self._items:
            self._items.move_to_end(key)
            return self._items[key]
        item = build_reconstructor(design, settings, prior)
        self.built += 1
        self._items[key] = item
        while len(self._items) > self.size:
            self._items.popitem(last=False)
        return item


def probe_image_figures(model, lin, voltages: Sequence[np.ndarray | None], presses: np.ndarray,
                        lambda_rel: float) -> dict[str, np.ndarray]:
    """:func:`footprint_figures` of the one-step images of stored press voltages.

    Parameters
    ----------
    model, lin
        From :func:`build_reconstructor`.
    voltages
        Touched voltages of every press, each shape ``(n_rows,)`` (V), ``None`` where the press failed.
    presses : array, shape (m, 4)
        The presses, in the order of ``voltages``.
    lambda_rel
        Tikhonov lambda relative to ``lin``'s largest eigenvalue.

    Returns
    -------
    dict
        ``"cc"`` and :data:`FIGURES`, each shape ``(m,)``, NaN where a press failed.
    """
    from ..recon.dataset import relative_change

    m = len(presses)
    out = {k: np.full(m, np.nan) for k in ("cc", *FIGURES)}
    ok = [i for i, V in enumerate(voltages) if V is not None]
    if not ok:
        return out
    rows = [np.asarray(voltages[i], dtype=float).ravel() for i in ok]
    for i, r in zip(ok, rows):
        if r.size != model.n_rows or not np.isfinite(r).all():
            raise LatticeoptError(f"image_cc needs {model.n_rows} finite touched voltages per probe; probe {i} has "
                                  f"{r.size} values" + ("" if np.isfinite(r).all() else " with NaN"))
    V = np.stack(rows)
    images = lin.reconstruct(relative_change(V, model.v_ref), lambda_rel * lin.eigenvalues.max())
    figs = footprint_figures(images, np.asarray(presses, dtype=float)[ok], model)
    for k, a in figs.items():
        out[k][ok] = a
    return out
