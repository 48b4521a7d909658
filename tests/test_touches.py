"""Touch validation: bad touches are rejected with messages naming the touch, the parameter and the range."""

import math

import pytest

from latticeopt import LatticeDesign
from latticeopt.errors import ParameterError
from latticeopt.touches import Touch, validate_touches

DESIGN = LatticeDesign()  # 100 x 100 mm, 9 mm thick


def test_valid_touches_pass_and_are_normalised():
    out = validate_touches(DESIGN, [(50, 50, 8.75, 4), {"x_mm": 20, "y_mm": 20, "radius_mm": 6.25,
                                                        "depth_mm": 1}, Touch(80, 80, 7, 0)])
    assert [type(t) for t in out] == [Touch] * 3
    assert out[0] == Touch(50.0, 50.0, 8.75, 4.0)
    # edges touching (distance = radius sum) and indenters flush with the rim are allowed
    validate_touches(DESIGN, [(10, 10, 10, 1), (30, 10, 10, 1)])
    validate_touches(DESIGN, [(8.75, 91.25, 8.75, 1)])


@pytest.mark.parametrize("touches, name, fragment", [
    ([(50, 50, 8.75, 4), (95, 50, 8.75, 1)], "touch #2 x_mm", "8.75 <= x_mm <= 91.25"),
    ([(50, 5, 8.75, 1)], "touch #1 y_mm", "8.75 <= y_mm <= 91.25"),
    ([(50, 50, 8.75, 9.0)], "touch #1 depth_mm", "< 9"),
    ([(50, 50, 8.75, 12.0)], "touch #1 depth_mm", "< 9"),
    ([(50, 50, 0.0, 1)], "touch #1 radius_mm", "0 < radius_mm"),
    ([(50, 50, -2, 1)], "touch #1 radius_mm", "0 < radius_mm"),
    ([(50, 50, 8, 1), (60, 55, 8, 1)], "touch #2 (x_mm, y_mm)", "overlap"),
    ([(20, 20, 8, 1), (80, 80, 8, 1), (30, 25, 8, 1)], "touch #3 (x_mm, y_mm)", "touch #1"),
    ([(50, math.nan, 8, 1)], "touch #1 y_mm", "finite"),
    ([(50, 50, 8, math.inf)], "touch #1 depth_mm", ""),
    ([(50, 50, 8, -1)], "touch #1 depth_mm", "0 <= depth_mm"),
    ([(50, 50, 60, 1)], "touch #1 radius_mm", "fit on the sensor"),
    ([(50, 50, 8)], "touch #1", "four values"),
    ([], "touches", "at least one"),
])
def test_bad_touches_rejected_with_index_parameter_range_and_value(touches, name, fragment):
    with pytest.raises(ParameterError) as err:
        validate_touches(DESIGN, touches)
    assert err.value.name == name
    assert fragment in err.value.expected
    assert "got" in str(err.value)


def test_touch_itself_rejects_nan_and_nonpositive_radius():
    with pytest.raises(ParameterError, match="radius_mm"):
        Touch(1, 1, math.nan, 1)
    with pytest.raises(ParameterError, match="radius_mm"):
        Touch(1, 1, 0, 1)
    with pytest.raises(ParameterError, match="x_mm"):
        Touch("a", 1, 1, 1)


@pytest.mark.parametrize("text", ["50,50,8.75", "50,50,8.75,4,1", "a,b,c,d", "", "50;50;8;4"])
def test_parse_rejects_malformed(text):
    with pytest.raises(ParameterError, match="--touch"):
        Touch.parse(text)


def test_parse_reads_four_numbers():
    assert Touch.parse(" 50, 40 ,8.75,4") == Touch(50, 40, 8.75, 4)
    with pytest.raises(ParameterError, match="radius_mm"):
        Touch.parse("50,50,-1,4")
