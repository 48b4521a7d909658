"""``latticeopt recon-train`` and ``recon-eval``: simulate the paper's touch dataset, train the learned
reconstructor, and score every reconstruction method on the test part."""

from __future__ import annotations

import time
from pathlib import Path

from ._common import check_input_file, check_output_path, emit_json, parse_output
from .recon import SNR_DB_RANGE, _add_method_args, _ints, _lam, _load_model


def register(sub) -> None:
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
    g.add_argument("--presses", type=int, default=0,
                   help="add this many random single presses, simulated by the coupled model of the exported "
                        "design (seconds to minutes each), to the training part, each with its footprint disc as "
                        "target; stored in --dataset, so a re-run reads them; default 0 (discs only, even if the "
                        "dataset holds presses)")
    g.add_argument("--press-seed", type=int, default=1,
                   help="seed of the training presses; default 1 (recon-eval's presses default to seed 0)")
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
    e.add_argument("--presses", type=int, default=0,
                   help="also reconstruct this many random single presses simulated by the coupled model of the "
                        "exported design (minutes each on the default mesh) and report the gap to discs of the "
                        "same footprint; default 0")
    e.add_argument("--press-seed", type=int, default=0, help="seed of the presses; default 0")
    e.add_argument("--figure", default=None, help="PNG of ground truth beside each method")
    e.add_argument("--json", action="store_true", help="print one JSON object")
    e.add_argument("--no-progress", action="store_true", help="no progress bars (--json implies it)")
    e.set_defaults(func=run_eval)


def _add_dataset_args(p) -> None:
    g = p.add_argument_group("dataset")
    g.add_argument("--per-count", type=int, default=10_000, help="samples per touch count; default 10000 (paper)")
    g.add_argument("--touch-counts", default="1,2,3,4,5", help="comma list; default 1,2,3,4,5")
    g.add_argument("--seed", type=int, default=0, help="seed of touches, split and noise; default 0")
    g.add_argument("--jobs", type=int, default=1, help="worker processes for the forward solves; default 1")
    g.add_argument("--dataset", default=None, help="dataset .npz: read if it exists, else written after simulation")


def run_train(args) -> int:
    from .._extras import require_extra

    # before anything else: without torch the dataset (up to an hour of solves) would be simulated for nothing
    require_extra("learn", "recon-train trains the network and scores its images with it")
    from ..recon.dataset import DatasetConfig, ReconDataset, generate_dataset
    from ..recon.dnn import ReconTrainConfig, save_reconstructor, train_reconstructor
    from ..recon.evaluate import evaluate_methods

    out = check_output_path("-o", args.output, suffixes=(".npz",))
    _check_train_args(args)
    model = _load_model(args.model)
    t0 = time.perf_counter()
    data = _dataset(args, model, DatasetConfig, ReconDataset, generate_dataset)
    data = _mix_presses(args, model, data)
    t_data = time.perf_counter() - t0
    cfg = ReconTrainConfig(epochs=args.epochs, batch_size=args.batch_size, learning_rate=args.lr,
                           patience=args.patience, seed=args.seed, num_threads=args.threads,
                           augment=not args.no_augment, progress=not args.json)
    net, result, meta = train_reconstructor(data, model, cfg)
    save_reconstructor(out, net, meta)
    scores = evaluate_methods(model, data, ("dnn",), net_path=out)["methods"]["dnn"]
    info = {"output": str(out), "samples": len(data), "train_presses": meta["train_presses"],
            "n_train_augmented": meta["n_train"],
            "dataset_seconds": t_data, "train": result.to_dict(), "test_dnn": scores,
            "seconds": time.perf_counter() - t0}
    if args.json:
        emit_json(info)
        return 0
    presses = meta["train_presses"]
    mixed = f" + {presses['solved']} coupled presses" if presses else ""
    print(f"dataset: {len(data)} samples ({len(data.train)} train{mixed} -> {meta['n_train']} augmented, "
          f"{len(data.val)} validation, {len(data.test)} test) in {t_data:.1f} s")
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
    v.integer("--presses", args.presses, lo=0, hi=10_000)
    v.integer("--press-seed", args.press_seed, lo=0)
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


def _mix_presses(args, model, data):
    """``data`` with ``--presses`` coupled presses in its training part; new ones are written to ``--dataset``."""
    import sys

    from ..recon.presses import with_presses

    progress = not args.json
    if args.presses and progress:
        print(f"{args.presses} coupled presses (seed {args.press_seed}) for the training part: read from the "
              "dataset if it holds them, else one coupled solve each", file=sys.stderr, flush=True)
    mixed = with_presses(data, model, args.presses, args.press_seed, progress=progress)
    if args.presses and mixed is not data and args.dataset:
        mixed.save(parse_output(args.dataset, (".npz",), "--dataset"))
    return mixed


