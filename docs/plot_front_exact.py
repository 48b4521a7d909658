"""The response-against-uniformity front on the exact mesh: every outline of ``studies/heldout_layouts.toml`` and
``studies/uniformity_layouts.toml`` with its mean V_rel over the 100 held-out presses against its uniformity over
the 7 x 7 probe grid, and the layouts to cast drawn beside it.

The front of ``studies/front_graded.toml`` is drawn from the density model's numbers (``front.png``); this script
draws the same points after their outlines were meshed exactly and pressed where the optimizer never pressed, with
the square lattices of their gel fraction and minimum feature, and prints the table of ``docs/results.md``
(paired differences over the common held-out presses)::

    latticeopt sweep studies/heldout_layouts.toml --jobs 2 --out runs/heldout_layouts
    latticeopt sweep studies/uniformity_layouts.toml --jobs 2 --out runs/uniformity_layouts
    python docs/plot_front_exact.py runs/heldout_layouts runs/uniformity_layouts   # writes docs/front_exact.png
"""

from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path

import numpy as np

from latticeopt.design import design_from_table
from latticeopt.optimize.front import draw_front
from latticeopt.study.layout_plot import draw_layout

DOCS = Path(__file__).resolve().parent
DATA = DOCS.parent / "studies" / "data"

#: The outlines on the figure: file -> (role, label). Front points are joined in order of uniformity; references
#: are labelled "<family> w<width>" as on the density model's front; the others are drawn apart.
OUTLINES = {
    "front_free_d4_t3.geojson": ("front", "no floor"),
    "front_u025_d4_t3.geojson": ("front", "u0.25"),
    "front_u030_d4_t3.geojson": ("front", "u0.30"),
    "front_u035_d4_t3.geojson": ("front", "u0.35"),
    "front_u040_d4_t3.geojson": ("front", "u0.40"),
    "square_w1.geojson": ("reference", "square w1"),
    "square_same_fraction_as_freeform_30.geojson": ("reference", "square w2.6"),
    "square_same_fraction_as_graded.geojson": ("reference", "square w3.7"),
    "square_w4.geojson": ("reference", "square w4"),
    "square_w6.geojson": ("reference", "square w6"),
    "square_w8.geojson": ("reference", "square w8"),
    "diagonal_w4.geojson": ("reference", "diagonal w4"),
    "diagonal_same_fraction_as_graded_diagonal.geojson": ("reference", "diagonal w5.1"),
    "graded_d4_t3.geojson": ("other", "graded, 1 mm mould"),
    "freeform_d4_t3_30.geojson": ("other", "free-form"),
    "graded_diagonal_d4_t3.geojson": ("other", "graded diagonal, 4 mm mould"),
    "graded_shift_d4_t3.geojson": ("other", "graded, lines moved, 4 mm mould"),
    "hexagonal_same_fraction_as_graded_hex.geojson": ("reference", "hexagonal w6.7"),
    "graded_hex_mirror_t3.geojson": ("other", "graded honeycomb, 4 mm mould"),
}


def _rows(path: Path) -> list[dict]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def collect(heldout: Path, probes: Path) -> dict[str, dict]:
    """Per outline file of :data:`OUTLINES`: gel fraction, held-out mean V_rel and SE, probe uniformity and
    worst-to-best, and the held-out V_rel per phantom (``{phantom_key: v_rel}``) for paired differences."""
    by_key = {r["design_key"]: r for r in _rows(probes / "summary.csv")}
    per_phantom: dict[str, dict[str, float]] = {}
    for r in _rows(heldout / "results.csv"):
        if r["status"] == "ok":  # phantom_index counts within a touch count: the content hash names a phantom
            per_phantom.setdefault(r["design_key"], {})[r["phantom_key"]] = float(r["v_rel"])
    out = {}
    for r in _rows(heldout / "summary.csv"):
        probe = by_key.get(r["design_key"])
        if probe is None or probe["design"] not in OUTLINES:
            continue
        design = design_from_table({"layout": str(DATA / probe["design"]), "thickness_mm": 3.0}, DATA)
        out[probe["design"]] = {
            "gel": design.hydrogel_area_fraction(), "design": design,
            "v_rel": float(r["v_rel_mean"]), "se": float(r["v_rel_se"]), "n": int(r["n_ok"]),
            "uniformity": float(probe["uniformity"]), "worst_to_best": float(probe["worst_to_best"]),
            "phantoms": per_phantom[r["design_key"]]}
    return {f: out[f] for f in OUTLINES if f in out}  # references in order of width, as a family's line


def paired(a: dict, b: dict) -> tuple[float, float, int]:
    """Mean and standard error of ``a - b`` over the held-out phantoms both solved, and their count."""
    common = sorted(set(a["phantoms"]) & set(b["phantoms"]))
    d = np.array([a["phantoms"][i] - b["phantoms"][i] for i in common])
    return float(d.mean()), float(d.std(ddof=1) / math.sqrt(len(d))), len(d)


