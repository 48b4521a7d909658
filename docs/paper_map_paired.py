"""The paired differences ``docs/results.md`` quotes for a finished two-level paper map, read from its store.

The map's ``report.txt`` ranks the designs and pairs the best with the runner-up; the results page also compares
other pairs (the best against each design, the paper's optimum against w = 6 and the uniform layer, thicknesses
at each width, widths at each thickness). This prints the table of means (fine counts in brackets, as the page
gives it) and those paired two-level differences
(:func:`latticeopt.study.multilevel_report.paired_difference`: coarse over every phantom, fine over the phantoms
both designs ran), computing nothing: it reads a copy of the store, and stops with a message if the map would
need another evaluation (unfinished, or run with other settings)::

    python docs/paper_map_paired.py runs/paper_fig4_takeall --set multilevel.depth_split_mm=0
    python docs/paper_map_paired.py runs/paper_fig4_rim_takeall --set design.rim=channel \
        --set multilevel.depth_split_mm=0
"""

from __future__ import annotations

import argparse
import sqlite3
import sys
import tempfile
from pathlib import Path

from latticeopt import coupled
from latticeopt.errors import ModelBugError
from latticeopt.study.config import load_study
from latticeopt.study.multilevel_report import paired_difference
from latticeopt.study.sweep import run_sweep

STUDY = Path(__file__).resolve().parent.parent / "studies" / "paper_fig4.toml"
WIDTHS, THICKNESSES = (0, 2, 3, 4, 5, 6), (1, 2, 3, 4, 5)


class _WouldCompute(Exception):
    """Raised instead of building a model: the store lacks an evaluation the map needs."""


def _refuse(design, settings):
    raise _WouldCompute(f"{design.describe()} at {settings.key[:8]}")


def read_map(folder: Path, overrides: list[str]):
    """``(study, run)`` of the finished two-level map in ``folder`` (``run``: its ``MultilevelRun``)."""
    study = load_study(STUDY, ["multilevel.pilot=15", *overrides])
    with tempfile.TemporaryDirectory() as tmp:
        src = sqlite3.connect(f"file:{folder / 'results.sqlite'}?mode=ro", uri=True)
        dst = sqlite3.connect(Path(tmp) / "results.sqlite")
        src.backup(dst)  # a consistent copy, even of a store a sweep is writing
        src.close()
        dst.close()
        prepare, coupled.evaluate_phantom.prepare = coupled.evaluate_phantom.prepare, _refuse
        try:
            res = run_sweep(study, out_dir=tmp, outputs=False, progress=False, jobs=1)
        finally:
            coupled.evaluate_phantom.prepare = prepare
    return study, res.multilevel


def finished_map(prog: str, folder: Path, overrides: list[str]):
    """:func:`read_map`, or ``None`` after a one-line message on stderr naming ``prog`` when ``folder`` holds no
    store or the map there is unfinished with these settings (a script then exits with status 2)."""
    if not (folder / "results.sqlite").is_file():
        print(f"{prog}: folder: expected a sweep folder holding results.sqlite, got {folder}", file=sys.stderr)
        return None
    try:
        return read_map(folder, overrides)
    except ModelBugError as exc:
        if "_WouldCompute" not in str(exc):
            raise
        print(f"{prog}: {folder}: the map is not finished with these settings (it would compute more); finish "
              f"it with its sweep command first", file=sys.stderr)
        return None


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path, help="the map's output folder (holding results.sqlite)")
    ap.add_argument("--set", action="append", default=[], help="a study override the map ran with (key=value)")
    args = ap.parse_args(argv)
    loaded = finished_map("paper_map_paired", args.folder, args.set)
    if loaded is None:
        return 2
    study, run = loaded
    idx = {(d.width_mm, d.thickness_mm): i for i, d in enumerate(study.designs)}
    est = {k: run.estimates[i] for k, i in idx.items()}

    def diff(a, b) -> str:
        e = paired_difference(study, run, idx[a], idx[b])
        return f"w = {a[0]:g}, t = {a[1]:g} minus w = {b[0]:g}, t = {b[1]:g}: {e.mean:+.4f} ± {e.se:.4f} " \
               f"(z = {e.mean / e.se:.1f})"

    print("| t \\ w (mm) | " + " | ".join("0 (uniform)" if w == 0 else f"{w}" for w in WIDTHS) + " |")
    print("|---" * (len(WIDTHS) + 1) + "|")
    for t in THICKNESSES:
        cells = [f"{est[(w, t)].mean:.4f} ± {est[(w, t)].se:.4f} ({est[(w, t)].n_fine})" for w in WIDTHS]
        print(f"| {t} | " + " | ".join(cells) + " |")
    order = sorted(idx, key=lambda k: -est[k].mean)
    best = order[0]
    print(f"\nbest w = {best[0]:g}, t = {best[1]:g}; against the next five and the paper's optimum:")
    for k in [*order[1:6], (4, 3)]:
        if k != best:
            print("  " + diff(best, k))
    print("\nthe paper's optimum against w = 6 and the uniform layer, at t = 3:")
    print("  " + diff((4, 3), (6, 3)) + "\n  " + diff((4, 3), (0, 3)))
    print("\nthicknesses at each width:")
    for w in WIDTHS:
        print("  " + "; ".join(diff((w, a), (w, b)) for a, b in ((3, 5), (3, 1), (1, 5))))
    print("\nwidths at each thickness: the most responsive lattice minus each other width and the uniform layer:")
    for t in THICKNESSES:
        top = max(WIDTHS[1:], key=lambda w: est[(w, t)].mean)
        print("  " + "; ".join(diff((top, t), (w, t)) for w in WIDTHS if w != top))
    print("\nlattice / uniform layer of the same thickness, and the fall from w = 2 to w = 6:")
    for t in THICKNESSES:
        ratios = ", ".join(f"{est[(w, t)].mean / est[(0, t)].mean:.2f}" for w in WIDTHS[1:])
        print(f"  t = {t}: {ratios}; {1 - est[(6, t)].mean / est[(2, t)].mean:.1%}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
