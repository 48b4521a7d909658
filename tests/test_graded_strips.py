"""Graded straight-line lattices (latticeopt.density.graded_strips) and their optimization through the CLI."""

import json
from pathlib import Path

import numpy as np
import pytest

from latticeopt.cli import main
from latticeopt.density.graded import GradedSquare
from latticeopt.density.graded_strips import GradedStrips, line_orbits
from latticeopt.design import LatticeDesign
from latticeopt.layout import check_electrodes, lattice_lines

ROOT = Path(__file__).resolve().parents[1]


def _design(pattern: str) -> LatticeDesign:
    return LatticeDesign(thickness_mm=3.0, pattern=pattern)


@pytest.mark.parametrize("symmetry", ["none", "mirror", "d4"])
def test_on_the_square_pattern_it_is_the_outer_product_construction(symmetry):
    """GradedSquare builds the square lattice as an outer product along x and y; the general strips must give the
    same orbits, density and gradient."""
    strips = GradedStrips(_design("square"), 12, symmetry, smoothing_mm=1.0, samples=2)
    square = GradedSquare(_design("square"), 12, symmetry, smoothing_mm=1.0, samples=2)
    rng = np.random.default_rng(0)
    x = rng.uniform(1.0, 8.0, square.n_variables)
    g = rng.normal(size=(12, 12))
    assert np.array_equal(strips.group, square.group)
    assert np.allclose(strips.density(x), square.density(x), atol=1e-14)
    assert np.allclose(strips.gradient(x, None, g), square.gradient(x, None, g), atol=1e-12)


@pytest.mark.parametrize("pattern", ["diagonal", "triangular"])
def test_gradient_matches_central_differences(pattern):
    param = GradedStrips(_design(pattern), 12, "d4", smoothing_mm=1.0, samples=2)
    rng = np.random.default_rng(1)
    x = rng.uniform(1.5, 6.0, param.n_variables)
    g = rng.normal(size=(12, 12))
    h = 1e-5
    fd = [(np.sum(g * param.density(x + h * e)) - np.sum(g * param.density(x - h * e))) / (2 * h)
          for e in np.eye(param.n_variables)]
    assert np.allclose(param.gradient(x, None, g), fd, rtol=1e-6, atol=1e-9 * np.abs(fd).max())


@pytest.mark.parametrize("pattern", ["diagonal", "triangular"])
def test_sharp_density_covers_the_exact_polygons(pattern):
    """With a smoothing far below a cell, each cell's density tends to the polygons' share of it as the samples
    per cell grow (sample rows along a 45-degree edge fall wholly in or out: an error of order the spacing)."""
    import shapely

    x = np.random.default_rng(2).uniform(1.0, 6.0, GradedStrips(_design(pattern), 10).n_variables)
    errors = []
    for k in (4, 16):
        param = GradedStrips(_design(pattern), 10, "d4", smoothing_mm=0.01, samples=k)
        rho, geom = param.density(x), param.polygons(x)
        cells = np.array([[geom.intersection(shapely.box(10 * j, 10 * i, 10 * j + 10, 10 * i + 10)).area / 100
                           for j in range(10)] for i in range(10)])
        errors.append((np.abs(rho - cells).max(), abs(rho.mean() - cells.mean())))
    assert errors[1][0] < 0.5 * errors[0][0] and errors[1][0] < 0.05 and errors[1][1] < 0.01


def test_d4_orbits_make_a_d4_symmetric_layout():
    param = GradedStrips(_design("diagonal"), 20, "d4", smoothing_mm=1.0, samples=2)
    # 11 lines in each direction; D4 joins the two directions and mirrors each about the centre: 6 orbits
    assert len(param.offsets_mm) == 22 and param.n_variables == 6
    rho = param.density(np.random.default_rng(3).uniform(1.0, 6.0, 6))
    for image in (rho.T, rho[::-1], rho[:, ::-1], np.rot90(rho)):
        assert np.allclose(image, rho, atol=1e-12)
    n, o = lattice_lines("triangular", 100.0, 12.5)
    assert line_orbits(n, o, "none").max() == len(o) - 1  # no symmetry: every line its own variable


def test_leads_join_every_electrode_the_lines_miss():
    """The triangular lines miss some electrodes at the narrowest width; the fixed leads join them."""
    param = GradedStrips(_design("triangular"), 10, lead_width_mm=1.0)
    assert param.leads.area > 0
    narrow = np.full(param.n_variables, 1.0)
    check_electrodes(param.polygons(narrow), _design("triangular").electrodes(), 100.0)
    assert (param.density(narrow) > 0).all()  # the smooth bands reach everywhere a little
    with pytest.raises(Exception, match="electrode"):
        check_electrodes(param._geometry(param.widths(narrow)), _design("triangular").electrodes(), 100.0)


SMALL = ["--set", "mesh.size_mm=5", "--set", "graded.cells=10", "--set", "phantoms.counts={1=1,2=0,3=0}",
         "--set", "graded.iterations=2", "--set", "graded.min_width_mm=2"]


def test_cli_optimizes_a_graded_diagonal_lattice_and_refuses_the_honeycomb(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(ROOT)
    out = tmp_path / "diag"
    assert main(["optimize", "studies/optimize_graded.toml", "--out", str(out), "--set", "design.pattern=diagonal",
                 *SMALL]) == 0
    widths = json.loads((out / "widths.json").read_text())
    assert widths["pattern"] == "diagonal" and len(widths["lines"]) == 22 and len(widths["variables_mm"]) == 6
    assert all(2.0 <= line["width_mm"] <= 10.5 for line in widths["lines"])
    assert "graded diagonal lattice: pitch 12.5 mm, 22 lines in 6 orbits" in (out / "report.txt").read_text()
    assert main(["mesh", "--layout", str(out / "layout.geojson"), "--mesh-size", "6", "--json"]) == 0
    capsys.readouterr()
    assert main(["optimize", "studies/optimize_graded.toml", "--out", str(tmp_path / "hex"),
                 "--set", "design.pattern=hexagonal", *SMALL]) == 2
    err = capsys.readouterr().err
    assert "--set design.pattern" in err and "square, diagonal, triangular" in err and "hexagonal" in err
    assert err.count("\n") == 1 and "Traceback" not in err and not (tmp_path / "hex").exists()
    assert main(["optimize", "studies/optimize_graded.toml", "--set", "design.pattern=hexagonal", "--dry-run"]) == 2
