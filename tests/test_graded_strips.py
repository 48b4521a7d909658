"""Graded straight-line lattices (latticeopt.density.graded_strips) and their optimization through the CLI."""

import json
from pathlib import Path

import numpy as np
import pytest
from graded_checks import assert_gradient_matches_central_differences

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
    assert_gradient_matches_central_differences(param, x, g)


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


def test_cli_optimizes_a_graded_diagonal_lattice_and_refuses_a_quarter_turn_of_the_honeycomb(tmp_path, monkeypatch,
                                                                                           capsys):
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
                 "--set", "design.pattern=hexagonal", *SMALL]) == 2  # the study's symmetry is d4
    err = capsys.readouterr().err
    assert "graded.symmetry" in err and "'mirror' or 'none' for the hexagonal pattern" in err and "'d4'" in err
    assert err.count("\n") == 1 and "Traceback" not in err and not (tmp_path / "hex").exists()
    assert main(["optimize", "studies/optimize_graded.toml", "--set", "design.pattern=hexagonal", "--dry-run"]) == 2


# -- lines that move (graded.max_shift_mm) -------------------------------------------------------------------------
def _moving(pattern: str, symmetry: str, n: int = 12, **kw) -> GradedStrips:
    return GradedStrips(_design(pattern), n, symmetry, smoothing_mm=1.0, samples=2, max_shift_mm=3.0, **kw)


@pytest.mark.parametrize("pattern,symmetry", [("square", "none"), ("square", "mirror"), ("diagonal", "d4")])
def test_gradient_in_widths_and_shifts_matches_central_differences(pattern, symmetry):
    param = _moving(pattern, symmetry)
    assert param.n_shifts > 0
    rng = np.random.default_rng(4)
    x = np.r_[rng.uniform(1.5, 6.0, param.n_widths), rng.uniform(-2.5, 2.5, param.n_shifts)]
    g = rng.normal(size=(12, 12))
    assert_gradient_matches_central_differences(param, x, g)


def test_without_shift_the_moving_lattice_is_the_fixed_one():
    fixed, moving = (GradedStrips(_design("diagonal"), 12, "d4", smoothing_mm=1.0, samples=2),
                     _moving("diagonal", "d4"))
    w = np.random.default_rng(5).uniform(1.0, 6.0, fixed.n_variables)
    x = np.r_[w, np.zeros(moving.n_shifts)]
    assert np.array_equal(moving.density(x), fixed.density(w))
    assert moving.polygons(x).symmetric_difference(fixed.polygons(w)).area < 1e-9


@pytest.mark.parametrize("pattern,pitch_mm", [("square", 12.5), ("diagonal", 12.5), ("square", 10.0),
                                              ("diagonal", 10.0)])
def test_shifted_lines_keep_the_symmetry_and_the_electrodes(pattern, pitch_mm):
    """Shifts move an orbit's lines as the group maps them: the layout stays D4-symmetric; lines that carry an
    electrode or a lead stay, so every electrode keeps its contact and the layout stays in one piece; the centre
    lines (mapped onto themselves reversed) stay. At pitch 10 mm the lines miss electrodes and leads join them."""
    from latticeopt.layout import electrode_contact_mm

    design = LatticeDesign(thickness_mm=3.0, pattern=pattern, pitch_mm=pitch_mm)
    param = GradedStrips(design, 20, "d4", smoothing_mm=1.0, samples=2, max_shift_mm=3.0)
    assert param.n_shifts > 0 and (pitch_mm == 12.5 or param.leads.area > 0)
    x = np.r_[np.full(param.n_widths, 2.0), np.full(param.n_shifts, 2.5)]
    rho = param.density(x)
    for image in (rho.T, rho[::-1], rho[:, ::-1], np.rot90(rho)):
        assert np.allclose(image, rho, atol=1e-12)
    assert np.abs(param.shifts(x)).max() == 2.5
    assert np.all(param.shifts(x)[np.abs(param.offsets_mm) < 1e-9] == 0)
    # at the narrowest width (the leads'), every electrode still has at least half that width on hydrogel, and the
    # hydrogel is one piece
    narrow = np.r_[np.full(param.n_widths, 1.0), np.full(param.n_shifts, 2.5)]
    geom = param.polygons(narrow)
    assert (electrode_contact_mm(geom, design.electrodes()) >= 0.5).all()
    assert len(getattr(geom, "geoms", [geom])) == 1