#: Further pairs printed under the table: outline -> the outline it was optimized from.
ALSO_AGAINST = {"graded_shift_d4_t3.geojson": "front_free_d4_t3.geojson"}


def table(scores: dict[str, dict]) -> list[str]:
    """Markdown rows: each front point and other optimized outline against the lattice of its family (square;
    diagonal or hexagonal for a diagonal outline or a honeycomb) of the nearest gel fraction and against its
    family's w = 4 (the 4 mm mould's minimum feature), then the pairs of :data:`ALSO_AGAINST`."""
    lines = ["| outline (gel fraction) | held-out mean V_rel ± SE | uniformity | worst-to-best "
             "| minus the lattice of its gel fraction | minus the lattice w = 4 |", "|---|---|---|---|---|---|"]
    for f, s in scores.items():
        if OUTLINES[f][0] == "reference":
            continue
        family = "diagonal" if "diagonal" in f else "hexagonal" if "hex" in f else "square"
        refs = {g: r for g, r in scores.items() if OUTLINES[g][0] == "reference" and OUTLINES[g][1].startswith(family)}
        near = min(refs, key=lambda g: abs(refs[g]["gel"] - s["gel"]))
        cells = []
        for ref in (near, f"{family}_w4.geojson"):
            if ref not in scores:
                cells.append("not scored")
                continue
            d, se, _ = paired(s, scores[ref])
            cells.append(f"{d:+.4f} ± {se:.4f} ({100 * d / scores[ref]['v_rel']:+.0f} %, "
                         f"{OUTLINES[ref][1]}, {scores[ref]['gel']:.2f})")
        lines.append(f"| {OUTLINES[f][1]} ({s['gel']:.2f}) | {s['v_rel']:.4f} ± {s['se']:.4f} "
                     f"| {s['uniformity']:.3f} | {s['worst_to_best']:.3f} | {cells[0]} | {cells[1]} |")
    for f, g in ALSO_AGAINST.items():
        if f in scores and g in scores:
            d, se, _ = paired(scores[f], scores[g])
            lines.append(f"{OUTLINES[f][1]} minus {OUTLINES[g][1]}: {d:+.4f} ± {se:.4f} "
                         f"({100 * d / scores[g]['v_rel']:+.1f} %), uniformity {scores[f]['uniformity']:.3f} "
                         f"against {scores[g]['uniformity']:.3f}")
    return lines


def plot(scores: dict[str, dict], best: list[str], path: Path) -> Path:
    """Left: held-out mean V_rel (± SE) against probe uniformity; right: the outlines ``best`` from above."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(10.5, 5.6), layout="constrained")
    axes = fig.subplot_mosaic([["front", str(i)] for i in range(len(best))], width_ratios=(2.1, 1))
    ax = axes["front"]
    points = [{"label": OUTLINES[f][1], "floor_met": None, **s} for f, s in scores.items() if OUTLINES[f][0] == "front"]
    refs = [{"label": OUTLINES[f][1], **s} for f, s in scores.items() if OUTLINES[f][0] == "reference"]
    for s in scores.values():
        ax.errorbar(s["uniformity"], s["v_rel"], yerr=s["se"], color="0.75", lw=0.8, zorder=1)
    draw_front(ax, points, refs)
    for f, s in scores.items():
        if OUTLINES[f][0] == "other":
            ax.plot(s["uniformity"], s["v_rel"], "P", ms=7, label=OUTLINES[f][1])
    ax.set_xlabel("uniformity over the 7 x 7 probe grid (1 - CV of V_rel), exact mesh")
    ax.set_ylabel("mean V_rel over 100 held-out presses (± SE, unpaired), exact mesh")
    ax.set_title("graded lattices with a 4 mm mould (black; u = their uniformity floor in the density model)\n"
                 "against square, diagonal and hexagonal lattices (w in mm), t = 3 mm, 2 mm mesh", fontsize=8)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    for i, f in enumerate(best):
        s = scores[f]
        role, label = OUTLINES[f]
        name = f"graded, 4 mm mould, {label}" if role == "front" else label
        draw_layout(axes[str(i)], s["design"], f"{name} ({f})\nV_rel {s['v_rel']:.4f} ± {s['se']:.4f}, "
                    f"uniformity {s['uniformity']:.2f}, gel {s['gel']:.2f}")
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("heldout", type=Path, help="output folder of studies/heldout_layouts.toml")
    ap.add_argument("probes", type=Path, help="output folder of studies/uniformity_layouts.toml")
    ap.add_argument("--best", nargs="+", default=["graded_d4_t3.geojson", "front_free_d4_t3.geojson"],
                    choices=sorted(OUTLINES), help="the outlines drawn beside the front")
    ap.add_argument("-o", "--output", type=Path, default=DOCS / "front_exact.png")
    args = ap.parse_args(argv)
    scores = collect(args.heldout, args.probes)
    print("\n".join(table(scores)))
    print(plot(scores, args.best, args.output))


if __name__ == "__main__":
    main()
