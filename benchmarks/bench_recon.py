"""Reconstruction pipeline: dataset speed against pyEIT, training time per epoch, simulated test-set metrics.

Usage::

    python benchmarks/bench_recon.py [--size 2.0] [--per-count 100] [--epochs 20] [--jobs 2] [--out out/bench_recon]

1. **Dataset speed.** Samples per second of :func:`latticeopt.recon.generate_dataset`'s forward path (render a
   phantom, map pixels to tets, nonlinear CEM solve of all 16 drives) in one process and with ``--jobs``
   processes, against pyEIT 1.2.4's ``EITForward.solve_eit`` on the *same* hydrogel tets (point electrodes, its
   only mode) for the same element conductivities. Two levers are measured and reported, not used: a Woodbury
   low-rank update from a precomputed dense inverse (exact, but it pays only for small touches), and PARDISO
   without iterative refinement (``latticeopt.linalg`` leaves MKL's default of two steps on).
2. **Training time per epoch** of the MLP-CNN reconstructor at this size, extrapolated linearly to the paper's
   280 000 augmented samples (the loop costs the same per batch).
3. **Metrics** (CC, PSNR, SSIM, RE; mean and best over the test part) per method, on *simulated* test sets
   (noise-free and 50 dB), next to the paper's *real-data* best-phantom figures. Plainly: these are not
   comparable measurements; the table only puts them side by side.

Threads: BLAS/MKL limited to 1 per process before numpy loads (torch uses ``--torch-threads``). The machine is
shared while this runs: load average is printed with the timings.
"""

from __future__ import annotations

import argparse
import os
import time

for _var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ[_var] = "1"

import numpy as np  # noqa: E402

PAPER = {"cc": 0.9275, "psnr": 29.03, "ssim": 0.9660, "re": 0.3798}


def _args():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--size", type=float, default=2.0, help="mesh size of the exported model (mm); default 2")
    p.add_argument("--per-count", type=int, default=100, help="samples per touch count; default 100")
    p.add_argument("--epochs", type=int, default=20, help="training epochs; default 20")
    p.add_argument("--jobs", type=int, default=2, help="processes for dataset generation; default 2")
    p.add_argument("--speed-samples", type=int, default=60, help="samples timed per speed row; default 60")
    p.add_argument("--gn-per-count", type=int, default=4, help="test frames per touch count for GN; default 4")
    p.add_argument("--torch-threads", type=int, default=2, help="torch threads for training; default 2")
    p.add_argument("--skip-woodbury", action="store_true", help="skip the dense-inverse Woodbury measurement")
    p.add_argument("--out", default="out/bench_recon", help="folder for the model, dataset, network and figure")
    return p.parse_args()


def _load() -> str:
    return "load average {:.1f} {:.1f} {:.1f}".format(*os.getloadavg())


def _phantoms(model, k: int, seed: int = 11):
    from latticeopt.recon.dataset import DatasetConfig, render_touches, sample_touches

    cfg = DatasetConfig()
    imgs, counts = [], []
    for i in range(k):
        c = 1 + i % 5
        rng = np.random.default_rng([seed, i])
        imgs.append(render_touches(sample_touches(rng, c, cfg, model.design.size_mm), model.sigma0_S_per_m))
        counts.append(c)
    return np.array(imgs), np.array(counts)


def _pyeit_rate(sim, imgs) -> float:
    from pyeit.eit import protocol as pyeit_protocol
    from pyeit.eit.fem import EITForward
    from pyeit.mesh import PyEITMesh

    from latticeopt.electrics import ForwardModel

    point = ForwardModel(sim.model.mesh, sim.model.sigma_S_per_m, electrode_mode="point")
    el_pos = point.point_nodes
    ref = int(np.setdiff1d(np.arange(point.mesh.n_nodes), el_pos)[0])
    pm = PyEITMesh(node=point.mesh.nodes_mm * 1e-3, element=point.mesh.tets[:, [0, 2, 1, 3]],
                   perm=point.sigma, el_pos=el_pos, ref_node=ref)
    fwd = EITForward(pm, pyeit_protocol.create(16, 1, 1, "std"))
    t = time.perf_counter()
    for img in imgs:
        fwd.solve_eit(perm=sim.element_conductivity(img)[0])
    return len(imgs) / (time.perf_counter() - t)