def test_island_constraints_are_the_gaps_between_the_exact_strips():
    """The smallest slack of ``A x <= b`` is the narrowest gap between neighbouring parallel strips (measured
    on the shapely rectangles) less the island width."""
    import shapely

    from latticeopt.layout import line_strip

    param = _moving("square", "none")
    A, b = param.island_constraints(2.0)
    rng = np.random.default_rng(6)
    for _ in range(5):
        x = np.r_[rng.uniform(1.0, 6.0, param.n_widths), rng.uniform(-3.0, 3.0, param.n_shifts)]
        offsets, w = param.offsets_mm + param.shifts(x), param.widths(x)
        gaps = []
        for i in range(len(w)):
            for j in range(len(w)):
                parallel = np.allclose(param.normals[i], param.normals[j])
                if parallel and 0 < offsets[j] - offsets[i] < 12.5 + 6.1:  # neighbours (shifts < pitch / 2)
                    si, sj = (line_strip(param.normals[k], offsets[k], np.array([50.0, 50.0]), w[k] / 2, 100.0)
                              for k in (i, j))
                    gaps.append(shapely.distance(si, sj) if not si.intersects(sj) else -shapely.intersection(
                        si, sj).area / 200.0)
        assert np.isclose(np.min(b - A @ x), min(gaps) - 2.0, atol=1e-9)


def test_cli_moves_the_lines_of_a_square_lattice_and_refuses_moving_triangles(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(ROOT)
    out = tmp_path / "moving"
    assert main(["optimize", "studies/optimize_graded.toml", "--out", str(out), "--set", "graded.max_shift_mm=3",
                 "--set", "graded.symmetry=mirror", *SMALL]) == 0
    widths = json.loads((out / "widths.json").read_text())
    shifts = np.array([line["shift_mm"] for line in widths["lines"]])
    assert len(widths["variables_mm"]) == 10 and np.abs(shifts).max() <= 3.0 + 1e-9
    assert "line shifts (mm, within +-3)" in (out / "report.txt").read_text()
    assert main(["mesh", "--layout", str(out / "layout.geojson"), "--mesh-size", "6", "--json"]) == 0
    capsys.readouterr()
    for bad, says in (("design.pattern=triangular", "0 for the triangular pattern"),
                      ("graded.max_shift_mm=7", "at most half the pitch (6.25 mm)")):
        args = ["--set", bad] + (["--set", "graded.max_shift_mm=3"] if "triangular" in bad else [])
        assert main(["optimize", "studies/optimize_graded.toml", *args, "--dry-run"]) == 2
        err = capsys.readouterr().err
        assert "--set graded.max_shift_mm" in err and says in err and err.count("\n") == 1


def test_lines_on_the_pitch_keep_the_identity_of_runs_stored_before_shifts_existed():
    from latticeopt.coupled import PhysicsSettings
    from latticeopt.mesh import MeshSettings
    from latticeopt.optimize.graded import GradedConfig
    from latticeopt.optimize.identity import run_identity

    ident = run_identity(_design("square"), [], MeshSettings(), PhysicsSettings(), GradedConfig())
    assert "max_shift_mm" not in ident["config"] and "min_island_mm" in ident["config"]
    moved = run_identity(_design("square"), [], MeshSettings(), PhysicsSettings(), GradedConfig(max_shift_mm=2.0))
    assert moved["config"]["max_shift_mm"] == 2.0
