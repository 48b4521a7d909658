"""``latticeopt indent``: JSON output, VTU export and one-line errors for bad input."""

import json

import numpy as np
import pytest

from latticeopt.cli import main

COARSE = ["--sensor-size", "50", "--size", "5", "--no-cache"]


def test_indent_json_and_vtu(capsys, tmp_path):
    out = tmp_path / "pressed.vtu"
    code = main(["indent", "--width", "4", "--thickness", "3", "--touch", "25,25,7.5,1.5",
                 "--touch", "10,40,5,1", "--json", "-o", str(out), *COARSE])
    assert code == 0
    data = json.loads(capsys.readouterr().out)
    assert len(data["forces_N"]) == 2 and all(f > 0 for f in data["forces_N"])
    assert data["newton_steps"] >= 1 and data["seconds"] > 0
    assert 1.0 < data["max_hydrogel_stretch"] < 3.0
    assert out.exists()
    import meshio

    assert np.isfinite(meshio.read(out).point_data["displacement_mm"]).all()


def test_indent_text_output(capsys):
    assert main(["indent", "--touch", "25,25,7.5,1", *COARSE]) == 0
    text = capsys.readouterr().out
    assert "force" in text and "Newton steps" in text


@pytest.mark.parametrize("touch, fragment", [
    ("25,25,7.5", "--touch #1"), ("25,25,x,1", "--touch #1"), ("25,25,-1,1", "radius_mm"),
    ("49,25,7.5,1", "--touch #1 x_mm"), ("25,25,7.5,9.5", "--touch #1 depth_mm"),
])
def test_bad_touch_is_a_one_line_exit_2(capsys, touch, fragment):
    code = main(["indent", "--touch", touch, *COARSE])
    err = capsys.readouterr().err
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and fragment in err and "Traceback" not in err


def test_overlapping_touches_rejected(capsys):
    assert main(["indent", "--touch", "20,25,6,1", "--touch", "28,25,6,1", *COARSE]) == 2
    err = capsys.readouterr().err
    assert "--touch #2 (x_mm, y_mm)" in err and "from --touch #1 at" in err and "touches[" not in err


@pytest.mark.parametrize("cmd", ["indent", "simulate"])
def test_a_touch_the_mesh_cannot_hold_is_named_by_its_option(capsys, cmd):
    # found once the mesh exists (no top node inside a 0.2 mm disc), yet named as the checks before any work name it
    code = main([cmd, "--touch", "20,20,5,1", "--touch", "24.3,35.7,0.2,1", *COARSE])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "--touch #2 radius_mm" in err and "top-surface node" in err and "touches[" not in err
