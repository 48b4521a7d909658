"""Image and classification metrics against independent facts (no torch needed)."""

from __future__ import annotations

import numpy as np
import pytest

from latticeopt.errors import ParameterError
from latticeopt.learn.metrics import (
    classification_report,
    confusion_matrix,
    correlation_coefficient,
    evaluate_images,
    plot_confusion_matrix,
    relative_error,
)


def _blobs(n=6, side=48, seed=0):
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:side, 0:side]
    c = rng.uniform(10, side - 10, (n, 2))
    return np.exp(-((xx - c[:, 0, None, None]) ** 2 + (yy - c[:, 1, None, None]) ** 2) / 40.0) + 0.1


def test_cc_is_one_for_affine_copies_and_matches_numpy():
    x = _blobs()
    assert np.allclose(correlation_coefficient(2.5 * x - 7.0, x), 1.0)
    assert np.allclose(correlation_coefficient(-0.3 * x + 1.0, x), -1.0)
    y = x + np.random.default_rng(1).normal(0, 0.2, x.shape)
    expected = [np.corrcoef(a.ravel(), b.ravel())[0, 1] for a, b in zip(y, x)]
    assert np.allclose(correlation_coefficient(y, x), expected)
    const = np.full_like(x, 0.1)  # all-background prediction: correlation undefined
    assert np.all(np.isnan(correlation_coefficient(const, x)))


def test_relative_error_known_values():
    x = _blobs()
    assert np.all(relative_error(x, x) == 0)
    assert np.allclose(relative_error(2 * x, x), 1.0)
    assert np.allclose(relative_error(np.zeros_like(x), x), 1.0)
    assert np.allclose(relative_error(x + 0.5 * x, x), 0.5)


def test_psnr_and_ssim_known_values():
    x = _blobs()
    same = evaluate_images(x, x)
    assert np.all(np.isinf(same["psnr"])) and np.all(same["psnr"] > 0)
    assert np.allclose(same["ssim"], 1.0)
    assert np.allclose(same["cc"], 1.0) and np.all(same["re"] == 0)
    # A constant offset c gives MSE = c^2, so PSNR = 20 log10(R / c) with R the data range.
    c, R = 0.05, 2.0
    off = evaluate_images(x + c, x, data_range=R)
    assert np.allclose(off["psnr"], 20 * np.log10(R / c))
    assert np.all(off["data_range"] == R)
    assert np.all(off["ssim"] < 1)
    # Default data range: one number for the whole set, max - min over all true images.
    default = evaluate_images(x + c, x)
    assert np.allclose(default["data_range"], x.max() - x.min())
    assert np.allclose(default["psnr"], 20 * np.log10((x.max() - x.min()) / c))
    per_sample = evaluate_images(x + c, x, data_range="sample")
    assert np.allclose(per_sample["data_range"], x.max(axis=(1, 2)) - x.min(axis=(1, 2)))


def test_ssim_decreases_with_noise():
    x = _blobs(n=1)[0]
    rng = np.random.default_rng(2)
    scores = [evaluate_images(x + s * rng.standard_normal(x.shape), x, data_range=1.0)["ssim"][0]
              for s in (0.0, 0.02, 0.1, 0.3)]
    assert scores[0] == pytest.approx(1.0) and all(a > b for a, b in zip(scores, scores[1:]))


def test_group_summaries_are_means_of_their_samples():
    x = _blobs(n=9)
    rng = np.random.default_rng(3)
    pred = x + rng.normal(0, 0.05, x.shape)
    groups = np.array([1, 2, 3] * 3)
    res = evaluate_images(pred, x, groups=groups)
    assert sorted(res["by_group"]) == [1, 2, 3]
    for g in (1, 2, 3):
        summary = res["by_group"][g]
        assert summary["n"] == 3
        for m in ("cc", "psnr", "ssim", "re"):
            assert summary[m] == pytest.approx(res[m][groups == g].mean())
        assert summary["best_re"] == pytest.approx(res["re"][groups == g].min())
        assert summary["best_cc"] == pytest.approx(res["cc"][groups == g].max())
    assert res["mean"]["psnr"] == pytest.approx(res["psnr"].mean())


def test_nan_cc_is_counted_not_averaged():
    x = _blobs(n=4)
    pred = x.copy()
    pred[0] = 0.3  # constant prediction for the first sample
    res = evaluate_images(pred, x)
    assert res["mean"]["n_nan_cc"] == 1
    assert res["mean"]["cc"] == pytest.approx(1.0)


def test_image_metric_errors():
    x = _blobs(n=2)
    with pytest.raises(ParameterError, match="true"):
        evaluate_images(x, x[:, :40])
    with pytest.raises(ParameterError, match="11 x 11"):
        evaluate_images(x[:, :8, :8], x[:, :8, :8])
    with pytest.raises(ParameterError, match="data_range"):
        evaluate_images(x, np.zeros_like(x))
    with pytest.raises(ParameterError, match="data_range"):
        evaluate_images(x, x, data_range="global")
    with pytest.raises(ParameterError, match="groups"):
        evaluate_images(x, x, groups=[1, 2, 3])


def test_confusion_matrix_of_a_known_labelling():
    y_true = np.array([0, 0, 1, 1, 2, 2])
    y_pred = np.array([0, 1, 1, 1, 2, 0])
    cm = confusion_matrix(y_pred=y_pred, y_true=y_true, n_classes=3)
    assert cm.tolist() == [[1, 1, 0], [0, 2, 0], [1, 0, 1]]
    rep = classification_report(y_pred, y_true, ["a", "b", "c"])
    assert rep["accuracy"] == pytest.approx(4 / 6)
    assert np.allclose(rep["precision"], [1 / 2, 2 / 3, 1.0])
    assert np.allclose(rep["recall"], [1 / 2, 1.0, 1 / 2])
    assert np.allclose(rep["f1"], [1 / 2, 0.8, 2 / 3])
    assert rep["support"].tolist() == [2, 2, 2]


def test_confusion_matrix_matches_a_plain_count_and_undefined_precision_is_nan():
    rng = np.random.default_rng(4)
    y_true, y_pred = rng.integers(0, 5, 300), rng.integers(0, 4, 300)  # class 4 is never predicted
    cm = confusion_matrix(y_pred=y_pred, y_true=y_true, n_classes=5)
    for i in range(5):
        for j in range(5):
            assert cm[i, j] == np.sum((y_true == i) & (y_pred == j))
    rep = classification_report(y_pred, y_true, list("abcde"))
    assert np.isnan(rep["precision"][4]) and rep["recall"][4] == 0
    assert rep["accuracy"] == pytest.approx(np.mean(y_true == y_pred))
    with pytest.raises(ParameterError, match="y_pred"):
        classification_report(np.array([0, 5]), np.array([0, 1]), list("abcde"))
    with pytest.raises(ParameterError, match="y_true"):
        classification_report(np.array([0, 1]), np.array([0.0, 1.0]), list("ab"))


def test_confusion_matrix_plot_is_a_png(tmp_path):
    import matplotlib.image

    names = [f"class {k}" for k in range(12)]
    rng = np.random.default_rng(5)
    cm = confusion_matrix(y_pred=rng.integers(0, 12, 500), y_true=rng.integers(0, 12, 500), n_classes=12)
    path = plot_confusion_matrix(cm, names, tmp_path / "cm.png", title="simulated")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert matplotlib.image.imread(path).shape[0] > 300
    with pytest.raises(ParameterError, match="cm"):
        plot_confusion_matrix(cm[:3], names, tmp_path / "bad.png")
