"""How long a press takes to give up, and what its Newton iterations look like on the way: every load step
attempt (depths, iterations, seconds, outcome) and every Newton iteration's line search.

    python benchmarks/give_up.py --design 2:1 --touch 50,50,7.5,8.9         # paper mesh: cannot converge
    python benchmarks/give_up.py --design 2:1 --phantom 1:95 --iterations   # a deep press that converges
    python benchmarks/give_up.py --mesh default --design 4:3 --touch 50,50,7.5,8.9 --physics KEY=VALUE
    python benchmarks/give_up.py --mesh default --pattern hexagonal --design 1.1:3 \
        --touch 8.0108,13.0568,7.2240,4.5004 --touch 53.1726,50.1997,8.5922,1.7555   # ~ the optimizer's 2:9

Meshes: ``paper`` (the paper map's: 2 mm grid, 2 channel cells, no electrode edge lines) or ``default``
(``MeshSettings()``). Mechanics only (no electrics). Per attempt: the depths, Newton iterations, seconds, the
outcome and, per iteration with ``--iterations``, the free residual (N, and as a multiple of the norm of the
reaction forces at the step's start), the iterate's own reaction norm, the line search's step length ``alpha``
(the accepted fraction of the Newton increment), the energy change, the smallest det F of the accepted iterate
(of the start, where the line search failed) and the factorization's diagonal shift; per attempt, how long
its residual stalled: iterations without a new smallest residual, counted from its largest (past the rise while
the increment is applied), at the attempt's end and longest. The summary gives the whole solve, the time
and work from the end of the last accepted load step to the error, and the linear algebra's operation counts
(factorizations, failed Cholesky tries of shifted tangents included; Krylov iterations; seconds factorizing).

Per attempt of more than a ``--window`` (10 s), once its increment is applied, three measures of progress that
a "no progress within 10 s" rule could use: the smallest relative energy decrease over any window of that length,
the longest time without a residual 10 % below the lowest so far, and the longest run of iterations whose energy
change equals the increment's first-order prediction ``R . du`` to 2 % (the energy flat to second order along it).
``--mesh coarse --size-mm 50 --design 4:3`` is the unit tests' stack (50 mm, 2.5 mm grid), where a 1,000-iteration
rescue takes minutes (the ``[physics]`` key ``mechanics_rescue_newton``; docs/verification.md, "A press that
cannot finish still makes progress"):

    python benchmarks/give_up.py --mesh coarse --size-mm 50 --design 4:3 --touch 25,25,7.5,8.999 \
        --physics mechanics_rescue_newton=1000
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
import time
from typing import NamedTuple

for _var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

from latticeopt import LatticeDesign, MeshSettings  # noqa: E402
from latticeopt.cli._physics import add_physics_arg, physics_settings  # noqa: E402
from latticeopt.errors import ConvergenceError, ParameterError  # noqa: E402
from latticeopt.mechanics import IndentationSolver  # noqa: E402
from latticeopt.mesh import mesh_design  # noqa: E402

MESHES = {"paper": MeshSettings(size_mm=2.0, channel_cells=2, layer_cells=2, electrode_edges=False),
          "default": MeshSettings(), "coarse": MeshSettings(size_mm=2.5)}


class Iterate(NamedTuple):
    """One Newton iteration's line search, as traced."""

    residual_N: float  # free residual at the iteration's start
    alpha: float  # accepted fraction of the increment (0: the line search failed)
    dE_Nmm: float  # energy change of the accepted iterate (nan: failed)
    shift: float  # the factorization's relative diagonal shift
    reaction_N: float  # norm of the constrained residual at the start
    min_J: float  # smallest det F of the accepted iterate (of the start, where the line search failed)
    seconds: float  # perf_counter when the line search ended
    jump: bool  # part of the step's prescribed increment still being applied
    slope_Nmm: float  # R . du (nan: failed)
    energy_Nmm: float  # energy of the accepted iterate (of the start, where the line search failed)


def stall(norms) -> tuple[int, int]:
    """Iterations without a new smallest residual in ``norms`` after its largest: (at the end, longest run)."""
    if not norms:
        return 0, 0
    best, run, longest = np.inf, 0, 0
    for r in norms[int(np.argmax(norms)):]:
        run = 0 if r < best else run + 1
        best, longest = min(best, r), max(longest, run)
    return run, longest