def _woodbury(sim, imgs, counts) -> dict:
    """Exact low-rank update ``T = T0 - X_S^T (I + D Z)^-1 D X_S`` from a precomputed dense inverse."""
    f = sim.forward
    t0 = time.perf_counter()
    inv = np.asarray(f.solve(np.eye(f.n_dof)))
    setup = time.perf_counter() - t0
    uk = f._unit_k.reshape(-1, 4, 4)
    ed, p = f._topology.electrode_dofs, f.protocol
    out = {"setup_s": setup, "inverse_GB": inv.nbytes / 1e9}
    for c in np.unique(counts):
        tw = tr = 0.0
        sizes, errs = [], []
        for img in imgs[counts == c]:
            sig = sim.element_conductivity(img)[0]
            t = time.perf_counter()
            V_ref = f.with_conductivity(sig).voltages
            tr += time.perf_counter() - t
            t = time.perf_counter()
            d = sig - f.sigma
            k = np.flatnonzero(np.abs(d) > 1e-12 * np.abs(f.sigma))  # pixel-map rounding is not a change
            S, loc = np.unique(f.mesh.tets[k], return_inverse=True)
            loc = loc.reshape(-1, 4)
            D = np.zeros((len(S), len(S)))
            np.add.at(D, (loc[:, :, None], loc[:, None, :]), uk[k] * d[k, None, None])
            Y = np.linalg.solve(np.eye(len(S)) + D @ inv[np.ix_(S, S)], D @ f._basis[S])
            T = f._basis[ed] - inv[np.ix_(ed, S)] @ Y
            U = f.current_A * p.drive_currents @ T.T
            V = np.einsum("re,re->r", p.measure, U[p.row_drive])
            tw += time.perf_counter() - t
            sizes.append(len(S))
            errs.append(np.max(np.abs(V - V_ref)) / np.max(np.abs(V_ref)))
        n = int(np.sum(counts == c))
        out[int(c)] = {"refactor_ms": 1e3 * tr / n, "woodbury_ms": 1e3 * tw / n,
                       "touched_nodes": float(np.median(sizes)), "max_rel_diff": float(max(errs))}
    return out


