"""``latticeopt forward`` end to end on a coarse mesh."""

import json

import numpy as np
import pytest

from latticeopt.cli import main
from latticeopt.electrics import DEFAULT_CONTACT_IMPEDANCE_OHM_M2, DEFAULT_SIGMA_S_PER_M, Protocol

COARSE = ["--width", "4", "--thickness", "3", "--size", "5", "--no-cache"]


def test_forward_json(capsys):
    assert main(["forward", *COARSE, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    V = np.array(out["voltages"])
    p = Protocol.adjacent(16)
    assert V.shape == (208,) and len(out["independent"]) == 104
    np.testing.assert_array_equal(out["independent"], V[p.independent])
    np.testing.assert_array_equal(out["meas_pairs"], p.meas_pairs)
    assert out["reciprocity_error"] < 1e-8
    assert out["seconds"] > 0
    # z_c sigma / w with the design's 4 mm electrodes
    assert out["contact_number"] == pytest.approx(DEFAULT_CONTACT_IMPEDANCE_OHM_M2 * DEFAULT_SIGMA_S_PER_M / 4e-3)


@pytest.mark.parametrize("pattern, width, dead", [("diagonal", "3", True), ("square", "4", False)])
def test_forward_names_rows_at_round_off(pattern, width, dead, capsys):
    """The diagonal lattice at w = 3 hangs its corner electrodes on dead-end channels: rows at round-off."""
    args = ["forward", "--pattern", pattern, "--width", width, "--mesh-size", "5", "--channel-cells", "1", "--no-cache"]
    assert main([*args, "--json"]) == 0
    small = json.loads(capsys.readouterr().out)["min_reference_rel"]
    assert (small < 1e-10) == dead and (small > 1e-6) == (not dead)
    assert main(args) == 0
    assert ("round-off" in capsys.readouterr().out) == dead


def test_forward_fields(tmp_path, capsys):
    png, vtu = tmp_path / "f.png", tmp_path / "f.vtu"
    assert main(["forward", *COARSE, "--plot", str(png), "--plot-uniform", "--vtu", str(vtu), "--drive", "3"]) == 0
    text = capsys.readouterr().out
    assert "reciprocity error" in text and png.stat().st_size > 10_000 and vtu.stat().st_size > 10_000
    import meshio

    m = meshio.read(vtu)
    assert "potential_V_drive_16" in m.point_data and "current_density_A_per_m2" in m.cell_data


@pytest.mark.parametrize("args, name", [(["--protocol", "zigzag"], "--protocol"), (["--sigma", "0"], "--sigma"),
                                        (["--drive", "0"], "--drive"), (["--plot", "a.jpg"], "--plot"),
                                        (["--electrode-mode", "gap"], "--electrode-mode")])
def test_bad_input_exits_2(args, name, capsys):
    assert main(["forward", *COARSE, *args]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and name in err
