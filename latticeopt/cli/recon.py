"""``latticeopt export``, ``reconstruct``, ``recon-train`` and ``recon-eval``: sensor models and tactile images."""

from __future__ import annotations

import time
from pathlib import Path

from ._common import (
    add_design_args,
    add_mesh_args,
    check_input_file,
    check_mesh_args,
    check_output_path,
    design_from_args,
    emit_json,
    mesh_settings_from_args,
    parse_output,
)


def register(sub) -> None:
    from ..electrics.forward import DEFAULT_CURRENT_A

    p = sub.add_parser("export", help="export a design as a sensor-model file for reconstruction",
                       description="Mesh a design, solve its rest state at the background conductivity and write "
                                   "the sensor-model .npz (format: docs/sensor_model.md).")
    add_design_args(p)
    add_mesh_args(p)
    g = p.add_argument_group("sensor model")
    g.add_argument("--sigma", type=float, default=0.00312, help="background conductivity sigma0 (S/m); "
                   "default 0.00312 (the paper's)")
    g.add_argument("--contact-impedance", type=float, default=None,
                   help="contact impedance (ohm m^2); default keeps z_c * sigma = 2e-3 ohm m^3/m (0.641 at sigma0)")
    g.add_argument("--current", type=float, default=DEFAULT_CURRENT_A, help="drive current (A); default 1e-3")
    g.add_argument("--pixels", type=int, default=48, help="pixels per side of the image grid; default 48")
    p.add_argument("-o", "--output", required=True, help="output .npz file")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run_export)

    r = sub.add_parser("reconstruct", help="reconstruct tactile images from voltage frames",
                       description="Reconstruct normalized conductivity-change images from frames (CSV/NPY with 208 "
                                   "or 104 values per frame, docs/sensor_model.md) or from touches simulated with "
                                   "the sensor model.")
    r.add_argument("--model", required=True, help="sensor-model .npz from 'latticeopt export'")
    src = r.add_mutually_exclusive_group(required=True)
    src.add_argument("--frames", help="frames file (.npy, .csv or .txt)")
    src.add_argument("--touch", action="append", metavar="X,Y,D,RATIO",
                     help="simulate a circular touch: centre (mm), diameter (mm), conductivity / sigma0 (repeatable)")
    r.add_argument("--reference", help="reference (no-touch) frames file; default the model's simulated reference")
    r.add_argument("--snr-db", type=float, default=None, help="with --touch: add noise of this SNR (dB)")
    r.add_argument("--seed", type=int, default=0, help="noise seed; default 0")
    _add_method_args(r)
    r.add_argument("--method", default="tikhonov", help="tikhonov (one-step GN), gn (iterative) or dnn")
    r.add_argument("-o", "--output", required=True, help="output PNG")
    r.add_argument("--save-images", default=None, help="also write the images as .npy, shape (k, n, n)")
    r.add_argument("--max-frames", type=int, default=8, help="frames drawn in the PNG; default 8")
    r.add_argument("--json", action="store_true", help="print one JSON object")
    r.set_defaults(func=run_reconstruct)

    t = sub.add_parser("recon-train", help="simulate the paper's dataset and train the learned reconstructor",
                       description="Simulate circular touches with the sensor model (paper §V: 1-5 touches, "
                                   "7.5-27.5 mm, 0.05-2 sigma0, 7:2:1, eight-fold augmentation with noise) and "
                                   "train the MLP-CNN reconstructor.")
    t.add_argument("--model", required=True, help="sensor-model .npz")
    _add_dataset_args(t)
    g = t.add_argument_group("training")
    g.add_argument("--epochs", type=int, default=100, help="maximum epochs; default 100")
    g.add_argument("--batch-size", type=int, default=256, help="default 256")
    g.add_argument("--lr", type=float, default=1e-3, help="Adam learning rate; default 1e-3")
    g.add_argument("--patience", type=int, default=15, help="early stop after this many epochs without "
                   "improvement; default 15")
    g.add_argument("--no-augment", action="store_true", help="train on the clean training part only")
    g.add_argument("--threads", type=int, default=None, help="torch threads; default torch's")
    t.add_argument("-o", "--output", required=True, help="network file (.npz)")
    t.add_argument("--json", action="store_true", help="print one JSON object")
    t.set_defaults(func=run_train)

    e = sub.add_parser("recon-eval", help="score reconstruction methods on the simulated test set",
                       description="CC, PSNR, SSIM and RE per touch count for each method on the test part of a "
                                   "dataset (simulation), and a figure of ground truth beside each method.")
    e.add_argument("--model", required=True, help="sensor-model .npz")
    e.add_argument("--dataset", required=True, help="dataset .npz written by recon-train --dataset")
    e.add_argument("--net", default=None, help="network file for method dnn")
    e.add_argument("--methods", default="background,tikhonov,gn,dnn",
                   help="comma list of background, tikhonov, gn, dnn; default all")
    _add_method_args(e, multi_prior=True)
    e.add_argument("--gn-per-count", type=int, default=10, help="test frames per touch count for gn; default 10")
    e.add_argument("--test-snr-db", type=float, default=None, help="noise on the test frames; default none")
    e.add_argument("--figure", default=None, help="PNG of ground truth beside each method")
    e.add_argument("--json", action="store_true", help="print one JSON object")
    e.add_argument("--no-progress", action="store_true", help="no progress bars (--json implies it)")
    e.set_defaults(func=run_eval)


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


