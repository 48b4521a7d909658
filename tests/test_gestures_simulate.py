"""Gesture frames through a coarse exported sensor model: shapes, determinism, cache, drift/noise, physics."""

from __future__ import annotations

import numpy as np
import pytest

from latticeopt.design import LatticeDesign
from latticeopt.errors import ParameterError
from latticeopt.gestures import simulate
from latticeopt.gestures.simulate import GestureDataset, MeasurementConfig, generate_gestures, measured_frames
from latticeopt.gestures.trajectories import GESTURES, trajectory
from latticeopt.mesh import MeshSettings
from latticeopt.sensor_model import SensorSimulator, export_sensor_model, load_sensor_model

CLEAN = MeasurementConfig.clean()


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("gest")
    path = export_sensor_model(LatticeDesign(width_mm=4, thickness_mm=3), tmp / "sensor.npz",
                               MeshSettings(size_mm=5), cache_dir=tmp / "meshes")
    return load_sensor_model(path)


@pytest.fixture(scope="module")
def sim(model):
    return SensorSimulator(model)


@pytest.fixture(scope="module")
def small(model, sim):
    return generate_gestures(model, 2, seed=3, simulator=sim)


@pytest.fixture(scope="module")
def clean(model, sim):
    """Noise- and drift-free sequences of the classes the physics tests look at."""
    names = ("no contact", "finger press", "finger double tap", "finger swipe up", "finger swipe left")
    return generate_gestures(model, 3, seed=1, measurement=CLEAN, simulator=sim,
                             classes=[GESTURES.index(n) for n in names])


def test_shapes_labels_and_determinism(model, sim, small):
    assert small.frames.shape == (24, 15, 104) and small.frames.dtype == np.float32
    assert np.array_equal(np.bincount(small.labels), np.full(12, 2))
    assert small.info["forward_solves"] < 24 * 15  # repeated images were solved once
    # the same seed gives the same sequences, however many classes, sequences per class or blocks are drawn
    again = generate_gestures(model, 2, seed=3, simulator=sim, classes=[1, 8], block=3)
    assert np.array_equal(again.frames, small.frames[np.isin(small.labels, [1, 8])])
    # another seed, or the test pool with the same seed, gives other sequences
    first = (small.index == 0) & (small.labels == 1)
    for other in (generate_gestures(model, 1, seed=4, simulator=sim, classes=[1]),
                  generate_gestures(model, 1, seed=3, pool="test", simulator=sim, classes=[1])):
        assert not np.allclose(other.frames, small.frames[first])
    # the stored trajectories are the generator's
    t = small.trajectory(13)
    ref = trajectory(int(small.labels[13]), simulate._streams(3, "trainval", int(small.labels[13]), 1)[0])
    assert np.allclose(t.centres_mm, ref.centres_mm, atol=1e-4) and np.allclose(t.delta, ref.delta, atol=1e-6)


def test_parallel_workers_give_the_same_frames(model, small):
    par = generate_gestures(model, 2, seed=3, jobs=2, block=2, classes=[6, 10])
    assert np.array_equal(par.frames, small.frames[np.isin(small.labels, [6, 10])])


def test_cache_round_trip_without_recomputing(model, sim, tmp_path, monkeypatch):
    first = generate_gestures(model, 1, seed=5, simulator=sim, cache_dir=tmp_path, classes=[2, 5])
    files = list(tmp_path.glob("gestures-*.npz"))
    assert len(files) == 1

    def boom(*args, **kwargs):
        raise AssertionError("the cached dataset was recomputed")

    monkeypatch.setattr(simulate, "_simulate_block", boom)
    cached = generate_gestures(model, 1, seed=5, simulator=sim, cache_dir=tmp_path, classes=[2, 5])
    assert np.array_equal(cached.frames, first.frames) and cached.info == first.info
    with pytest.raises(AssertionError, match="recomputed"):  # other settings, other key
        generate_gestures(model, 1, seed=5, simulator=sim, cache_dir=tmp_path, classes=[2, 5],
                          measurement=MeasurementConfig(snr_db=(50, 60)))
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    with pytest.raises(ParameterError, match="dataset"):
        GestureDataset.load(tmp_path / "bad.npz")


