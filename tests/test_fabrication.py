"""The narrowest gel and silicone features of a footprint, against hand-built layouts and a second measurement."""

from __future__ import annotations

import math

import pytest
import shapely

from latticeopt import LatticeDesign
from latticeopt.fabrication import castable_widths, narrowest_features, spans_text

L = 100.0


def _gel_around(*islands):
    """A footprint: the whole square gel except the given silicone boxes ``(x0, y0, x1, y1)``."""
    return shapely.box(0, 0, L, L).difference(shapely.union_all([shapely.box(*b) for b in islands]))


def test_hand_built_gaps_and_islands():
    # two islands 0.3 mm apart, one 0.2 mm from the right wall, a 2 mm-thin one touching the bottom wall
    f = narrowest_features(_gel_around((10, 10, 30, 30), (30.3, 10, 50, 30), (60, 0, 62, 20), (60, 40, 99.8, 60)),
                           L)
    assert f.gel_mm == pytest.approx(0.2, abs=1e-9)
    assert f.gel_at == pytest.approx((99.9, 50.0), abs=10.0)  # on the right wall, beside the long island
    assert f.gel_at[0] == pytest.approx(99.9, abs=1e-9)
    assert f.silicone_mm == pytest.approx(2.0, abs=2e-3)
    assert f.silicone_at[0] == pytest.approx(61.0, abs=2e-3)
    assert f.below(0.25, 1.0) == ["gel 0.2 mm wide at (99.9, " + f"{f.gel_at[1]:.4g}) mm < min_channel_mm = 0.25"]
    assert f.below(0.1, 2.5) == [f"silicone 2 mm wide at (61, {f.silicone_at[1]:.4g}) mm < min_island_mm = 2.5"]
    assert f.below(0.1, 1.0) == []


def test_islands_touching_each_other_or_a_wall_leave_no_gel_between():
    f = narrowest_features(_gel_around((0, 0, 20, 20), (20, 0, 40, 20), (45, 0, 60, 20)), L)
    assert f.gel_mm == pytest.approx(5.0, abs=1e-9)  # between the touching pair and the third island


def test_uniform_layer_has_no_feature():
    f = narrowest_features(shapely.box(0, 0, L, L), L)
    assert math.isinf(f.gel_mm) and math.isinf(f.silicone_mm) and f.gel_at is None and f.silicone_at is None
    assert f.below(1.0, 1.0) == []


@pytest.mark.parametrize("w", [1.0, 2.5, 4.0])
def test_square_lattice_is_w_and_p_minus_w_and_its_rim_channel_w_over_2(w):
    f = narrowest_features(LatticeDesign(width_mm=w).footprint(), L)
    assert f.gel_mm == pytest.approx(w, abs=1e-9)
    assert f.silicone_mm == pytest.approx(12.5 - w, abs=2e-3)
    f = narrowest_features(LatticeDesign(width_mm=w, rim="channel").footprint(), L)
    assert f.gel_mm == pytest.approx(w / 2, abs=1e-9)


@pytest.mark.parametrize("pattern, w", [("hexagonal", 1.0), ("triangular", 1.0), ("diagonal", 4.35),
                                        ("hexagonal", 3.0)])
def test_edge_strips_agree_with_a_wall_by_wall_measurement(pattern, w):
    # a second measurement of the gel between the walls and the islands that do not touch them, wall by wall
    # as segments (not the bodies and pruning of the code under test), and of the islands' inscribed circles
    gel = LatticeDesign(pattern=pattern, width_mm=w).footprint()
    silicone = shapely.box(0, 0, L, L).difference(gel)
    islands = [g for g in silicone.geoms if g.area > 1e-9]
    walls = [shapely.LineString(s) for s in (((0, 0), (L, 0)), ((L, 0), (L, L)), ((L, L), (0, L)), ((0, L), (0, 0)))]
    to_walls = min(d for wall in walls for d in (wall.distance(i) for i in islands) if d > 1e-7)
    between = min(d for a in range(len(islands)) for b in range(a) if (d := islands[a].distance(islands[b])) > 1e-7)
    thinnest = min(2 * shapely.maximum_inscribed_circle(i, 1e-4).length for i in islands)
    f = narrowest_features(gel, L)
    assert f.gel_mm == pytest.approx(min(to_walls, between), abs=1e-9)
    assert f.silicone_mm == pytest.approx(thinnest, abs=2e-3)
    assert min(f.gel_mm, f.silicone_mm) < 1.0  # each of these lattices has a sub-millimetre edge feature


@pytest.mark.parametrize("min_island, rim, spans", [
    (1.0, "none", [(1.0, 8.0)]),        # channel w >= 1, island 12.5 - w >= 1: every width of the bounds
    (5.0, "none", [(1.0, 7.5)]),        # island 12.5 - w >= 5
    (1.0, "channel", [(2.0, 8.0)]),     # the rim channel w / 2 >= 1
])
def test_castable_widths_of_the_square_lattice_are_its_analytic_limits(min_island, rim, spans):
    """The square lattice has no edge feature below its channel and island (p = 12.5 mm puts a channel end under
    every electrode): its castable widths are w >= limit (w / 2 with the rim channel) and p - w >= limit."""
    assert castable_widths(LatticeDesign(rim=rim), 1.0, 8.0, 1.0, min_island) == spans


def test_castable_widths_split_where_an_edge_feature_breaks_a_limit():
    """Each reported interval passes at its ends and fails just outside them, measured width by width; a width
    the design refuses (triangular: w < 2/3 p = 8.33 mm) counts as failing."""
    spans = castable_widths(LatticeDesign(pattern="triangular"), 1.0, 9.0, 1.0, 1.0)
    assert len(spans) >= 2 and spans[-1][1] < 8.34

    def ok(w):
        f = narrowest_features(LatticeDesign(pattern="triangular", width_mm=w).footprint(), 100.0)
        return f.gel_mm >= 1.0 - 1e-3 and f.silicone_mm >= 1.0 - 1e-3

    for a, b in spans:
        assert ok(a) and ok(b) and not ok(round(a - 0.1, 1)) and not ok(round(b + 0.1, 1))
    assert spans_text(spans) == ", ".join(f"{a:g}-{b:g}" if a != b else f"{a:g}" for a, b in spans)
    assert spans_text([]) == "none"


def test_a_density_study_report_warns_of_features_below_its_mould_naming_the_key():
    from latticeopt.optimize.layout_outputs import mould_lines

    geom = _gel_around((10, 10, 30, 30), (30.5, 10, 50, 30))  # gel 0.5 mm between two islands
    lines = mould_lines(geom, L, (("graded.min_width_mm", 1.0), ("graded.min_island_mm", 2.0)))
    assert lines[0] == "what the mould must make: narrowest gel 0.5 mm, narrowest silicone 19.5 mm"
    assert len(lines) == 2 and "gel 0.5 mm wide" in lines[1] and "< graded.min_width_mm = 1" in lines[1]
    assert mould_lines(geom, L, (("freeform.min_feature_mm", 0.4), ("freeform.min_feature_mm", 0.4)))[1:] == []
