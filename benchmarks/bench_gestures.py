"""Cost of simulated gesture data: conductivity-change frames versus mechanical presses.

Measures, for the design w = 4 mm, t = 3 mm at one mesh size:

1. the exported sensor model's nonlinear forward solve per frame (:class:`SensorSimulator`);
2. gesture generation: forward solves per sequence after deduplicating repeated images, and sequences per
   second with 1 and 2 worker processes;
3. one coupled mechanical press (hyperelastic indentation + current flow on the deformed gel), and what the
   paper-size gesture set (13 200 sequences x 15 frames) would cost with mechanical presses instead;
4. how a mechanical press compares with a conductivity-change disc: the disc drop whose relative voltage change
   has the press's rms, and the correlation of the two 104-channel patterns.

Timings on a shared 2-core machine are noisy; run it when the machine is quiet and say so with the numbers.

Usage::

    python benchmarks/bench_gestures.py --size 5 --sequences 120
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np

for _var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_var, "1")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", type=float, default=5.0, help="mesh size (mm) of the sensor model and mechanics")
    ap.add_argument("--sequences", type=int, default=120, help="gesture sequences to generate (multiple of 12)")
    ap.add_argument("--depth", type=float, default=2.0, help="press depth (mm) of the mechanical finger")
    args = ap.parse_args()

    from latticeopt.design import LatticeDesign
    from latticeopt.electrics import ForwardModel
    from latticeopt.gestures import generate_gestures
    from latticeopt.mechanics import IndentationSolver
    from latticeopt.mesh import MeshSettings, mesh_design
    from latticeopt.recon.dataset import render_touches
    from latticeopt.sensor_model import SensorSimulator, export_sensor_model, load_sensor_model
    from latticeopt.touches import Touch

    design = LatticeDesign(width_mm=4, thickness_mm=3)
    settings = MeshSettings(size_mm=args.size)
    tmp = Path(tempfile.mkdtemp(prefix="bench_gestures_"))
    t = time.perf_counter()
    model = load_sensor_model(export_sensor_model(design, tmp / "sensor.npz", settings, cache_dir=tmp))
    t_export = time.perf_counter() - t
    sim = SensorSimulator(model)
    s0, ind = model.sigma0_S_per_m, model.independent
    print(f"design w=4 t=3, mesh {args.size:g} mm: hydrogel {model.mesh.n_nodes} nodes, {model.mesh.n_tets} tets; "
          f"export {t_export:.1f} s")

    # 1. forward solve per frame
    rng = np.random.default_rng(0)
    imgs = np.stack([render_touches([[*rng.uniform(15, 85, 2), 15.0, 0.5]], s0, model.n_pixels, model.extent_mm)
                     for _ in range(40)])
    t = time.perf_counter()
    sim.voltages(imgs)
    per_frame = (time.perf_counter() - t) / len(imgs)
    print(f"1. forward solve per frame: {1e3 * per_frame:.1f} ms")

    # 2. generation
    per_class = max(1, args.sequences // 12)
    block = max(1, 12 * per_class // 8)  # eight tasks, so two workers share the load
    rows = []
    for jobs in (1, 2):
        t = time.perf_counter()
        d = generate_gestures(model, per_class, seed=0, jobs=jobs, block=block,
                              simulator=sim if jobs == 1 else None)
        sec = time.perf_counter() - t
        rows.append((jobs, len(d), d.info["forward_solves"], sec))
    print(f"2. generation (12 classes x {per_class} sequences x 15 frames, blocks of {block} sequences; "
          "two workers include process start-up)")
    print("   jobs  sequences  forward solves  solves/sequence  seconds  sequences/s")
    for jobs, n, solves, sec in rows:
        print(f"   {jobs:4d}  {n:9d}  {solves:14d}  {solves / n:15.2f}  {sec:7.1f}  {n / sec:11.2f}")
    solves_per_seq = rows[0][2] / rows[0][1]
    paper_seq = 12 * 1100
    best = max(r[1] / r[3] for r in rows)
    print(f"   paper size ({paper_seq} sequences): about {paper_seq / best / 60:.0f} min at the best rate above")

    # 3. one mechanical press, coupled
    mesh = mesh_design(design, settings, cache_dir=tmp)
    t = time.perf_counter()
    mech = IndentationSolver(mesh)
    t_setup = time.perf_counter() - t
    fwd = ForwardModel(mesh, s0, model.contact_impedance_ohm_m2, current_A=model.current_A)
    t = time.perf_counter()
    res = mech.solve([Touch(50.0, 50.0, 7.5, args.depth)])
    pressed = fwd.with_nodes(res.deformed_mesh.nodes_mm)
    t_press = time.perf_counter() - t
    y_mech = ((pressed.voltages - fwd.voltages) / fwd.voltages)[ind]
    frames = paper_seq * 15
    print(f"3. mechanical press (r 7.5 mm, depth {args.depth:g} mm, full stack {mesh.n_nodes} nodes): "
          f"{t_press:.1f} s ({res.newton_steps} Newton steps; solver setup {t_setup:.1f} s once)")
    print(f"   paper-size set with mechanical presses: {frames} frames; even at the dedup rate "
          f"{solves_per_seq:.1f} solves/sequence that is {paper_seq * solves_per_seq:.0f} presses = "
          f"{paper_seq * solves_per_seq * t_press / 3600:.0f} h on one core, vs "
          f"{paper_seq * solves_per_seq * per_frame / 3600:.2f} h for conductivity-change frames")

    # 4. equivalent conductivity drop of a 15 mm disc at the same place
    drops = np.linspace(0.05, 0.95, 19)
    V = sim.voltages(np.stack([render_touches([[50.0, 50.0, 15.0, 1 - dr]], s0, model.n_pixels, model.extent_mm)
                               for dr in drops]))
    Y = ((V - model.v_ref) / model.v_ref)[:, ind]
    rms = np.sqrt(np.mean(Y ** 2, axis=1))
    target = np.sqrt(np.mean(y_mech ** 2))
    k = int(np.argmin(np.abs(rms - target)))
    corr = np.corrcoef(Y[k], y_mech)[0, 1]
    print(f"4. press rms relative change {target:.4f} (mean {y_mech.mean():+.4f}: voltages rise, the gel conducts "
          f"less); a 15 mm disc with drop {drops[k]:.2f} has rms {rms[k]:.4f}; pattern correlation {corr:.3f}")


if __name__ == "__main__":
    main()