def _print_scores(methods: dict) -> None:
    print("simulated test set (not the paper's real data): mean CC / PSNR (dB) / SSIM / RE")
    print(f"  {'method':22s} {'touches':>7s} {'n':>5s} {'CC':>7s} {'PSNR':>7s} {'SSIM':>7s} {'RE':>7s}")
    for name, entry in methods.items():
        rows = [("all", entry["overall"])] + [(str(k), s) for k, s in entry["by_touches"].items()]
        for label, s in rows:
            print(f"  {name:22s} {label:>7s} {s['n']:5d} {s['cc']:7.4f} {s['psnr']:7.2f} {s['ssim']:7.4f} "
                  f"{s['re']:7.4f}")
    print("  paper (real data, best phantom): CC 0.9275, PSNR 29.03 dB, SSIM 0.9660, RE 0.3798")
    print("GREIT figures, mean over the one-touch frames (docs/sensor_model.md): amplitude (mm^2), position "
          "error / offset (mm), resolution, shape deformation, ringing")
    for name, entry in methods.items():
        g = entry.get("greit", {})
        if "resolution" not in g:
            print(f"  {name:22s} n {g.get('n', 0):4d}  (no one-touch frame with an image)")
            continue
        print(f"  {name:22s} n {g['n']:4d}  {g['amplitude']:8.3g} {g['position_error_mm']:7.2f} "
              f"{g['position_offset_mm']:6.2f} {g['resolution']:7.3f} {g['shape_deformation']:7.3f} "
              f"{g['ringing']:7.3f}")


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


def _check_press_seed(args, model) -> None:
    """Refuse to score the network on presses of the seed it was trained on (it would have seen them)."""
    from ..errors import ParameterError
    from ..recon.dnn import DNNReconstructor

    trained = DNNReconstructor(args.net, model).metadata.get("train_presses")
    if trained and trained.get("seed") == args.press_seed:
        raise ParameterError("--press-seed", f"a seed other than {args.press_seed}, the seed of the presses the "
                             "network was trained on", args.press_seed)


def run_eval(args) -> int:
    from .. import _validate as v
    from .._extras import require_extra
    from ..recon.dataset import ReconDataset
    from ..recon.evaluate import evaluate_methods, plot_comparison

    png = check_output_path("--figure", args.figure, suffixes=(".png",))
    methods, priors = _check_eval_args(args)
    require_extra("learn", "recon-eval scores PSNR and SSIM with it", modules=("skimage",))
    if "dnn" in methods:
        require_extra("learn", "method dnn runs the network with it", name="--methods dnn", modules=("torch",))
    v.integer("--presses", args.presses, lo=0, hi=10_000)
    v.integer("--press-seed", args.press_seed, lo=0)
    model = _load_model(args.model)
    data = ReconDataset.load(args.dataset)
    presses = press_y = None
    if args.presses and "dnn" in methods and args.net is not None:
        _check_press_seed(args, model)
    if args.presses:
        from ..recon.presses import press_frames, random_presses

        presses = random_presses(args.presses, model.design.size_mm, args.press_seed)
        press_y = press_frames(model, presses, progress=not (args.json or args.no_progress))
    result = evaluate_methods(model, data, methods, priors, _lam(args.lam), args.net, args.gn_per_count,
                              args.test_snr_db, progress=not (args.json or args.no_progress), presses=presses,
                              press_y=press_y)
    if png is not None:
        plot_comparison(result, png)
    if args.json:
        emit_json({"methods": result["methods"], "test_snr_db": args.test_snr_db,
                   "presses": result.get("presses"), "figure": None if png is None else str(png)})
        return 0
    _print_scores(result["methods"])
    if "presses" in result:
        print("coupled presses against discs of the same footprint (0.5 sigma0): CC between the two images; "
              "position offset (mm) and resolution of each")
        for name, g in result["presses"].items():
            pr, dc = g["press"], g["disc"]
            if not pr:
                print(f"  {name:22s} n {g['n']:4d}  (blank images)")
                continue
            print(f"  {name:22s} n {g['n']:4d}  CC {g['cc']:6.3f}  offset {pr['position_offset_mm']:6.2f} / "
                  f"{dc['position_offset_mm']:6.2f}  resolution {pr['resolution']:6.3f} / {dc['resolution']:6.3f}")
    for name, entry in result["methods"].items():
        lam = entry.get("lambda_relative")
        extra = "" if lam is None else f", lambda/g_max median {lam['median']:.2g} ({lam['rule']})"
        print(f"  {name}: {entry['seconds_per_frame'] * 1e3:.1f} ms/frame{extra}")
    if png is not None:
        print(f"wrote {png}")
    return 0
