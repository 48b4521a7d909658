"""The README: short enough to lead to the result, its set-up commands the ones CI runs, its links alive."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"


def _slug(heading: str) -> str:
    """GitHub's anchor for a Markdown heading: lower case, punctuation dropped, spaces to hyphens."""
    text = heading.strip().lower()
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def _anchors(path: Path) -> set[str]:
    return {_slug(m.group(1)) for m in re.finditer(r"^#+ (.+)$", path.read_text(), flags=re.M)}


def test_readme_is_at_most_200_lines():
    assert len(README.read_text().splitlines()) <= 200


def test_the_test_set_up_command_is_the_one_ci_runs():
    ci = (ROOT / ".ci" / "run").read_text().strip().splitlines()[-1]
    blocks = re.findall(r"```\n(.*?)\n```", README.read_text(), flags=re.S)
    assert ci in blocks
    assert "python3 -m venv .venv && . .venv/bin/activate && pip install -e . && latticeopt sweep " \
           "studies/quick.toml" in blocks


def test_the_main_job_names_its_time_and_the_files_to_open():
    text = " ".join(README.read_text().split())
    assert "minutes" in text and "runs/quick/report.txt" in text and "runs/quick/vrel_lines.png" in text
    # V_rel and phantom are defined before any other use
    first_v = text.index("V_rel")
    assert text[first_v:first_v + 120].startswith("V_rel**, the response: the mean over the 208 measurements")
    assert text.index("**Phantom**") <= text.lower().index("phantom")


@pytest.mark.parametrize("doc", [README, ROOT / "docs" / "usage.md", ROOT / "docs" / "results.md"])
def test_relative_links_and_their_anchors_exist(doc):
    for target in re.findall(r"\]\(([^)\s]+)\)", doc.read_text()):
        if "://" in target or target.startswith("mailto:"):
            continue
        file, _, anchor = target.partition("#")
        path = (doc.parent / file).resolve() if file else doc
        assert path.exists(), (doc.name, target)
        if anchor and path.suffix == ".md":
            assert anchor in _anchors(path), (doc.name, target)


def test_the_figures_redrawn_from_tables_read_every_design():
    import importlib.util

    spec = importlib.util.spec_from_file_location("replot", ROOT / "docs" / "replot_from_tables.py")
    replot = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(replot)
    text = (ROOT / "docs" / "results.md").read_text()
    for anchor in ("### The paper map: 30 designs", "### The paper map with the rim channel"):
        rows = replot._table(text[text.index(anchor):], "| t \\ w (mm) |")
        assert [r[0] for r in rows] == ["1", "2", "3", "4", "5"] and all(len(r) == 7 for r in rows)
        cells = [replot._cell(c, 300) for r in rows for c in r[1:]]
        assert all(0.04 < c["v_rel_mean"] < 0.12 and 15 <= c["n_fine"] <= 300 for c in cells)
    assert replot._cell("**0.1155 ± 0.0069 (15)**".strip("*"), 280) == {"v_rel_mean": 0.1155, "v_rel_se": 0.0069,
                                                                         "n": 280, "n_fine": 15}