def _add_dataset_args(p) -> None:
    g = p.add_argument_group("dataset")
    g.add_argument("--per-count", type=int, default=10_000, help="samples per touch count; default 10000 (paper)")
    g.add_argument("--touch-counts", default="1,2,3,4,5", help="comma list; default 1,2,3,4,5")
    g.add_argument("--seed", type=int, default=0, help="seed of touches, split and noise; default 0")
    g.add_argument("--jobs", type=int, default=1, help="worker processes for the forward solves; default 1")
    g.add_argument("--dataset", default=None, help="dataset .npz: read if it exists, else written after simulation")


def _load_model(path):
    from ..errors import ParameterError
    from ..sensor_model import SensorModelError, load_sensor_model

    check_input_file("--model", path, (".npz",), "an existing sensor-model file (latticeopt export)")
    try:
        return load_sensor_model(path)
    except SensorModelError as exc:
        raise ParameterError("--model", "a sensor-model file written by 'latticeopt export'", str(exc)) from None


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


def run_export(args) -> int:
    from ..sensor_model import build_sensor_model, save_sensor_model

    out = check_output_path("-o", args.output, suffixes=(".npz",))
    check_mesh_args(args)
    t0 = time.perf_counter()
    cache = False if args.no_cache else args.cache_dir
    model = build_sensor_model(design_from_args(args), mesh_settings_from_args(args), args.sigma,
                               args.contact_impedance, args.pixels, args.current, cache)
    save_sensor_model(model, out)
    info = {**model.summary(), "output": str(out), "seconds": time.perf_counter() - t0}
    if args.json:
        emit_json(info)
        return 0
    print(f"{model.design.describe()}")
    print(f"hydrogel mesh {info['gel_nodes']} nodes, {info['gel_tets']} tets; sigma0 {model.sigma0_S_per_m:g} S/m, "
          f"z_c {info['contact_impedance_ohm_m2']:.4g} ohm m^2 (z_c sigma / w = {info['contact_number']:.3g}), "
          f"I = {model.current_A * 1e3:g} mA")
    print(f"{info['n_rows']} rows, Jacobian {model.jacobian.shape[0]} x {model.jacobian.shape[1]} on "
          f"{model.n_pixels} x {model.n_pixels} pixels; |V_ref| {info['v_ref_range_V'][0]:.4g} to "
          f"{info['v_ref_range_V'][1]:.4g} V; fingerprint {model.fingerprint}")
    print(f"wrote {out} ({out.stat().st_size / 1e6:.1f} MB) in {info['seconds']:.1f} s")
    return 0


def run_reconstruct(args) -> int:
    import numpy as np

    from .. import _validate as v
    from ..errors import ParameterError
    from ..recon.dataset import add_noise, relative_change, render_touches
    from ..recon.evaluate import plot_images
    from ..recon.frames import read_frames, reference_frame

    method = v.choice("--method", args.method, ("tikhonov", "gn", "dnn"))
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
    if args.touch:
        from ..sensor_model import SensorSimulator

        touches = np.array([_touch(t, model.extent_mm) for t in args.touch])
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


#: Largest --touch conductivity ratio: beyond a 1e6 contrast the forward solve's conditioning leaves fewer
#: than ten significant digits in double precision (and the paper's touches span 0.05-2).
MAX_TOUCH_RATIO = 1e6
#: --snr-db range: below -40 dB the noise is 100 times the signal (an image of noise); above 200 dB it is below
#: double-precision rounding of the voltages.
SNR_DB_RANGE = (-40.0, 200.0)


