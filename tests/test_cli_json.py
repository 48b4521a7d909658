"""``--json`` outputs: strict JSON (``null``, never ``NaN``), self-describing (design, resolved mesh settings,
touches), and the commands write nothing into the working folder (caches go to the user cache folder)."""

from __future__ import annotations

import json
import math

import pytest

from latticeopt.cli import main
from latticeopt.cli._common import emit_json

COARSE = ["--width", "4", "--thickness", "3", "--size", "6"]


def _reject_constant(name):
    raise ValueError(f"not JSON: {name}")


def _strict(text: str) -> dict:
    lines = text.strip().splitlines()
    assert len(lines) == 1, text[:300]
    return json.loads(lines[0], parse_constant=_reject_constant)


@pytest.fixture
def clean_cwd(tmp_path, monkeypatch):
    """A fresh working folder, with the user cache folder (and home) pointed elsewhere."""
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.delenv("LATTICEOPT_MESH_CACHE", raising=False)
    return work


def test_emit_json_writes_null_for_non_finite_values(capsys):
    emit_json({"cc": float("nan"), "nested": {"x": [1.0, float("-inf")]}, "ok": 2.5})
    out = _strict(capsys.readouterr().out)
    assert out == {"cc": None, "nested": {"x": [1.0, None]}, "ok": 2.5}
    assert math.isfinite(out["ok"])


def test_mesh_json_has_design_and_resolved_settings(clean_cwd, tmp_path, capsys):
    assert main(["mesh", *COARSE, "--json"]) == 0
    out = _strict(capsys.readouterr().out)
    assert out["design"]["width_mm"] == 4.0 and out["design"]["thickness_mm"] == 3.0
    assert out["design"]["pattern"] == "square" and out["design"]["rim"] == "none"
    settings = out["mesh_settings"]
    assert settings["mesher"] == "grid" and settings["size_mm"] == 6.0  # "auto" resolved
    assert {"channel_cells", "layer_cells", "epsilon_rel"} <= set(settings)
    assert list(clean_cwd.iterdir()) == []
    cached = list((tmp_path / "xdg" / "latticeopt" / "meshes").iterdir())
    assert len(cached) == 1 and cached[0].name.startswith("grid-")


def test_tetwild_mesher_writes_nothing_into_the_working_folder(clean_cwd, capfd):
    """fTetWild drops ``__tracked_surface.stl`` into its working directory: it must run elsewhere."""
    assert main(["mesh", *COARSE, "--mesher", "tetwild", "--no-cache", "--json"]) == 0
    out = _strict(capfd.readouterr().out)
    assert out["mesh_settings"]["mesher"] == "tetwild" and out["design"]["width_mm"] == 4.0
    assert list(clean_cwd.iterdir()) == []


def test_indent_json_has_design_touches_and_mesh_settings(clean_cwd, capsys):
    assert main(["indent", *COARSE, "--touch", "50,50,8.75,1", "--json"]) == 0
    out = _strict(capsys.readouterr().out)
    assert out["design"]["width_mm"] == 4.0
    assert out["touches"] == [{"x_mm": 50.0, "y_mm": 50.0, "radius_mm": 8.75, "depth_mm": 1.0}]
    assert out["mesh_settings"]["mesher"] == "grid" and out["mesh_settings"]["size_mm"] == 6.0
    assert list(clean_cwd.iterdir()) == []


def test_simulate_json_has_design_touches_and_mesh_settings(clean_cwd, capsys):
    assert main(["simulate", *COARSE, "--touch", "50,50,8.75,1", "--touch", "25,75,5,0.5", "--json"]) == 0
    out = _strict(capsys.readouterr().out)
    assert out["design"]["thickness_mm"] == 3.0
    assert [t["x_mm"] for t in out["touches"]] == [50.0, 25.0] and out["touches"][1]["depth_mm"] == 0.5
    assert out["mesh_settings"]["mesher"] == "grid" and out["mesh_settings"]["size_mm"] == 6.0
    assert out["v_rel"] > 0 and len(out["forces_N"]) == 2
    assert list(clean_cwd.iterdir()) == []


@pytest.mark.parametrize("cmd", ["indent", "simulate"])
def test_a_press_draws_its_progress_on_a_terminal_only(cmd, clean_cwd, capsys, monkeypatch):
    """On a terminal the press's depth is drawn on stderr (a deep press takes minutes); piped, nothing is."""
    args = [cmd, *COARSE, "--touch", "50,50,8.75,2", "--json"]
    assert main(args) == 0
    assert "pressing" not in capsys.readouterr().err
    monkeypatch.setattr("sys.stderr.isatty", lambda: True, raising=False)
    assert main(args) == 0
    captured = capsys.readouterr()
    assert "pressing: 2.000 of 2.000 mm" in captured.err
    assert _strict(captured.out)["touches"][0]["depth_mm"] == 2.0
