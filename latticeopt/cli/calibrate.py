"""``latticeopt calibrate``: fit [physics] parameters to measured presses (nlopt), with uncertainty."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ..errors import ParameterError
from ._common import add_mesh_args, check_mesh_args, check_output_path, emit_json, mesh_settings_from_args
from ._physics import add_physics_arg, physics_settings, physics_values

#: What ``calibrate`` writes into ``--out``.
CALIBRATION_FILES = ("calibration.json", "calibration.png")


def register(sub) -> None:
    p = sub.add_parser(
        "calibrate", help="fit physics parameters to measured presses",
        description="Fit numeric [physics] keys (e.g. hydrogel_shear_kPa) to measured presses by nlopt within "
                    "the given bounds: fitted values with standard errors and likelihood-ratio intervals, "
                    "residuals, a measured-vs-predicted plot and, with --fit-on, a predictive check on the rows "
                    "left out of the fit. DATA columns: design keys (width_mm, thickness_mm, rim, ...), x_mm, "
                    "y_mm, radius_mm, depth_mm, and v_rel or V1..V208 (pyEIT 'std' order; voltage rows need a "
                    "depth_mm = 0 reference row). Example: studies/data/paper_press_measured.csv. Writes "
                    f"{' and '.join(CALIBRATION_FILES)} (the fit and its plot) into --out, by default "
                    "runs/calibrate-<DATA stem> under the working directory.")
    p.add_argument("data", metavar="DATA.csv", help="measured presses")
    p.add_argument("--fit", action="append", required=True, metavar="KEY=LOW:HIGH",
                   help="a [physics] key to fit and its bounds, e.g. hydrogel_shear_kPa=1:50 (repeatable)")
    p.add_argument("--fit-on", action="append", default=[], metavar="KEY=V1,V2",
                   help="fit only on rows whose design KEY is one of the values; predict the others (repeatable)")
    add_physics_arg(p)
    p.add_argument("--max-evals", type=int, default=30, help="objective evaluations of the fit (default 30)")
    p.add_argument("--profile-points", type=int, default=7,
                   help="points of each conditional profile (0: none; default 7)")
    p.add_argument("--out", type=Path, default=None, help="output folder (default runs/calibrate-<DATA stem>)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress lines on stderr")
    add_mesh_args(p)
    p.set_defaults(func=run_calibrate)


def _fit_on(texts) -> dict:
    out = {}
    for text in texts:
        key, sep, vals = str(text).partition("=")
        if not sep or not key.strip() or not vals.strip():
            raise ParameterError("--fit-on", "KEY=V1,V2, e.g. width_mm=0,4", text)
        out[key.strip()] = [v.strip() for v in vals.split(",") if v.strip()]
    return out


def run_calibrate(args: argparse.Namespace) -> int:
    from ..study.calibrate import calibrate, coupled_predictor, parse_fit, plot_calibration, read_presses

    params = [parse_fit(t) for t in args.fit]
    if len({q.name for q in params}) != len(params):
        raise ParameterError("--fit", "each key once", [q.name for q in params])
    if args.max_evals < 1:
        raise ParameterError("--max-evals", "an integer >= 1", args.max_evals)
    if args.profile_points < 0 or args.profile_points == 1:
        raise ParameterError("--profile-points", "0 (none) or an integer >= 2", args.profile_points)
    resolved = physics_settings(args)
    physics = {k: getattr(resolved, k) for k in physics_values(args)}  # the keys given, checked
    clash = sorted(set(physics) & {q.name for q in params})
    if clash:
        raise ParameterError("--physics", "keys other than the fitted ones", clash[0])
    fit_on = _fit_on(args.fit_on)
    presses = read_presses(args.data)
    check_mesh_args(args)
    mesh = mesh_settings_from_args(args)
    out = check_output_path("--out", args.out or Path("runs") / f"calibrate-{Path(args.data).stem}", kind="dir")
    out.mkdir(parents=True, exist_ok=True)
    say = None if args.quiet else (lambda msg: print(msg, file=sys.stderr, flush=True))
    predict = coupled_predictor(mesh, physics, cache_dir=False if args.no_cache else args.cache_dir)
    cal = calibrate(presses, params, predict, fit_on=fit_on, max_evals=args.max_evals,
                    profile_points=args.profile_points, progress=say)
    summary = {**cal.summary(), "data": str(args.data), "physics": physics, "mesh": mesh.as_dict()}
    table, picture = CALIBRATION_FILES
    (out / table).write_text(json.dumps(summary, indent=1))
    figure = plot_calibration(cal, out / picture)
    if args.json:
        emit_json({**summary, "figure": str(figure)})
        return 0
    for name, val in cal.values.items():
        lo, hi = cal.intervals.get(name, (float("nan"), float("nan")))
        bound = "  AT A BOUND: the data want a value outside the range given" if name in cal.at_bound else ""
        print(f"{name} = {val:.4g} ± {cal.standard_errors[name]:.2g} (SE; 95 % likelihood-ratio interval "
              f"{lo:.4g} .. {hi:.4g}, conditional){bound}")
    print(f"RSS {cal.rss:.4g} over {cal.dof + len(params)} presses ({cal.dof} degrees of freedom), "
          f"{cal.evaluations} evaluations")
    print("row  used  measured   predicted  design / depth")
    for r in cal.rows:
        print(f"{r['row']:>3}  {'fit ' if r['used_in_fit'] else 'pred'}  {r['measured']:.5f}    {r['predicted']:.5f}"
              f"    {r['design']}, {r['depth_mm']:g} mm")
    print(f"wrote {out / table} and {figure}")
    return 0