def _touch(text: str, extent_mm=None):
    import math

    from ..errors import ParameterError

    form = "X,Y,DIAMETER,RATIO (mm, mm, mm, conductivity / sigma0)"
    try:
        x, y, d, r = (float(s) for s in text.split(","))
    except ValueError:
        raise ParameterError("--touch", form, text) from None
    if not all(math.isfinite(val) for val in (x, y, d, r)):
        raise ParameterError("--touch", f"{form}, all finite", text)
    if not (0 < r <= MAX_TOUCH_RATIO):
        raise ParameterError("--touch", f"a conductivity ratio 0 < RATIO <= {MAX_TOUCH_RATIO:g}", text)
    if d <= 0:
        raise ParameterError("--touch", "a positive diameter", text)
    if extent_mm is not None:
        x0, x1, y0, y1 = (float(e) for e in extent_mm)
        if not (x0 <= x <= x1 and y0 <= y <= y1):
            raise ParameterError("--touch", f"a centre on the sensor ({x0:g} <= X <= {x1:g}, {y0:g} <= Y <= {y1:g} mm)",
                                 text)
        side = max(x1 - x0, y1 - y0)
        if d > side:
            raise ParameterError("--touch", f"a diameter 0 < DIAMETER <= {side:g} mm (the sensor side)", text)
    return (x, y, d, r)


def _check_reconstruct_args(args) -> None:
    """reconstruct's numbers, before the model is read: touches' form, --snr-db, --seed, --max-frames, --max-iter."""
    from .. import _validate as v
    from ..recon.classical import PRIORS

    for text in args.touch or []:
        _touch(text)
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


def run_train(args) -> int:
    from ..recon.dataset import DatasetConfig, ReconDataset, generate_dataset
    from ..recon.dnn import ReconTrainConfig, save_reconstructor, train_reconstructor
    from ..recon.evaluate import evaluate_methods

    out = check_output_path("-o", args.output, suffixes=(".npz",))
    _check_train_args(args)
    model = _load_model(args.model)
    t0 = time.perf_counter()
    data = _dataset(args, model, DatasetConfig, ReconDataset, generate_dataset)
    t_data = time.perf_counter() - t0
    cfg = ReconTrainConfig(epochs=args.epochs, batch_size=args.batch_size, learning_rate=args.lr,
                           patience=args.patience, seed=args.seed, num_threads=args.threads,
                           augment=not args.no_augment, progress=not args.json)
    net, result, meta = train_reconstructor(data, model, cfg)
    save_reconstructor(out, net, meta)
    scores = evaluate_methods(model, data, ("dnn",), net_path=out)["methods"]["dnn"]
    info = {"output": str(out), "samples": len(data), "n_train_augmented": meta["n_train"],
            "dataset_seconds": t_data, "train": result.to_dict(), "test_dnn": scores,
            "seconds": time.perf_counter() - t0}
    if args.json:
        emit_json(info)
        return 0
    print(f"dataset: {len(data)} samples ({len(data.train)} train -> {meta['n_train']} augmented, {len(data.val)} "
          f"validation, {len(data.test)} test) in {t_data:.1f} s")
    print(f"training: {result.epochs_run} epochs, {result.seconds_per_epoch:.2f} s/epoch, best epoch "
          f"{result.best_epoch} (validation MSE {result.best_val_loss:.4g})")
    _print_scores({"dnn": scores})
    print(f"wrote {out}")
    return 0


def _min_per_count(split=(0.7, 0.2, 0.1)) -> int:
    """Smallest --per-count whose 7:2:1 split of every touch count leaves at least one sample in each part."""
    from ..learn.splits import _fractions, _part_sizes

    f = _fractions(split)
    return next(n for n in range(1, 10_000) if (_part_sizes(n, f) >= 1).all())


def _check_train_args(args) -> None:
    """recon-train's numbers and paths, before the model is read and before any simulation or training."""
    import math

    from .. import _validate as v
    from ..errors import ParameterError

    v.integer("--epochs", args.epochs, lo=1)
    v.integer("--batch-size", args.batch_size, lo=1)
    if not (math.isfinite(args.lr) and args.lr > 0):
        raise ParameterError("--lr", "a finite learning rate > 0", args.lr)
    v.integer("--patience", args.patience, lo=1)
    if args.threads is not None:
        v.integer("--threads", args.threads, lo=1)
    v.integer("--seed", args.seed, lo=0)
    v.integer("--jobs", args.jobs, lo=1)
    counts = _ints("--touch-counts", args.touch_counts)
    if not counts or any(not 1 <= c <= 12 for c in counts):
        raise ParameterError("--touch-counts", "a comma list of touch counts 1..12", args.touch_counts)
    existing = False
    if args.dataset is not None:
        # an existing dataset is read, a missing one written after the simulation
        check_output_path("--dataset", args.dataset, suffixes=(".npz",))
        existing = Path(args.dataset).exists()
    if not existing:
        lo = _min_per_count()
        v.integer("--per-count", args.per_count, lo=lo,
                  expected=f"an integer >= {lo} (the 7:2:1 split needs one sample per part and touch count)")