def test_no_contact_frames_are_the_reference_and_press_frames_follow_the_intensity(clean):
    data = clean
    assert np.abs(data.frames[data.labels == 0]).max() < 1e-6
    for i in np.flatnonzero(data.labels == GESTURES.index("finger press")):
        t = data.trajectory(i)
        norm = np.linalg.norm(data.frames[i], axis=1)
        off = ~t.in_contact()
        assert norm[off].max(initial=0) < 1e-6 and norm[~off].min() > 1e-4
        # a stronger conductivity drop of the same disc changes the voltages more
        e = -t.delta[:, 0]
        on = np.flatnonzero(~off)
        order = np.argsort(e[on], kind="stable")
        assert np.all(np.diff(norm[on][order]) >= -1e-6 * norm.max())
        assert np.all(np.diff(e[on][order]) > 0) == np.all(np.diff(norm[on][order]) > 0)


def test_double_tap_voltages_show_two_contact_intervals(clean):
    data = clean
    for i in np.flatnonzero(data.labels == GESTURES.index("finger double tap")):
        norm = np.linalg.norm(data.frames[i], axis=1)
        on = np.concatenate([[False], norm > 1e-4, [False]]).astype(int)
        assert len(np.flatnonzero(np.diff(on))) == 4  # two separate runs of touched frames
        assert [tuple(x) for x in np.flatnonzero(np.diff(on)).reshape(2, 2)] == data.trajectory(i).contact_intervals()


def _image_centroid(img: np.ndarray, model) -> np.ndarray:
    w = np.clip(-img, 0, None).ravel()  # a press lowers the conductivity
    return (model.pixel_centres_mm() * w[:, None]).sum(0) / w.sum()


@pytest.mark.parametrize("name, axis, sign", [("finger swipe left", 0, -1), ("finger swipe up", 1, 1)])
def test_reconstructed_swipe_moves_the_named_way(model, clean, name, axis, sign):
    from latticeopt.recon.classical import LinearReconstructor
    from latticeopt.recon.frames import expand_independent

    rec = LinearReconstructor(model, "noser")
    label = GESTURES.index(name)
    data = clean
    for i in np.flatnonzero(data.labels == label):
        t = data.trajectory(i)
        f = np.flatnonzero(t.in_contact())
        first, last = f[1], f[-2]  # full-intensity frames at both ends of the stroke
        y = expand_independent(data.frames[i][[first, last]].astype(float), model.protocol)
        imgs = rec.reconstruct(y, lam=1e-2 * rec.eigenvalues.max())
        c0, c1 = (_image_centroid(im, model) for im in imgs)
        true = t.centroid_mm()[last] - t.centroid_mm()[first]
        assert sign * (c1 - c0)[axis] > 0.6 * sign * true[axis]  # one-step images blur and shrink motion


def test_common_drift_is_a_uniform_linear_offset(model):
    cfg = MeasurementConfig(snr_db=None, drift_offset=0.02, drift_rate=0.01, channel_offset=0.0, channel_rate=0.0)
    V = np.tile(model.v_ref, (15, 1))
    y = measured_frames(V, model.v_ref, model.independent, np.random.default_rng(0), cfg)
    assert y.shape == (15, 104)
    assert np.ptp(y, axis=1).max() < 1e-12  # every channel alike
    assert np.allclose(np.diff(y[:, 0], 2), 0, atol=1e-12)  # linear in time
    assert abs(y[0, 0]) <= 0.02 and abs(y[-1, 0] - y[0, 0]) <= 0.01 + 1e-12


def test_noise_has_the_requested_snr(model):
    cfg = MeasurementConfig(snr_db=(40.0, 40.0), drift_offset=0.0, drift_rate=0.0, channel_offset=0.0,
                            channel_rate=0.0)
    V = np.tile(model.v_ref, (400, 1))
    y = measured_frames(V, model.v_ref, model.independent, np.random.default_rng(1), cfg)
    noise_V = y * model.v_ref[model.independent]
    expected = np.sqrt(np.mean(model.v_ref ** 2)) * 10 ** (-40 / 20)
    assert abs(noise_V.std() / expected - 1) < 0.02


@pytest.mark.parametrize("kwargs, name", [(dict(snr_db=(60, 40)), "snr_db"), (dict(snr_db=5), "snr_db"),
                                          (dict(drift_rate=-0.1), "drift_rate")])
def test_measurement_config_errors(kwargs, name):
    with pytest.raises(ParameterError, match=name):
        MeasurementConfig(**kwargs)


def test_generate_rejects_bad_arguments(model):
    with pytest.raises(ParameterError, match="pool"):
        generate_gestures(model, 1, pool="validation")
    with pytest.raises(ParameterError, match="per_class"):
        generate_gestures(model, 0)
    with pytest.raises(ParameterError, match="model"):
        generate_gestures("sensor.npz", 1)
    with pytest.raises(ParameterError, match="classes"):
        generate_gestures(model, 1, classes=[1, 1])
