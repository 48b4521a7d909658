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
    for anchor, _, _ in replot.MAPS:
        rows = replot._table(text[text.index(anchor):], replot.MAP_HEADER)
        assert [r[0] for r in rows] == ["1", "2", "3", "4", "5"] and all(len(r) == 7 for r in rows)
        cells = [replot._cell(c, 300) for r in rows for c in r[1:]]
        assert all(0.03 < c["v_rel_mean"] < 0.2 and 15 <= c["n_fine"] <= 300 for c in cells)
    assert replot._cell("**0.1155 ± 0.0069 (15)**".strip("*"), 280) == {"v_rel_mean": 0.1155, "v_rel_se": 0.0069,
                                                                         "n": 280, "n_fine": 15}


def test_every_value_with_an_se_in_the_readme_is_one_the_results_page_reports():
    """The README quotes results (a mean or a paired difference with its SE) from docs/results.md; a re-run map
    that updates the page and not the README (or the reverse) leaves a pair found on one side only."""
    readme = (ROOT / "README.md").read_text()
    results = (ROOT / "docs" / "results.md").read_text()
    quoted = set(re.findall(r"\d\.\d+ ± \d\.\d+", readme))
    assert quoted, "the README quotes no value with its SE"
    assert not sorted(q for q in quoted if q not in results)


def test_the_paired_differences_script_computes_nothing(tmp_path, capsys):
    """docs/paper_map_paired.py reads a finished map; on a store that lacks evaluations it stops at once with a
    message (exit 2) instead of running the sweep, and leaves the folder as it was."""
    import importlib.util
    import sqlite3

    spec = importlib.util.spec_from_file_location("paired", ROOT / "docs" / "paper_map_paired.py")
    paired = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(paired)
    sqlite3.connect(tmp_path / "results.sqlite").close()  # an empty store: the map has not run
    assert paired.main([str(tmp_path)]) == 2
    assert "the map is not finished" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["results.sqlite"]
    assert paired.main([str(tmp_path / "nowhere")]) == 2


def test_the_exact_front_pairs_each_point_with_the_nearest_square_lattice(tmp_path):
    """docs/plot_front_exact.py on two small sweep folders written by hand: the paired difference over the common
    phantoms (a phantom one design failed is left out), the square of the nearest gel fraction, and the figure."""
    import csv
    import importlib.util

    spec = importlib.util.spec_from_file_location("front_exact", ROOT / "docs" / "plot_front_exact.py")
    fe = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(fe)
    files = ["front_free_d4_t3.geojson", "square_w4.geojson", "square_w6.geojson", "graded_shift_d4_t3.geojson"]
    v = {"front_free_d4_t3.geojson": [0.10, 0.12, 0.14, 0.16, 0.50], "square_w4.geojson": [0.09, 0.10, 0.11, 0.12, 0.0],
         "square_w6.geojson": [0.08, 0.09, 0.10, 0.11, 0.20],
         "graded_shift_d4_t3.geojson": [0.11, 0.12, 0.15, 0.18, 0.5]}
    held, probes = tmp_path / "held", tmp_path / "probes"
    held.mkdir(), probes.mkdir()

    def write(path, rows):
        with open(path, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)

    # phantom_index counts within a touch count (two phantoms share index 0 here): pairs go by phantom_key
    write(held / "results.csv", [{"design_key": f, "phantom_index": i % 3, "phantom_key": f"p{i}", "v_rel": x,
                                  "status": "failed" if (f == "square_w4.geojson" and i == 4) else "ok"}
                                 for f in files for i, x in enumerate(v[f])])
    write(held / "summary.csv", [{"design_key": f, "v_rel_mean": sum(v[f][:4]) / 4, "v_rel_se": 0.01, "n_ok": 4}
                                 for f in files])
    write(probes / "summary.csv", [{"design_key": f, "design": f, "uniformity": u, "worst_to_best": 0.1}
                                   for f, u in zip(files, (0.26, 0.22, 0.30, 0.24))])
    scores = fe.collect(held, probes)
    assert sorted(scores) == sorted(files) and abs(scores["square_w6.geojson"]["gel"] - 0.664) < 0.002
    d, se, n = fe.paired(scores["front_free_d4_t3.geojson"], scores["square_w4.geojson"])
    # differences 0.01, 0.02, 0.03, 0.04 on the four phantoms both solved: mean 0.025, sd 0.0129, SE sd / 2
    assert n == 4 and abs(d - 0.025) < 1e-12 and abs(se - 0.012909944 / 2) < 1e-8
    row = fe.table(scores)[2]
    # the free point's 0.65 gel is nearest w = 6 (0.66), not w = 4 (0.48): differences 0.02-0.05 and 0.30, mean 0.088
    assert "square w6, 0.66" in row.split("|")[5] and "+0.0880" in row.split("|")[5]
    # the moved-lines outline against the point it was optimized from: differences 0.01, 0, 0.01, 0.02, 0 -> 0.008
    assert "graded, lines moved, 4 mm mould minus no floor: +0.0080" in fe.table(scores)[-1]
    assert fe.plot(scores, ["front_free_d4_t3.geojson"], tmp_path / "f.png").stat().st_size > 10_000
