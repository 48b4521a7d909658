"""The two-level estimator against the plain fine-mesh mean, design by design, over every phantom of a study.

    python benchmarks/validate_multilevel.py STUDY.toml --out RUN_DIR --designs 2,1 4,3 6,5
                                             [--set KEY=VALUE ...] [--jobs 2] [--csv table.csv]

``STUDY.toml`` (with the same ``--set`` overrides as the sweep) must have a ``[multilevel]`` table and
``RUN_DIR`` its results store. The script

1. reads the two-level run from the store (:func:`~latticeopt.study.multilevel_sweep.run_multilevel`; anything
   the run still lacks is computed first, so run the sweep itself beforehand);
2. evaluates the designs named by ``--designs`` (``width,thickness`` in mm, matched against the study's grid) on
   every phantom the two-level estimate used, on the fine mesh, through the same store: the fine phantoms the
   two-level run made are read, only the rest are computed;
3. prints per design the two-level mean and SE with its fine count ``n`` of ``N``; the plain fine mean and SE
   over the same ``N`` phantoms (stratified by touch count, as the estimator is); their difference in units of
   the two-level SE and of the difference's own SE (:func:`~latticeopt.study.multilevel_check.gap_to_plain`); the SE
   ratio two-level / plain (the target is ``se_factor``); and the model seconds each estimator cost.

Agreement means ``|two-level - plain| <= 2`` two-level SEs. A phantom that fails on the fine mesh outside the
two-level subset cannot enter the two-level estimate; it is counted and left out of the plain mean.
"""

from __future__ import annotations

import argparse
import csv
import math
import os
import sys

for _var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

from latticeopt.errors import LatticeoptError  # noqa: E402
from latticeopt.study.config import load_study  # noqa: E402
from latticeopt.study.multilevel import multilevel_estimate  # noqa: E402
from latticeopt.study.multilevel_check import gap_to_plain  # noqa: E402
from latticeopt.study.multilevel_sweep import run_multilevel  # noqa: E402
from latticeopt.study.sweep import evaluate_designs, resolve_model  # noqa: E402


def _design_pair(text: str) -> tuple[float, float]:
    try:
        w, t = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTH,THICKNESS in mm (e.g. 4,3), got {text!r}") from None
    return w, t


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("study")
    ap.add_argument("--out", required=True, help="folder of the two-level run's results store")
    ap.add_argument("--designs", nargs="+", type=_design_pair, required=True, metavar="W,T")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--csv", help="also write the table here")
    args = ap.parse_args(argv)
    try:
        study = load_study(args.study, args.overrides)
    except LatticeoptError as exc:
        print(f"latticeopt: error: {exc}", file=sys.stderr)
        return 2
    if study.multilevel is None:
        print("latticeopt: error: study: expected a [multilevel] table (add --set multilevel.pilot=30), got none",
              file=sys.stderr)
        return 2
    if args.jobs < 1:
        print(f"latticeopt: error: --jobs: expected an integer >= 1, got {args.jobs}", file=sys.stderr)
        return 2
    index = {(float(d.width_mm), float(d.thickness_mm)): i for i, d in enumerate(study.designs)}
    missing = [f"{w:g},{t:g}" for w, t in args.designs if (w, t) not in index]
    if missing:
        have = " ".join(f"{w:g},{t:g}" for w, t in index)
        print(f"latticeopt: error: --designs: expected among {have}, got {missing[0]}", file=sys.stderr)
        return 2
    chosen = [index[p] for p in args.designs]
    settings = study.settings
    evaluate = resolve_model(settings.model)
    run = run_multilevel(study, settings, args.out, evaluate, jobs=args.jobs, progress=True)
    used = list(run.used)
    plain, computed = evaluate_designs([study.designs[i] for i in chosen], [study.phantoms[j] for j in used],
                                       settings, args.out, evaluate, jobs=args.jobs, progress=True,
                                       label=f"{study.name} (plain fine)")
    print(f"{study.name}: {len(used)} phantoms; plain fine evaluations computed now: {computed}")
    header = ["width_mm", "thickness_mm", "n_fine", "N", "two_level_mean", "two_level_se", "plain_mean", "plain_se",
              "diff", "diff_in_two_level_se", "diff_in_own_se", "se_ratio", "plain_failed", "seconds_two_level",
              "seconds_plain", "cost_ratio"]
    rows = []
    nu = len(used)
    for g, i in enumerate(chosen):
        d = study.designs[i]
        c, f_two, strata, whole = run.level_arrays(study, i)
        f_all = np.array([plain[g * nu + k].v_rel if plain[g * nu + k].ok else np.nan for k in range(nu)])
        ok = np.isfinite(f_all)
        in_subset = np.isfinite(f_two)
        est = run.estimates[i]
        if est is None:
            print(f"w = {d.width_mm:g}, t = {d.thickness_mm:g}: no coarse phantom solved, nothing to compare")
            continue
        ref = multilevel_estimate(c[ok], f_all[ok], strata[ok])  # n = N: the plain fine mean and its SE
        diff, own = gap_to_plain(c[ok], f_all[ok], strata[ok], in_subset[ok], whole[ok], run.parts()[ok])
        sec_two = sum(run.coarse[i * len(study.phantoms) + j].seconds or 0.0 for j in used) + sum(
            run.fine[(i, j)].seconds or 0.0 for j in run.order[:run.n_fine[i]])
        sec_plain = sum(plain[g * nu + k].seconds or 0.0 for k in range(nu))
        rows.append([d.width_mm, d.thickness_mm, est.n_fine, est.n_coarse, est.mean, est.se, ref.mean, ref.se, diff,
                     diff / est.se, diff / own if own > 0 else math.nan, est.se / ref.se, int((~ok).sum()),
                     sec_two, sec_plain, sec_two / sec_plain])
    print(f"{'w':>4} {'t':>3} {'n/N':>8} {'two-level':>18} {'plain fine':>18} {'diff':>9} {'/SE':>6} {'/own':>6} "
          f"{'SE ratio':>8} {'cost':>6}")
    for r in rows:
        print(f"{r[0]:4g} {r[1]:3g} {r[2]:>4d}/{r[3]:<3d} {r[4]:9.5f} ± {r[5]:.5f} {r[6]:9.5f} ± {r[7]:.5f} "
              f"{r[8]:+9.5f} {r[9]:+6.2f} {r[10]:+6.2f} {r[11]:8.3f} {r[15]:6.3f}")
    worst = max(abs(r[9]) for r in rows)
    print(f"largest |two-level - plain| = {worst:.2f} two-level SEs ({'within' if worst <= 2 else 'NOT within'} 2)")
    if args.csv:
        with open(args.csv, "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(header)
            w.writerows(rows)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
