"""Training time per epoch of the learning models at the paper's data sizes on this CPU.

Paper sizes: the reconstruction network trains on 280,000 augmented samples with 10,000 for validation (§V);
each gesture classifier on 9,600 sequences with 2,400 for validation (§VII, 12 x 1000 split 8:2). Batch 256,
Adam. The data are random arrays of the right shapes: the time per epoch does not depend on the values.

The gesture models run whole epochs through :func:`latticeopt.learn.training.train_model` (two epochs; the
second is reported, the first includes warm-up). A full reconstruction epoch takes minutes, so by default
its training and validation throughputs are measured on ``--recon-samples`` samples and the paper-size epoch
is extrapolated linearly (the loop is a fixed cost per batch); ``--full-recon`` runs a real one.

Usage::

    python benchmarks/bench_learn.py                # 1 and 2 threads
    python benchmarks/bench_learn.py --threads 1 --full-recon
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np


def _time_gesture(cls, n_train: int, n_val: int, threads: int) -> dict:
    from latticeopt.learn.training import TrainConfig, seed_everything, train_model

    rng = np.random.default_rng(0)
    x = rng.standard_normal((n_train + n_val, 15, 104)).astype(np.float32)
    y = rng.integers(0, 12, n_train + n_val)
    seed_everything(0)
    model = cls()
    res = train_model(model, (x[:n_train], y[:n_train]), (x[n_train:], y[n_train:]),
                      TrainConfig(epochs=2, num_threads=threads, progress=False))
    return {"epoch_s": res.epoch_seconds[-1], "measured": "full epoch",
            "params": sum(p.numel() for p in model.parameters())}


def _time_recon(n_meas: int, n_train: int, n_val: int, n_sample: int, threads: int, full: bool) -> dict:
    import torch

    from latticeopt.learn.recon_net import ReconNet
    from latticeopt.learn.training import TrainConfig, predict, seed_everything, train_model

    rng = np.random.default_rng(0)
    n_tr = n_train if full else n_sample
    n_va = n_val if full else max(n_sample // 4, 256)
    x = rng.standard_normal((n_tr + n_va, n_meas)).astype(np.float32)
    img = rng.standard_normal((n_tr + n_va, 48, 48)).astype(np.float32)
    seed_everything(0)
    model = ReconNet(n_meas)
    params = sum(p.numel() for p in model.parameters())
    cfg = TrainConfig(loss="mse", epochs=1, num_threads=threads, progress=False)
    # Warm-up (allocator, kernels) on one batch, then the measured epoch.
    train_model(model, (x[:256], img[:256]), (x[:256], img[:256]), cfg)
    res = train_model(model, (x[:n_tr], img[:n_tr]), (x[n_tr:], img[n_tr:]), cfg)
    if full:
        return {"epoch_s": res.epoch_seconds[-1], "measured": "full epoch", "params": params}
    old = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        t0 = time.perf_counter()
        predict(model, x[n_tr:], batch_size=256)
        val_s_per_sample = (time.perf_counter() - t0) / n_va
    finally:
        torch.set_num_threads(old)
    # The epoch time includes its own validation pass; remove it to get the training part.
    train_s_per_sample = max(res.epoch_seconds[-1] - val_s_per_sample * n_va, 0.0) / n_tr
    epoch = train_s_per_sample * n_train + val_s_per_sample * n_val
    return {"epoch_s": epoch, "measured": f"extrapolated from {n_tr} + {n_va} samples", "params": params,
            "train_per_s": 1 / train_s_per_sample}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2], help="torch intra-op thread counts")
    parser.add_argument("--recon-samples", type=int, default=4096,
                        help="training samples timed for the reconstruction extrapolation")
    parser.add_argument("--full-recon", action="store_true", help="run a real 280,000-sample epoch")
    args = parser.parse_args()

    import torch

    from latticeopt.learn.classifiers import GestureCNN, GestureLSTM

    print(f"torch {torch.__version__}, {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, "
          f"load average before {os.getloadavg()[0]:.2f}")
    header = f"{'model':<22} {'params':>9} {'threads':>7} {'epoch (s)':>10}  {'train samples/s':>15}  how"
    print(header)
    print("-" * len(header))
    rows = []
    for threads in args.threads:
        for n_meas in (208, 104):
            r = _time_recon(n_meas, 280_000, 10_000, args.recon_samples, threads, args.full_recon)
            rows.append((f"ReconNet({n_meas})", threads, r))
        for cls in (GestureCNN, GestureLSTM):
            rows.append((cls.__name__, threads, _time_gesture(cls, 9_600, 2_400, threads)))
        for name, th, r in rows[-4:]:
            rate = f"{r['train_per_s']:.0f}" if "train_per_s" in r else "-"
            print(f"{name:<22} {r['params']:>9} {th:>7} {r['epoch_s']:>10.1f}  {rate:>15}  {r['measured']}")
    print(f"load average after {os.getloadavg()[0]:.2f} (above ~0 means other jobs shared the CPU)")
    if len(args.threads) > 1:
        base = {name: r["epoch_s"] for name, th, r in rows if th == args.threads[0]}
        for name, th, r in rows:
            if th != args.threads[0]:
                print(f"speed-up {name} {args.threads[0]} -> {th} threads: {base[name] / r['epoch_s']:.2f}x")
    print("Paper-size epochs: recon 280,000 train + 10,000 val; gestures 9,600 train + 2,400 val; batch 256.")


if __name__ == "__main__":
    main()
