"""The paper's training data: touch geometry, pixel rendering, determinism, split and file round trip."""

import numpy as np
import pytest

from latticeopt.design import LatticeDesign
from latticeopt.errors import ParameterError
from latticeopt.mesh import MeshSettings
from latticeopt.recon.dataset import (
    DatasetConfig,
    ReconDataset,
    add_noise,
    generate_dataset,
    render_touches,
    sample_touches,
)
from latticeopt.sensor_model import build_sensor_model


@pytest.fixture(scope="module")
def model():
    return build_sensor_model(LatticeDesign(width_mm=4, thickness_mm=3), MeshSettings(size_mm=5), cache_dir=False)


@pytest.fixture(scope="module")
def data(model):
    return generate_dataset(model, DatasetConfig(per_count=30, touch_counts=(1, 2, 5), seed=7))


def test_rendered_touch_has_the_circle_area_and_value():
    s0 = 0.00312
    for x, y, d in [(50.0, 50.0, 7.5), (31.3, 62.1, 27.5), (14.0, 80.0, 12.0)]:
        img = render_touches(np.array([[x, y, d, 0.05]]), s0)
        cover = (s0 - img) / (s0 - 0.05 * s0)
        area = cover.sum() * (100 / 48) ** 2
        assert area == pytest.approx(np.pi * d * d / 4, rel=0.02)
        assert img.min() == pytest.approx(0.05 * s0) and img.max() == pytest.approx(s0)


def test_touches_lie_on_the_sensor_without_overlap():
    cfg = DatasetConfig()
    for seed in range(30):
        t = sample_touches(np.random.default_rng(seed), 5, cfg, 100.0)
        r = t[:, 2] / 2
        assert np.all(t[:, :2] - r[:, None] >= 0) and np.all(t[:, :2] + r[:, None] <= 100)
        assert np.all((t[:, 2] >= 7.5) & (t[:, 2] <= 27.5) & (t[:, 3] >= 0.05) & (t[:, 3] <= 2.0))
        dist = np.linalg.norm(t[:, None, :2] - t[None, :, :2], axis=2)
        need = r[:, None] + r[None, :]
        off = ~np.eye(5, dtype=bool)
        assert np.all(dist[off] >= need[off])


def test_dataset_is_seeded_split_and_consistent(model, data):
    assert len(data) == 90 and data.voltages.shape == (90, 208) and data.images.shape == (90, 48, 48)
    for c in (1, 2, 5):
        members = np.flatnonzero(data.n_touches == c)
        assert [len(np.intersect1d(members, part)) for part in (data.train, data.val, data.test)] == [21, 6, 3]
        assert np.all(np.isfinite(data.touches[members, :c])) and np.all(np.isnan(data.touches[members, c:]))
    again = generate_dataset(model, DatasetConfig(per_count=30, touch_counts=(1, 2, 5), seed=7))
    np.testing.assert_array_equal(again.touches, data.touches)
    np.testing.assert_allclose(again.voltages, data.voltages, rtol=1e-12)
    # Images are the normalized change of the rendered touches; voltages move away from the reference.
    i = 4
    img = render_touches(data.touches[i], model.sigma0_S_per_m)
    np.testing.assert_allclose(data.images[i], (img - model.sigma0_S_per_m) / model.sigma0_S_per_m, atol=1e-6)
    assert np.all(np.abs(data.voltages - model.v_ref).max(axis=1) > 0)


def test_dataset_file_round_trip_and_model_check(model, data, tmp_path):
    back = ReconDataset.load(data.save(tmp_path / "d.npz"))
    for name in ("voltages", "images", "touches", "n_touches", "train", "val", "test"):
        np.testing.assert_array_equal(getattr(back, name), getattr(data, name))
    assert back.config == data.config
    back.check_model(model)
    other = build_sensor_model(LatticeDesign(width_mm=0, thickness_mm=3), MeshSettings(size_mm=5), cache_dir=False)
    with pytest.raises(ParameterError, match="fingerprint"):
        back.check_model(other)
    (tmp_path / "junk.npz").write_bytes(b"junk")
    with pytest.raises(ParameterError, match="dataset"):
        ReconDataset.load(tmp_path / "junk.npz")


def test_noise_has_the_requested_snr():
    V = np.random.default_rng(0).uniform(-5, 5, (2000, 208))
    noisy = add_noise(V, 40.0, np.random.default_rng(1))
    snr = 10 * np.log10(np.mean(V ** 2) / np.mean((noisy - V) ** 2))
    assert snr == pytest.approx(40.0, abs=0.05)
