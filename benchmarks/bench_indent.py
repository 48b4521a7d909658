"""Indentation speed: one 8.75 mm flat punch to 4 mm at the centre of the default design, default mesh.

Prints seconds per Newton iteration (assembly, factorization, back-substitution), iterations, load steps,
total and peak memory for

* ``latticeopt`` -- the default solver: P1 + mean-dilatation tangent compiled with numba, single-precision
  PARDISO factorization (Cholesky, symbolic analysis reused), inexact Newton (``method="newton-krylov"``:
  GMRES on each tangent preconditioned by the latest factorization), conforming punch rim;
* ``(newton)`` -- the same with a factorization every iteration (exact Newton);
* ``baseline`` -- plain scikit-fem: neo-Hookean residual and tangent written with ``skfem.helpers`` inside
  the forms (so ``F``, ``inv(F)``, ``det(F)`` are re-evaluated for every pair of basis functions), 4-point
  quadrature, Dirichlet DOFs condensed, ``scipy.sparse.linalg.spsolve``. One Newton iteration is timed and
  the whole indentation is extrapolated with the iteration count full Newton needed (a plain Newton loop
  needs at least as many).

Every part runs in its own process (one BLAS/MKL thread) so peak RSS is per part.

    python benchmarks/bench_indent.py [--size 2.0] [--baseline-size 2.0] [--skip-baseline]

Operation counts beside times on paper phantoms (docs/performance.md, "Cheaper fine-mesh solves"):

    python benchmarks/bench_indent.py --phantoms 6 [--designs 4,3 2,1] [--compare step_rtol=0.1 ...]
                                      [--orderings] [--undeformed-preconditioner]

``--phantoms N`` runs the first N phantoms of studies/paper_fig4.toml (1, 2, 3 touches in turn) through
:class:`~latticeopt.coupled.CoupledModel` on paper_fig4.toml's mesh, once with the default settings and once
per ``--compare`` variant (``IndentSettings`` fields, ``key=value[,key=value]``), each in its own process, and
prints per design the Newton iterations, factorizations, GMRES iterations (back-substitutions), load steps,
halvings and failures beside the mechanics seconds, and the largest ``|dV_rel| / V_rel`` against the default.
``--orderings`` compares PARDISO's fill-reducing orderings on the design's undeformed tangent (factor non-zeros,
flops, factorization and back-substitution time). ``--undeformed-preconditioner`` counts the GMRES iterations
the first load step's increment would take through the design's undeformed tangent, factorized once per
design, instead of through the phantom's own factorization.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time

for _v in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ[_v] = "1"

TOUCH = (50.0, 50.0, 8.75, 4.0)


def _mesh(size_mm: float):
    from latticeopt import LatticeDesign, MeshSettings, mesh_design

    return mesh_design(LatticeDesign(), MeshSettings(size_mm=size_mm))


def part_ours(size_mm: float, method: str) -> dict:
    from latticeopt.mechanics import IndentationSolver, IndentSettings

    mesh = _mesh(size_mm)
    t0 = time.perf_counter()
    solver = IndentationSolver(mesh, IndentSettings(method=method))
    setup = time.perf_counter() - t0
    res = solver.solve([TOUCH])
    t = res.timings
    n_it, n_f = res.newton_steps, res.solver["n_factorizations"]
    return {"nodes": mesh.n_nodes, "tets": mesh.n_tets, "dofs": res.solver["n_dofs"], "setup_s": setup,
            "total_s": t["total"], "iterations": n_it, "factorizations": n_f, "load_steps": res.load_steps,
            "halvings": res.step_halvings, "assembly_s": t["assembly"], "factorization_s": t["factorization"],
            "solve_s": t["solve"], "krylov_s": t["krylov"], "krylov_its": res.solver["krylov_iterations"],
            "assembly_per_it": t["assembly"] / n_it,
            "factor_per_factorization": t["factorization"] / max(n_f, 1), "solve_per_it": t["solve"] / n_it,
            "force_N": float(res.forces_N[0])}


def part_baseline(size_mm: float) -> dict:
    """One naive scikit-fem Newton iteration at a mid-indentation state (plain P1, nu = 0.49)."""
    import numpy as np
    from scipy.sparse.linalg import spsolve
    from skfem import Basis, BilinearForm, ElementTetP1, ElementVector, LinearForm, asm, condense
    from skfem.helpers import ddot, det, eye, grad, inv, mul, transpose

    from latticeopt.mechanics import Materials

    mesh = _mesh(size_mm)
    m = mesh.to_skfem()
    basis = Basis(m, ElementVector(ElementTetP1()), intorder=2)  # 4 quadrature points per tet
    p0 = basis.with_element(ElementVector(ElementTetP1()))
    mu_t, kappa_t = Materials().moduli_MPa(mesh.region)
    from skfem import ElementTetP0

    pb = basis.with_element(ElementTetP0())
    mu, kap = pb.interpolate(mu_t), pb.interpolate(kappa_t)
    del p0

    def first_pk(F, w):
        J = det(F)
        C = J ** (-2.0 / 3.0)
        I1 = ddot(F, F)
        FinvT = transpose(inv(F))
        return w.mu * C * (F - I1 / 3.0 * FinvT) + 0.5 * w.kap * (J * J - 1.0) * FinvT

    @LinearForm
    def residual(v, w):
        G = grad(w["disp"])
        F = G + eye(np.ones_like(G[0, 0]), 3)
        return ddot(first_pk(F, w), grad(v))

    @BilinearForm
    def tangent(u, v, w):
        # directional derivative of P, written naively: every helper below runs for each basis pair
        G = grad(w["disp"])
        F = G + eye(np.ones_like(G[0, 0]), 3)
        J = det(F)
        C = J ** (-2.0 / 3.0)
        I1 = ddot(F, F)
        FinvT = transpose(inv(F))
        dF = grad(u)
        dJ = J * ddot(FinvT, dF)
        dC = -2.0 / 3.0 * C / J * dJ
        dI1 = 2.0 * ddot(F, dF)
        dFinvT = -transpose(mul(mul(inv(F), dF), inv(F)))
        dP = (w.mu * (dC * (F - I1 / 3.0 * FinvT) + C * (dF - dI1 / 3.0 * FinvT - I1 / 3.0 * dFinvT))
              + w.kap * J * dJ * FinvT + 0.5 * w.kap * (J * J - 1.0) * dFinvT)
        return ddot(dP, grad(v))

    # a mid-indentation state: the punch pushed 2 mm with a smooth decay (representative F field)
    X = mesh.nodes_mm
    rho = np.hypot(X[:, 0] - 50, X[:, 1] - 50)
    uz = -2.0 * np.exp(-np.maximum(rho - 8.75, 0) / 8.0) * (X[:, 2] / 9.0)
    u = np.zeros(basis.N)
    u[2::3] = uz
    top = np.unique(mesh.facets["top"])
    punch = top[rho[top] <= 8.75]
    bottom = np.unique(mesh.facets["bottom"])
    D = np.r_[3 * bottom, 3 * bottom + 1, 3 * bottom + 2, 3 * punch, 3 * punch + 1, 3 * punch + 2]
    t0 = time.perf_counter()
    w = basis.interpolate(u)
    K = asm(tangent, basis, disp=w, mu=mu, kap=kap)
    t1 = time.perf_counter()
    R = asm(residual, basis, disp=w, mu=mu, kap=kap)
    t2 = time.perf_counter()
    du = np.zeros(basis.N)
    Kc, rc, _, I = condense(K, -R, x=du, D=D)
    du[I] = spsolve(Kc, rc)
    t3 = time.perf_counter()
    return {"nodes": mesh.n_nodes, "tets": mesh.n_tets, "dofs": int(basis.N), "tangent_s": t1 - t0,
            "residual_s": t2 - t1, "spsolve_s": t3 - t2, "iteration_s": t3 - t0,
            "finite": bool(np.isfinite(du).all())}


def _paper():
    from pathlib import Path

    from latticeopt.study.config import load_study

    return load_study(Path(__file__).resolve().parent.parent / "studies" / "paper_fig4.toml")


def _paper_mesh(design: tuple[float, float]):
    from pathlib import Path

    from latticeopt import LatticeDesign, mesh_design

    return mesh_design(LatticeDesign(width_mm=design[0], thickness_mm=design[1]), _paper().settings.mesh,
                       cache_dir=Path(__file__).resolve().parent.parent / "meshes")


def _phantom_touches(n: int):
    from latticeopt.study.phantoms import random_phantom

    return [random_phantom(100.0, 1 + i % 3, i // 3, 2025).touches for i in range(n)]


def _overrides(text: str) -> dict:
    """``key=value[,key=value]`` -> IndentSettings keyword arguments (numbers where they parse)."""
    out = {}
    for item in filter(None, text.split(",")):
        key, _, value = item.partition("=")
        try:
            out[key.strip()] = json.loads(value)
        except json.JSONDecodeError:
            out[key.strip()] = value.strip()
    return out


def part_phantoms(design: tuple[float, float], n: int, variant: str) -> dict:
    """Op counts, seconds and V_rel of the first ``n`` paper phantoms with ``IndentSettings`` overrides."""
    import dataclasses

    from latticeopt import LatticeDesign
    from latticeopt.coupled import CoupledModel
    from latticeopt.errors import ConvergenceError
    from latticeopt.mechanics import IndentationSolver

    _paper_mesh(design)
    from pathlib import Path

    model = CoupledModel(LatticeDesign(width_mm=design[0], thickness_mm=design[1]), _paper().settings.mesh,
                         cache_dir=Path(__file__).resolve().parent.parent / "meshes")
    if variant:
        model.mechanics = IndentationSolver(model.mesh, dataclasses.replace(model.mechanics.settings,
                                                                             **_overrides(variant)))
    rows = []
    for touches in _phantom_touches(n):
        try:
            r = model.simulate(touches)
        except ConvergenceError:
            rows.append(None)
            continue
        ind = r.indentation
        rows.append({"v_rel": r.v_rel, "newton": ind.newton_steps, "fact": ind.solver["n_factorizations"],
                     "gmres": ind.solver["krylov_iterations"], "steps": ind.load_steps, "halvings": ind.step_halvings,
                     "mech_s": r.timings["mechanics"], "fact_s": ind.timings["factorization"],
                     "gmres_s": ind.timings["krylov"]})
    return {"nodes": model.mesh.n_nodes, "dofs": model.mechanics.op.n_dofs, "rows": rows}


def part_orderings(design: tuple[float, float]) -> dict:
    """PARDISO orderings (``iparm(2)``; ``iparm(37) < 0``: variable block rows) on the undeformed tangent."""
    import numpy as np

    import latticeopt.linalg as la
    from latticeopt.mechanics import IndentationSolver

    mech = IndentationSolver(_paper_mesh(design))
    isD = np.zeros(mech.op.n_dofs, dtype=bool)
    isD[(3 * mech.bottom_nodes[:, None] + np.arange(3)).ravel()] = True
    A = mech._matrix(mech._ev0.data, isD)
    b = np.random.default_rng(0).standard_normal(mech.op.n_dofs)
    default = la._pardiso_parameters
    out = {}
    for name, extra in (("nested dissection (METIS), default", {}), ("minimum degree", {2: 0}),
                        ("parallel METIS", {2: 3}), ("METIS, variable block rows", {37: -80})):
        la._pardiso_parameters = lambda mtype, single, extra=extra: {**default(mtype, single), 18: -1, 19: -1,
                                                                     **extra}
        try:
            S = la.SymmetricSolver(A, positive_definite=True, factorize=False, precision="single")
            fact, solve = [], []
            for _ in range(3):
                t0 = time.perf_counter()
                S.refactor(A)
                fact.append(time.perf_counter() - t0)
            for _ in range(10):
                t0 = time.perf_counter()
                S.solve(b)
                solve.append(time.perf_counter() - t0)
            # iparm(18), iparm(19): factor non-zeros and factorization Mflops (reported in the solver's units)
            out[name] = {"nnz_factor": int(S._ps.iparm[17]), "mflops": int(S._ps.iparm[18]),
                         "factor_s": min(fact), "solve_ms": 1e3 * min(solve)}
        finally:
            la._pardiso_parameters = default
    return {"dofs": mech.op.n_dofs, "orderings": out}


def part_undeformed(design: tuple[float, float], n: int) -> dict:
    """GMRES iterations of the first load step's increment through the design's undeformed tangent."""
    import importlib

    import numpy as np

    from latticeopt.linalg import SymmetricSolver, gmres
    from latticeopt.mechanics import IndentationSolver
    from latticeopt.touches import check_touches

    ind = importlib.import_module("latticeopt.mechanics.indent")
    mesh = _paper_mesh(design)
    m = IndentationSolver(mesh)
    isB = np.zeros(m.op.n_dofs, dtype=bool)
    isB[(3 * m.bottom_nodes[:, None] + np.arange(3)).ravel()] = True
    K0 = SymmetricSolver(m._matrix(m._ev0.data, isB), positive_definite=True, precision="single")
    m._clock = {"assembly": 0.0}
    rows = []
    for touches in _phantom_touches(n):
        touches = check_touches(touches, m.x_range, m.y_range, m.thickness_mm)
        ref = ind.conform_punch_edges(mesh.nodes_mm, mesh.tets, mesh.facets["top"], m._movable, touches)
        m._op = m.op.with_reference(ref)
        ev = m._evaluate(np.zeros_like(ref))
        cons = ind.Constraints(ref, m.top_nodes, m.bottom_nodes, touches, "flat", "bonded")
        lam = min(1.0, m.settings.max_step_mm / max(t.depth_mm for t in touches))
        u = np.zeros_like(ref)
        cons.start_step(u, lam)
        D, vals = cons.dirichlet(lam)
        isD = np.zeros(m.op.n_dofs, dtype=bool)
        isD[D] = True
        b = m._free_rhs(ev, D, vals - u.ravel()[D], ev.residual_N)
        b[D] = 0.0
        A = m._symmetric_operator(m._constrained(ev.data, isD))
        own = SymmetricSolver(m._matrix(ev.data, isD), positive_definite=True, precision="single")
        row = {"touches": len(touches), "punch_dofs": int(isD.sum() - isB.sum())}
        for name, M in (("undeformed", K0), ("own", own)):
            for rtol in (1e-1, 1e-2, ind._JUMP_RTOL):
                _, its, ok = gmres(A, b, lambda r, M=M: M.solve(r).ravel(), rtol * float(np.linalg.norm(b)), 200)
                row[f"{name} {rtol:g}"] = its if ok else None
        rows.append(row)
    return {"rows": rows}


def _design_arg(text: str) -> tuple[float, float]:
    w, t = (float(x) for x in text.split(","))
    return w, t


def phantom_report(a) -> None:
    with open("/proc/loadavg") as fh:
        load = fh.read().split()[:3]
    print(f"first {a.phantoms} paper phantoms (1-3 touches), paper_fig4.toml's mesh, CoupledModel defaults "
          f"(mechanics_rtol 1e-4); 1 MKL thread; load average before: {' '.join(load)} (2 cores)")
    for design in a.designs:
        _paper_mesh(design)  # mesh once, outside the timed parts
        tag = f"{design[0]:g},{design[1]:g}"
        if a.orderings:
            o = run_part("orderings", "--design", tag)
            print(f"\nw,t = {tag}: PARDISO orderings of the undeformed tangent ({o['dofs']} DOFs, single precision)")
            print("| ordering | factor non-zeros | factorization Mflop | factorization s | back-substitution ms |")
            print("|---|---|---|---|---|")
            for name, r in o["orderings"].items():
                print(f"| {name} | {r['nnz_factor']:,} | {r['mflops']:,} | {r['factor_s']:.3f} | "
                      f"{r['solve_ms']:.1f} |")
        if a.undeformed_preconditioner:
            u = run_part("undeformed", "--design", tag, "--phantoms", str(a.phantoms or 6))
            keys = [k for k in u["rows"][0] if k.startswith(("undeformed", "own"))]
            print(f"\nw,t = {tag}: GMRES iterations of the first load step's increment, to relative residual")
            print("| phantom | touches | punch DOFs | " + " | ".join(f"through {k}" for k in keys) + " |")
            print("|---" * (3 + len(keys)) + "|")
            for i, r in enumerate(u["rows"]):
                print(f"| {i} | {r['touches']} | {r['punch_dofs']} | "
                      + " | ".join(str(r[k]) if r[k] is not None else "-" for k in keys) + " |")
        if a.phantoms and not a.skip_counts:
            print(f"\nw,t = {tag}: totals over {a.phantoms} phantoms")
            print("| settings | Newton | factorizations | GMRES its | load steps | halvings | failed | "
                  "mechanics s | factorization s | GMRES s | max dV_rel/V_rel |")
            print("|---|---|---|---|---|---|---|---|---|---|---|")
            ref = None
            for variant in ["", *a.compare]:
                out = run_part("phantoms", "--design", tag, "--phantoms", str(a.phantoms), "--variant", variant)
                rows = out["rows"]
                ok = [r for r in rows if r is not None]
                ref = ref or rows
                dv = [abs(r["v_rel"] - q["v_rel"]) / abs(q["v_rel"]) for r, q in zip(rows, ref) if r and q]
                tot = {k: sum(r[k] for r in ok) for k in ("newton", "fact", "gmres", "steps", "halvings", "mech_s",
                                                          "fact_s", "gmres_s")}
                print(f"| {variant or 'default'} | {tot['newton']} | {tot['fact']} | {tot['gmres']} | {tot['steps']} | "
                      f"{tot['halvings']} | {len(rows) - len(ok)} | {tot['mech_s']:.2f} | {tot['fact_s']:.2f} | "
                      f"{tot['gmres_s']:.2f} | {max(dv, default=0.0):.1e} |", flush=True)


def run_part(name: str, *args: str) -> dict:
    cmd = [sys.executable, __file__, "--part", name, *args]
    out = subprocess.run(cmd, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--size", type=float, default=2.0, help="grid size of the mesh (default: MeshSettings())")
    ap.add_argument("--baseline-size", type=float, default=None, help="mesh of the baseline (default --size)")
    ap.add_argument("--skip-baseline", action="store_true")
    ap.add_argument("--part", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--method", default="newton-krylov", help=argparse.SUPPRESS)
    ap.add_argument("--phantoms", type=int, default=0,
                    help="op counts and times on the first N paper phantoms instead of the single press")
    ap.add_argument("--designs", type=_design_arg, nargs="+", default=[(4.0, 3.0)], help="WIDTH,THICKNESS (mm)")
    ap.add_argument("--compare", nargs="*", default=[],
                    help="IndentSettings variants to run beside the default, each key=value[,key=value]")
    ap.add_argument("--orderings", action="store_true", help="compare PARDISO orderings per design")
    ap.add_argument("--undeformed-preconditioner", action="store_true",
                    help="GMRES iterations of the first increment through the design's undeformed tangent")
    ap.add_argument("--skip-counts", action="store_true", help="with --phantoms: skip the op-count table")
    ap.add_argument("--design", type=_design_arg, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--variant", default="", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.part in ("phantoms", "orderings", "undeformed"):
        res = (part_phantoms(a.design, a.phantoms, a.variant) if a.part == "phantoms" else
               part_orderings(a.design) if a.part == "orderings" else part_undeformed(a.design, a.phantoms))
        print(json.dumps(res))
        return
    if a.phantoms or a.orderings or a.undeformed_preconditioner:
        phantom_report(a)
        return
    if a.part:
        res = part_ours(a.size, a.method) if a.part == "ours" else part_baseline(a.size)
        res["peak_rss_MB"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
        print(json.dumps(res))
        return
    _mesh(a.size)  # build the mesh cache once, outside the timed parts
    with open("/proc/loadavg") as fh:
        load = fh.read().split()[:3]
    print(f"8.75 mm flat punch to 4 mm at the centre of LatticeDesign(), grid mesh size {a.size} mm; "
          f"1 MKL thread; load average before: {' '.join(load)} (2 cores)")
    ours = run_part("ours", "--size", str(a.size), "--method", "newton-krylov")
    newton = run_part("ours", "--size", str(a.size), "--method", "newton")
    print(f"mesh: {ours['nodes']} nodes, {ours['tets']} tets, {ours['dofs']} DOFs")
    print(f"{'solver':<18} {'iters':>5} {'factor':>6} {'gmres':>5} {'steps':>5} {'asm/it s':>8} {'fact/f s':>8} "
          f"{'gmres s':>7} {'total s':>8} {'setup s':>7} {'peak MB':>8} {'force N':>9}")
    for name, r in (("latticeopt", ours), ("(newton)", newton)):
        print(f"{name:<18} {r['iterations']:>5} {r['factorizations']:>6} {r['krylov_its']:>5} {r['load_steps']:>5} "
              f"{r['assembly_per_it']:>8.3f} {r['factor_per_factorization']:>8.3f} {r['krylov_s']:>7.2f} "
              f"{r['total_s']:>8.2f} {r['setup_s']:>7.2f} {r['peak_rss_MB']:>8.0f} {r['force_N']:>9.4f}")
    print(f"target: at most 10 s on one core -> {'met' if ours['total_s'] <= 10 else 'NOT met'} "
          f"({ours['total_s']:.2f} s)")
    if a.skip_baseline:
        return
    bsize = a.baseline_size or a.size
    base = run_part("baseline", "--size", str(bsize))
    scale = ours["dofs"] / base["dofs"]
    per_it = base["iteration_s"] * (scale if bsize != a.size else 1.0)
    total = per_it * newton["iterations"]
    note = "" if bsize == a.size else f" (measured at {base['dofs']} DOFs, scaled linearly by {scale:.2f})"
    print(f"{'scikit-fem naive':<18} one iteration: tangent {base['tangent_s']:.2f} s, residual "
          f"{base['residual_s']:.2f} s, spsolve {base['spsolve_s']:.2f} s = {base['iteration_s']:.2f} s{note}; "
          f"peak {base['peak_rss_MB']:.0f} MB")
    print(f"baseline extrapolated: {per_it:.2f} s/iteration x {newton['iterations']} iterations = {total:.1f} s")
    print(f"speed-up of latticeopt (default) over the baseline: {total / ours['total_s']:.1f}x "
          f"(exact Newton {total / newton['total_s']:.1f}x); target 10x -> "
          f"{'met' if total / ours['total_s'] >= 10 else 'NOT met'}")


if __name__ == "__main__":
    main()
