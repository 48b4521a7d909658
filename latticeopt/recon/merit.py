"""GREIT figures of merit (Adler et al., Physiol. Meas. 30 (2009) S35) and their maps over the sensor.

The five figures are computed as EIDORS' ``eval_GREIT_fig_merit`` defines them, on an image whose target lobe
is made positive (multiplied by the sign of the target's contrast):

- the *quarter-maximum set* is the pixels at or above 1/4 of the image's maximum;
- **amplitude**: the sum of the image over every pixel, times the pixel area (mm², of the normalized change);
  :func:`greit_figures` also gives it relative to the target nearest the sensor's centre;
- **position error** (mm): the target's distance from the sensor's centre minus that of the quarter-maximum
  set's centroid (positive: the image sits towards the centre); ``position_offset_mm`` is the plain distance
  between target and centroid;
- **resolution**: the square root of the quarter-maximum set's area over the image area (the sensor);
- **shape deformation**: the fraction of the quarter-maximum set outside the circle of equal area centred on
  its centroid;
- **ringing**: minus the opposite-sign image outside the quarter-maximum set, over the image inside it.

GREIT asks for small amplitude, position-error, resolution and shape-deformation *variation* across the
domain, and small ringing. :func:`merit_map` reconstructs small conductivity targets on a grid across the
sensor (nonlinear forward solves of the sensor model, then one-step Tikhonov) and maps every figure.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import _validate as v
from ..captions import layout_caption, mesh_caption
from ..errors import ParameterError
from ..sensor_model import SensorModel

#: Largest relative voltage change (noise-free) below which a target counts as unseen (it lies on silicone).
NO_RESPONSE = 1e-9
KEYS = ("amplitude", "amplitude_rel", "position_error_mm", "position_offset_mm", "resolution",
        "shape_deformation", "ringing")
LABELS = {"amplitude_rel": "amplitude (rel. to centre)", "position_error_mm": "position error (mm)",
          "resolution": "resolution", "shape_deformation": "shape deformation", "ringing": "ringing"}


def greit_figures(images: np.ndarray, targets_xy_mm: np.ndarray, extent_mm, contrast: np.ndarray | float = -1.0
                  ) -> dict[str, np.ndarray]:
    """GREIT figures of merit of single-target images.

    Parameters
    ----------
    images : array, shape (k, n, n)
        Reconstructed normalized changes, row ``iy``, column ``ix``, over ``extent_mm``.
    targets_xy_mm : array, shape (k, 2)
        Centre of each image's target (mm).
    extent_mm
        ``(x0, x1, y0, y1)`` of the pixel grid (the sensor).
    contrast : float or array of shape (k,)
        Sign (or value) of each target's conductivity change; the image is flipped so the target is positive.

    Returns
    -------
    dict
        :data:`KEYS` -> array of shape (k,) (see the module docstring). ``amplitude_rel`` divides by the
        amplitude of the target nearest the centre.
    """
    img = np.asarray(images, dtype=float)
    if img.ndim != 3 or img.shape[1] != img.shape[2]:
        raise ValueError(f"images must have shape (k, n, n), got {img.shape}")
    k, n, _ = img.shape
    xy = np.asarray(targets_xy_mm, dtype=float).reshape(k, 2)
    img = img * np.sign(np.broadcast_to(np.asarray(contrast, dtype=float), (k,)))[:, None, None]
    x0, x1, y0, y1 = (float(e) for e in extent_mm)
    hx, hy = (x1 - x0) / n, (y1 - y0) / n
    X, Y = np.meshgrid(x0 + (np.arange(n) + 0.5) * hx, y0 + (np.arange(n) + 0.5) * hy)
    centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2])
    out = {key: np.full(k, np.nan) for key in KEYS}
    for i in range(k):
        im = img[i]
        peak = im.max()
        if not peak > 0:  # no positive lobe: nothing to measure
            continue
        qm = im >= 0.25 * peak
        cx, cy = X[qm].mean(), Y[qm].mean()
        out["amplitude"][i] = im.sum() * hx * hy
        out["position_error_mm"][i] = np.hypot(*(xy[i] - centre)) - np.hypot(cx - centre[0], cy - centre[1])
        out["position_offset_mm"][i] = np.hypot(xy[i, 0] - cx, xy[i, 1] - cy)
        out["resolution"][i] = np.sqrt(qm.sum() / qm.size)
        radius2 = qm.sum() * hx * hy / np.pi
        out["shape_deformation"][i] = np.sum(qm & ((X - cx) ** 2 + (Y - cy) ** 2 >= radius2)) / qm.sum()
        out["ringing"][i] = -im[(im < 0) & ~qm].sum() / im[qm].sum()
    ref = int(np.argmin(np.hypot(*(xy - centre).T)))
    out["amplitude_rel"] = out["amplitude"] / out["amplitude"][ref]
    return out


@dataclass(frozen=True, eq=False)
class MeritMap:
    """GREIT figures over a ``m x m`` grid of targets.

    Attributes
    ----------
    targets_mm : ndarray, shape (m * m, 2)
        Target centres, row-major over ``y`` then ``x``.
    figures : dict
        :data:`KEYS` -> ndarray, shape (m, m) (row ``iy``).
    images : ndarray, shape (m * m, n, n)
        The reconstructions.
    settings : dict
        Target diameter, contrast ratio, method, prior, lambda rule, SNR.
    """

    targets_mm: np.ndarray
    figures: dict
    images: np.ndarray
    settings: dict
    summary: dict = field(init=False)

    def __post_init__(self) -> None:
        def stats(a: np.ndarray) -> dict:
            a = a[np.isfinite(a)]  # unseen targets (NaN) left out
            if a.size == 0:
                return dict.fromkeys(("mean", "std", "min", "max"), float("nan"))
            return {"mean": float(a.mean()), "std": float(a.std()), "min": float(a.min()), "max": float(a.max())}

        object.__setattr__(self, "summary", {k: stats(a) for k, a in self.figures.items()})


def target_grid(model: SensorModel, m: int, diameter_mm: float) -> np.ndarray:
    """``m x m`` target centres from one diameter inside the sensor's edge to the other, shape ``(m * m, 2)``."""
    x0, x1, y0, y1 = model.extent_mm
    xs = np.linspace(x0 + diameter_mm, x1 - diameter_mm, m)
    ys = np.linspace(y0 + diameter_mm, y1 - diameter_mm, m)
    X, Y = np.meshgrid(xs, ys)
    return np.stack([X.ravel(), Y.ravel()], axis=1)


