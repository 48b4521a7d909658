"""DXF layouts: drawings written with ezdxf, read back, against closed-form areas and the GeoJSON path."""

from __future__ import annotations

import math

import pytest

from latticeopt.design import LatticeDesign, design_from_table
from latticeopt.errors import ParameterError
from latticeopt.layout_dxf import FLATTEN_TOL_MM, read_dxf
from latticeopt.layout_files import geometry_from_polygons

ezdxf = pytest.importorskip("ezdxf")


def _drawing(tmp_path, add, units=4, name="layout.dxf"):
    doc = ezdxf.new()
    doc.header["$INSUNITS"] = units
    add(doc.modelspace())
    path = tmp_path / name
    doc.saveas(path)
    return path


def _square_lattice_outline(msp, scale=1.0):
    """The rim-free square lattice (w = 4, p = 12.5) as a frame-free drawing: its footprint's rings as closed
    polylines, in drawing units of ``1 / scale`` mm."""
    gel = LatticeDesign(width_mm=4).footprint()
    for poly in getattr(gel, "geoms", [gel]):
        for ring in (poly.exterior, *poly.interiors):
            msp.add_lwpolyline([(x / scale, y / scale) for x, y in ring.coords[:-1]], close=True)


def test_nested_loops_alternate_gel_and_hole_and_curves_keep_their_area(tmp_path):
    def add(msp):
        msp.add_lwpolyline([(0, 0), (100, 0), (100, 100), (0, 100)], close=True)  # gel
        msp.add_circle((50, 50), radius=30)                                      # hole
        msp.add_circle((50, 50), radius=10)                                      # gel again inside the hole

    polys = read_dxf(_drawing(tmp_path, add))
    d = LatticeDesign(pattern="custom", custom_polygons_mm=polys)
    exact = 100 ** 2 - math.pi * 30 ** 2 + math.pi * 10 ** 2
    # each circle is flattened to within FLATTEN_TOL_MM: the area moves by at most its perimeter times that
    tol = 2 * math.pi * (30 + 10) * FLATTEN_TOL_MM
    assert abs(d.footprint().area - exact) <= tol
    assert d.region_volumes_mm3()["hydrogel"] == pytest.approx(d.footprint().area * d.thickness_mm, rel=1e-12)


def test_dxf_of_a_lattice_equals_the_lattice_in_any_unit(tmp_path):
    ref = LatticeDesign(width_mm=4)
    for units, mm_per_unit in ((4, 1.0), (5, 10.0), (1, 25.4)):
        path = _drawing(tmp_path, lambda msp, s=mm_per_unit: _square_lattice_outline(msp, s), units=units,
                        name=f"lattice{units}.dxf")
        custom = design_from_table({"layout": str(path)})
        assert custom.pattern == "custom"
        assert custom.footprint().symmetric_difference(ref.footprint()).area < 1e-6


def test_bulge_arcs_are_followed(tmp_path):
    # a 20 x 20 square whose right side bulges out into a half circle of radius 10 (bulge 1 = 180 degrees)
    def add(msp):
        msp.add_lwpolyline([(40, 40, 0, 0, 0), (60, 40, 0, 0, 1), (60, 60, 0, 0, 0), (40, 60, 0, 0, 0)],
                           format="xyseb", close=True)

    gel = geometry_from_polygons(read_dxf(_drawing(tmp_path, add)))
    exact = 20 * 20 + math.pi * 10 ** 2 / 2
    assert abs(gel.area - exact) <= 2 * math.pi * 10 * FLATTEN_TOL_MM
    assert gel.bounds == pytest.approx((40, 40, 70, 60), abs=FLATTEN_TOL_MM)


def test_bad_drawings_are_rejected_with_what_is_wrong(tmp_path):
    with pytest.raises(ParameterError, match=r"--layout: expected closed curves.*LWPOLYLINE \(handle"):
        read_dxf(_drawing(tmp_path, lambda msp: msp.add_lwpolyline([(0, 0), (100, 0), (100, 100)]), name="o.dxf"))
    with pytest.raises(ParameterError, match=r"only closed curves.*LINE \(handle"):
        read_dxf(_drawing(tmp_path, lambda msp: msp.add_line((0, 0), (1, 1)), name="l.dxf"))
    with pytest.raises(ParameterError, match=r"\$INSUNITS.*got '2 in"):  # feet
        read_dxf(_drawing(tmp_path, lambda msp: msp.add_circle((50, 50), 10), units=2, name="f.dxf"))
    with pytest.raises(ParameterError, match="at least one closed curve"):
        read_dxf(_drawing(tmp_path, lambda msp: None, name="e.dxf"))
    (tmp_path / "bad.dxf").write_text("not a drawing")
    with pytest.raises(ParameterError, match="a readable DXF file"):
        read_dxf(tmp_path / "bad.dxf")
    with pytest.raises(ParameterError, match=r"layout: expected a GeoJSON \(.geojson, .json\) or DXF"):
        design_from_table({"layout": str(tmp_path / "x.svg")})
    # a drawing that misses an electrode fails in the design, naming the electrode
    strip = _drawing(tmp_path, lambda msp: msp.add_lwpolyline([(0, 10), (100, 10), (100, 15), (0, 15)], close=True),
                     name="s.dxf")
    with pytest.raises(ParameterError, match="electrode 1 at x = 12.5, y = 0"):
        design_from_table({"layout": str(strip), "electrode_leads": False})


def test_cli_reads_a_dxf_layout(tmp_path, capsys):
    import json

    from latticeopt.cli import main

    path = _drawing(tmp_path, _square_lattice_outline)
    assert main(["mesh", "--layout", str(path), "--thickness", "3", "--size", "4", "--no-cache", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    area = LatticeDesign(width_mm=4).footprint().area
    assert out["region_volumes_mm3"]["hydrogel"] == pytest.approx(area * 3, rel=1e-9)


def test_without_ezdxf_the_error_says_how_to_install_it(tmp_path, monkeypatch):
    import sys

    path = _drawing(tmp_path, lambda msp: msp.add_circle((50, 50), 10))
    monkeypatch.setitem(sys.modules, "ezdxf", None)  # import ezdxf now raises ImportError
    with pytest.raises(ParameterError, match=r"latticeopt\[dxf\]"):
        read_dxf(path)