def speed(model, args) -> dict:
    from latticeopt.sensor_model import SensorSimulator

    sim = SensorSimulator(model)
    imgs, counts = _phantoms(model, args.speed_samples)
    sim.voltages(imgs[:2])  # warm-up
    t = time.perf_counter()
    sim.voltages(imgs)
    serial = len(imgs) / (time.perf_counter() - t)
    many, _ = _phantoms(model, 4 * args.speed_samples, seed=12)
    t = time.perf_counter()
    sim.voltages(many, jobs=args.jobs, chunk=args.speed_samples)
    parallel = len(many) / (time.perf_counter() - t)
    pyeit = _pyeit_rate(sim, imgs[: max(10, args.speed_samples // 4)])
    solver = sim.forward._shared.solver
    no_refine = None
    if solver.backend == "pardiso":  # what-if: MKL PARDISO without iterative refinement (iparm(8) = 0)
        solver._ps.set_iparm(8, 0)
        t = time.perf_counter()
        V0 = sim.voltages(imgs)
        no_refine = len(imgs) / (time.perf_counter() - t)
        solver._ps.set_iparm(8, 2)
        no_refine_diff = float(np.max(np.abs(V0 - sim.voltages(imgs))) / np.max(np.abs(V0)))
    res = {"serial": serial, "parallel": parallel, "pyeit": pyeit, "no_refinement": no_refine,
           "gel_nodes": model.mesh.n_nodes, "gel_tets": model.mesh.n_tets, "load": _load()}
    if no_refine is not None:
        res["no_refinement_max_rel_diff"] = no_refine_diff
    if not args.skip_woodbury:
        res["woodbury"] = _woodbury(sim, imgs, counts)
    return res


def main() -> int:
    args = _args()
    os.makedirs(args.out, exist_ok=True)
    from latticeopt.design import LatticeDesign
    from latticeopt.mesh import MeshSettings
    from latticeopt.recon.dataset import DatasetConfig, generate_dataset
    from latticeopt.recon.dnn import ReconTrainConfig, save_reconstructor, train_reconstructor
    from latticeopt.recon.evaluate import evaluate_methods, plot_comparison
    from latticeopt.sensor_model import build_sensor_model, save_sensor_model

    t = time.perf_counter()
    model = build_sensor_model(LatticeDesign(width_mm=4, thickness_mm=3), MeshSettings(size_mm=args.size))
    save_sensor_model(model, os.path.join(args.out, "sensor.npz"))
    print(f"export (w = 4, t = 3, {args.size:g} mm mesh): {model.mesh.n_nodes} gel nodes, {model.mesh.n_tets} gel "
          f"tets, {time.perf_counter() - t:.1f} s ({_load()})")

    s = speed(model, args)
    print("\n## Dataset speed (samples/s; one sample = phantom, pixel map, nonlinear 16-drive solve)")
    print(f"  latticeopt CEM, 1 process          {s['serial']:8.2f}")
    print(f"  latticeopt CEM, {args.jobs} processes        {s['parallel']:8.2f}   (x{s['parallel'] / s['serial']:.2f})")
    print(f"  pyEIT 1.2.4 point electrodes, same tets {s['pyeit']:6.2f}   (ours / pyEIT = "
          f"{s['serial'] / s['pyeit']:.1f} on one process)")
    if s["no_refinement"]:
        print(f"  what-if: PARDISO without iterative refinement {s['no_refinement']:.2f} (x"
              f"{s['no_refinement'] / s['serial']:.2f}; max relative voltage change "
              f"{s['no_refinement_max_rel_diff']:.1e}) - not used, see report")
    if "woodbury" in s:
        w = s["woodbury"]
        print(f"  what-if: Woodbury update from a dense inverse (setup {w['setup_s']:.1f} s, {w['inverse_GB']:.2f} GB "
              "per process):")
        for c in range(1, 6):
            if c in w:
                r = w[c]
                print(f"    {c} touch(es): refactor {r['refactor_ms']:6.1f} ms, Woodbury {r['woodbury_ms']:7.1f} ms "
                      f"(touched nodes {r['touched_nodes']:.0f}, max rel. diff {r['max_rel_diff']:.0e})")
    print(f"  ({s['load']})")

    t = time.perf_counter()
    data = generate_dataset(model, DatasetConfig(per_count=args.per_count), jobs=args.jobs)
    t_data = time.perf_counter() - t
    data.save(os.path.join(args.out, "dataset.npz"))
    print(f"\n## Dataset: {len(data)} samples ({args.per_count} per touch count 1-5) in {t_data:.1f} s "
          f"({len(data) / t_data:.1f} samples/s, {args.jobs} processes)")

    cfg = ReconTrainConfig(epochs=args.epochs, patience=None, num_threads=args.torch_threads)
    net, result, meta = train_reconstructor(data, model, cfg)
    net_path = save_reconstructor(os.path.join(args.out, "net.npz"), net, meta)
    per_epoch = float(np.median(result.epoch_seconds))
    n_train = meta["n_train"]
    print(f"\n## Training: {n_train} augmented samples, {result.epochs_run} epochs, median {per_epoch:.1f} s/epoch "
          f"({args.torch_threads} torch threads), best epoch {result.best_epoch}; paper size (280 000) "
          f"extrapolated {per_epoch * 280_000 / n_train / 60:.1f} min/epoch ({_load()})")

    rows = {}
    priors = ("identity", "noser", "laplacian")
    for snr in (None, 50.0):
        label = "noise-free" if snr is None else f"{snr:g} dB"
        runs = [(("background", "tikhonov", "dnn"), priors, "gcv"), (("gn",), ("laplacian",), "gcv"),
                (("tikhonov",), priors, "validation"), (("gn",), ("laplacian",), "validation")]
        for methods, prs, rule in runs:
            r = evaluate_methods(model, data, methods, prs, rule, net_path, args.gn_per_count, snr)
            for name, entry in r["methods"].items():
                key = name if name in ("dnn", "background") else f"{name} [{rule}]"
                rows[(label, key)] = entry
            if methods[0] == "background":
                plot_comparison(r, os.path.join(args.out, f"compare_{'clean' if snr is None else f'{snr:g}dB'}.png"))
    print("\n## Simulated test set (SIMULATION, not comparable to the paper's real-data figures)")
    print(f"  {'test':10s} {'method':30s} {'n':>4s} {'CC':>7s} {'PSNR':>6s} {'SSIM':>6s} {'RE':>7s}   "
          f"{'best CC':>7s} {'PSNR':>6s} {'SSIM':>6s} {'RE':>6s}  ms/frame")
    for (label, key), e in rows.items():
        o = e["overall"]
        print(f"  {label:10s} {key:30s} {e['n']:4d} {o['cc']:7.4f} {o['psnr']:6.2f} {o['ssim']:6.4f} {o['re']:7.4f}"
              f"   {o['best_cc']:7.4f} {o['best_psnr']:6.2f} {o['best_ssim']:6.4f} {o['best_re']:6.3f}  "
              f"{e['seconds_per_frame'] * 1e3:8.1f}")
    print(f"  {'paper':10s} {'DNN, real data, best phantom':30s} {'':4s} {PAPER['cc']:7.4f} {PAPER['psnr']:6.2f} "
          f"{PAPER['ssim']:6.4f} {PAPER['re']:7.4f}")
    print("\n  DNN per touch count (noise-free): " + ", ".join(
        f"{k}: CC {v['cc']:.3f} SSIM {v['ssim']:.3f}" for k, v in rows[("noise-free", "dnn")]["by_touches"].items()))
    print(f"\nfigures and files in {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