def merit_map(model: SensorModel, targets: int = 7, diameter_mm: float | None = None, ratio: float = 0.5,
              prior: str = "laplacian", lam="lcurve", snr_db: float | None = None, jobs: int = 1,
              progress: bool = False, seed: int = 0) -> MeritMap:
    """Reconstruct a small disc at each of ``targets x targets`` places and map the GREIT figures.

    Parameters
    ----------
    model
        The exported sensor model.
    targets
        Targets per side (2-25).
    diameter_mm
        Target diameter (mm); default the lattice pitch. GREIT uses 5 % of the domain's width, but on a lattice
        a target smaller than the pitch can fall on silicone and change nothing (its figures are NaN).
    ratio
        Target conductivity over ``sigma0`` (0 < ratio, != 1).
    prior, lam
        One-step Tikhonov's prior and lambda rule (:class:`~latticeopt.recon.classical.LinearReconstructor`).
    snr_db
        Noise added to the frames (None: noise-free).
    jobs, progress
        Forward-solve workers and a progress bar.
    """
    from ..sensor_simulator import SensorSimulator
    from .classical import LinearReconstructor
    from .dataset import add_noise, relative_change, render_touches

    m = v.integer("targets", targets, lo=2, hi=25)
    L = min(model.extent_mm[1] - model.extent_mm[0], model.extent_mm[3] - model.extent_mm[2])
    d = v.real("diameter_mm", model.design.pitch_mm if diameter_mm is None else diameter_mm, lo=0, lo_open=True,
               hi=L / 3)
    r = v.real("ratio", ratio, lo=0, lo_open=True, hi=100)
    if r == 1:
        raise ParameterError("ratio", "a target conductivity ratio other than 1", r)
    lin = LinearReconstructor(model, prior)  # checks the prior before any solve
    xy = target_grid(model, m, d)
    sigma = np.stack([render_touches(np.array([[x, y, d, r]]), model.sigma0_S_per_m, model.n_pixels,
                                     model.extent_mm) for x, y in xy])
    V = SensorSimulator(model).voltages(sigma, jobs=jobs, progress=progress)
    y = y_clean = relative_change(V, model.v_ref)
    if snr_db is not None:
        y = relative_change(add_noise(V, v.real("snr_db", snr_db), np.random.default_rng(seed)), model.v_ref)
    images, _ = lin.solve(y, lam)
    images = images.reshape(len(xy), model.n_pixels, model.n_pixels)
    figs = greit_figures(images, xy, model.extent_mm, contrast=r - 1)
    silent = np.max(np.abs(y_clean), axis=1) < NO_RESPONSE
    for a in figs.values():  # a target on silicone changes nothing: no image to score
        a[silent] = np.nan
    return MeritMap(targets_mm=xy, figures={k: a.reshape(m, m) for k, a in figs.items()}, images=images,
                    settings={"targets": m, "diameter_mm": d, "ratio": r, "prior": prior, "lambda": lam,
                              "snr_db": snr_db, "layout": _layout(model.design),
                              "mesh": mesh_caption(model.mesh_settings)})


