"""``latticeopt merit``: GREIT figures of merit mapped over a grid of small targets across the sensor."""

from __future__ import annotations

import time

from ._common import check_output_path, emit_json


def register(sub) -> None:
    from .recon import _add_method_args

    p = sub.add_parser("merit", help="map GREIT figures of merit over the sensor (uniformity maps)",
                       description="Simulate a small conductivity target at each of N x N places (nonlinear forward "
                                   "solves of the sensor model), reconstruct each by one-step Tikhonov and map the "
                                   "GREIT figures: amplitude, position error, resolution, shape deformation, ringing.")
    p.add_argument("model", metavar="MODEL", help="sensor-model .npz from 'latticeopt export'")
    p.add_argument("--targets", type=int, default=7, help="targets per side; default 7")
    p.add_argument("--diameter", type=float, default=None,
                   help="target diameter (mm); default the lattice pitch (smaller targets can miss the channels)")
    p.add_argument("--ratio", type=float, default=0.5, help="target conductivity / sigma0; default 0.5")
    p.add_argument("--snr-db", type=float, default=None, help="noise added to the frames (dB); default none")
    p.add_argument("--seed", type=int, default=0, help="noise seed; default 0")
    _add_method_args(p, multi_prior=False)
    p.add_argument("--jobs", type=int, default=1, help="forward-solve workers; default 1")
    p.add_argument("-o", "--output", default=None, help="figure (.png): the five maps")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run_merit)


def run_merit(args) -> int:
    import numpy as np

    from .. import _validate as v
    from ..errors import ParameterError
    from ..recon.classical import PRIORS
    from ..recon.merit import merit_map, plot_merit_map
    from .recon import _lam, _load_model

    out = check_output_path("-o", args.output, suffixes=(".png",))
    v.integer("--targets", args.targets, lo=2, hi=25)
    v.real("--ratio", args.ratio, lo=0, lo_open=True, hi=100)
    if args.diameter is not None:
        v.real("--diameter", args.diameter, lo=0, lo_open=True)
    if args.snr_db is not None:
        v.real("--snr-db", args.snr_db)
    v.integer("--jobs", args.jobs, lo=1, hi=256)
    v.integer("--seed", args.seed, lo=0)
    v.choice("--prior", args.prior, PRIORS)
    lam = _lam(args.lam)
    if lam == "validation" or (not isinstance(lam, str) and not lam > 0):
        raise ParameterError("--lambda", "lcurve, gcv or a positive number", args.lam)
    model = _load_model(args.model, "MODEL")
    t0 = time.perf_counter()
    try:
        res = merit_map(model, args.targets, args.diameter, args.ratio, args.prior, lam, args.snr_db, args.jobs,
                        progress=not args.no_progress and not args.json, seed=args.seed)
    except ParameterError as exc:  # the model-dependent bounds (diameter against the sensor)
        flag = {"diameter_mm": "--diameter", "ratio": "--ratio"}.get(exc.name, exc.name)
        raise ParameterError(flag, exc.expected, exc.got) from None
    if out is not None:
        plot_merit_map(res, out)
    info = {"settings": res.settings, "summary": res.summary, "targets_mm": res.targets_mm.tolist(),
            "figures": {k: a.tolist() for k, a in res.figures.items()}, "figure": None if out is None else str(out),
            "unseen_targets": int(np.isnan(res.figures["resolution"]).sum()),
            "seconds": time.perf_counter() - t0}
    if args.json:
        emit_json(info)
        return 0
    print(f"{model.design.describe()}: {args.targets} x {args.targets} targets of {res.settings['diameter_mm']:g} mm, "
          f"sigma/sigma0 = {args.ratio:g}, one-step Tikhonov ({args.prior}, lambda {args.lam})")
    print(f"{'figure':>20} {'mean':>9} {'sd':>9} {'min':>9} {'max':>9}")
    for k, s in res.summary.items():
        print(f"{k:>20} {s['mean']:9.4g} {s['std']:9.3g} {s['min']:9.4g} {s['max']:9.4g}")
    if info["unseen_targets"]:
        print(f"{info['unseen_targets']} target(s) changed no voltage (on silicone): left out")
    if out is not None:
        print(f"wrote {out}")
    return 0
