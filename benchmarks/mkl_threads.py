"""Threads for presses solved in-process (``jobs = 1``, the API, ``indent``): what each library gets, measured.

    python benchmarks/mkl_threads.py                                  # 2 mm and 1.4 mm meshes, three presses
    python benchmarks/mkl_threads.py --levels 2:2:2:0 1.4:3:3:0 1:4:4:0 --phantoms 1:13 2:0 --repeats 3
    python benchmarks/mkl_threads.py --settings PYTHONPATH=/path/to/an/older/checkout "" MKL_NUM_THREADS=1

Worker processes start with one thread for OpenMP, MKL and OpenBLAS; a press solved in the calling process runs
MKL (PARDISO) on the threads it starts with and OpenBLAS on one (``latticeopt.linalg.single_threaded_blas``).
Each ``--settings`` item is a set of environment variables (``NAME=VALUE,...``; ``""``: none; the first is the
baseline of the ratio; ``PYTHONPATH=`` an older checkout compares code versions). For each
mesh level (``SIZE:CHANNEL_CELLS:LAYER_CELLS[:ELECTRODE_EDGES]``) and paper-map phantom (``K:I``,
``studies/paper_fig4.toml``) the same press is solved ``--repeats`` times per setting, each run a fresh process
(PARDISO keeps the thread count of its symbolic analysis: changing it later, with ``MKL_Set_Num_Threads``,
has no effect or crashes), the settings in turn, the order reversed every other repeat. Prints a Markdown table:
press seconds (median, range; the model's set-up is not timed), CPU seconds per second (how many cores the
process kept busy), the threads MKL reports, Newton iterations and tangent factorizations beside them, whether
repeated runs gave the same V_rel bit for bit, and the ratio baseline / setting of the medians. Run it on an
otherwise idle machine: threaded runs need the second core.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

from _common import check_paper_keys, mesh_level, pair, paper_phantoms

from latticeopt import LatticeDesign
from latticeopt.cli._physics import add_physics_arg, physics_settings
from latticeopt.errors import ParameterError
from latticeopt.linalg import pardiso_available

#: no variable; MKL on one; everything on one, as in a worker process
SETTINGS = ("", "MKL_NUM_THREADS=1", "OMP_NUM_THREADS=1,MKL_NUM_THREADS=1,OPENBLAS_NUM_THREADS=1,NUMBA_NUM_THREADS=1")


def _setting(text: str) -> dict[str, str]:
    env = dict(item.split("=", 1) for item in text.split(",") if "=" in item)
    if len(env) != len([item for item in text.split(",") if item]) or any(not k for k in env):
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE,... or \"\", got {text!r}")
    return env


def _child(args, design, physics, phantoms) -> None:
    """Solve every press once on every level, printing one JSON line each (runs in its own process)."""
    from latticeopt.coupled import CoupledModel
    from latticeopt.execution import blas_threads

    for mesh in args.levels:
        model = CoupledModel(design, mesh, physics)
        mkl = [n for name, n in blas_threads().items() if "mkl_rt" in name]
        for key in args.phantoms:
            t0, c0 = time.perf_counter(), time.process_time()
            res = model.simulate(list(phantoms[key].touches))
            seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
            ind = res.indentation
            print(json.dumps({"level": f"{mesh.size_mm:g}:{mesh.channel_cells}:{mesh.layer_cells}:"
                                       f"{int(mesh.electrode_edges)}", "nodes": len(model.mesh.nodes_mm),
                              "phantom": f"{key[0]}:{key[1]}", "mkl_threads": mkl[0] if mkl else None,
                              "seconds": seconds, "busy": cpu / seconds, "newton": ind.newton_steps,
                              "factorizations": ind.solver["n_factorizations"], "v_rel": float(res.v_rel).hex()}),
                  flush=True)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--levels", nargs="+", type=mesh_level, default=[mesh_level("2:2:2:0"), mesh_level("1.4:3:3:0")],
                    help="mesh levels SIZE:CHANNEL_CELLS:LAYER_CELLS[:ELECTRODE_EDGES] (default 2:2:2:0 1.4:3:3:0)")
    ap.add_argument("--phantoms", nargs="+", type=pair("K:I", int, "1:13"), default=[(1, 13), (2, 0)],
                    help="paper-map phantoms K:I (default 1:13, the deep press, and 2:0)")
    ap.add_argument("--design", type=pair("W:T", float, "2:1"), default=(2.0, 1.0),
                    help="W:T (mm), pitch 12.5 mm (default 2:1)")
    ap.add_argument("--settings", nargs="+", type=_setting, default=[_setting(x) for x in SETTINGS],
                    help="environments NAME=VALUE,... to compare; \"\" for none (default: %(default)s)")
    ap.add_argument("--repeats", type=int, default=2, help="presses per setting (default 2)")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    add_physics_arg(ap)
    args = ap.parse_args(argv)
    if args.repeats < 1:
        ap.error(f"--repeats: expected an integer >= 1, got {args.repeats}")
    if len(args.settings) < 2:
        ap.error(f"--settings: expected two or more environments, got {len(args.settings)}")
    try:
        physics = physics_settings(args)
    except ParameterError as exc:
        ap.error(str(exc))
    try:
        design = LatticeDesign(width_mm=args.design[0], thickness_mm=args.design[1], pitch_mm=12.5)
    except ParameterError as exc:
        ap.error(f"--design: {exc}")
    if not pardiso_available():
        ap.error("pypardiso is not installed: nothing runs on MKL threads")
    phantoms = paper_phantoms()
    check_paper_keys(ap, args.phantoms, phantoms)
    if args.child:
        _child(args, design, physics, phantoms)
        return
    child = [sys.executable, __file__, "--child", *(argv if argv is not None else sys.argv[1:])]
    runs: dict[tuple, list] = {}
    names = [",".join(f"{k}={v}" for k, v in env.items()) or "no variable" for env in args.settings]
    for r in range(args.repeats):
        for j in (range(len(names)) if r % 2 == 0 else reversed(range(len(names)))):
            env = {k: v for k, v in os.environ.items() if not k.endswith("_NUM_THREADS")}
            out = subprocess.run(child, env={**env, **args.settings[j]}, capture_output=True, text=True,
                                 check=True).stdout
            for row in map(json.loads, out.splitlines()):
                runs.setdefault((row["level"], row["nodes"], row["phantom"]), {}).setdefault(j, []).append(row)
            print(f"  repeat {r + 1}, {names[j]}: done", file=sys.stderr, flush=True)
    depth = {f"{k}:{i}": max(t.depth_mm for t in phantoms[k, i].touches) for k, i in args.phantoms}
    print(f"design {args.design[0]:g}:{args.design[1]:g}, {args.repeats} presses per setting, "
          "each in a fresh process\n")
    print("| mesh | nodes | phantom | depth (mm) | setting | MKL threads | seconds (median, range) | CPU s per s "
          "| Newton | tangent factorizations | V_rel repeats | ratio to the first |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for (level, nodes, phantom), by_setting in runs.items():
        base = statistics.median(row["seconds"] for row in by_setting[0])
        for j, rows in sorted(by_setting.items()):
            secs = [row["seconds"] for row in rows]
            values = {row["v_rel"] for row in rows}
            print(f"| {level} | {nodes} | {phantom} | {depth[phantom]:.2f} | {names[j]} | "
                  f"{'/'.join(sorted({str(row['mkl_threads']) for row in rows}))} "
                  f"| {statistics.median(secs):.1f} ({min(secs):.1f}-{max(secs):.1f}) "
                  f"| {statistics.median(row['busy'] for row in rows):.2f} "
                  f"| {'/'.join(sorted({str(row['newton']) for row in rows}))} "
                  f"| {'/'.join(sorted({str(row['factorizations']) for row in rows}))} "
                  f"| {'same' if len(values) == 1 else f'{len(values)} values'} "
                  f"| {base / statistics.median(secs):.2f} |")


if __name__ == "__main__":
    main()
