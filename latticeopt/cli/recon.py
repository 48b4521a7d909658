"""``latticeopt reconstruct``: tactile images from voltage frames or simulated touches (classical or learned)."""

from __future__ import annotations

import argparse
import time

from ._common import (
    check_input_file,
    check_output_path,
    emit_json,
)


def register(sub) -> None:
    r = sub.add_parser("reconstruct", help="reconstruct tactile images from voltage frames",
                       description="Reconstruct normalized conductivity-change images from frames (CSV/NPY with 208 "
                                   "or 104 values per frame, docs/sensor_model.md) or from conductivity discs "
                                   "simulated with the sensor model (--disc).")
    r.add_argument("--model", required=True, help="sensor-model .npz from 'latticeopt export'")
    src = r.add_mutually_exclusive_group(required=True)
    src.add_argument("--frames", help="frames file (.npy, .csv or .txt)")
    src.add_argument("--disc", action="append", metavar="X,Y,DIAMETER,RATIO",
                     help="simulate a conductivity disc: centre (mm), diameter (mm), conductivity / sigma0 "
                          "(repeatable)")
    # --touch is X,Y,R,D (radius, depth) in simulate and indent: here it would silently mean a disc of another
    # size, so the old spelling is refused with a hint (run_reconstruct)
    src.add_argument("--touch", action="append", help=argparse.SUPPRESS)
    r.add_argument("--reference", help="reference (no-touch) frames file; default the model's simulated reference")
    r.add_argument("--snr-db", type=float, default=None, help="with --disc: add noise of this SNR (dB)")
    r.add_argument("--seed", type=int, default=0, help="noise seed; default 0")
    _add_method_args(r)
    r.add_argument("--method", default="tikhonov", help="tikhonov (one-step GN), gn (iterative) or dnn")
    r.add_argument("-o", "--output", required=True, help="output PNG")
    r.add_argument("--save-images", default=None, help="also write the images as .npy, shape (k, n, n)")
    r.add_argument("--max-frames", type=int, default=8, help="frames drawn in the PNG; default 8")
    r.add_argument("--json", action="store_true", help="print one JSON object")
    r.set_defaults(func=run_reconstruct)

def _add_method_args(p, multi_prior: bool = False) -> None:
    g = p.add_argument_group("methods")
    g.add_argument("--prior", default="laplacian", help="identity, noser or laplacian" +
                   (" (comma list)" if multi_prior else "") + "; default laplacian (best in benchmarks/bench_recon.py)")
    g.add_argument("--lambda", dest="lam", default="lcurve",
                   help="regularization: lcurve (L-curve corner per frame), gcv (per frame; needs noise), " +
                        ("validation (tuned on the validation part), " if multi_prior else "") +
                        "or a number relative to the largest eigenvalue of A P^-1 A^T; default lcurve")
    if not multi_prior:
        g.add_argument("--net", default=None, help="network file (method dnn)")
        g.add_argument("--max-iter", type=int, default=6, help="gn: iterations; default 6")


def _load_model(path, flag: str = "--model"):
    from ..errors import ParameterError
    from ..sensor_model import SensorModelError, load_sensor_model

    check_input_file(flag, path, (".npz",), "an existing sensor-model file (latticeopt export)")
    try:
        return load_sensor_model(path)
    except SensorModelError as exc:
        raise ParameterError(flag, "a sensor-model file written by 'latticeopt export'", str(exc)) from None


def _lam(text: str):
    from ..errors import ParameterError

    if text in ("lcurve", "gcv", "validation"):
        return text
    try:
        return float(text)
    except ValueError:
        raise ParameterError("--lambda", "lcurve, gcv, validation or a positive number", text) from None


