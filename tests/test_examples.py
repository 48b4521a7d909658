"""The scripts in examples/ run as documented (on coarse meshes, in a scratch folder)."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def _run(script: str, *args: str, cwd: Path) -> str:
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "LATTICEOPT_MESH_CACHE": str(cwd / "meshes")}
    proc = subprocess.run([sys.executable, str(EXAMPLES / script), *args], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    return proc.stdout


def test_simulate_press(tmp_path):
    out = _run("simulate_press.py", "--mesh-size", "6", cwd=tmp_path)
    v_rel = float(out.split("V_rel = ")[1].split(",")[0])
    assert 0.01 < v_rel < 0.2


def test_small_sweep(tmp_path):
    out = _run("small_sweep.py", "--out", "sweep", "--mesh-size", "6", cwd=tmp_path)
    assert "2 designs x 1 phantom = 2 evaluations, 0 failed" in out
    for name in ("results.csv", "summary.csv", "report.txt"):
        assert (tmp_path / "sweep" / name).is_file()


def test_export_and_reconstruct(tmp_path):
    out = _run("export_and_reconstruct.py", "--mesh-size", "6", "--out", "sensor.npz", cwd=tmp_path)
    assert (tmp_path / "sensor.npz").is_file()
    x, y = (float(s) for s in out.split(" at (")[1].split(")")[0].split(","))
    assert abs(x - 30) < 10 and abs(y - 65) < 10  # the image's largest change lies on the disc


@pytest.mark.parametrize("script", sorted(p.name for p in EXAMPLES.glob("*.py")))
def test_example_documents_its_usage(script):
    assert f"python examples/{script}" in (EXAMPLES / script).read_text()


def test_density_gradient_map(tmp_path):
    out = _run("density_gradient_map.py", "--size", "8", "--cells", "10", "--per-count", "1", "-o", "map.png",
               cwd=tmp_path)
    assert "over 3 presses" in out and (tmp_path / "map.png").stat().st_size > 10_000
    with __import__("numpy").load(tmp_path / "map.npz") as z:
        assert z["dv_rel_ddensity"].shape == (10, 10)