def _layout(design) -> str:
    return layout_caption([design]) + (f", w = {design.width_mm:g} mm" if design.has_lattice else "")


def plot_merit_map(result: MeritMap, path: str | Path, title: str | None = None) -> Path:
    """Five panels, one per GREIT figure, coloured over the target grid (the uniformity maps)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    xy = result.targets_mm
    xs, ys = np.unique(xy[:, 0]), np.unique(xy[:, 1])
    hx = (xs[1] - xs[0]) / 2 if len(xs) > 1 else 1.0
    hy = (ys[1] - ys[0]) / 2 if len(ys) > 1 else 1.0
    extent = (xs[0] - hx, xs[-1] + hx, ys[0] - hy, ys[-1] + hy)
    fig, axes = plt.subplots(1, len(LABELS), figsize=(3.3 * len(LABELS), 3.9), constrained_layout=True)
    for ax, (key, label) in zip(axes, LABELS.items(), strict=True):
        a = result.figures[key]
        s = result.summary[key]
        im = ax.imshow(a, origin="lower", extent=extent, cmap="viridis")
        fig.colorbar(im, ax=ax, shrink=0.8)
        ax.set_title(f"{label}\nmean {s['mean']:.3g}, sd {s['std']:.2g}", fontsize=9)
        ax.set_xlabel("x (mm)")
        ax.set_aspect("equal")
    axes[0].set_ylabel("y (mm)")
    st = result.settings
    noise = "noise-free" if st.get("snr_db") is None else f"SNR {st['snr_db']:g} dB"
    default = (f"GREIT figures over {st['targets'] ** 2} targets ({st['targets']} x {st['targets']}) of "
               f"{st['diameter_mm']:g} mm, sigma/sigma0 = {st['ratio']:g}, one-step Tikhonov ({st['prior']}, "
               f"lambda {st['lambda']}), {noise}")
    if "layout" in st:  # the sensor the targets were imaged on
        default += f"\n{st['layout']}; {st['mesh']}"
    fig.suptitle(title or default, fontsize=10)
    path = Path(path)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
