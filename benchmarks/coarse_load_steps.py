"""Longer load steps, or other Krylov settings, on a two-level sweep's coarse level: is the coarse pass cheaper?

The coarse level (mechanics on a 4 mm grid with one cell across a channel, ``mechanics_rtol = 1e-2``, electrics
on the fine mesh) presses every phantom of a map, and its mechanics is nearly all of its time. A press is
applied in load steps of at most ``max_step_mm`` (1 mm); fewer, longer steps might save Newton iterations. Its
factorization costs about 10 back-substitutions (20 on the fine mesh), so the inexact Newton's knobs tuned on
the fine mesh (``max_krylov``: back-substitutions before a refactorization; ``krylov_rtol``: the forcing term;
``method = "newton"``: a factorization every iteration) may sit elsewhere for it. For each design this presses
the first 4 paper phantoms of every touch count and the 6 deepest with each ``--steps`` value, then with each
``--solver`` variant at the first step value (a fresh solver per row, in this one process, after one untimed
press) and prints the Newton iterations, the factorizations, the Krylov iterations, the CPU seconds (steadier
than wall time on a shared machine) and how far V_rel moved from the first row's.

    python benchmarks/coarse_load_steps.py --steps 1 2.5 5 --designs 4,3 2,1 6,5
    python benchmarks/coarse_load_steps.py --steps 1 --solver max_krylov=8 method=newton \
        krylov_rtol=0.3 --designs 4,3 2,1 0,3
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time

for _v in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import numpy as np  # noqa: E402

from latticeopt import LatticeDesign  # noqa: E402
from latticeopt.coupled import model_for_settings  # noqa: E402
from latticeopt.errors import ConvergenceError  # noqa: E402
from latticeopt.mechanics.indent import IndentationSolver  # noqa: E402
from latticeopt.mechanics.settings import IndentSettings  # noqa: E402
from latticeopt.study.config import load_study  # noqa: E402
from latticeopt.study.settings import coarse_level_settings  # noqa: E402


def _phantoms(study) -> list[int]:
    phs = study.phantoms
    first = [i for k in (1, 2, 3) for i in [j for j in range(len(phs)) if phs[j].n_touches == k][:4]]
    deepest = sorted(range(len(phs)), key=lambda i: -max(t.depth_mm for t in phs[i].touches))[:6]
    return sorted(set(first) | set(deepest))


def _variant(text: str) -> dict:
    """``"max_krylov=8,krylov_rtol=0.3"`` -> the IndentSettings keys it changes (checked by IndentSettings)."""
    out = {}
    for item in text.split(","):
        key, sep, value = item.partition("=")
        try:
            if not sep:
                raise ValueError(item)
            out[key] = _KNOBS[key](value)
        except (KeyError, ValueError):
            raise argparse.ArgumentTypeError(
                f"KEY=VALUE[,KEY=VALUE] with KEY one of max_krylov (integer), krylov_rtol (number), method, "
                f"got {text!r}") from None
    return out


_KNOBS = {"max_krylov": int, "krylov_rtol": float, "method": str}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=float, nargs="+", default=[1.0, 2.5, 5.0], help="max_step_mm values (mm)")
    ap.add_argument("--solver", type=_variant, nargs="*", default=[],
                    help="solver variants, each KEY=VALUE[,KEY=VALUE] (max_krylov, krylov_rtol, method), run at "
                         "the first --steps value")
    ap.add_argument("--designs", nargs="+", default=["4,3", "2,1", "6,5"], help="WIDTH,THICKNESS pairs (mm)")
    args = ap.parse_args()
    if not all(s > 0 for s in args.steps):  # NaN too
        ap.error(f"--steps: step lengths > 0 mm, got {args.steps}")
    try:
        for v in args.solver:
            dataclasses.replace(IndentSettings(), **v)
    except ValueError as exc:
        ap.error(f"--solver: {exc}")
    study = load_study("studies/paper_fig4.toml", ["multilevel.pilot=15"])
    level = coarse_level_settings(study.settings, study.multilevel)
    pick = _phantoms(study)
    print(f"{len(pick)} phantoms (first 4 per touch count and the 6 deepest, "
          f"{max(max(t.depth_mm for t in study.phantoms[i].touches) for i in pick):.2f} mm deepest)")
    print("| w, t | max_step_mm | solver | Newton | factorizations | Krylov iterations | CPU seconds | failed | "
          "V_rel change: median | max |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    rows_wanted = [(step, {}) for step in args.steps] + [(args.steps[0], v) for v in args.solver]
    for pair in args.designs:
        w, t = map(float, pair.split(","))
        model = model_for_settings(LatticeDesign(width_mm=w, thickness_mm=t), level)
        base = None
        for step, knobs in rows_wanted:
            # the same model with only the mechanics' load step or Krylov settings changed
            model.mechanics = IndentationSolver(model.mechanics_mesh, dataclasses.replace(
                model.physics.indent_settings(), max_step_mm=step, **knobs))
            model.simulate(study.phantoms[pick[0]].touches)  # untimed: first-call costs off the first row
            rows = []
            for i in pick:
                t0 = time.process_time()
                try:
                    r = model.simulate(study.phantoms[i].touches)
                    ops = r.indentation.solver
                    rows.append((r.v_rel, r.newton_steps, ops["n_factorizations"], ops["krylov_iterations"]))
                except ConvergenceError:
                    rows.append((np.nan, 0, 0, 0))
                rows[-1] += (time.process_time() - t0,)
            r = np.array(rows)
            base = r if base is None else base
            rel = np.abs(r[:, 0] / base[:, 0] - 1)
            ops = " | ".join(f"{r[:, k].sum():.0f}" for k in (1, 2, 3))
            label = ", ".join(f"{k} = {v}" for k, v in knobs.items()) or "default"
            print(f"| {w:g}, {t:g} | {step:g} | {label} | {ops} | {r[:, 4].sum():.1f} | "
                  f"{int(np.isnan(r[:, 0]).sum())} | {np.nanmedian(rel):.1e} | {np.nanmax(rel):.1e} |", flush=True)


if __name__ == "__main__":
    main()
