"""``latticeopt sweep``: run a study file (resumable, parallel, optionally on a dask cluster)."""

from __future__ import annotations

import argparse

from ._common import check_parallel_args, check_study_file, check_study_outputs, study_overrides
from ._physics import add_physics_arg, physics_values


def register(sub) -> None:
    p = sub.add_parser(
        "sweep", help="run a study (grid of designs x phantoms) into a resumable results store",
        description="Run every design x phantom of a study TOML file that its results store does not hold "
                    "yet, in parallel, writing each result the moment it finishes. Re-run the same command "
                    "after an interruption to resume. Kinds: grid (random phantoms, [phantoms]), press (one indenter "
                    "ever deeper, [press]) and probes (the probe grid, [probes]: one press at every cell centre of "
                    "an n x n grid, each design scored by its uniformity 1 - std/mean of V_rel). "
                    "Writes into the study's out folder (or --out): "
                    "results.sqlite (the store), study.json, latticeopt.lock (held while it runs), results.csv and "
                    "report.txt; for a grid summary.csv, paired.csv (every design against the best), "
                    "vrel_lines.png and vrel_heatmap.png (two fields); for a press study press.csv and press.png; "
                    "for a probes study summary.csv (uniformity, worst-to-best, weakest probe) and probes.png; "
                    "excluded.csv and error.log when phantoms fail. "
                    "Schema: docs/studies.md.")
    p.add_argument("study", metavar="STUDY.toml", help="study file (e.g. studies/quick.toml)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a study key; dotted for tables, value in TOML syntax "
                        "(e.g. --set mesh.size_mm=3 --set grid.width_mm=[0,4]); repeatable")
    add_physics_arg(p)  # [physics] values merged into the study table, checked with it, named --physics KEY
    p.add_argument("--jobs", "-j", type=int, default=None, help="worker processes (default: the study's jobs)")
    p.add_argument("--backend", choices=("local", "dask"), default="local",
                   help="local processes (default) or a dask.distributed cluster")
    p.add_argument("--scheduler", default=None, metavar="ADDR",
                   help="dask scheduler address, e.g. tcp://10.0.0.5:8786 (with --backend dask; "
                        "default: a local cluster)")
    p.add_argument("--out", default=None, help="output folder (default: the study's out)")
    p.add_argument("--evaluate", default=None, metavar="MODULE:FUNCTION",
                   help="model evaluating one phantom (same as --set model=...; default "
                        "latticeopt.coupled:evaluate_phantom)")
    p.add_argument("--retry-failed", action="store_true", help="re-run phantoms stored as failed")
    p.add_argument("--dry-run", action="store_true",
                   help="validate the study, print what would run and an estimated wall time, and stop")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run_sweep_command)


def run_sweep_command(args: argparse.Namespace) -> int:
    from ..captions import counted
    from ..study.config import load_study
    from ..study.estimators import estimator_for
    from ..study.sweep import run_sweep
    from ..study.walltime import wall_time

    check_study_file(args.study)
    study = load_study(args.study, study_overrides(args), physics_values(args))
    check_parallel_args(args)
    check_study_outputs(args, study)
    if args.dry_run:
        stored = _stored_counts(study)
        print(f"{study.name} ({study.kind}): {counted(len(study.designs), 'design')} x "
              f"{counted(len(study.phantoms), 'phantom')} = {counted(study.n_tasks, 'evaluation')}, "
              f"{stored[study.settings.key]} stored; model {study.settings.model}; "
              f"mesh {study.settings.mesh.mesher} {study.settings.mesh.size_mm:g} mm; out {study.out_dir}")
        estimator = estimator_for(study)
        for line in estimator.describe(study.settings, stored):
            print(line)
        tasks = [(d.content_hash(), p.key) for d, p in study.tasks()]
        print(wall_time(estimator.levels(study.settings), tasks, study.out_dir,
                        study.jobs if args.jobs is None else args.jobs).line())
        return 0
    result = run_sweep(study, jobs=args.jobs, backend=args.backend, scheduler=args.scheduler,
                       progress=not args.no_progress, retry_failed=args.retry_failed)
    print(f"{result.computed} computed, {result.skipped} already stored, {result.failed} failed in total, "
          f"{result.seconds:.1f} s")
    for line in result.report:
        print(line)
    for name, path in result.outputs.items():
        print(f"wrote {name}: {path}")
    return 0


def _stored_counts(study) -> dict[str, int]:
    """Evaluations of the study's tasks its store holds (ok or failed), per settings key; 0 for a missing key."""
    from collections import Counter
    from pathlib import Path

    from ..study.store import ResultStore

    if not (Path(study.out_dir) / "results.sqlite").exists():
        return Counter()
    tasks = {(d.content_hash(), p.key) for d, p in study.tasks()}
    with ResultStore(study.out_dir, readonly=True) as store:
        return Counter(s for d, p, s in store.done_keys() if (d, p) in tasks)
