"""Graded honeycomb (latticeopt.density.graded_honeycomb) and its optimization through the CLI."""

import json
from pathlib import Path

import numpy as np
import pytest
import shapely
from graded_checks import assert_gradient_matches_central_differences

from latticeopt.cli import main
from latticeopt.density.graded_honeycomb import GradedHoneycomb, edge_orbits
from latticeopt.design import LatticeDesign
from latticeopt.layout import parametric_footprint

ROOT = Path(__file__).resolve().parents[1]
HEX = LatticeDesign(thickness_mm=3.0, pattern="hexagonal")


@pytest.mark.parametrize("symmetry", ["none", "mirror"])
def test_gradient_matches_central_differences(symmetry):
    param = GradedHoneycomb(HEX, 10, symmetry, smoothing_mm=1.0, samples=2)
    rng = np.random.default_rng(1)
    x = rng.uniform(1.5, 6.0, param.n_variables)
    g = rng.normal(size=(10, 10))
    assert_gradient_matches_central_differences(param, x, g)


def test_equal_widths_are_the_parametric_honeycomb():
    """Every edge at w: the exact outline is the parametric hexagonal lattice of width w (which leaves out the edges
    on the sides: no rim channel) plus the graded lattice's fixed leads; the smooth density holds the outline's gel;
    every electrode is joined."""
    from latticeopt.layout import electrode_contact_mm

    param = GradedHoneycomb(HEX, 25, "mirror", smoothing_mm=0.2, samples=8)
    assert param.leads.area > 0  # the honeycomb at pitch 12.5 misses electrodes on two sides
    for w in (1.0, 3.0, 6.0):
        x = np.full(param.n_variables, w)
        exact = parametric_footprint("hexagonal", 100.0, w, 12.5, "none", 0.0)
        geom = param.polygons(x)
        assert geom.symmetric_difference(exact).difference(param.leads).area < 1e-9 * exact.area
        assert abs(param.density(x).mean() - geom.area / 1e4) < 0.005
        assert (electrode_contact_mm(geom, HEX.electrodes()) >= 0.5).all()


def test_mirror_orbits_make_a_mirror_symmetric_layout_and_a_quarter_turn_is_no_symmetry():
    param = GradedHoneycomb(HEX, 20, "mirror", smoothing_mm=1.0, samples=2)
    none = GradedHoneycomb(HEX, 20, "none", smoothing_mm=1.0, samples=2)
    assert none.n_variables == len(none.segments_mm) > 3 * param.n_variables - 10
    rho = param.density(np.random.default_rng(3).uniform(1.0, 6.0, param.n_variables))
    for image in (rho[::-1], rho[:, ::-1], rho[::-1, ::-1]):
        assert np.allclose(image, rho, atol=1e-12)
    assert not np.allclose(rho.T, rho, atol=1e-3)
    quarter = np.array([[0.0, -1.0], [1.0, 0.0]])
    mid = (param.segments_mm[:, 0] + param.segments_mm[:, 1]) / 2 - 50.0
    assert not np.allclose(np.sort(mid @ quarter.T, axis=0), np.sort(mid, axis=0))  # what "d4" is refused for
    with pytest.raises(Exception, match="symmetry"):
        GradedHoneycomb(HEX, 20, "d4")
    with pytest.raises(ValueError, match="not mapped"):
        edge_orbits(np.array([[1.0, 2.0]]), "mirror")


def test_sharp_density_covers_the_exact_polygons():
    x = np.random.default_rng(2).uniform(1.0, 6.0, GradedHoneycomb(HEX, 10).n_variables)
    errors = []
    for k in (4, 16):
        param = GradedHoneycomb(HEX, 10, "mirror", smoothing_mm=0.01, samples=k)
        rho, geom = param.density(x), param.polygons(x)
        cells = np.array([[geom.intersection(shapely.box(10 * j, 10 * i, 10 * j + 10, 10 * i + 10)).area / 100
                           for j in range(10)] for i in range(10)])
        errors.append((np.abs(rho - cells).max(), abs(rho.mean() - cells.mean())))
    assert errors[1][0] < 0.5 * errors[0][0] and errors[1][0] < 0.05 and errors[1][1] < 0.01


SMALL = ["--set", "mesh.size_mm=5", "--set", "graded.cells=10", "--set", "phantoms.counts={1=1,2=0,3=0}",
         "--set", "graded.iterations=2", "--set", "graded.min_width_mm=2"]


def test_cli_optimizes_a_graded_honeycomb(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(ROOT)
    out = tmp_path / "hex"
    assert main(["optimize", "studies/optimize_graded.toml", "--out", str(out), "--set", "design.pattern=hexagonal",
                 "--set", "graded.symmetry=mirror", *SMALL]) == 0
    widths = json.loads((out / "widths.json").read_text())
    n = GradedHoneycomb(HEX, 10, "mirror").n_variables
    assert widths["pattern"] == "hexagonal" and len(widths["variables_mm"]) == n
    assert all(2.0 - 1e-9 <= e["width_mm"] <= 10.5 + 1e-9 for e in widths["edges"])
    assert "graded honeycomb: pitch 12.5 mm" in (out / "report.txt").read_text()
    assert main(["mesh", "--layout", str(out / "layout.geojson"), "--mesh-size", "6", "--json"]) == 0
    capsys.readouterr()
    assert main(["optimize", "studies/optimize_graded.toml", "--set", "design.pattern=hexagonal",
                 "--set", "graded.symmetry=mirror", "--dry-run"]) == 0
    assert "a width per edge of pitch 12.5 mm" in capsys.readouterr().out
