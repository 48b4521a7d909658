"""Layouts of the conductive layer against facts that do not come from the layout code.

Periodic patterns: inside a window that is a whole number of periods of the tiling (away from the rim), the
hydrogel fraction is the island-scaling result ``1 - (1 - c w / p)^2`` (c = 1 for square, diagonal and
hexagonal cells, whose islands are the cells shrunk by ``w / 2`` per side; c = 3/2 for triangles, whose
inradius is ``p / 3``). Symmetry of the square sensor, and closed-form rim bands.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import shapely
from shapely.affinity import scale

from latticeopt.design import LatticeDesign, design_from_table, width_for_fraction
from latticeopt.errors import ParameterError
from latticeopt.layout import electrode_contact_mm

P = 12.5


def _window_fraction(design: LatticeDesign, half_w: float, half_h: float) -> float:
    box = shapely.box(50 - half_w, 50 - half_h, 50 + half_w, 50 + half_h)
    return design.footprint().intersection(box).area / box.area


@pytest.mark.parametrize("w", [1.0, 3.0, 5.5])
def test_periodic_fractions_match_island_scaling(w):
    # One period of each tiling, centred on the sensor centre (every pattern is centred there).
    sq = _window_fraction(LatticeDesign(width_mm=w), P / 2 * 2, P / 2 * 2)
    diag = _window_fraction(LatticeDesign(pattern="diagonal", width_mm=w), P * math.sqrt(2) / 2, P * math.sqrt(2) / 2)
    hexa = _window_fraction(LatticeDesign(pattern="hexagonal", width_mm=w), P * math.sqrt(3) / 2, P / 2)
    side = 2 * P / math.sqrt(3)
    tri = _window_fraction(LatticeDesign(pattern="triangular", width_mm=min(w, 5.0)), side / 2, P)
    for got, c, ww in ((sq, 1.0, w), (diag, 1.0, w), (hexa, 1.0, w), (tri, 1.5, min(w, 5.0))):
        assert got == pytest.approx(1 - (1 - c * ww / P) ** 2, rel=1e-9)


@pytest.mark.parametrize("pattern", ["square", "hexagonal", "triangular", "diagonal"])
@pytest.mark.parametrize("rim", ["none", "channel"])
def test_layouts_have_the_square_sensors_mirror_symmetry(pattern, rim):
    gel = LatticeDesign(pattern=pattern, width_mm=3, rim=rim).footprint()
    for fx, fy in ((-1, 1), (1, -1)):
        mirrored = scale(gel, xfact=fx, yfact=fy, origin=(50, 50))
        assert gel.symmetric_difference(mirrored).area < 1e-7 * gel.area


@pytest.mark.parametrize("pattern", ["square", "hexagonal", "triangular", "diagonal"])
def test_rim_channel_covers_the_whole_outline_and_none_does_not(pattern):
    d = LatticeDesign(pattern=pattern, width_mm=3, rim="channel")
    outline = shapely.box(0, 0, 100, 100).boundary
    assert d.footprint().intersection(outline).length == pytest.approx(400.0, rel=1e-12)
    # The band is w/2 wide: a rim channel adds exactly the band's area not already covered by channels.
    band = shapely.box(0, 0, 100, 100).difference(shapely.box(1.5, 1.5, 98.5, 98.5))
    assert d.footprint().intersection(band).area == pytest.approx(band.area, rel=1e-12)
    without = d.replace(rim="none").footprint()
    assert without.intersection(outline).length < 0.5 * 400.0


def test_frame_is_silicone_but_for_the_leads_and_every_electrode_touches_gel():
    d = LatticeDesign(width_mm=4, frame_mm=6)
    band = shapely.box(0, 0, 100, 100).difference(shapely.box(6, 6, 94, 94))
    # Inside the frame only the 16 leads (w x frame depth each) are hydrogel.
    assert d.footprint().intersection(band).area == pytest.approx(16 * 4 * 6, rel=1e-9)
    assert np.all(electrode_contact_mm(d.footprint(), d.electrodes()) == pytest.approx(4.0))
    with pytest.raises(ParameterError, match=r"layout: expected .*electrode 1 at x = 12.5, y = 0"):
        d.replace(electrode_leads=False)


def test_leads_join_electrodes_the_channels_miss():
    # Pitch 30: lines at 30, 60, 90 miss the electrodes at 12.5, 37.5, ...: each gets a straight lead.
    d = LatticeDesign(width_mm=2, pitch_mm=30, electrode_width_mm=3)
    assert np.all(electrode_contact_mm(d.footprint(), d.electrodes()) > 1.9)
    with pytest.raises(ParameterError, match="electrode 1 at"):
        d.replace(electrode_leads=False)


def test_electrode_positions_are_counter_clockwise_on_every_side():
    d = LatticeDesign(electrode_positions_mm=(10, 30, 60, 80), width_mm=0)
    e = d.electrodes()
    assert e[:4, 0].tolist() == [10, 30, 60, 80] and np.all(e[:4, 1] == 0)
    assert e[4:8, 1].tolist() == [10, 30, 60, 80] and np.all(e[4:8, 0] == 100)
    assert e[8:12, 0].tolist() == [90, 70, 40, 20] and np.all(e[8:12, 1] == 100)
    assert e[12:, 1].tolist() == [90, 70, 40, 20] and np.all(e[12:, 0] == 0)
    for bad in ((10, 30, 60), (30, 10, 60, 80), (1, 30, 60, 80), (10, 12, 60, 80)):
        with pytest.raises(ParameterError, match="electrode_positions_mm"):
            LatticeDesign(electrode_positions_mm=bad)


@pytest.mark.parametrize("pattern", ["square", "hexagonal", "triangular", "diagonal"])
def test_hydrogel_fraction_solves_the_width(pattern):
    d = width_for_fraction(LatticeDesign(pattern=pattern, width_mm=1), 0.45)
    assert d.hydrogel_area_fraction() == pytest.approx(0.45, abs=1e-7)
    assert design_from_table({"pattern": pattern, "hydrogel_fraction": 0.45}) == d
    with pytest.raises(ParameterError, match="hydrogel_fraction"):
        design_from_table({"pattern": pattern, "hydrogel_fraction": 0.001})


def _polygon(ring) -> tuple:
    return (tuple(tuple(map(float, xy)) for xy in ring),)


def test_bad_custom_layouts_are_rejected_with_the_reason():
    bowtie = [[0, 0], [100, 100], [100, 0], [0, 100], [0, 0]]
    with pytest.raises(ParameterError, match=r"custom_polygons_mm\[0\]: expected a valid polygon.*Self-intersection"):
        LatticeDesign(pattern="custom", custom_polygons_mm=(_polygon(bowtie),))
    outside = [[-10, 0], [100, 0], [100, 100], [-10, 100], [-10, 0]]
    with pytest.raises(ParameterError, match="inside the sensor"):
        LatticeDesign(pattern="custom", custom_polygons_mm=(_polygon(outside),))
    with pytest.raises(ParameterError, match="closed rings"):
        LatticeDesign(pattern="custom", custom_polygons_mm=(((0, 0), (100, 0), (100, 100), (0, 100)),))
    strip = [[0, 10], [100, 10], [100, 15], [0, 15], [0, 10]]
    with pytest.raises(ParameterError, match="electrode 1 at x = 12.5, y = 0"):
        LatticeDesign(pattern="custom", custom_polygons_mm=(_polygon(strip),))
    with pytest.raises(ParameterError, match="no polygons unless pattern = 'custom'"):
        LatticeDesign(custom_polygons_mm=(((0, 0), (1, 0), (1, 1), (0, 0)),))


def test_a_family_added_to_the_table_is_a_pattern_with_its_channels_and_width_bound(monkeypatch):
    from latticeopt import layout

    def stripes(size_mm, pitch_mm, h):  # vertical channels only
        lines = layout.square_lines_mm(size_mm, pitch_mm, "channel")
        return [shapely.box(a - h, -1, a + h, size_mm + 1) for a in lines]

    monkeypatch.setitem(layout.FAMILIES, "stripes", layout.Family("stripes", stripes, 0.5, "pitch_mm / 2"))
    design = LatticeDesign(pattern="stripes", width_mm=2.0, rim="channel")
    square = LatticeDesign(pattern="square", width_mm=2.0, rim="channel")
    assert 0 < design.hydrogel_area_fraction() < square.hydrogel_area_fraction()
    with pytest.raises(ParameterError, match=r"width_mm < pitch_mm / 2 = 6.25 mm"):
        LatticeDesign(pattern="stripes", width_mm=6.25)
    assert width_for_fraction(design, 0.2).width_mm < 6.25


def test_the_pattern_lists_come_from_the_family_table():
    from latticeopt import layout

    assert layout.PATTERNS == tuple(layout.FAMILIES) and "custom" in layout.PATTERNS
    assert layout.PARAMETRIC == tuple(n for n in layout.PATTERNS if n != "custom")
    assert layout.MAX_WIDTH_FRACTION == {n: layout.FAMILIES[n].max_width_fraction for n in layout.PARAMETRIC}
    with pytest.raises(ParameterError, match="2/3 pitch_mm"):
        LatticeDesign(pattern="triangular", width_mm=2 / 3 * 12.5)