def progress(iterates: list[Iterate], window_s: float) -> str:
    """The progress measures of the module docstring for one attempt's iterations once its increment is applied;
    empty when they span less than ``window_s``."""
    rows = [it for it in iterates if not it.jump]
    if len(rows) < 2 or rows[-1].seconds - rows[0].seconds < window_s:
        return ""
    t, r, E, dE, slope = (np.array([getattr(it, f) for it in rows])
                          for f in ("seconds", "residual_N", "energy_Nmm", "dE_Nmm", "slope_Nmm"))
    j = np.searchsorted(t, t + window_s)
    drops = [(E[i] - E[k]) / abs(E[i]) for i, k in enumerate(j) if k < len(t)]
    best, since, no_min, flat, run = np.inf, t[0], 0.0, 0, 0
    for ti, ri, d, s in zip(t, r, dE, slope):
        if ri < 0.9 * best:
            best, since = ri, ti
        no_min = max(no_min, ti - since)
        run = run + 1 if s < 0 and abs(d / s - 1.0) <= 0.02 else 0
        flat = max(flat, run)
    return (f"; progress over {window_s:g} s: energy down by at least {min(drops):.2g} of itself in every window, "
            f"{no_min:.1f} s at most without a 10 % lower residual, {flat} iterations in a row at dE = R.du")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--design", default="2:1", help="W:T (mm)")
    ap.add_argument("--pattern", default="square", help="the lattice's pattern (LatticeDesign.pattern)")
    ap.add_argument("--mesh", default="paper", choices=sorted(MESHES))
    ap.add_argument("--touch", action="append", default=[], metavar="X,Y,R,D", help="a touch (mm); repeatable")
    ap.add_argument("--phantom", help="a paper phantom K:I (benchmarks/deep_presses.py) instead of --touch")
    ap.add_argument("--iterations", action="store_true", help="print every Newton iteration")
    ap.add_argument("--size-mm", type=float, default=100.0, help="the sensor's side (mm; default 100)")
    ap.add_argument("--window", type=float, default=10.0, metavar="SECONDS",
                    help="the window of the progress measures (s; default 10)")
    add_physics_arg(ap)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(message)s")
    if args.phantom:
        sys.path.insert(0, os.path.dirname(__file__))
        from deep_presses import paper_phantoms

        touches = list(paper_phantoms()[tuple(int(x) for x in args.phantom.split(":"))].touches)
    else:
        touches = [tuple(float(x) for x in t.split(",")) for t in args.touch]
    if not touches:
        ap.error("--touch or --phantom: expected a touch, got none")
    if not args.window > 0:
        ap.error(f"--window: expected seconds > 0, got {args.window:g}")
    try:
        physics = physics_settings(args)
    except ParameterError as exc:
        ap.error(str(exc))
    w, t = (float(x) for x in args.design.split(":"))
    try:
        design = LatticeDesign(width_mm=w, thickness_mm=t, pitch_mm=12.5, pattern=args.pattern, size_mm=args.size_mm)
    except ParameterError as exc:
        ap.error(f"--design, --pattern or --size-mm: {exc}")
    t0 = time.perf_counter()
    mesh = mesh_design(design, MESHES[args.mesh])
    solver = IndentationSolver(mesh, physics.indent_settings())
    print(f"design {args.design}, {args.mesh} mesh: {mesh.n_nodes} nodes, {solver.op.n_dofs} dofs; mesh and set-up "
          f"{time.perf_counter() - t0:.1f} s; max_newton {solver.settings.max_newton}, rescue_newton "
          f"{solver.settings.rescue_newton}; touches {touches}", flush=True)
    attempts, iters = [], []
    newton, line_search = solver._newton, solver._line_search
    d_max = max(float(x[3]) if not hasattr(x, "depth_mm") else x.depth_mm for x in touches)
    state = {"from": 0.0}

    def traced_line_search(u, du, ev, has_jump, isD):
        try:
            ev_new, u_new = line_search(u, du, ev, has_jump, isD)
        except Exception:
            iters.append(Iterate(float(np.linalg.norm(ev.residual_N[~isD])), 0.0, np.nan, solver._shift,
                                 float(np.linalg.norm(ev.residual_N[isD])), ev.min_J, time.perf_counter(),
                                 bool(has_jump), np.nan, ev.energy_Nmm))
            raise
        step = float(np.linalg.norm(u_new.ravel() - u.ravel())) / max(float(np.linalg.norm(du)), 1e-300)
        iters.append(Iterate(float(np.linalg.norm(ev.residual_N[~isD])), step, ev_new.energy_Nmm - ev.energy_Nmm,
                             solver._shift, float(np.linalg.norm(ev.residual_N[isD])), ev_new.min_J,
                             time.perf_counter(), bool(has_jump), float(ev.residual_N @ du), ev_new.energy_Nmm))
        return ev_new, u_new

    def traced_newton(u, ev, cons, lam, final=True):
        t = time.perf_counter()
        del iters[:]
        n0 = solver._n_solves
        row = {"from_mm": state["from"], "to_mm": lam * d_max, "start": t - t_start}
        try:
            out = newton(u, ev, cons, lam, final)
        except Exception as exc:
            row.update(ok=False, why=getattr(exc, "reason", str(exc)), residual=getattr(exc, "residual", np.nan))
            raise
        else:
            row.update(ok=True, why="", residual=out[2][-1])
            state["from"] = lam * d_max
            return out
        finally:
            row.update(seconds=time.perf_counter() - t, newton=solver._n_solves - n0, iters=list(iters))
            attempts.append(row)
            end, longest = stall([it.residual_N for it in row["iters"]])
            print(f"  {'ok    ' if row['ok'] else 'FAILED'} {row['from_mm']:.4f} -> {row['to_mm']:.4f} mm: "
                  f"{row['newton']} Newton, {row['seconds']:.1f} s, residual {row['residual']:.3g} N "
                  f"{row['why'] + '; ' if row['why'] else ''}stalled {end} at the end (longest {longest})"
                  f"{progress(row['iters'], args.window)}", flush=True)
            if args.iterations:
                reaction = max(row["iters"][0].reaction_N, 1e-300) if row["iters"] else np.nan
                for k, it in enumerate(row["iters"]):
                    print(f"      it {k}: |R| {it.residual_N:.3g} N ({it.residual_N / reaction:.3g} x the step's start "
                          f"reaction), reaction {it.reaction_N:.3g} N, alpha {it.alpha:.3g}, dE {it.dE_Nmm:.3g} Nmm, "
                          f"min det F {it.min_J:.3g}, shift {it.shift:g}")

    def counts() -> str:
        return (f"{solver._n_factor} factorizations (failed Cholesky tries included; {solver._n_shifted} tangents "
                f"shifted, {solver._n_projected} projected), {solver._n_krylov} Krylov iterations, "
                f"{solver._clock['factorization']:.1f} s factorizing")

    solver._newton, solver._line_search = traced_newton, traced_line_search
    t_start = time.perf_counter()
    try:
        res = solver.solve(touches)
    except ConvergenceError as exc:
        total = time.perf_counter() - t_start
        ok = [i for i, a in enumerate(attempts) if a["ok"]]
        tail = attempts[ok[-1] + 1:] if ok else attempts
        t_last = attempts[ok[-1]]["start"] + attempts[ok[-1]]["seconds"] if ok else 0.0
        print(f"GAVE UP after {total:.1f} s ({sum(a['newton'] for a in attempts)} Newton, "
              f"{sum(not a['ok'] for a in attempts)} failed attempts); from the last accepted step "
              f"({attempts[ok[-1]]['to_mm'] if ok else 0:.4f} mm) to the error: {total - t_last:.1f} s, "
              f"{sum(a['newton'] for a in tail)} Newton, {len(tail)} failed attempts; {counts()}\n  {exc}")
    else:
        print(f"CONVERGED after {time.perf_counter() - t_start:.1f} s: {res.newton_steps} Newton, {res.load_steps} "
              f"load steps, {res.step_halvings} halvings, forces {np.round(res.forces_N, 4).tolist()} N; {counts()}")


if __name__ == "__main__":
    main()
