"""Each gesture's trajectory does what its name says, over many random draws (no forward solves here)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from latticeopt.errors import ParameterError
from latticeopt.gestures.trajectories import GESTURES, GestureConfig, Trajectory, envelope, trajectory

CFG = GestureConfig()
DRAWS = 40
SIZE = 100.0


def draws(name: str, n: int = DRAWS, seed: int = 0) -> list[Trajectory]:
    label = GESTURES.index(name)
    return [trajectory(label, np.random.default_rng([seed, label, i]), CFG, SIZE) for i in range(n)]


def contact_frames(t: Trajectory) -> np.ndarray:
    return np.flatnonzero(t.in_contact())


def test_class_names_match_the_classifiers():
    learn = pytest.importorskip("latticeopt.learn.classifiers")
    assert GESTURES == learn.GESTURE_CLASSES


@pytest.mark.parametrize("label", range(12))
def test_shapes_determinism_and_discs_on_the_sensor(label):
    ts = [trajectory(label, np.random.default_rng(7), CFG) for _ in range(2)]
    other = trajectory(label, np.random.default_rng(8), CFG)
    k = {0: 0, 2: 4, 10: 2, 11: 2}.get(label, 1)
    for t in ts:
        assert t.centres_mm.shape == (15, k, 2) and t.radius_mm.shape == (15, k) and t.delta.shape == (15, k)
    assert np.array_equal(ts[0].centres_mm, ts[1].centres_mm) and np.array_equal(ts[0].delta, ts[1].delta)
    if k:
        assert not np.array_equal(ts[0].delta, other.delta)
    for t in draws(GESTURES[label], 20, seed=3):
        a = t.active
        lo = t.centres_mm - t.radius_mm[..., None]
        hi = t.centres_mm + t.radius_mm[..., None]
        assert np.all(lo[a] >= -1e-9) and np.all(hi[a] <= SIZE + 1e-9)
        assert np.all(t.delta <= 0) and np.all(t.delta > -1)
        if k:
            assert t.in_contact().any()
            assert not t.in_contact().all() or GESTURES[label] == "finger press"


def test_padding_round_trip():
    t = draws("four-finger scratch", 1)[0]
    back = Trajectory.from_padded(t.label, *t.padded())
    assert np.array_equal(back.centres_mm, t.centres_mm) and np.array_equal(back.delta, t.delta)
    assert Trajectory.from_padded(0, *draws("no contact", 1)[0].padded()).delta.shape == (15, 0)


def test_no_contact_has_no_touch():
    for t in draws("no contact"):
        assert not t.active.any() and t.contact_intervals() == []


@pytest.mark.parametrize("name, diameter", [("finger press", CFG.finger_diameter_mm),
                                            ("fist press", CFG.fist_diameter_mm)])
def test_presses_are_one_stationary_contact(name, diameter):
    for t in draws(name):
        assert len(t.contact_intervals()) == 1
        c = t.centroid_mm()[contact_frames(t)]
        assert np.ptp(c, axis=0).max() == 0.0
        assert diameter[0] <= 2 * t.radius_mm[0, 0] <= diameter[1]
        # intensity rises, holds at the peak for at least 4 frames, and falls
        e = -t.delta[:, 0]
        assert np.sum(e == e.max()) >= 4
        start, stop = t.contact_intervals()[0]
        assert np.all(np.diff(e[start:int(np.argmax(e)) + 1]) > 0)


def test_a_fist_is_larger_than_any_finger():
    assert min(t.radius_mm[0, 0] for t in draws("fist press")) > max(t.radius_mm[0, 0] for t in draws("finger press"))


def test_double_tap_has_two_contact_intervals_at_one_place():
    for t in draws("finger double tap"):
        iv = t.contact_intervals()
        assert len(iv) == 2
        assert iv[1][0] - iv[0][1] >= 1  # at least one frame without contact between the taps
        assert all(1 <= b - a <= 3 for a, b in iv)
        c = t.centroid_mm()
        assert np.linalg.norm(c[iv[0][0]] - c[iv[1][0]]) <= 1.5 + 1e-9


def test_palm_pat_is_one_short_large_contact():
    for t in draws("palm pat"):
        iv = t.contact_intervals()
        assert len(iv) == 1 and iv[0][1] - iv[0][0] <= 4
        assert 2 * t.radius_mm[0, 0] >= CFG.palm_diameter_mm[0]


@pytest.mark.parametrize("name, axis, sign", [("finger swipe up", 1, 1), ("finger swipe down", 1, -1),
                                              ("finger swipe left", 0, -1), ("finger swipe right", 0, 1)])
def test_swipes_move_the_centroid_the_named_way(name, axis, sign):
    for t in draws(name):
        f = contact_frames(t)
        c = t.centroid_mm()[f]
        step = np.diff(c, axis=0)
        travel = c[-1] - c[0]
        assert sign * travel[axis] >= CFG.swipe_length_mm[0] * math.cos(math.radians(10)) - 1e-9
        assert abs(travel[1 - axis]) <= abs(travel[axis]) * math.tan(math.radians(10)) + 1e-9
        assert np.all(sign * step[:, axis] > 0)  # monotonic: the finger never goes back
        assert len(t.contact_intervals()) == 1


@pytest.mark.parametrize("name, sign", [("zoom-in", 1), ("zoom-out", -1)])
def test_zoom_in_spreads_the_fingers_and_zoom_out_closes_them(name, sign):
    for t in draws(name):
        f = contact_frames(t)
        s = t.spread_mm()[f]
        assert np.all(sign * np.diff(s) > 0)
        assert sign * (s[-1] - s[0]) >= CFG.zoom_far_mm[0] - CFG.zoom_near_mm[1] - 1e-9
        c = t.centroid_mm()[f]
        assert np.ptp(c, axis=0).max() < 1e-9  # the fingers move symmetrically about a fixed point


def test_scratch_is_four_fingers_dragged_back_and_forth():
    for t in draws("four-finger scratch"):
        f = contact_frames(t)
        assert t.active[f].all() and len(t.contact_intervals()) == 1
        c = t.centroid_mm()[f]
        # main motion direction: the largest principal axis of the centroid path
        d = c - c.mean(axis=0)
        axis = np.linalg.svd(d, full_matrices=False)[2][0]
        v = np.diff(d @ axis)
        v = v[np.abs(v) > 1e-9]
        assert np.any(np.sign(v[1:]) != np.sign(v[:-1])), "no reversal of the scratching motion"
        # the row of four fingertips keeps its shape (rigid translation)
        rel = t.centres_mm[f] - t.centres_mm[f][:, :1]
        assert np.abs(rel - rel[0]).max() < 1e-9


def test_variation_covers_position_size_speed_and_intensity():
    ts = draws("finger swipe right", 200)
    starts = np.array([t.centroid_mm()[contact_frames(t)[0]] for t in ts])
    assert np.ptp(starts[:, 1]) > 60  # position
    r = np.array([t.radius_mm[0, 0] for t in ts])
    assert np.ptp(r) > 0.8 * (CFG.finger_diameter_mm[1] - CFG.finger_diameter_mm[0]) / 2  # size
    durations = {len(contact_frames(t)) for t in ts}
    assert durations == set(range(CFG.move_frames[0], CFG.move_frames[1] + 1))  # speed
    drops = np.array([-t.delta.min() for t in ts])
    assert drops.min() >= CFG.drop[0] and drops.max() <= CFG.drop[1] and np.ptp(drops) > 0.3  # intensity


def test_envelope():
    e = envelope(15, 3, 2, 4, 1)
    assert np.allclose(e[3:10], [1 / 3, 2 / 3, 1, 1, 1, 1, 0.5]) and not e[:3].any() and not e[10:].any()
    with pytest.raises(ParameterError, match="start"):
        envelope(15, 12, 1, 4, 1)


@pytest.mark.parametrize("kwargs, name", [(dict(n_frames=10), "n_frames"), (dict(drop=(0.5, 0.2)), "drop"),
                                          (dict(drop=(0.5, 1.5)), "drop"), (dict(move_frames=(1, 4)), "move_frames"),
                                          (dict(zoom_far_mm=(20, 30)), "zoom_far_mm"),
                                          (dict(finger_diameter_mm=5), "finger_diameter_mm")])
def test_config_errors_name_the_parameter(kwargs, name):
    with pytest.raises(ParameterError, match=name):
        GestureConfig(**kwargs)


def test_bad_label_is_rejected():
    with pytest.raises(ParameterError, match="label"):
        trajectory(12, np.random.default_rng(0))


def test_too_small_sensor_is_rejected():
    with pytest.raises(ParameterError, match="size_mm"):
        trajectory(GESTURES.index("palm pat"), np.random.default_rng(0), size_mm=40.0)
