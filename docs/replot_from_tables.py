"""Re-draw the figures of runs too long to repeat from the tables of ``docs/results.md`` that summarize them.

The paper maps (two-level, about 3 h each on 2 cores) and the 12-phantom layout study (70 min) are not re-run
to change a title: their means, standard errors and fine counts are in the results tables, at the four digits
the tables give. This script reads those tables and draws the figures with the sweep's own plotting code, so
they name layout, mesh and phantom count like a fresh sweep's figures::

    PYTHONPATH=. python docs/replot_from_tables.py        # rewrites the five PNGs in docs/
"""

from __future__ import annotations

import re
from pathlib import Path

from latticeopt.study.config import load_study
from latticeopt.study.plots import plot_heatmap, plot_lines

DOCS = Path(__file__).resolve().parent
STUDIES = DOCS.parent / "studies"
CELL = re.compile(r"([0-9.]+) ± ([0-9.]+)(?: \((\d+)\))?")


def _table(text: str, header: str) -> list[list[str]]:
    """The rows (cells as strings) of the Markdown table whose header row starts with ``header``."""
    lines = text[text.index(header):].splitlines()
    rows = []
    for line in lines[2:]:
        if not line.startswith("|"):
            break
        rows.append([c.strip().strip("*") for c in line.strip("|").split("|")])
    return rows


def _cell(text: str, n: int) -> dict:
    mean, se, fine = CELL.fullmatch(text).groups()
    out = {"v_rel_mean": float(mean), "v_rel_se": float(se), "n": n}
    if fine is not None:
        out["n_fine"] = int(fine)
    return out


#: The paper maps' figures draw the runs with the default two-level plan (the ones the README quotes): the header
#: of their tables, and per map the heading or lead-in of the table's section, the study's overrides and the
#: figures' file stem.
MAP_HEADER = "| t \\ w (mm), default plan |"
MAPS = (("### The paper map: 30 designs x 300 phantoms, two-level", [], "paper_fig4"),
        ("### The paper map with the rim channel", ["design.rim=channel"], "paper_fig4_rim"))


def paper_map(text: str, anchor: str, overrides: list[str], n: int, stem: str) -> None:
    section = text[text.index(anchor):]
    rows = _table(section, MAP_HEADER)
    values = {(float(r[0]), w): _cell(c, n) for r in rows for w, c in zip((0, 2, 3, 4, 5, 6), r[1:])}
    study = load_study(STUDIES / "paper_fig4.toml", ["multilevel.pilot=15", *overrides])
    summary = [values[(d.thickness_mm, d.width_mm)] for d in study.designs]
    plot_lines(study, summary, DOCS / f"{stem}_vrel_lines.png")
    plot_heatmap(study, summary, DOCS / f"{stem}_vrel_heatmap.png")


def layouts(text: str) -> None:
    rows = _table(text, "| mean V_rel ± SE (12 phantoms) |")
    families = ("square", "hexagonal", "triangular", "diagonal")
    rims = {"no rim channel": "none", "rim channel": "channel"}
    values = {(fam, rims[r[0]]): {"v_rel_mean": float(m), "v_rel_se": float(s), "n": 12}
              for r in rows for fam, c in zip(families, r[1:]) for m, s in [c.split(" ± ")]}
    # the 12-phantom rows ran with 2 cells across every channel (docs/results.md says so)
    study = load_study(STUDIES / "layouts.toml", ["phantoms.counts={1=4,2=4,3=4}", "mesh.channel_cells=2"])
    summary = [values[(d.pattern, d.rim)] for d in study.designs]
    plot_lines(study, summary, DOCS / "layouts_vrel.png")


def main() -> None:
    text = (DOCS / "results.md").read_text()
    for anchor, overrides, stem in MAPS:
        paper_map(text, anchor, overrides, 300, stem)
    layouts(text)


if __name__ == "__main__":
    main()
