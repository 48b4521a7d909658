"""LatticeDesign: the paper's sensor as default, validation messages, derived geometry, electrodes."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from latticeopt.design import REGION_IDS, LatticeDesign
from latticeopt.errors import ParameterError

FLOAT_FIELDS = ("width_mm", "thickness_mm", "pitch_mm", "size_mm", "total_thickness_mm", "sealing_mm",
                "electrode_width_mm")


def test_defaults_are_the_papers_sensor():
    d = LatticeDesign()
    # Sensor 100 x 100 x 9 mm, sealing 2 mm, square lattice of pitch 12.5 mm, 16 electrodes 4 mm wide;
    # w = 4, t = 3 is the paper's simulated optimum.
    assert (d.size_mm, d.total_thickness_mm, d.sealing_mm) == (100.0, 9.0, 2.0)
    assert (d.pattern, d.pitch_mm) == ("square", 12.5)
    assert (d.n_electrodes, d.electrode_width_mm) == (16, 4.0)
    assert (d.width_mm, d.thickness_mm) == (4.0, 3.0)
    assert d.substrate_mm == pytest.approx(9 - 2 - 3)
    assert d.layer_z_mm == pytest.approx((4.0, 7.0))


@pytest.mark.parametrize("t", [1.0, 2.5, 5.0, 7.0])
def test_total_thickness_is_kept_constant(t):
    d = LatticeDesign(thickness_mm=t)
    assert d.substrate_mm + d.thickness_mm + d.sealing_mm == pytest.approx(9.0)
    assert d.layer_z_mm[1] == pytest.approx(9.0 - 2.0)


def _message(exc: pytest.ExceptionInfo) -> str:
    return str(exc.value)


@pytest.mark.parametrize("w", [-0.5, -1e-9, -100.0])
def test_negative_width_is_rejected_with_a_message_naming_range_and_value(w):
    with pytest.raises(ParameterError) as exc:
        LatticeDesign(width_mm=w)
    msg = _message(exc)
    assert msg.startswith("width_mm:")
    assert "0 (no lattice) or 0.05 <= width_mm < pitch_mm = 12.5 mm" in msg
    assert repr(w) in msg
    assert exc.value.name == "width_mm" and exc.value.got == w


@pytest.mark.parametrize("w, p", [(12.5, 12.5), (20.0, 12.5), (10.0, 10.0), (10.5, 10.0)])
def test_width_not_below_pitch_is_rejected(w, p):
    with pytest.raises(ParameterError) as exc:
        LatticeDesign(width_mm=w, pitch_mm=p)
    msg = _message(exc)
    assert "width_mm" in msg and f"pitch_mm = {p:g} mm" in msg and repr(w) in msg


@pytest.mark.parametrize("w", [1e-9, 0.001, 0.049])
def test_channels_narrower_than_the_minimum_are_rejected(w):
    with pytest.raises(ParameterError, match=r"width_mm: expected 0 \(no lattice\) or 0.05 <= width_mm"):
        LatticeDesign(width_mm=w)


def test_width_just_below_pitch_and_zero_are_valid():
    assert LatticeDesign(width_mm=12.4).width_mm == 12.4
    d = LatticeDesign(width_mm=0)
    assert d.width_mm == 0.0 and isinstance(d.width_mm, float) and not d.has_lattice


@pytest.mark.parametrize("t", [7.01, 8.0, 9.0, 100.0])
def test_thickness_leaving_a_negative_substrate_is_rejected(t):
    with pytest.raises(ParameterError) as exc:
        LatticeDesign(thickness_mm=t)
    msg = _message(exc)
    assert msg.startswith("thickness_mm:") and "= 7 mm" in msg and "substrate" in msg and repr(t) in msg


@pytest.mark.parametrize("t", [0.0, -1.0])
def test_non_positive_thickness_is_rejected(t):
    with pytest.raises(ParameterError, match=r"^thickness_mm: expected 0 < thickness_mm"):
        LatticeDesign(thickness_mm=t)


def test_thickness_bound_follows_sealing_and_total():
    assert LatticeDesign(thickness_mm=7.0).substrate_mm == 0.0
    with pytest.raises(ParameterError, match="= 5 mm"):
        LatticeDesign(thickness_mm=6.0, sealing_mm=4.0)
    assert LatticeDesign(thickness_mm=8.0, total_thickness_mm=12.0).substrate_mm == pytest.approx(2.0)


@pytest.mark.parametrize("field", FLOAT_FIELDS)
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_values_are_rejected(field, bad):
    with pytest.raises(ParameterError) as exc:
        LatticeDesign(**{field: bad})
    assert _message(exc).startswith(f"{field}:") and repr(bad) in _message(exc)


@pytest.mark.parametrize("field", FLOAT_FIELDS)
@pytest.mark.parametrize("bad", [True, False, "4", None, [4.0], 4 + 0j])
def test_wrong_types_are_rejected(field, bad):
    with pytest.raises(ParameterError) as exc:
        LatticeDesign(**{field: bad})
    assert _message(exc).startswith(f"{field}:") and repr(bad) in _message(exc)


@pytest.mark.parametrize("bad", [True, 16.0, "16", None, 15, 0, -4, 2])
def test_electrode_count_must_be_a_positive_multiple_of_4(bad):
    with pytest.raises(ParameterError) as exc:
        LatticeDesign(n_electrodes=bad)
    assert _message(exc).startswith("n_electrodes:") and "multiple of 4" in _message(exc)


def test_numpy_scalars_are_accepted_and_stored_as_python_numbers():
    d = LatticeDesign(width_mm=np.float32(4.0), thickness_mm=np.int64(3), n_electrodes=np.int32(8))
    assert type(d.width_mm) is float and type(d.thickness_mm) is float and type(d.n_electrodes) is int
    assert d == LatticeDesign(width_mm=4.0, thickness_mm=3.0, n_electrodes=8)


@pytest.mark.parametrize("pattern", ["honeycomb", "Square", "", 1])
def test_unknown_pattern_lists_the_valid_ones(pattern):
    with pytest.raises(ParameterError, match=r"pattern: expected one of 'square'"):
        LatticeDesign(pattern=pattern)


def test_electrode_width_cannot_exceed_its_share_of_the_side():
    LatticeDesign(electrode_width_mm=25.0)
    with pytest.raises(ParameterError, match=r"electrode_width_mm: .*= 25 mm"):
        LatticeDesign(electrode_width_mm=25.5)
    with pytest.raises(ParameterError, match="electrode_width_mm"):
        LatticeDesign(electrode_width_mm=0.0)


def test_other_bounds():
    for kwargs, name in [({"size_mm": 0.0}, "size_mm"), ({"total_thickness_mm": -1.0}, "total_thickness_mm"),
                         ({"sealing_mm": 9.0}, "sealing_mm"), ({"pitch_mm": 0.0}, "pitch_mm"),
                         ({"pitch_mm": 150.0}, "pitch_mm")]:
        with pytest.raises(ParameterError, match=rf"^{name}:"):
            LatticeDesign(**kwargs)


def test_parameter_error_is_a_value_error_and_designs_are_frozen():
    with pytest.raises(ValueError):
        LatticeDesign(width_mm=-1)
    d = LatticeDesign()
    with pytest.raises(AttributeError):
        d.width_mm = 2.0  # type: ignore[misc]
    with pytest.raises(ParameterError, match="width_mm"):
        d.replace(width_mm=20.0)  # replace validates too


# -- hypothesis: bad inputs anywhere in their domain ------------------------------------------------------

_finite = st.floats(allow_nan=False, allow_infinity=False, width=64)


@settings(max_examples=60, deadline=None)
@given(w=_finite.filter(lambda w: w < 0 or w >= 12.5))
def test_any_width_outside_the_valid_set_is_rejected(w):
    with pytest.raises(ParameterError) as exc:
        LatticeDesign(width_mm=w)
    assert exc.value.name == "width_mm" and "12.5" in exc.value.expected


@settings(max_examples=60, deadline=None)
@given(w=st.one_of(st.just(0.0), st.floats(min_value=0.05, max_value=12.5, exclude_max=True)),
       t=st.floats(min_value=0.0, max_value=7.0, exclude_min=True))
@example(w=0.05, t=1.0)  # the narrowest channel allowed
def test_any_valid_width_and_thickness_give_consistent_volumes(w, t):
    d = LatticeDesign(width_mm=w, thickness_mm=t, rim="channel")
    vols = d.region_volumes_mm3()
    assert min(vols.values()) >= -1e-9
    assert sum(vols.values()) == pytest.approx(100 * 100 * 9, rel=1e-12)
    # The pitch divides the side, so the rim's two half channels make up one more channel: the hydrogel
    # covers the fraction 1 - (1 - w/p)^2 of the footprint (w = 0: the whole layer).
    f = 1.0 if w == 0 else (w / 12.5) * (2 - w / 12.5)  # 1 - (1 - w/p)^2, written without cancellation
    # channel edges are coordinates near 50 mm: their round-off bounds the error relative to the layer volume
    assert vols["hydrogel"] == pytest.approx(t * 100 ** 2 * f, rel=1e-9, abs=1e-12 * t * 100 ** 2)


@settings(max_examples=60, deadline=None)
@given(field=st.sampled_from(FLOAT_FIELDS),
       bad=st.one_of(st.text(max_size=5), st.booleans(), st.none(), st.lists(_finite, max_size=2),
                     st.sampled_from([math.nan, math.inf, -math.inf])))
def test_any_non_number_is_rejected_by_name(field, bad):
    with pytest.raises(ParameterError) as exc:
        LatticeDesign(**{field: bad})
    assert exc.value.name == field and str(exc.value).startswith(f"{field}: expected ")


@settings(max_examples=40, deadline=None)
@given(t=st.floats(min_value=7.0, max_value=1e6, exclude_min=True))
def test_any_thickness_leaving_a_negative_substrate_is_rejected(t):
    with pytest.raises(ParameterError, match="substrate"):
        LatticeDesign(thickness_mm=t)


# -- derived geometry ---------------------------------------------------------------------------------------

def test_paper_optimum_hydrogel_volume():
    # w = 4, t = 3, p = 12.5: 3 * 100^2 * (1 - (1 - 4/12.5)^2) = 16128 mm^3 (the closed form).
    assert LatticeDesign(rim="channel").region_volumes_mm3()["hydrogel"] == pytest.approx(16128.0, rel=1e-12)
    # Without the rim channel the 7 inner lines per axis remain: f = 7 w / L per axis, 1 - (1 - f)^2 in all.
    assert LatticeDesign().region_volumes_mm3()["hydrogel"] == pytest.approx(3e4 * (1 - (1 - 0.28) ** 2), rel=1e-12)


def test_channel_intervals_half_channels_at_the_rim():
    iv = LatticeDesign(width_mm=4, rim="channel").channel_intervals_mm()
    assert iv[0] == pytest.approx([0, 2]) and iv[-1] == pytest.approx([98, 100])
    assert len(iv) == 9
    assert np.diff(iv, axis=1)[1:-1] == pytest.approx(4.0)
    assert LatticeDesign(width_mm=0).channel_intervals_mm().shape == (0, 2)


def test_pitch_not_dividing_the_side_adds_a_rim_line():
    d = LatticeDesign(width_mm=4, pitch_mm=30, rim="channel")
    assert d.line_positions_mm() == pytest.approx([0, 30, 60, 90, 100])
    assert d.replace(rim="none").line_positions_mm() == pytest.approx([30, 60, 90])
    # Channels around 90 and 100 are 10 mm apart; with w = 12 they merge into one interval.
    merged = LatticeDesign(width_mm=12, pitch_mm=30, rim="channel").channel_intervals_mm()
    assert merged[-1] == pytest.approx([84, 100])


def test_region_at_classifies_known_points():
    d = LatticeDesign(rim="channel")  # substrate [0, 4], layer [4, 7], sealing [7, 9]; channels around 0, 12.5
    pts = np.array([[50, 50, 2.0],  # substrate
                    [50, 50, 8.0],  # sealing
                    [12.5, 30, 5.5],  # on an x-channel
                    [30, 37.5, 5.5],  # on a y-channel
                    [30, 30, 5.5],  # island centre (cell [25, 37.5])
                    [1.0, 30, 5.5],  # rim half channel
                    [6.25, 6.25, 5.5]])  # island
    ids = [REGION_IDS[n] for n in ("substrate", "sealing", "hydrogel", "hydrogel", "islands", "hydrogel",
                                   "islands")]
    assert d.region_at(pts).tolist() == ids
    ids[5] = REGION_IDS["islands"]  # without the rim channel the rim band is silicone
    assert d.replace(rim="none").region_at(pts).tolist() == ids
    assert set(LatticeDesign(width_mm=0).region_at(pts).tolist()) == {0, 1, 3}


# -- electrodes ----------------------------------------------------------------------------------------------

def test_electrodes_numbering_and_positions():
    d = LatticeDesign()
    e = d.electrodes()
    assert e.shape == (16, 8)
    c = [12.5, 37.5, 62.5, 87.5]
    # Electrode 1 on y = 0 at x = 12.5, then counter-clockwise seen from above.
    assert e[:4, :2] == pytest.approx(np.c_[c, np.zeros(4)])
    assert e[4:8, :2] == pytest.approx(np.c_[np.full(4, 100), c])
    assert e[8:12, :2] == pytest.approx(np.c_[c[::-1], np.full(4, 100)])
    assert e[12:, :2] == pytest.approx(np.c_[np.zeros(4), c[::-1]])
    angle = np.unwrap(np.arctan2(e[:, 1] - 50, e[:, 0] - 50))
    assert np.all(np.diff(angle) > 0) and angle[-1] - angle[0] < 2 * np.pi  # once round, counter-clockwise
    # Each sits at mid-height of the conductive layer, is w_e wide and t high, normal pointing outward.
    assert e[:, 2] == pytest.approx(5.5) and e[:, 6] == pytest.approx(4.0) and e[:, 7] == pytest.approx(3.0)
    assert np.all(np.einsum("ij,ij->i", e[:, 3:5], e[:, :2] - 50) > 0)
    assert np.linalg.norm(e[:, 3:5], axis=1) == pytest.approx(1.0)
    # The tangent axis is perpendicular to the normal.
    assert np.all(e[np.arange(16), 3 + e[:, 5].astype(int)] == 0)


def test_electrodes_follow_design_parameters():
    d = LatticeDesign(n_electrodes=8, thickness_mm=2, electrode_width_mm=6, size_mm=80)
    e = d.electrodes()
    assert e.shape == (8, 8)
    assert e[:2, 0] == pytest.approx([20, 60])
    assert e[:, 2] == pytest.approx(d.substrate_mm + 1.0) and e[:, 7] == pytest.approx(2.0)


def test_content_hash_identifies_the_design():
    a, b = LatticeDesign(width_mm=4), LatticeDesign(width_mm=4.0)
    assert a.content_hash() == b.content_hash() and len(a.content_hash()) == 64
    assert a.content_hash() != LatticeDesign(width_mm=4.000001).content_hash()
    assert a.content_hash() != LatticeDesign(electrode_width_mm=3.0).content_hash()
