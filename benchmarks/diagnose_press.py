"""Where a deep press's Newton iterations stall: every load step's residual history, and at every failed step the
nodes holding the residual and the smallest volume ratio.

    python benchmarks/diagnose_press.py 2 1 1:13                      # w = 2, t = 1, paper phantom 1:13
    python benchmarks/diagnose_press.py 2 1 1:13 --indent max_newton=40

Arguments: width and thickness (mm), a paper phantom ``K:I`` (``benchmarks/deep_presses.py``), and
``--indent KEY=VALUE`` overrides of :class:`latticeopt.mechanics.IndentSettings` (numbers). Paper mesh (2 mm
grid, 2 channel cells), default physics. For each failed load step: the free residual's norm, the share of its
square on the 8 largest nodes, each of those nodes (reference position, displacement, distance to the nearest
punch rim, negative inside; whether it is a top or a hydrogel node), the smallest det F (tet) and patch mean
dilatation, and how many tets fall below det F = 0.1 and 0.2.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import os
import sys
import time

for _var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

from latticeopt import LatticeDesign, MeshSettings  # noqa: E402
from latticeopt.coupled import CoupledModel, PhysicsSettings  # noqa: E402
from latticeopt.errors import ConvergenceError  # noqa: E402
from latticeopt.mechanics import IndentationSolver  # noqa: E402
from latticeopt.mechanics.tangent import _StepFailed  # noqa: E402

sys.path.insert(0, os.path.dirname(__file__))
from deep_presses import paper_phantoms  # noqa: E402


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("width", type=float)
    ap.add_argument("thickness", type=float)
    ap.add_argument("phantom", help="K:I")
    ap.add_argument("--indent", nargs="*", default=[], metavar="KEY=VALUE")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    for name in ("numba", "latticeopt.mesh", "latticeopt.electrics", "latticeopt.mechanics.tangent"):
        logging.getLogger(name).setLevel(logging.WARNING)
    touches = list(paper_phantoms()[tuple(int(x) for x in args.phantom.split(":"))].touches)
    print(touches)
    mesh = MeshSettings(size_mm=2.0, channel_cells=2, layer_cells=2, electrode_edges=False)
    model = CoupledModel(LatticeDesign(width_mm=args.width, thickness_mm=args.thickness, pitch_mm=12.5), mesh,
                         PhysicsSettings())
    solver = model.mechanics
    if args.indent:
        kw = {k: (int(v) if k == "max_newton" else float(v)) for k, v in (a.split("=") for a in args.indent)}
        solver = model.mechanics = IndentationSolver(solver.mesh, dataclasses.replace(solver.settings, **kw))
    d_max = max(t.depth_mm for t in touches)
    last = {}
    line_search, newton = solver._line_search, solver._newton

    def keep(u, du, ev, has_jump, isD):
        out = line_search(u, du, ev, has_jump, isD)
        last.update(ev=out[0], u=out[1], isD=isD)
        return out

    def report(u, ev, cons, lam, final=True):
        try:
            out = newton(u, ev, cons, lam, final)
        except _StepFailed as exc:
            print(f"  step to {lam * d_max:.4f} mm FAILED ({exc.reason}); residuals "
                  f"{' '.join(f'{r:.3g}' for r in exc.norms)}")
            where(solver, touches, cons)
            raise
        print(f"  step to {lam * d_max:.4f} mm: {len(out[2]) - 1} iterations, residuals "
              f"{' '.join(f'{r:.3g}' for r in out[2])}, min det F {out[1].min_J:.3f}")
        return out

    def where(s, touches, cons):
        if "ev" not in last:
            return
        ev, u, isD = last["ev"], last["u"], last["isD"]
        R = ev.residual_N.copy()
        R[isD] = 0.0
        Rn = np.linalg.norm(R.reshape(-1, 3), axis=1)
        top = np.argsort(-Rn)[:8]
        J, Jbar = s._op.jacobians(u)
        print(f"    last iterate: |R_free| {np.linalg.norm(Rn):.3g} N, {np.sum(Rn[top] ** 2) / np.sum(Rn ** 2):.2f} of "
              f"|R|^2 on 8 nodes; min det F {J.min():.4f}, min patch J {Jbar.min():.4f}; tets with det F < 0.1: "
              f"{(J < 0.1).sum()}, < 0.2: {(J < 0.2).sum()}")
        gel = set(s.mesh.tets[s._gel].ravel().tolist())
        top_nodes = set(s.top_nodes.tolist())

        def rim(p):
            return min(np.hypot(p[0] - t.x_mm, p[1] - t.y_mm) - t.radius_mm for t in touches)

        for n in top:
            p = s.mesh.nodes_mm[n]
            print(f"      node {n}: |R| {Rn[n]:.3g} N at ({p[0]:.1f}, {p[1]:.1f}, {p[2]:.2f}) mm, u ({u[n, 0]:.2f}, "
                  f"{u[n, 1]:.2f}, {u[n, 2]:.2f}); to the rim {rim(p):+.2f} mm; top {n in top_nodes}, gel {n in gel}")
        k = int(np.argmin(J))
        c = s.mesh.nodes_mm[s.mesh.tets[k]].mean(axis=0)
        print(f"      smallest det F {J[k]:.4f}: tet {k}, region {s.mesh.region[k]}, centroid ({c[0]:.1f}, {c[1]:.1f}, "
              f"{c[2]:.2f}) mm, to the rim {rim(c):+.2f} mm")

    solver._line_search, solver._newton = keep, report
    t0 = time.perf_counter()
    try:
        r = model.simulate(touches)
    except ConvergenceError as exc:
        print(f"FAILED after {time.perf_counter() - t0:.1f} s: {exc}")
    else:
        ind = r.indentation
        print(f"converged in {time.perf_counter() - t0:.1f} s: V_rel {r.v_rel:.5f}, {ind.load_steps} load steps, "
              f"{ind.step_halvings} halvings, {ind.solver['shifted_factorizations']} shifted factorizations, "
              f"min det F {ind.min_det_F:.4f}")


if __name__ == "__main__":
    main()
