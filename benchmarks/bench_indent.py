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
    a = ap.parse_args()
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