def _ints(flag: str, text: str) -> tuple[int, ...]:
    from ..errors import ParameterError

    try:
        return tuple(int(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise ParameterError(flag, "a comma list of integers", text) from None


def run_reconstruct(args) -> int:
    import numpy as np

    from .. import _validate as v
    from ..errors import ParameterError
    from ..recon.dataset import add_noise, relative_change, render_touches
    from ..recon.evaluate import plot_images
    from ..recon.frames import read_frames, reference_frame

    if args.touch:  # the old spelling of --disc: refused before anything else is read
        raise ParameterError("--touch", "--disc X,Y,DIAMETER,RATIO for a conductivity disc in reconstruct "
                             "(--touch is X,Y,R,D, a press of radius R and depth D, in simulate and indent)",
                             args.touch[0])
    method = v.choice("--method", args.method, ("tikhonov", "gn", "dnn"))
    if method == "dnn":
        from .._extras import require_extra

        require_extra("learn", "method dnn runs the network with it", name="--method dnn", modules=("torch",))
    png = check_output_path("-o", args.output, suffixes=(".png",))
    npy = check_output_path("--save-images", args.save_images, suffixes=(".npy",))
    lam = _lam(args.lam)
    if lam == "validation":
        raise ParameterError("--lambda", "lcurve, gcv or a number (validation needs a dataset: use recon-eval)", lam)
    _check_reconstruct_args(args)
    from ..recon.frames import FRAME_SUFFIXES

    check_input_file("--frames", args.frames, FRAME_SUFFIXES)
    check_input_file("--reference", args.reference, FRAME_SUFFIXES)
    check_input_file("--net", args.net, (".npz",), "an existing network file (recon-train -o)")
    model = _load_model(args.model)
    t0 = time.perf_counter()
    truth = None
    sim = None
    if args.disc:
        from ..sensor_model import SensorSimulator

        touches = np.array([_disc(t, model.extent_mm) for t in args.disc])
        img = render_touches(touches, model.sigma0_S_per_m, model.n_pixels, model.extent_mm)
        sim = SensorSimulator(model)
        V = sim.voltages(img)
        if args.snr_db is not None:
            V = add_noise(V, args.snr_db, np.random.default_rng(args.seed))
        truth = ((img - model.sigma0_S_per_m) / model.sigma0_S_per_m)[None]
        ref = model.v_ref
    else:
        try:
            V = read_frames(args.frames, model.protocol)
        except ParameterError as exc:
            raise ParameterError("--frames", exc.expected, exc.got) from None
        try:
            ref = reference_frame(args.reference, model.v_ref, model.protocol)
        except ParameterError as exc:
            raise ParameterError("--reference", exc.expected, exc.got) from None
    y = relative_change(V, ref)
    lam_used = None
    if method == "dnn":
        from ..recon.dnn import DNNReconstructor

        if args.net is None:
            raise ParameterError("--net", "a network file from 'latticeopt recon-train' for --method dnn", None)
        images = DNNReconstructor(args.net, model).reconstruct(y)
    else:
        from ..recon.classical import GaussNewton, LinearReconstructor

        lin = LinearReconstructor(model, args.prior)
        lam_abs = lam if lam in ("lcurve", "gcv") else (v.real("--lambda", lam, lo=0, lo_open=True)
                                                         * lin.eigenvalues.max())
        if method == "tikhonov":
            x, lam_used = lin.solve(y, lam_abs)
            images = x.reshape(-1, model.n_pixels, model.n_pixels)
        else:
            from ..sensor_model import SensorSimulator

            res = GaussNewton(sim or SensorSimulator(model), args.prior, max_iter=args.max_iter).reconstruct(y, lam_abs)
            images, lam_used = res.images, res.lam
    k = min(len(images), v.integer("--max-frames", args.max_frames, lo=1))
    plot_images(images[:k], png, truth=None if truth is None else truth[:k], extent_mm=model.extent_mm)
    if npy is not None:
        np.save(npy, images)
    out = {"method": method, "prior": None if method == "dnn" else args.prior, "frames": int(len(images)),
           "lambda_relative": None if lam_used is None else (np.asarray(lam_used) / lin.eigenvalues.max()).tolist(),
           "peak_mm": [_peak(model, im) for im in images], "seconds": time.perf_counter() - t0, "output": str(png)}
    if args.json:
        emit_json(out)
        return 0
    for i, (px, val) in enumerate(out["peak_mm"][:k]):
        print(f"frame {i}: largest change {val:+.3f} at ({px[0]:.1f}, {px[1]:.1f}) mm")
    print(f"{method}{'' if method == 'dnn' else ' / ' + args.prior}: {len(images)} frame(s) in {out['seconds']:.2f} s; "
          f"wrote {png}" + (f" and {npy}" if npy else ""))
    return 0


#: Largest --disc conductivity ratio: beyond a 1e6 contrast the forward solve's conditioning leaves fewer
#: than ten significant digits in double precision (and the paper's touches span 0.05-2).
MAX_TOUCH_RATIO = 1e6
#: --snr-db range: below -40 dB the noise is 100 times the signal (an image of noise); above 200 dB it is below
#: double-precision rounding of the voltages.
SNR_DB_RANGE = (-40.0, 200.0)


def _disc(text: str, extent_mm=None):
    import math

    from ..errors import ParameterError

    form = "X,Y,DIAMETER,RATIO (mm, mm, mm, conductivity / sigma0)"
    try:
        x, y, d, r = (float(s) for s in text.split(","))
    except ValueError:
        raise ParameterError("--disc", form, text) from None
    if not all(math.isfinite(val) for val in (x, y, d, r)):
        raise ParameterError("--disc", f"{form}, all finite", text)
    if not (0 < r <= MAX_TOUCH_RATIO):
        raise ParameterError("--disc", f"a conductivity ratio 0 < RATIO <= {MAX_TOUCH_RATIO:g}", text)
    if d <= 0:
        raise ParameterError("--disc", "a positive diameter", text)
    if extent_mm is not None:
        x0, x1, y0, y1 = (float(e) for e in extent_mm)
        if not (x0 <= x <= x1 and y0 <= y <= y1):
            raise ParameterError("--disc", f"a centre on the sensor ({x0:g} <= X <= {x1:g}, {y0:g} <= Y <= {y1:g} mm)",
                                 text)
        side = max(x1 - x0, y1 - y0)
        if d > side:
            raise ParameterError("--disc", f"a diameter 0 < DIAMETER <= {side:g} mm (the sensor side)", text)
    return (x, y, d, r)


def _check_reconstruct_args(args) -> None:
    """reconstruct's numbers, before the model is read: discs' form, --snr-db, --seed, --max-frames, --max-iter."""
    from .. import _validate as v
    from ..recon.classical import PRIORS

    for text in args.disc or []:
        _disc(text)
    if args.snr_db is not None:
        v.real("--snr-db", args.snr_db, lo=SNR_DB_RANGE[0], hi=SNR_DB_RANGE[1])
    v.integer("--seed", args.seed, lo=0)
    v.integer("--max-frames", args.max_frames, lo=1)
    v.integer("--max-iter", args.max_iter, lo=1)
    v.choice("--prior", args.prior, PRIORS)


def _peak(model, image):
    import numpy as np

    i = int(np.argmax(np.abs(image)))
    return model.pixel_centres_mm()[i].tolist(), float(image.ravel()[i])


