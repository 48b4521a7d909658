"""Image-reconstruction and classification metrics (numpy, scikit-image, matplotlib; no torch).

Image metrics follow the paper (§V; wang2004image, yu2024high), per sample and aggregated:

* **CC**, Pearson correlation coefficient of the pixel values of prediction and truth (1 = same pattern up to
  an affine map; undefined, reported as NaN, when either image is constant, e.g. an all-background frame);
* **PSNR** from :func:`skimage.metrics.peak_signal_noise_ratio` (infinite for identical images);
* **SSIM** from :func:`skimage.metrics.structural_similarity` with Wang et al.'s settings (Gaussian window
  sigma 1.5, population covariances, K1 = 0.01, K2 = 0.03); images need at least 11 x 11 pixels;
* **RE**, relative image error ``||pred - true||_F / ||true||_F`` (infinite or NaN when the true image is
  all zero; use images whose background is not the zero of the scale, or ignore those samples).

PSNR and SSIM depend on ``data_range``, the dynamic range of the images. The default ``"dataset"`` uses the
range of *all* true images evaluated together (``max - min`` over the set), the same number for every
sample: the per-sample range is zero for empty frames and would make one sample's score depend on its own
contrast. ``"sample"`` uses each true image's own range; a number fixes it (e.g. the physical range of
the normalized conductivity change). State the choice with results; scores are only comparable with the
same choice.

The paper reports the best phantom's values ("CC up to 0.9275, RE as low as 0.3798"); the summaries here give
means (NaN samples ignored, their count reported) and the best values, overall and per group (e.g. touch
count).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .. import _validate as v
from ..errors import ParameterError
from ._torch import require_module

IMAGE_METRICS = ("cc", "psnr", "ssim", "re")
#: Better direction of each metric: +1 larger is better, -1 smaller is better.
BETTER = {"cc": 1, "psnr": 1, "ssim": 1, "re": -1}
#: Wang et al. (2004) SSIM settings.
SSIM_KWARGS = dict(gaussian_weights=True, sigma=1.5, use_sample_covariance=False, K1=0.01, K2=0.03)
_SSIM_MIN_SIDE = 11  # Gaussian window of sigma 1.5 truncated at 3.5 sigma


def _images(name: str, a) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    if a.ndim == 2:
        a = a[None]
    if a.ndim != 3 or a.shape[0] == 0:
        raise ParameterError(name, "images of shape (n, height, width) or (height, width)", a.shape)
    if not np.all(np.isfinite(a)):
        raise ParameterError(name, "finite pixel values", "NaN or infinite values")
    return a


def correlation_coefficient(pred: np.ndarray, true: np.ndarray) -> np.ndarray:
    """Pearson CC over pixels of each image pair, shape ``(n,)``; NaN where an image is constant."""
    p, t = _images("pred", pred), _images("true", true)
    if p.shape != t.shape:
        raise ParameterError("true", f"the shape of pred {p.shape}", t.shape)
    p, t = p.reshape(len(p), -1), t.reshape(len(t), -1)
    # Exact test for constant images: centring a constant leaves rounding noise whose "correlation" is garbage.
    constant = (p.max(axis=1) == p.min(axis=1)) | (t.max(axis=1) == t.min(axis=1))
    p = p - p.mean(axis=1, keepdims=True)
    t = t - t.mean(axis=1, keepdims=True)
    denom = np.sqrt((p * p).sum(axis=1) * (t * t).sum(axis=1))
    cc = (p * t).sum(axis=1) / np.where(constant, 1.0, denom)
    return np.where(constant, np.nan, np.clip(cc, -1.0, 1.0))


def relative_error(pred: np.ndarray, true: np.ndarray) -> np.ndarray:
    """``||pred - true||_F / ||true||_F`` per image pair, shape ``(n,)``."""
    p, t = _images("pred", pred), _images("true", true)
    if p.shape != t.shape:
        raise ParameterError("true", f"the shape of pred {p.shape}", t.shape)
    num = np.sqrt(((p - t) ** 2).sum(axis=(1, 2)))
    den = np.sqrt((t * t).sum(axis=(1, 2)))
    with np.errstate(invalid="ignore", divide="ignore"):
        return num / den


def _data_ranges(true: np.ndarray, data_range) -> np.ndarray:
    if isinstance(data_range, str):
        v.choice("data_range", data_range, ("dataset", "sample"))
        if data_range == "dataset":
            r = np.full(len(true), float(true.max() - true.min()))
        else:
            r = true.max(axis=(1, 2)) - true.min(axis=(1, 2))
        if np.any(r <= 0):
            raise ParameterError("data_range", "'dataset'/'sample' with non-constant true images, or a number",
                                 f"{data_range!r} with constant true image(s) {np.flatnonzero(r <= 0)[:5].tolist()}")
        return r
    return np.full(len(true), v.real("data_range", data_range, lo=0, lo_open=True,
                                     expected="'dataset', 'sample' or a positive number"))


def _summary(values: dict[str, np.ndarray]) -> dict:
    out: dict = {"n": int(len(values["cc"]))}
    for name in IMAGE_METRICS:
        x = values[name]
        finite_or_inf = x[~np.isnan(x)]
        out[name] = float(np.mean(finite_or_inf)) if finite_or_inf.size else float("nan")
        out[f"best_{name}"] = (float(finite_or_inf.max() if BETTER[name] > 0 else finite_or_inf.min())
                               if finite_or_inf.size else float("nan"))
        out[f"n_nan_{name}"] = int(np.isnan(x).sum())
    return out


def evaluate_images(pred: np.ndarray, true: np.ndarray, *, data_range: str | float = "dataset",
                    groups: np.ndarray | None = None) -> dict:
    """CC, PSNR, SSIM and RE of reconstructed images against the truth.

    Parameters
    ----------
    pred, true
        Images of shape ``(n, height, width)`` (or one ``(height, width)`` image), e.g. ``(n, 48, 48)``
        normalized conductivity changes. ``true`` is the reference of PSNR/SSIM.
    data_range
        ``"dataset"`` (default), ``"sample"`` or a positive number; see the module docstring.
    groups
        Optional group label per sample, shape ``(n,)`` (e.g. the number of touches) for per-group summaries.

    Returns
    -------
    dict
        ``"cc"``, ``"psnr"``, ``"ssim"``, ``"re"``: per-sample arrays ``(n,)``; ``"data_range"``: the
        ranges used ``(n,)``; ``"mean"``: overall summary (``n``, the mean of each metric ignoring NaN,
        ``best_<metric>``, ``n_nan_<metric>``); ``"by_group"``: ``{group: summary}`` when ``groups`` is given.
    """
    skm = require_module("skimage.metrics", "scikit-image", "PSNR and SSIM")
    p, t = _images("pred", pred), _images("true", true)
    if p.shape != t.shape:
        raise ParameterError("true", f"the shape of pred {p.shape}", t.shape)
    if min(t.shape[1:]) < _SSIM_MIN_SIDE:
        raise ParameterError("true", f"images of at least {_SSIM_MIN_SIDE} x {_SSIM_MIN_SIDE} pixels (SSIM "
                                     "window)", t.shape)
    ranges = _data_ranges(t, data_range)
    psnr = np.empty(len(t))
    ssim = np.empty(len(t))
    with np.errstate(divide="ignore"):  # identical images: PSNR = +inf by definition
        for i in range(len(t)):
            psnr[i] = skm.peak_signal_noise_ratio(t[i], p[i], data_range=ranges[i])
            ssim[i] = skm.structural_similarity(t[i], p[i], data_range=ranges[i], **SSIM_KWARGS)
    values = {"cc": correlation_coefficient(p, t), "psnr": psnr, "ssim": ssim, "re": relative_error(p, t)}
    result: dict = {**values, "data_range": ranges, "mean": _summary(values)}
    if groups is not None:
        g = np.asarray(groups)
        if g.shape != (len(t),):
            raise ParameterError("groups", f"one label per sample, shape ({len(t)},)", g.shape)
        result["by_group"] = {
            (k.item() if hasattr(k, "item") else k): _summary({m: values[m][g == k] for m in IMAGE_METRICS})
            for k in np.unique(g)}
    return result


# -- classification ------------------------------------------------------------------------------------------

def _labels(name: str, y, n_classes: int) -> np.ndarray:
    y = np.asarray(y)
    if y.ndim != 1 or not (np.issubdtype(y.dtype, np.integer) or y.size == 0):
        raise ParameterError(name, "a 1-D array of integer class labels", f"{y.dtype} array of shape {y.shape}")
    if y.size and (y.min() < 0 or y.max() >= n_classes):
        raise ParameterError(name, f"labels in 0..{n_classes - 1}", f"labels in {y.min()}..{y.max()}")
    return y.astype(np.int64)


def confusion_matrix(*, y_pred, y_true, n_classes: int) -> np.ndarray:
    """Counts ``C[i, j]`` of samples of true class ``i`` predicted as class ``j``, shape ``(C, C)``."""
    n_classes = v.integer("n_classes", n_classes, lo=1)
    p, t = _labels("y_pred", y_pred, n_classes), _labels("y_true", y_true, n_classes)
    if p.shape != t.shape:
        raise ParameterError("y_true", f"as many labels as y_pred ({p.size})", t.size)
    return np.bincount(t * n_classes + p, minlength=n_classes * n_classes).reshape(n_classes, n_classes)


def classification_report(y_pred, y_true, class_names) -> dict:
    """Accuracy, confusion matrix and per-class precision, recall and F1.

    Parameters
    ----------
    y_pred, y_true
        Predicted and true integer labels, shape ``(n,)``, in ``0..len(class_names) - 1``.
    class_names
        Name of each class in label order (e.g. :data:`latticeopt.learn.classifiers.GESTURE_CLASSES`).

    Returns
    -------
    dict
        ``accuracy`` (float), ``n``, ``class_names`` (list), ``confusion_matrix`` ``(C, C)`` (rows true,
        columns predicted), ``precision``, ``recall``, ``f1`` (float ``(C,)``; NaN where undefined: a class
        never predicted has no precision, one absent from ``y_true`` no recall) and ``support`` ``(C,)``.
    """
    names = [str(c) for c in class_names]
    if len(names) < 1:
        raise ParameterError("class_names", "at least one class name", class_names)
    cm = confusion_matrix(y_pred=y_pred, y_true=y_true, n_classes=len(names))
    tp = np.diag(cm).astype(float)
    with np.errstate(invalid="ignore", divide="ignore"):
        precision = tp / cm.sum(axis=0)
        recall = tp / cm.sum(axis=1)
        f1 = 2 * precision * recall / (precision + recall)
    n = int(cm.sum())
    return {"accuracy": float(tp.sum() / n) if n else float("nan"), "n": n, "class_names": names,
            "confusion_matrix": cm, "precision": precision, "recall": recall, "f1": f1,
            "support": cm.sum(axis=1)}


def plot_confusion_matrix(cm: np.ndarray, class_names, path: str | Path, *, title: str | None = None) -> Path:
    """Write a confusion-matrix PNG: cells coloured by row-normalized fraction (recall), labelled with counts.

    Parameters
    ----------
    cm
        Count matrix ``(C, C)``, rows true class, columns predicted (as from :func:`confusion_matrix`).
    class_names
        ``C`` class names for the axes.
    path
        Output PNG path.
    title
        Figure title (e.g. ``"LSTM, simulated test set, accuracy 97.3 %"``).

    Returns
    -------
    Path
        The file written.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    cm = np.asarray(cm)
    names = [str(c) for c in class_names]
    if cm.ndim != 2 or cm.shape[0] != cm.shape[1] or cm.shape[0] != len(names):
        raise ParameterError("cm", f"a square ({len(names)}, {len(names)}) count matrix", cm.shape)
    rows = cm.sum(axis=1, keepdims=True)
    frac = np.divide(cm, rows, out=np.zeros(cm.shape), where=rows > 0)
    size = 2.0 + 0.55 * len(names)
    fig = Figure(figsize=(size + 1.5, size), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    im = ax.imshow(frac, cmap="Blues", vmin=0.0, vmax=1.0)
    fig.colorbar(im, ax=ax, fraction=0.046, label="fraction of true class")
    ticks = np.arange(len(names))
    ax.set_xticks(ticks, names, rotation=45, ha="right")
    ax.set_yticks(ticks, names)
    ax.set_xlabel("predicted class")
    ax.set_ylabel("true class")
    for i in range(len(names)):
        for j in range(len(names)):
            if cm[i, j]:
                ax.text(j, i, str(int(cm[i, j])), ha="center", va="center", fontsize=8,
                        color="white" if frac[i, j] > 0.5 else "black")
    if title:
        ax.set_title(title)
    path = Path(path)
    fig.savefig(path, dpi=120)
    return path
