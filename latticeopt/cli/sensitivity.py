"""``latticeopt sensitivity``: how a study's verdict moves with each uncertain input (table and tornado plot)."""

from __future__ import annotations

import argparse
import math
import sys

from ._common import check_study_file, check_study_outputs, emit_json
from ._physics import add_physics_arg, physics_values


def register(sub) -> None:
    p = sub.add_parser(
        "sensitivity", help="re-run a press study or a small map under each uncertain input",
        description="Run STUDY as it is (the baseline) and once per value of every --vary key, one key at a time, "
                    "each into <out>/sensitivity/KEY=VALUE (resumable stores). Prints the figures of every run "
                    "(press: V_rel at the deepest depth and the [[press.compare]] ratios; grid: mean V_rel ± SE "
                    "per design and the best design) and draws a tornado plot of how far each key moves them. "
                    "Writes <out>/sensitivity/sensitivity.csv and tornado.png besides the runs' folders (<out> "
                    "the study's out).")
    p.add_argument("study", metavar="STUDY.toml", help="a press study or a small grid (e.g. "
                   "studies/sensitivity_press.toml)")
    p.add_argument("--vary", action="append", required=True, metavar="KEY=V1,V2",
                   help="an uncertain input and its values, e.g. hydrogel_shear_kPa=2,15 or design.rim=channel "
                        "(a bare [physics] or design key is completed); repeatable")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a study key for every run (as for sweep); repeatable")
    add_physics_arg(p)  # every run's baseline [physics], merged into the study table before the variants
    p.add_argument("--jobs", "-j", type=int, default=None, help="worker processes (default: the study's jobs)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.add_argument("--dry-run", action="store_true",
                   help="check every run, print what would run (runs, evaluations, folders, files) and stop")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    p.set_defaults(func=run_sensitivity_command)


def run_sensitivity_command(args: argparse.Namespace) -> int:
    from ..errors import ParameterError
    from ..study.sensitivity import load_variants, parse_vary, plot_tornado, run_sensitivity, write_table
    from ..study.sweep import run_sweep

    if args.jobs is not None and args.jobs < 1:
        raise ParameterError("--jobs", "an integer >= 1", args.jobs)
    variations = [parse_vary(t) for t in args.vary]
    check_study_file(args.study)
    runs = load_variants(args.study, variations, args.overrides, physics_values(args))
    for run in runs:
        check_study_outputs(args, run[3])
    root = runs[0][3].out_dir.parent
    if args.dry_run:
        return _dry_run(runs, root, args.json)
    say = None if args.json else (lambda msg: print(msg, file=sys.stderr, flush=True))
    rows = run_sensitivity(runs, lambda s: run_sweep(s, jobs=args.jobs, progress=not args.no_progress), say)
    table = write_table(rows, root / "sensitivity.csv")
    tornado = plot_tornado(rows, root / "tornado.png")
    if args.json:
        emit_json({"runs": [{**r, "figures": {k: {"value": v, "se": None if (isinstance(se, float) and math.isnan(se))
                                                  else se} for k, (v, se) in r["figures"].items()}}
                            for r in rows], "table": str(table), "tornado": str(tornado) if tornado else None})
        return 0
    names = list(rows[0]["figures"])
    for name in names:
        print(name)
        for r in rows:
            val, se = r["figures"].get(name, (math.nan, math.nan))
            cell = f"{val:.5g}" if isinstance(val, float) else str(val)
            if isinstance(se, float) and math.isfinite(se):
                cell += f" ± {se:.2g}"
            print(f"    {r['run']:<44} {cell}" + (f"  ({r['failed']} failed)" if r["failed"] else ""))
    print(f"wrote {table}" + (f" and {tornado}" if tornado else ""))
    return 0


def _dry_run(runs, root, as_json: bool) -> int:
    """What ``sensitivity`` would run and write, without running it."""
    base = runs[0][3]
    plan = [{"run": label, "designs": len(s.designs), "phantoms": len(s.phantoms), "evaluations": s.n_tasks,
             "out": str(s.out_dir)} for label, _, _, s in runs]
    files = {"table": str(root / "sensitivity.csv"), "tornado": str(root / "tornado.png")}
    total = sum(r["evaluations"] for r in plan)
    if as_json:
        emit_json({"dry_run": True, "runs": plan, "evaluations": total, **files})
        return 0
    print(f"{base.name} ({base.kind}): {len(plan)} runs (the baseline and {len(plan) - 1} variants), {total} "
          f"evaluations; model {base.settings.model}; mesh {base.settings.mesh.mesher} "
          f"{base.settings.mesh.size_mm:g} mm")
    for r in plan:
        print(f"    {r['run']:<44} {r['designs']} designs x {r['phantoms']} phantoms = {r['evaluations']}; "
              f"out {r['out']}")
    print(f"would write {files['table']} and {files['tornado']}")
    return 0
