"""Every study file shipped in studies/ loads and plans from the CLI (``--dry-run``): a renamed layout file, a key
the schema no longer has or a value out of its range fails here, not hours into a user's run."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from latticeopt.cli import main

STUDIES = Path(__file__).parents[1] / "studies"
OPTIMIZING_TABLES = ("optimize", "freeform", "graded")


def _command(path: Path) -> str:
    raw = tomllib.loads(path.read_text(encoding="utf-8"))
    return "optimize" if any(t in raw for t in OPTIMIZING_TABLES) else "sweep"


@pytest.mark.parametrize("name", sorted(p.name for p in STUDIES.glob("*.toml")))
def test_shipped_study_plans_from_the_cli(name, tmp_path, capsys):
    path = STUDIES / name
    code = main([_command(path), str(path), "--dry-run", "--out", str(tmp_path / "out")])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert captured.out.strip()  # the plan is printed
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").rglob("*.sqlite"))  # nothing computed
