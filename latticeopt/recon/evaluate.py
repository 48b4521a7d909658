"""Compare reconstruction methods on a simulated test set: metrics per touch count and a picture.

Methods (names used by ``latticeopt recon-eval``): ``background`` (the all-background image, zero change: the
baseline every method must beat), ``tikhonov/<prior>`` (one-step Gauss-Newton at the
background), ``gn/<prior>`` (iterative Gauss-Newton, on a subset: it costs several forward solves and
Jacobians per frame) and ``dnn`` (the trained network). Metrics are CC, PSNR, SSIM and RE of
:func:`latticeopt.learn.evaluate_images` on the normalized change ``(sigma - sigma0) / sigma0``, with one data
range for the whole test set (``data_range="dataset"``); no method's images are rescaled before scoring.

Regularization of the classical methods: ``"lcurve"`` (the default) or ``"gcv"`` (per frame, the rules of
:mod:`.classical`), a number (relative to the largest eigenvalue of ``A P^-1 A^T``), or ``"validation"``:
the lambda of :data:`~latticeopt.recon.classical.GCV_GRID` with the lowest mean squared image error on the
validation part, with the test frames' noise level (a supervised choice, like the network's training, never
looking at the test part); iterative Gauss-Newton uses the one-step value.
GCV needs noise to see: on noise-free frames it drifts to the bottom of its grid.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np

from .. import _validate as v
from ..errors import ParameterError
from ..sensor_model import SensorModel, SensorSimulator
from .classical import GCV_GRID, PRIORS, GaussNewton, LinearReconstructor
from .dataset import ReconDataset, part_arrays

log = logging.getLogger(__name__)

METHODS = ("background", "tikhonov", "gn", "dnn")
LAMBDA_RULES = ("lcurve", "gcv", "validation")


def tune_lambda(lin: LinearReconstructor, y_val: np.ndarray, images_val: np.ndarray,
                grid: np.ndarray = GCV_GRID) -> float:
    """The lambda (absolute) on ``grid * max eigenvalue`` with the lowest mean squared error on validation data."""
    beta = lin._beta(y_val)
    truth = images_val.reshape(len(images_val), -1)
    best, best_err = None, np.inf
    for lam in np.asarray(grid) * lin.eigenvalues.max():
        x = (beta / (lin.eigenvalues + lam)) @ lin._M.T
        err = float(np.mean((x - truth) ** 2))
        if err < best_err:
            best, best_err = float(lam), err
    return best


def resolve_lambda(rule, lin: LinearReconstructor, data: ReconDataset | None, model: SensorModel,
                   snr_db: float | None = None):
    """Turn a rule (``"lcurve"``, ``"gcv"``, ``"validation"`` or a relative number) into what the reconstructors
    take.

    ``"validation"`` tunes on the validation part with noise of ``snr_db`` (the test frames' noise level).
    """
    if isinstance(rule, str):
        v.choice("lam", rule, LAMBDA_RULES)
        if rule in ("lcurve", "gcv"):
            return rule
        if data is None:
            raise ParameterError("lam", "'lcurve', 'gcv' or a number (no validation data given)", rule)
        y, img, _ = part_arrays(data, model, "val", snr_db=snr_db, seed=3)
        return tune_lambda(lin, y, img)
    return v.real("lam", rule, lo=0, lo_open=True) * lin.eigenvalues.max()


def parse_methods(methods, priors) -> list[str]:
    out = []
    for m in methods:
        v.choice("methods", m, METHODS)
        if m in ("dnn", "background"):
            out.append(m)
        else:
            out += [f"{m}/{v.choice('prior', p, PRIORS)}" for p in priors]
    return out


def evaluate_methods(model: SensorModel, data: ReconDataset, methods=("tikhonov", "dnn"), priors=("noser",),
                     lam="lcurve", net_path: str | Path | None = None, gn_per_count: int = 10,
                     test_snr_db: float | None = None, simulator: SensorSimulator | None = None,
                     progress: bool = False, presses: np.ndarray | None = None,
                     press_y: np.ndarray | None = None) -> dict:
    """Reconstruct the test part with every method and score it per touch count.

    Returns
    -------
    dict
        ``"methods"``: ``{name: {"overall": summary, "by_touches": {count: summary}, "n": int, "seconds":
        float, "lambda": ...}}`` (summaries from :func:`latticeopt.learn.evaluate_images`); ``"images"``:
        ``{name: (k, n, n)}`` and ``"indices"``: ``{name: test positions used}`` for figures; ``"truth"``,
        ``"n_touches"``: the test images and counts; ``"test_snr_db"``; ``"extent_mm"`` of the image grid;
        with ``presses`` (k, 4) and their frames ``press_y`` (:mod:`latticeopt.recon.presses`), ``"presses"``:
        :func:`~latticeopt.recon.presses.press_gap` of every method.
    """
    from ..learn import evaluate_images

    data.check_model(model)
    names = parse_methods(methods, priors)
    y, truth, counts = part_arrays(data, model, "test", snr_db=test_snr_db)
    touches = data.touches[data.test]
    gn_idx = np.concatenate([np.flatnonzero(counts == c)[:gn_per_count] for c in np.unique(counts)])
    out: dict = {"methods": {}, "images": {}, "indices": {}, "truth": truth, "n_touches": counts,
                 "test_snr_db": test_snr_db, "extent_mm": tuple(model.extent_mm)}
    linear, fns = {}, {}
    shape = (model.n_pixels, model.n_pixels)
    for name in names:
        t0 = time.perf_counter()
        kind, _, prior = name.partition("/")
        idx = gn_idx if kind == "gn" else np.arange(len(y))
        lam_used = None
        if kind == "background":
            images = np.zeros_like(truth)
            fns[name] = lambda yy: np.zeros((len(yy), *shape))
        elif kind == "dnn":
            if net_path is None:
                raise ParameterError("--net", "a trained network file for method 'dnn'", None)
            from .dnn import DNNReconstructor

            fns[name] = DNNReconstructor(net_path, model).reconstruct
            images = fns[name](y)
        else:
            lin = linear.get(prior) or LinearReconstructor(model, prior)
            linear[prior] = lin
            lam_k = resolve_lambda(lam, lin, data, model, test_snr_db)
            if kind == "tikhonov":
                images, lam_used = lin.solve(y, lam_k)
                images = images.reshape(truth.shape)
                fns[name] = lambda yy, lin=lin, lam_k=lam_k: lin.solve(yy, lam_k)[0].reshape(len(yy), *shape)
            else:
                sim = simulator or SensorSimulator(model)
                simulator = sim
                res = GaussNewton(sim, prior).reconstruct(y[idx], lam_k, progress=progress)
                images, lam_used = res.images, res.lam
                fns[name] = lambda yy, sim=sim, prior=prior, lam_k=lam_k: GaussNewton(sim, prior).reconstruct(
                    yy, lam_k).images
        seconds = time.perf_counter() - t0
        scores = evaluate_images(images, truth[idx], groups=counts[idx],
                                 data_range=float(truth.max() - truth.min()))
        entry = {"overall": scores["mean"], "by_touches": scores["by_group"], "n": int(len(idx)),
                 "seconds": seconds, "seconds_per_frame": seconds / len(idx),
                 "greit": _single_touch_greit(images, touches[idx], counts[idx], model.extent_mm)}
        if lam_used is not None:
            rel = np.asarray(lam_used) / linear[prior].eigenvalues.max()
            entry["lambda_relative"] = {"rule": lam if isinstance(lam, str) else "fixed",
                                        "median": float(np.median(rel)), "min": float(rel.min()),
                                        "max": float(rel.max())}
        out["methods"][name] = entry
        out["images"][name] = images
        out["indices"][name] = idx
        log.info("%s: %d frames in %.1f s, CC %.3f", name, len(idx), seconds, scores["mean"]["cc"])
    if presses is not None:
        from .presses import press_gap

        out["presses"] = press_gap(model, presses, fns, press_y)
    return out


def _single_touch_greit(images: np.ndarray, touches: np.ndarray, counts: np.ndarray, extent_mm) -> dict:
    """Mean GREIT figures (:mod:`latticeopt.recon.merit`) over the one-touch frames, with their count ``n``."""
    from .merit import greit_figures

    one = np.flatnonzero(counts == 1)
    if len(one) == 0 or not np.any(images[one]):
        return {"n": int(len(one))}
    figs = greit_figures(images[one], touches[one, 0, :2], extent_mm, contrast=touches[one, 0, 3] - 1)
    return {"n": int(len(one)), **{k: float(np.nanmean(a)) for k, a in figs.items()}}


#: Colour-bar label of every image: the normalized conductivity change, dimensionless.
CHANGE_LABEL = r"$(\sigma - \sigma_0)\,/\,\sigma_0$ (1)"


def _limit(images) -> float:
    """Symmetric colour limit: the largest absolute value (1 for an all-zero image, e.g. the background)."""
    lim = float(np.max(np.abs(images))) if np.size(images) else 0.0
    return lim if np.isfinite(lim) and lim > 0 else 1.0


def plot_comparison(result: dict, path: str | Path, per_count: int = 1) -> Path:
    """Ground truth beside each method's images, ``per_count`` test samples per touch count (rows).

    Every image is drawn in the unit of the data, ``(sigma - sigma0) / sigma0``, unnormalized. The panels of
    one column (one method, or the truth) share a symmetric colour scale, shown by the colour bar under the
    column: amplitudes compare down a column and, by the bars, across methods; a method that gets the
    shape right and the amplitude wrong shows it.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.ticker import MaxNLocator

    names = list(result["images"])
    counts = result["n_touches"]
    common = set(range(len(counts)))
    for name in names:
        common &= set(result["indices"][name].tolist())
    rows = [i for c in np.unique(counts) for i in sorted(j for j in common if counts[j] == c)[:per_count]]
    if not rows:
        raise ParameterError("result", "at least one test sample reconstructed by every method", "none")
    cols = ["truth", *names]
    extent = tuple(result.get("extent_mm") or (0, 100, 0, 100))
    panels = {}
    for name in cols:
        if name == "truth":
            panels[name] = [result["truth"][i] for i in rows]
        else:
            pos = [int(np.flatnonzero(result["indices"][name] == i)[0]) for i in rows]
            panels[name] = [result["images"][name][p] for p in pos]
    fig = Figure(figsize=(2.1 * len(cols), 2.0 * len(rows) + 1.2), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(len(rows), len(cols), squeeze=False)
    for c, name in enumerate(cols):
        lim = _limit(panels[name])
        for r, img in enumerate(panels[name]):
            ax = axes[r, c]
            im = ax.imshow(img, origin="lower", cmap="RdBu_r", vmin=-lim, vmax=lim, extent=extent)
            ax.set_xticks([])
            ax.set_yticks([])
            if r == 0:
                ax.set_title(name, fontsize=9)
            if c == 0:
                n = int(counts[rows[r]])
                ax.set_ylabel(f"{n} touch{'es' if n > 1 else ''}", fontsize=9)
        cb = fig.colorbar(im, ax=axes[:, c], location="bottom", shrink=0.9, aspect=12)
        cb.ax.xaxis.set_major_locator(MaxNLocator(4, symmetric=True))
        cb.ax.tick_params(labelsize=7)
        cb.set_label(CHANGE_LABEL, fontsize=8)
    snr = result.get("test_snr_db")
    fig.suptitle(f"simulated test set ({'noise-free' if snr is None else f'SNR {snr:g} dB'}); "
                 f"{extent[1] - extent[0]:g} x {extent[3] - extent[2]:g} mm; colour scale per column", fontsize=10)
    fig.get_layout_engine().set(h_pad=0.06)  # room between the suptitle and the column titles
    path = Path(path)
    fig.savefig(path, dpi=110)
    return path


def plot_images(images: np.ndarray, path: str | Path, titles=None, truth: np.ndarray | None = None,
                extent_mm=(0, 100, 0, 100)) -> Path:
    """Draw reconstructed images into a PNG, each beside its truth when ``truth`` is given.

    Parameters
    ----------
    images : ndarray, shape (k, n, n)
        Reconstructions, ``(sigma - sigma0) / sigma0``.
    path
        PNG file written.
    titles
        One title per frame (default ``frame i``).
    truth : ndarray, shape (k, n, n), optional
        Ground truth in the same unit: frame ``i`` is then a row, truth left and reconstruction right, each
        with its own colour bar (a one-step reconstruction's amplitude is seldom the truth's).
    extent_mm
        ``(x0, x1, y0, y1)`` of the image grid (mm).

    Returns
    -------
    Path
        ``path``.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    images = np.asarray(images)
    k = len(images)
    names = [f"frame {j}" for j in range(k)] if titles is None else [str(t) for t in titles]
    extent = tuple(extent_mm)

    def draw(ax, img, lim, title):
        im = ax.imshow(img, origin="lower", cmap="RdBu_r", vmin=-lim, vmax=lim, extent=extent)
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("x (mm)", fontsize=8)
        ax.set_ylabel("y (mm)", fontsize=8)
        ax.tick_params(labelsize=7)
        return im

    if truth is None:
        # One method, one unit: a shared scale and one colour bar compare the frames directly.
        fig = Figure(figsize=(3.0 * k + 1.2, 3.2), layout="constrained")
        FigureCanvasAgg(fig)
        axes = fig.subplots(1, k, squeeze=False)[0]
        lim = _limit(images)
        for j in range(k):
            im = draw(axes[j], images[j], lim, f"reconstruction, {names[j]}")
        cb = fig.colorbar(im, ax=list(axes), shrink=0.9)
        cb.set_label(CHANGE_LABEL, fontsize=9)
    else:
        truth = np.asarray(truth)
        fig = Figure(figsize=(8.0, 3.4 * k), layout="constrained")
        FigureCanvasAgg(fig)
        axes = fig.subplots(k, 2, squeeze=False)
        for j in range(k):
            for ax, img, label in ((axes[j, 0], truth[j], "truth"), (axes[j, 1], images[j], "reconstruction")):
                im = draw(ax, img, _limit(img), f"{label}, {names[j]}")
                cb = fig.colorbar(im, ax=ax, shrink=0.9)
                cb.set_label(CHANGE_LABEL, fontsize=9)
                cb.ax.tick_params(labelsize=7)
    path = Path(path)
    fig.savefig(path, dpi=110)
    return path
