"""Forward model and Jacobian speed on the default design's hydrogel mesh, against pyEIT on the same mesh.

Usage::

    python benchmarks/bench_forward.py [--threads 1] [--repeat 5] [--size 2.0]

Times are medians over ``--repeat`` runs after one warm-up (the first PARDISO call of a process also loads
MKL, about 0.5 s, reported separately). BLAS/MKL threads are set to ``--threads`` (default 1: the
one-core figure) before numpy is imported. pyEIT 1.2.4 has point electrodes only, so it is timed on the
same tets with our point-mode electrode nodes; its Jacobian inverts the dense stiffness matrix.
Targets (issue 3): >= 5x pyEIT's forward, >= 20x its Jacobian, all 208 measurements < 0.5 s on one core.
"""

from __future__ import annotations

import argparse
import os
import sys
import time


def _args():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--threads", type=int, default=1, help="BLAS/MKL threads (default 1)")
    p.add_argument("--repeat", type=int, default=5, help="repeats per timing (median)")
    p.add_argument("--size", type=float, default=None, help="mesh size (mm); default MeshSettings()")
    p.add_argument("--skip-pyeit-jacobian", action="store_true", help="skip pyEIT's dense-inverse Jacobian")
    return p.parse_args()


ARGS = _args()
for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ[var] = str(ARGS.threads)

import numpy as np  # noqa: E402

from latticeopt.design import LatticeDesign  # noqa: E402
from latticeopt.electrics import ForwardModel  # noqa: E402
from latticeopt.electrics.assembly import Topology, element_geometry, unit_stiffness  # noqa: E402
from latticeopt.linalg import SymmetricSolver  # noqa: E402
from latticeopt.mesh import MeshSettings, mesh_design  # noqa: E402
from latticeopt.mesh.tetmesh import electrode_name  # noqa: E402


def median_time(fn, repeat):
    times = []
    out = None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times)), out


