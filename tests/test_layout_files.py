"""Layout files: GeoJSON written and read back gives the same hydrogel, and bad files are refused with the reason."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from latticeopt.design import LatticeDesign, design_from_table
from latticeopt.errors import ParameterError
from latticeopt.layout import electrode_contact_mm
from latticeopt.layout_files import read_geojson, read_layout, write_geojson


def test_geojson_round_trip_gives_the_same_hydrogel(tmp_path):
    src = LatticeDesign(pattern="hexagonal", width_mm=3)
    path = tmp_path / "hex.geojson"
    write_geojson(src.footprint(), path)
    custom = design_from_table({"layout": str(path), "thickness_mm": 3})
    assert custom.pattern == "custom"
    assert custom.footprint().symmetric_difference(src.footprint()).area < 1e-9
    assert custom.region_volumes_mm3()["hydrogel"] == pytest.approx(src.region_volumes_mm3()["hydrogel"], rel=1e-12)
    # The design holds the polygons themselves: its identity does not depend on where the file was.
    assert LatticeDesign(**custom.as_dict()).content_hash() == custom.content_hash()


def _write(tmp_path, coords, name="l.geojson"):
    path = tmp_path / name
    path.write_text(json.dumps({"type": "Polygon", "coordinates": coords}))
    return path


def test_bad_geojson_files_are_refused_with_the_reason(tmp_path):
    (tmp_path / "p.geojson").write_text(json.dumps({"type": "Point", "coordinates": [1, 2]}))
    with pytest.raises(ParameterError, match="Polygon or MultiPolygon"):
        read_geojson(tmp_path / "p.geojson")
    (tmp_path / "b.geojson").write_bytes(b"\xff\xfe{")
    with pytest.raises(ParameterError, match="UTF-8 JSON"):
        read_geojson(tmp_path / "b.geojson")
    with pytest.raises(ParameterError, match="readable GeoJSON"):
        read_geojson(tmp_path / "missing.geojson")
    with pytest.raises(ParameterError, match=r"--layout: expected a GeoJSON \(.geojson, .json\) or DXF"):
        read_layout(tmp_path / "l.svg")
    bowtie = [[[0, 0], [100, 100], [100, 0], [0, 100], [0, 0]]]
    with pytest.raises(ParameterError, match="Self-intersection"):
        LatticeDesign(pattern="custom", custom_polygons_mm=read_geojson(_write(tmp_path, bowtie)))


def test_shipped_example_layout_is_valid():
    path = Path(__file__).resolve().parents[1] / "studies" / "data" / "ring_layout.geojson"
    d = design_from_table({"layout": str(path)})
    assert np.all(electrode_contact_mm(d.footprint(), d.electrodes()) > 0)


