"""``simulate --density --gradient`` and ``export-density`` from the command line: the written gradient agrees
with central differences of the V_rel that the command prints, and bad density files stop before meshing."""

import json

import numpy as np
import pytest
from test_cli_fuzz import run_cli

from latticeopt.cli import main

COMMON = ["--thickness", "3", "--touch", "45,55,12,2.5", "--size", "8", "--physics", "mechanics_rtol=1e-10"]


def _v_rel(capsys, density_file, common=COMMON) -> float:
    assert main(["simulate", "--density", str(density_file), *common, "--json"]) == 0
    return json.loads(capsys.readouterr().out)["v_rel"]


@pytest.mark.parametrize("edge", [[], ["--edge-radius", "6"]], ids=["sharp", "rounded"])
def test_cli_gradient_matches_central_differences(tmp_path, capsys, edge):
    # a rounded punch edge holds the top by unilateral contact: the adjoint takes its converged active set
    common = [*COMMON, *edge]
    start = tmp_path / "lattice.npz"
    assert main(["export-density", "--width", "4", "--cells", "8", "--smoothing-mm", "3", "-o", str(start)]) == 0
    capsys.readouterr()
    grad = tmp_path / "g.npz"
    assert main(["simulate", "--density", str(start), *common, "--gradient", str(grad), "--plot",
                 str(tmp_path / "g.png")]) == 0
    assert "gradients written to" in capsys.readouterr().out
    with np.load(grad) as z:
        g = z["dv_rel_ddensity"]
        assert g.shape == (8, 8) and z["dforce_ddensity"].shape == (8, 8)
        density = z["density"]
    y, x = np.mgrid[0:8, 0:8] / 8
    direction = np.cos(np.pi * x) * np.sin(np.pi * y + 0.4)
    h = 1e-4
    values = []
    for sign in (1, -1):
        path = tmp_path / f"d{sign}.npz"
        np.savez(path, density=np.clip(density + sign * h * direction, 0, 1))
        values.append(_v_rel(capsys, path, common))
    fd = (values[0] - values[1]) / (2 * h)
    assert 0 < density.min() and density.max() < 1  # no clipping: the difference is central
    assert abs(np.sum(g * direction) - fd) <= 1e-4 * abs(fd)
    assert (tmp_path / "g.png").stat().st_size > 10_000


@pytest.mark.parametrize("content, words", [
    ({"density": np.full((8, 9), 0.5)}, "shape (8, 9)"),
    ({"density": np.full((8, 8), np.nan)}, "NaN"),
    ({"density": np.full((8, 8), -0.1)}, "[0, 1]"),
    ({"rho": np.full((8, 8), 0.5)}, "'density'"),
])
def test_bad_density_file_is_one_line_before_meshing(tmp_path, content, words):
    np.savez(tmp_path / "bad.npz", **content)
    outcome, status, err = run_cli(["simulate", "--density", "bad.npz", "--touch", "50,50,8,3"], tmp_path)
    assert outcome == "returned" and status == 2 and len(err.splitlines()) == 1
    assert "--density" in err and words in err


def test_pickled_density_file_is_refused(tmp_path):
    np.save(tmp_path / "obj.npy", np.array([{"density": 1}], dtype=object), allow_pickle=True)
    (tmp_path / "obj.npz").write_bytes((tmp_path / "obj.npy").read_bytes())
    outcome, status, err = run_cli(["simulate", "--density", "obj.npz", "--touch", "50,50,8,3"], tmp_path)
    assert status == 2 and "--density" in err and "Traceback" not in err


@pytest.mark.parametrize("argv, flag", [
    (["--gradient", "g.npz"], "--density"),
    (["--density", "ok.npz", "--plot", "p.png"], "--plot"),
    (["--density", "ok.npz", "--gradient", "g.txt"], "--gradient"),
    (["--density", "ok.npz", "--interpolation", "conductivity_floor=0.5"], "conductivity_floor"),
    (["--density", "ok.npz", "--physics", "conductivity_law='linear'"], "conductivity_law"),
])
def test_density_options_are_checked_before_meshing(tmp_path, argv, flag):
    np.savez(tmp_path / "ok.npz", density=np.full((8, 8), 0.5))
    outcome, status, err = run_cli(["simulate", *argv, "--touch", "50,50,8,3"], tmp_path)
    assert outcome == "returned" and status == 2 and flag in err and len(err.splitlines()) == 1
