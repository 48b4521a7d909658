"""Two sampling plans of one two-level paper map, compared on the evaluations they ran: fine counts, fine model
hours and estimates per design.

Run the map with one plan, then, on the same folder, with the other (the store keeps every evaluation, so the
second run computes only the fine phantoms the first did not); this reads the store once per plan (computing
nothing: it stops with a message if a plan would need another evaluation) and prints per design each plan's fine
count, the model seconds of its fine evaluations (their own stored seconds, so a phantom both plans ran costs
both the same) and its estimate, then the totals::

    latticeopt sweep studies/paper_fig4.toml --set multilevel.depth_split_mm=0 --out runs/sub8 --jobs 2 \\
        --set 'grid.thickness_mm=[1,3]' --set 'grid.width_mm=[0,2,4,6]'
    latticeopt sweep studies/paper_fig4.toml --set multilevel.depth_split_mm=4 --out runs/sub8 --jobs 2 \\
        --set 'grid.thickness_mm=[1,3]' --set 'grid.width_mm=[0,2,4,6]'
    python benchmarks/multilevel_plans.py runs/sub8 --set 'grid.thickness_mm=[1,3]' \\
        --set 'grid.width_mm=[0,2,4,6]' --plan multilevel.depth_split_mm=0 --plan multilevel.depth_split_mm=4

``--set`` gives the overrides both runs share (besides ``multilevel.pilot=15``, which the paper map's studies
always take); each ``--plan`` the ones that tell a plan apart (repeatable within a plan as ``A,B``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "docs"))
from paper_map_paired import finished_map  # noqa: E402


def _fine_hours(run, design: int) -> float:
    return sum(run.fine[(design, j)].seconds or 0.0 for j in run.order[:run.n_fine[design]]) / 3600


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path, help="a two-level paper map's folder (holding results.sqlite)")
    ap.add_argument("--set", action="append", default=[], help="an override every plan ran with (key=value)")
    ap.add_argument("--plan", action="append", default=[],
                    help="the overrides of one plan, comma-separated (give two or more plans)")
    args = ap.parse_args(argv)
    if len(args.plan) < 2:
        print(f"multilevel_plans: --plan: expected at least two plans, got {len(args.plan)}", file=sys.stderr)
        return 2
    runs = []
    for plan in args.plan:
        loaded = finished_map("multilevel_plans", args.folder, [*args.set, *plan.split(",")])
        if loaded is None:
            return 2
        runs.append(loaded)
    study = runs[0][0]
    print("| design | " + " | ".join(f"{p}: fine n, fine h, mean ± SE" for p in args.plan) + " |")
    print("|---|" + "---|" * len(args.plan))
    totals = np.zeros((len(runs), 2))
    for i in runs[0][1].compared:
        d = study.designs[i]
        cells = []
        for k, (_, run) in enumerate(runs):
            e, hours = run.estimates[i], _fine_hours(run, i)
            totals[k] += (run.n_fine[i], hours)
            cells.append(f"{run.n_fine[i]}, {hours:.3f}, {e.mean:.4f} ± {e.se:.4f}")
        print(f"| w = {d.width_mm:g}, t = {d.thickness_mm:g} | " + " | ".join(cells) + " |")
    print("| total | " + " | ".join(f"{n:.0f}, {h:.2f}" for n, h in totals) + " |")
    for k in range(1, len(runs)):
        print(f"{args.plan[k]} against {args.plan[0]}: fine evaluations x{totals[k, 0] / totals[0, 0]:.3f}, "
              f"fine model hours x{totals[k, 1] / totals[0, 1]:.3f} ({totals[k, 1] - totals[0, 1]:+.2f} h)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