def _dataset(args, model, DatasetConfig, ReconDataset, generate_dataset):
    import sys

    progress = not getattr(args, "json", False)
    if args.dataset and Path(args.dataset).exists():
        if progress:
            print(f"reading the dataset {args.dataset}", file=sys.stderr, flush=True)
        data = ReconDataset.load(args.dataset)
        data.check_model(model)
        return data
    cfg = DatasetConfig(per_count=args.per_count, touch_counts=_ints("--touch-counts", args.touch_counts),
                        seed=args.seed)
    if progress:  # stderr, so that stdout keeps only the results
        print(f"building the dataset: {cfg.per_count} samples for each of {len(cfg.touch_counts)} touch counts "
              "(drawing touches, then one forward solve each)", file=sys.stderr, flush=True)
    data = generate_dataset(model, cfg, jobs=args.jobs, progress=progress)
    if args.dataset:
        data.save(parse_output(args.dataset, (".npz",), "--dataset"))
    return data


def _print_scores(methods: dict) -> None:
    print("simulated test set (not the paper's real data): mean CC / PSNR (dB) / SSIM / RE")
    print(f"  {'method':22s} {'touches':>7s} {'n':>5s} {'CC':>7s} {'PSNR':>7s} {'SSIM':>7s} {'RE':>7s}")
    for name, entry in methods.items():
        rows = [("all", entry["overall"])] + [(str(k), s) for k, s in entry["by_touches"].items()]
        for label, s in rows:
            print(f"  {name:22s} {label:>7s} {s['n']:5d} {s['cc']:7.4f} {s['psnr']:7.2f} {s['ssim']:7.4f} "
                  f"{s['re']:7.4f}")
    print("  paper (real data, best phantom): CC 0.9275, PSNR 29.03 dB, SSIM 0.9660, RE 0.3798")


def _check_eval_args(args) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """recon-eval's lists and numbers, before any file is read; returns (methods, priors)."""
    from .. import _validate as v
    from ..errors import ParameterError
    from ..recon.classical import PRIORS
    from ..recon.evaluate import METHODS

    methods = tuple(m.strip() for m in args.methods.split(",") if m.strip())
    if not methods or any(m not in METHODS for m in methods):
        raise ParameterError("--methods", "a comma list of " + ", ".join(METHODS), args.methods)
    priors = tuple(p.strip() for p in args.prior.split(",") if p.strip())
    if not priors or any(p not in PRIORS for p in priors):
        raise ParameterError("--prior", "a comma list of " + ", ".join(PRIORS), args.prior)
    v.integer("--gn-per-count", args.gn_per_count, lo=1)
    if args.test_snr_db is not None:
        v.real("--test-snr-db", args.test_snr_db, lo=SNR_DB_RANGE[0], hi=SNR_DB_RANGE[1])
    check_input_file("--dataset", args.dataset, (".npz",), "an existing dataset file (recon-train --dataset)")
    check_input_file("--net", args.net, (".npz",), "an existing network file (recon-train -o)")
    _lam(args.lam)
    return methods, priors


def run_eval(args) -> int:
    from ..recon.dataset import ReconDataset
    from ..recon.evaluate import evaluate_methods, plot_comparison

    png = check_output_path("--figure", args.figure, suffixes=(".png",))
    methods, priors = _check_eval_args(args)
    model = _load_model(args.model)
    data = ReconDataset.load(args.dataset)
    result = evaluate_methods(model, data, methods, priors, _lam(args.lam), args.net, args.gn_per_count,
                              args.test_snr_db, progress=not (args.json or args.no_progress))
    if png is not None:
        plot_comparison(result, png)
    if args.json:
        emit_json({"methods": result["methods"], "test_snr_db": args.test_snr_db,
                   "figure": None if png is None else str(png)})
        return 0
    _print_scores(result["methods"])
    for name, entry in result["methods"].items():
        lam = entry.get("lambda_relative")
        extra = "" if lam is None else f", lambda/g_max median {lam['median']:.2g} ({lam['rule']})"
        print(f"  {name}: {entry['seconds_per_frame'] * 1e3:.1f} ms/frame{extra}")
    if png is not None:
        print(f"wrote {png}")
    return 0

