"""``latticeopt mesh`` and ``latticeopt render``: JSON summary, files written, one-line errors with exit 2."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from latticeopt.cli import main

JSON_KEYS = {"nodes", "tets", "region_volumes_mm3", "electrode_areas_mm2", "min_quality", "seconds"}


def _run(argv: list[str], capsys) -> tuple[int, str, str]:
    """Call the CLI in-process; argparse errors exit through SystemExit, the rest return a status.

    ``capsys`` may also be pytest's ``capfd``.
    """
    try:
        code = main(argv)
    except SystemExit as exc:
        code = exc.code
    out, err = capsys.readouterr()
    return code, out, err


def _cli(args: list[str], cwd, env_extra: dict | None = None) -> subprocess.CompletedProcess:
    env = {**os.environ, "LATTICEOPT_MESH_CACHE": str(cwd / "cache"), **(env_extra or {})}
    return subprocess.run([sys.executable, "-m", "latticeopt", *args], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=600)


def test_mesh_json_summary(tmp_path, capsys):
    code, out, err = _run(["mesh", "--width", "4", "--thickness", "3", "--json", "--cache-dir", str(tmp_path)],
                          capsys)
    assert code == 0, err
    lines = out.strip().splitlines()
    assert len(lines) == 1  # one JSON object, nothing else on stdout
    s = json.loads(lines[0])
    assert JSON_KEYS <= s.keys()
    assert s["region_volumes_mm3"]["hydrogel"] == pytest.approx(14448.0, rel=1e-12)
    assert sum(s["region_volumes_mm3"].values()) == pytest.approx(90000.0)
    assert s["electrode_areas_mm2"] == pytest.approx([12.0] * 16)
    assert s["nodes"] > 0 and s["tets"] > s["nodes"] and 0 < s["min_quality"] <= 1 and s["seconds"] > 0
    assert s["mesher"] == "grid" and s["cached"] is False
    assert list(tmp_path.glob("grid-*.npz"))
    # Again: served from the cache.
    code, out, _ = _run(["mesh", "--width", "4", "--thickness", "3", "--json", "--cache-dir", str(tmp_path)],
                        capsys)
    again = json.loads(out)
    assert again["cached"] is True and again["nodes"] == s["nodes"]


def test_design_and_mesh_options_reach_the_mesh(tmp_path, capsys):
    code, out, _ = _run(["mesh", "--width", "2", "--thickness", "1.5", "--pitch", "10", "--electrode-width", "3",
                         "--rim", "channel", "--size", "4", "--json", "--no-cache", "--cache-dir", str(tmp_path)],
                        capsys)
    assert code == 0
    s = json.loads(out)
    # Pitch 10 divides 100 and the rim channel's halves make one more line: hydrogel = t L^2 (1 - (1 - w/p)^2).
    assert s["region_volumes_mm3"]["hydrogel"] == pytest.approx(1.5 * 1e4 * (1 - 0.8 ** 2), rel=1e-12)
    assert s["electrode_areas_mm2"] == pytest.approx([4.5] * 16)
    assert not list(tmp_path.iterdir())  # --no-cache wrote nothing


def test_mesh_text_summary_and_vtu_output(tmp_path, capsys):
    import meshio

    vtu = tmp_path / "sensor.vtu"
    code, out, err = _run(["mesh", "--width", "4", "--thickness", "3", "--size", "4", "-o", str(vtu),
                           "--cache-dir", str(tmp_path / "c")], capsys)
    assert code == 0, err
    assert "nodes" in out and "hydrogel 14448.0" in out and f"wrote {vtu}" in out
    m = meshio.read(vtu)
    tet = [i for i, c in enumerate(m.cells) if c.type == "tetra"][0]
    tri = [i for i, c in enumerate(m.cells) if c.type == "triangle"][0]
    assert set(np.unique(m.cell_data["region"][tet]).tolist()) == {0, 1, 2, 3}
    assert set(np.unique(m.cell_data["electrode"][tri]).tolist()) == set(range(17))


def test_invalid_width_exits_2_with_one_line_and_no_traceback(tmp_path):
    r = _cli(["mesh", "--width", "20", "--thickness", "3"], tmp_path)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert "Traceback" not in r.stderr
    assert "--width" in lines[0] and "12.5" in lines[0] and "20" in lines[0]
    assert r.stdout == ""
    assert not (tmp_path / "cache").exists()


@pytest.mark.parametrize("argv, names", [
    (["mesh", "--thickness", "8"], ["--thickness", "substrate", "8"]),
    (["mesh", "--width", "-1"], ["--width", "-1"]),
    (["mesh", "--width", "nan"], ["--width", "nan"]),
    (["mesh", "--width", "abc"], ["--width", "abc"]),
    (["mesh", "--mesher", "gmsh"], ["mesher", "'grid', 'extruded', 'tetwild'", "gmsh"]),
    (["mesh", "--size", "0"], ["size_mm", "0"]),
    (["mesh", "--electrodes", "6"], ["--electrodes", "multiple of 4", "6"]),
    (["mesh", "--pattern", "honeycomb"], ["--pattern", "'square', 'hexagonal'", "honeycomb"]),
    (["mesh", "--rim", "edge"], ["--rim", "'none', 'channel'", "edge"]),
    (["mesh", "--frame", "-1"], ["--frame", "-1"]),
    (["mesh", "--pattern", "triangular", "--width", "9"], ["--width", "2/3 pitch_mm", "9"]),
    (["mesh", "--layout", "missing.geojson"], ["--layout", "missing.geojson"]),
    (["mesh", "--layout", "layout.txt"], ["--layout", ".geojson", "layout.txt"]),
    (["mesh", "--electrode-positions", "10,20,x"], ["--electrode-positions", "10,20,x"]),
    (["mesh", "--electrode-positions", "10,20,30"], ["--electrode-positions", "4 increasing"]),
    (["mesh", "--hydrogel-fraction", "0.001", "--pattern", "hexagonal"], ["--hydrogel-fraction", "0.001"]),
    (["mesh", "--hydrogel-fraction", "0.3", "--width", "2"], ["--hydrogel-fraction", "not both"]),
    (["mesh", "-o", "sensor.stl"], ["-o", ".vtu", "sensor.stl"]),
    (["render", "-o", "sensor.jpg"], ["-o", ".png", "sensor.jpg"]),
    (["mesh", "--no-such-option"], ["--no-such-option"]),
])
def test_bad_inputs_give_one_line_naming_the_problem(argv, names, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, out, err = _run(argv + ["--cache-dir", str(tmp_path / "c")], capsys)
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    for name in names:
        assert name in lines[0], (name, lines[0])
    assert not (tmp_path / "c").exists() and not list(tmp_path.glob("sensor.*"))


def test_render_writes_a_png_showing_the_lattice(tmp_path, capfd):
    import matplotlib.image as mpimg

    png = tmp_path / "s.png"
    # capfd (file-descriptor level) so that VTK's C++ warnings would be seen too.
    code, out, err = _run(["render", "--width", "4", "--thickness", "3", "--size", "4", "-o", str(png),
                           "--cache-dir", str(tmp_path / "c")], capfd)
    assert code == 0, err
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    img = mpimg.imread(png)[:, :, :3]
    assert img.shape[0] > 200 and img.shape[1] > 200 and img.std() > 0.05
    # The hydrogel is drawn blue (#2b7bba) and the electrodes red: both must be visible.
    blue = (img[:, :, 2] > img[:, :, 0] + 0.25) & (img[:, :, 2] > img[:, :, 1] + 0.05)
    red = (img[:, :, 0] > 0.6) & (img[:, :, 1] < 0.35) & (img[:, :, 2] < 0.35)
    assert blue.mean() > 0.02 and red.sum() > 50
    assert "bad X server" not in err and "WARN" not in err


def test_tetwild_acceptance_through_the_cli(tmp_path_factory, capfd):
    """Issue acceptance: ``latticeopt mesh --width 4 --thickness 3 --json --mesher tetwild`` reports the hydrogel
    volume within 0.5 % of 14448 mm^3 (no rim channel: 7 lines of 4 mm per axis, 3e4 (1 - 0.72^2)); fTetWild's own
    printing must not leak into the JSON on stdout.

    Shares its cache folder with tests/test_mesh_tetwild.py (same design and settings).
    """
    cache = tmp_path_factory.getbasetemp() / "shared-mesh-cache"
    code = main(["mesh", "--width", "4", "--thickness", "3", "--json", "--mesher", "tetwild", "--size", "3",
                 "--cache-dir", str(cache)])
    out, err = capfd.readouterr()  # file-descriptor level: catches C++ output too
    assert code == 0, err
    lines = out.strip().splitlines()
    assert len(lines) == 1, out[:500]
    s = json.loads(lines[0])
    assert s["mesher"] == "tetwild"
    assert abs(s["region_volumes_mm3"]["hydrogel"] / 14448.0 - 1) < 0.005
    assert len(s["electrode_areas_mm2"]) == 16
    assert abs(np.mean(s["electrode_areas_mm2"]) / 12.0 - 1) < 0.01  # per-electrode: tests/test_mesh_tetwild.py


def test_mesh_size_is_the_element_size_and_size_its_old_name(capfd, tmp_path, monkeypatch):
    import latticeopt.mesh as mesh_module

    monkeypatch.setattr(mesh_module, "_WARNED_COARSE", set())
    base = ["mesh", "--width", "4", "--thickness", "3", "--no-cache", "--json"]
    res = _cli(base + ["--mesh-size", "40"], tmp_path)  # a process of its own: the CLI's logging set-up
    assert res.returncode == 0, res.stderr
    new = json.loads(res.stdout)
    # coarser than the 4 mm channel: one line on stderr, not an error
    err = res.stderr.strip().splitlines()
    assert len(err) == 1 and "size_mm = 40 mm" in err[0] and "channel width w = 4 mm" in err[0], err
    code, out, _ = _run(base + ["--size", "40"], capfd)
    old = json.loads(out)
    assert code == 0 and old["mesh_settings"]["size_mm"] == new["mesh_settings"]["size_mm"] == 40
    assert old["nodes"] == new["nodes"] and old["design"]["size_mm"] == 100  # the sensor side is untouched
    code, _, err = _run(["mesh", "--mesh-size", "0"], capfd)
    assert code == 2 and "--mesh-size" in err and len(err.strip().splitlines()) == 1


def test_help_tells_the_two_sizes_apart(capsys):
    code, out, _ = _run(["mesh", "--help"], capsys)
    text = " ".join(out.split())
    assert code == 0 and "--mesh-size MESH_SIZE_MM, --size MESH_SIZE_MM" in text
    assert "mesh element size" in text and "not the sensor side (--sensor-size)" in text
    assert "not the mesh element size (--mesh-size)" in text


def test_mesh_stl_says_what_it_wrote(tmp_path, capsys):
    folder = tmp_path / "stl"
    code, out, err = _run(["mesh", "--width", "4", "--thickness", "3", "--mesh-size", "6", "--no-cache", "--stl",
                           str(folder)], capsys)
    assert code == 0, err
    written = sorted(folder.iterdir())
    assert written and all(p.suffix == ".stl" for p in written)
    lines = [line for line in out.splitlines() if line.startswith("wrote ")]
    assert sorted(line.split()[1] for line in lines) == sorted(str(p) for p in written)  # one line per file
    assert any("hydrogel solid" in line for line in lines)
