"""The benchmark scripts are not run by the tests (they take minutes to hours), but every name they import
from latticeopt must still exist: a renamed or moved helper breaks them silently otherwise. Their argument
checks are cheap, so those run: bad input is a one-line usage error before any work."""

from __future__ import annotations

import ast
import importlib
from pathlib import Path

import pytest

BENCHMARKS = sorted((Path(__file__).resolve().parents[1] / "benchmarks").glob("*.py"))


@pytest.mark.parametrize("script", BENCHMARKS, ids=lambda p: p.name)
def test_every_latticeopt_name_a_benchmark_imports_exists(script):
    missing = []
    for node in ast.walk(ast.parse(script.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "latticeopt":
            module = importlib.import_module(node.module)
            for alias in node.names:
                if not hasattr(module, alias.name):
                    try:
                        importlib.import_module(f"{node.module}.{alias.name}")
                    except ImportError:
                        missing.append(f"{node.module}.{alias.name}")
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] == "latticeopt":
                    importlib.import_module(alias.name)
    assert not missing, f"{script.name} imports names latticeopt no longer has: {missing}"


PHYSICS_SCRIPTS = [p for p in BENCHMARKS if "add_physics_arg(" in p.read_text()]


@pytest.mark.parametrize("script", PHYSICS_SCRIPTS, ids=lambda p: p.name)
def test_a_bad_physics_value_is_a_usage_error_not_a_traceback(script):
    import subprocess
    import sys

    assert PHYSICS_SCRIPTS, "no benchmark takes --physics any more: drop this test"
    required = {"give_up.py": ["--touch", "25,25,7.5,1"]}.get(script.name, [])
    run = subprocess.run([sys.executable, str(script), *required, "--physics", "mechanics_rescue_newton=-1"],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 2, run.stderr
    assert "Traceback" not in run.stderr
    assert run.stderr.strip().splitlines()[-1].endswith(
        "error: --physics mechanics_rescue_newton: expected an integer 0 <= mechanics_rescue_newton <= 1000, got -1")
