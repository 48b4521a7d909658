"""``latticeopt optimize``: optimize continuous design variables of a study with nlopt (resumable)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ._common import check_parallel_args, check_study_file, check_study_outputs, study_overrides
from ._physics import add_physics_arg, physics_values


def register(sub) -> None:
    from ..optimize import ALGORITHMS

    p = sub.add_parser(
        "optimize", help="optimize lattice geometry with nlopt over a study's fixed phantoms",
        description="Maximize an objective of V_rel (mean, robust quantile, uniformity) or image quality "
                    "(image_cc) over the design variables "
                    "of a study's [optimize] table with an nlopt algorithm. Every phantom result goes to the "
                    "study's results store (shared with sweeps): stored designs are read, not recomputed, and an "
                    "interrupted run resumes by replaying its path from the store. Writes into the study's out "
                    "folder (or --out): results.sqlite, <name>_history.csv, <name>_report.txt, "
                    "<name>_result.json, <name>_convergence.png and <name>_path.png (<name> the study's name; "
                    "with categories, one such folder per category and categories.csv in their parent). "
                    "Schema: docs/studies.md. "
                    f"Algorithms: {', '.join(ALGORITHMS)}.")
    p.add_argument("study", metavar="STUDY.toml", help="study file with an [optimize] table "
                   "(e.g. studies/optimize_square.toml)")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a study key, dotted for tables, value in TOML syntax "
                        "(e.g. --set optimize.algorithm=LN_COBYLA --set optimize.max_evals=20); repeatable")
    add_physics_arg(p)  # [physics] values merged into the study table, checked with it, named --physics KEY
    p.add_argument("--jobs", "-j", type=int, default=None,
                   help="worker processes for the phantoms of each design (default: the study's jobs)")
    p.add_argument("--backend", choices=("local", "dask"), default="local",
                   help="local processes (default) or a dask.distributed cluster")
    p.add_argument("--scheduler", default=None, metavar="ADDR", help="dask scheduler address (with --backend dask)")
    p.add_argument("--out", default=None, help="output folder and results store (default: the study's out)")
    p.add_argument("--evaluate", default=None, metavar="MODULE:FUNCTION",
                   help="model evaluating one phantom (same as --set model=...)")
    p.add_argument("--dry-run", action="store_true",
                   help="validate, print the effective problem and what the store holds, and stop")
    p.add_argument("--retry-failed", action="store_true",
                   help="compute phantoms stored as failed again (parametric studies; e.g. after a solver change)")
    p.add_argument("--quiet", "-q", action="store_true", help="no line per evaluation")
    p.set_defaults(func=run_optimize_command)


def _step_line(step) -> str:
    x = ", ".join(f"{k.removesuffix('_mm')}={val:.4f}" for k, val in step.x.items())
    a = step.assessment
    if a is None:
        return f"[{step.index:3d}] start {step.start} {x}: not evaluated ({step.note})"
    src = "repeat" if step.repeat else f"{a.computed} computed, {a.seconds:.1f} s"
    flag = "" if step.feasible else "  INFEASIBLE"
    return f"[{step.index:3d}] start {step.start} {x}: score {step.score:.5g} ± {step.se:.2g} ({src}){flag}"


def run_optimize_command(args: argparse.Namespace) -> int:

    from ..errors import AllFailedError
    from ..optimize import effective_bounds_text, run_optimization
    from ..optimize.categories import plot_categories, write_summary
    from ..study.report_lines import floor_text

    check_study_file(args.study)
    from ..optimize.categories import categorical_optimizations
    from ..optimize.freeform_study import is_density_study
    from ..study.config import read_study_table

    raw, keys = read_study_table(args.study, study_overrides(args), physics_values(args))
    if is_density_study(raw):
        if args.retry_failed:
            from ..errors import ParameterError

            raise ParameterError("--retry-failed", "a parametric study ([optimize]): free-form and graded studies "
                                 "keep no store of phantoms to retry", "a density study")
        return _run_density_study(args, raw, keys)
    runs = categorical_optimizations(raw, source=str(args.study), overridden=keys, default_name=Path(args.study).stem)
    check_parallel_args(args)
    for run in runs:
        check_study_outputs(args, run.optimization.study)
    if args.dry_run:
        for run in runs:
            opt = run.optimization
            cfg, problem, study = opt.config, opt.problem, opt.study
            head = f"[{run.label}] " if run.label else ""
            print(f"{head}{study.name}: maximize {cfg.objective.describe()} with {cfg.algorithm} over "
                  f"{effective_bounds_text(problem)}; start {dict(zip(problem.names, problem.start))}; "
                  f"{len(study.phantoms)} phantoms + {len(opt.probes)} probes per design; max_evals "
                  f"{cfg.max_evals}; model {study.settings.model}; mesh {study.settings.mesh.mesher} "
                  f"{study.settings.mesh.size_mm:g} mm; out {study.out_dir}"
                  + floor_text(study.settings.physics_settings.measurement_floor_rel))
            for t in problem.folded:
                print(f"bound tightened: {t}")
        return 0
    callback = None if args.quiet else (lambda step: print(_step_line(step), flush=True))
    pairs, all_failed = [], []
    for run in runs:
        if run.label:
            print(f"== category {run.label} ==", flush=True)
        try:
            result = run_optimization(run.optimization, jobs=args.jobs, backend=args.backend,
                                      scheduler=args.scheduler, callback=callback, retry_failed=args.retry_failed)
        except AllFailedError as exc:
            if len(runs) == 1:
                raise
            # one category the model cannot evaluate at all must not hide the others: rank them, fail at the end
            print(f"category {run.label}: {exc}", flush=True)
            result = exc.result
            all_failed.append(run.label)
        print(f"{len(result.history)} calls, {result.computed} phantoms computed, {result.seconds:.1f} s")
        for line in result.report:
            print(line)
        for name, path in result.outputs.items():
            print(f"wrote {name}: {path}")
        pairs.append((run, result))
    if len(runs) > 1:
        out = runs[0].optimization.study.out_dir.parent
        for line in write_summary(pairs, out / "categories.csv"):
            print(line)
        figure = plot_categories(pairs, out / "categories.png")
        if figure is not None:
            print(f"wrote figure: {figure}")
        if len(all_failed) == len(runs):
            raise AllFailedError(f"every phantom evaluation failed in every category ({', '.join(all_failed)})")
    return 0


def _run_density_study(args: argparse.Namespace, raw: dict, keys: list) -> int:
    """A ``kind = "freeform"`` or ``"graded"`` study (:mod:`latticeopt.optimize.freeform`, :mod:`.graded`)."""
    from ..errors import ParameterError
    from ..optimize.freeform import run_freeform
    from ..optimize.freeform_study import freeform_from_dict
    from ..optimize.graded import run_graded
    from ._common import check_output_path

    check_parallel_args(args)
    if args.backend != "local":
        raise ParameterError("--backend", f"'local' for a {raw.get('kind')} study (its workers keep the model "
                             "between iterates)", args.backend)
    study = freeform_from_dict(raw, source=str(args.study), overridden=keys)
    out = check_output_path("--out", args.out or study.out_dir, kind="dir")
    cfg = study.config
    jobs = args.jobs or study.jobs
    if cfg.front:
        return _run_density_front(args, study, out, jobs)
    if args.dry_run:
        channel = "edge" if study.design.pattern == "hexagonal" else "line"
        layout = (f"{cfg.cells} x {cfg.cells} cells, minimum feature {cfg.min_feature_mm:g} mm, beta "
                  f"{list(cfg.betas)} x {cfg.iterations_per_beta} iterations" if study.kind == "freeform" else
                  f"a width per {channel} of pitch {study.design.pitch_mm:g} mm ({cfg.min_width_mm:g} mm <= w, "
                  f"islands >= {cfg.min_island_mm:g} mm)"
                  + (f", lines moving up to {cfg.max_shift_mm:g} mm" if cfg.max_shift_mm else "")
                  + f", {cfg.iterations} iterations")
        probes = (f"; uniformity >= {cfg.min_uniformity:g}" if cfg.min_uniformity is not None else "") + (
            f"; probes {cfg.probe_grid} x {cfg.probe_grid}" if cfg.probes_on else "")
        print(f"{study.name} ({study.kind}): maximize mean V_rel over {len(study.phantoms)} phantoms; {layout}; "
              f"symmetry {cfg.symmetry}; gel fraction {cfg.min_hydrogel_fraction:g}..{cfg.max_hydrogel_fraction:g}"
              f"{probes}; {cfg.algorithm}; mesh {study.mesh.size_mm:g} mm; {jobs} worker(s); out {out}")
        return 0
    run = run_freeform if study.kind == "freeform" else run_graded
    res = run(study.design, list(study.phantoms), study.mesh, study.physics, cfg, out,
              progress=None if args.quiet else print, jobs=jobs)
    print(f"mean V_rel {res.v_rel:.5f}, gel fraction {res.hydrogel_fraction:.3f}, {res.evaluations} evaluations; "
          f"wrote " + ", ".join(f"{k} {v}" for k, v in res.files.items() if k != "stl")
          + (f", STL solids in {out / 'stl'}" if "stl" in res.files else ""))
    return 0


def _run_density_front(args: argparse.Namespace, study, out, jobs: int) -> int:
    """A density study with a ``front`` (:mod:`latticeopt.optimize.front`)."""
    from ..optimize.front import describe_front, run_front

    if args.dry_run:
        print("\n".join(describe_front(study, out)))
        return 0
    res = run_front(study, out, progress=None if args.quiet else print, jobs=jobs)
    for row in res["points"] + res["references"]:
        print(f"{row['kind']:9s} {row['label']:16s} mean V_rel {row['v_rel']:.5f}  uniformity {row['uniformity']:.4f}"
              f"  worst/best {row['worst_to_best']:.3f}  gel {row['hydrogel_fraction']:.3f}"
              + (f"  dominated by {row['dominated_by']}" if row["dominated_by"] else ""))
    for line in res["warnings"]:
        print(line)
    print("wrote " + ", ".join(f"{k} {v}" for k, v in res["files"].items()))
    return 0