def main() -> int:
    r = ARGS.repeat
    settings = MeshSettings() if ARGS.size is None else MeshSettings(size_mm=ARGS.size)
    mesh = mesh_design(LatticeDesign(), settings)
    t = time.perf_counter()
    ForwardModel(mesh)
    warm = time.perf_counter() - t

    # Stage by stage on a fresh topology, as ForwardModel does them.
    t_restrict, (gel, _) = median_time(lambda: mesh.restrict(("hydrogel",)), r)
    tris = gel.electrode_facets()
    t_topo, topo = median_time(lambda: Topology(gel.tets, gel.n_nodes, tris, None), r)
    nodes_m = gel.nodes_mm * 1e-3
    weights = np.concatenate([gel.weights(electrode_name(k + 1)) for k in range(16)])

    def geometry():
        g, vol = element_geometry(nodes_m, gel.tets)
        return unit_stiffness(g, vol), topo.scatter_boundary(topo.boundary_values(nodes_m, weights, np.full(16, 1e-3)))

    t_geom, (uk, bnd) = median_time(geometry, r)
    sigma = np.ones(gel.n_tets)
    t_asm, A = median_time(lambda: topo.assemble(sigma, uk, bnd), r)
    t_fact, solver = median_time(lambda: SymmetricSolver(A), r)
    t_refac, _ = median_time(lambda: solver.refactor(A), r)
    rhs = np.zeros((topo.ndof, 16))
    rhs[topo.electrode_dofs] = np.eye(16) - 1 / 16
    t_solve, _ = median_time(lambda: solver.solve(rhs), r)

    t_total, model = median_time(lambda: ForwardModel(mesh), r)
    t_cond, _ = median_time(lambda: model.with_conductivity(sigma * 1.1), r)
    t_nodes, _ = median_time(lambda: model.with_nodes(mesh.nodes_mm * 1.001), r)
    t_jac, J = median_time(model.jacobian, r)
    t_pixm, F = median_time(lambda: model.pixel_matrix(48), r)
    t_pixj, _ = median_time(lambda: model.pixel_jacobian(48), max(1, r // 2))
    point = ForwardModel(mesh, electrode_mode="point", current_A=1.0)
    t_point, _ = median_time(lambda: ForwardModel(mesh, electrode_mode="point", current_A=1.0), r)
    t_point_jac, _ = median_time(point.jacobian, r)

    # scikit-fem assembly of the same stiffness matrix, for comparison with the numpy kernel.
    from skfem import Basis, ElementTetP1, MeshTet
    from skfem.models.poisson import laplace

    def skfem_assembly():
        basis = Basis(MeshTet(nodes_m.T.copy(), gel.tets.T.copy()), ElementTetP1())
        return laplace.assemble(basis)

    t_skfem, _ = median_time(skfem_assembly, max(1, r // 2))

    # pyEIT on the same tets (point electrodes at our electrode nodes).
    from pyeit.eit import protocol as pyeit_protocol
    from pyeit.eit.fem import EITForward
    from pyeit.mesh import PyEITMesh

    ref = int(np.setdiff1d(np.arange(gel.n_nodes), point.point_nodes)[0])
    pm = PyEITMesh(node=nodes_m, element=gel.tets[:, [0, 2, 1, 3]], perm=1.0, el_pos=point.point_nodes,
                   ref_node=ref)
    prot = pyeit_protocol.create(16, 1, 1, "std")
    t = time.perf_counter()
    fwd = EITForward(pm, prot)
    t_py_setup = time.perf_counter() - t
    t_py_solve, v = median_time(lambda: fwd.solve_eit(perm=sigma), max(1, r // 2))
    agree = np.max(np.abs(v - point.voltages)) / np.max(np.abs(v))
    t_py_jac = float("nan")
    if not ARGS.skip_pyeit_jacobian:
        t = time.perf_counter()
        jac, _ = fwd.compute_jac(perm=sigma)
        t_py_jac = time.perf_counter() - t
        jac_agree = np.linalg.norm(point.jacobian() + jac) / np.linalg.norm(jac)
    py_forward = t_py_setup + t_py_solve

    print(f"latticeopt forward benchmark: default design (w = 4, t = 3), mesh {settings}")
    print(f"hydrogel: {gel.n_nodes} nodes, {gel.n_tets} tets; system {topo.ndof} dof, {topo.nnz} nnz; "
          f"BLAS/MKL threads {ARGS.threads}; solver {solver.backend}; median of {r}")
    print(f"process warm-up (first model, loads MKL): {warm:.3f} s\n")
    rows = [
        ("restrict to hydrogel", t_restrict),
        ("pattern + scatter maps (new topology)", t_topo),
        ("geometry: P1 gradients, volumes, contact terms", t_geom),
        ("assembly (numpy scatter)", t_asm),
        ("factorization, first (symbolic + numeric)", t_fact),
        ("  refactorization (numeric only)", t_refac),
        ("16 solves (all drives and adjoints)", t_solve),
        ("ForwardModel(mesh): all 208 measurements", t_total),
        ("  .with_conductivity(sigma)", t_cond),
        ("  .with_nodes(deformed)", t_nodes),
        (f"  .jacobian() (208 x {gel.n_tets})", t_jac),
        ("  .pixel_matrix(48) (exact overlaps)", t_pixm),
        ("  .pixel_jacobian(48)", t_pixj),
        ("ForwardModel point mode", t_point),
        ("  point-mode .jacobian()", t_point_jac),
        ("scikit-fem assembly of the same stiffness (basis + laplace)", t_skfem),
        ("pyEIT EITForward(mesh, protocol) setup", t_py_setup),
        ("pyEIT solve_eit (16 drives)", t_py_solve),
        ("pyEIT compute_jac", t_py_jac),
    ]
    for name, sec in rows:
        print(f"  {name:<62s} {sec:9.4f} s")
    print()
    ours_jac = t_total + t_jac
    print(f"forward:  pyEIT setup + solve_eit {py_forward:.3f} s / ForwardModel {t_total:.3f} s = "
          f"{py_forward / t_total:.1f}x   (target >= 5x)")
    print(f"          pyEIT solve_eit alone {t_py_solve:.3f} s / ForwardModel {t_total:.3f} s = "
          f"{t_py_solve / t_total:.1f}x")
    core = t_asm + t_fact + t_solve
    print(f"          pyEIT solve_eit (assemble + 16 solves) {t_py_solve:.3f} s / our assemble + factorize + "
          f"16 solves {core:.3f} s = {t_py_solve / core:.1f}x")
    print(f"          pyEIT solve_eit(new perm) {t_py_solve:.3f} s / with_conductivity {t_cond:.3f} s = "
          f"{t_py_solve / t_cond:.1f}x")
    if not ARGS.skip_pyeit_jacobian:
        print(f"jacobian: pyEIT compute_jac {t_py_jac:.3f} s / (ForwardModel + jacobian) {ours_jac:.3f} s = "
              f"{t_py_jac / ours_jac:.1f}x   (target >= 20x)")
        print(f"          point-mode Jacobian agrees with -pyEIT's to {jac_agree:.1e}")
    print(f"208 measurements in {t_total:.3f} s on {ARGS.threads} thread(s) (target < 0.5 s on one core)")
    print(f"numpy assembly {t_asm + t_geom:.4f} s vs scikit-fem {t_skfem:.4f} s = {t_skfem / (t_asm + t_geom):.1f}x")
    print(f"point-mode voltages agree with pyEIT's to {agree:.1e} (relative)")
    print(f"dataset rate with_conductivity: {1 / t_cond:.1f} samples/s; pyEIT solve_eit: {1 / t_py_solve:.2f}/s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
