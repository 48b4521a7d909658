"""A linear press as the two-level map's coarse level: cheaper, but does it follow the fine level?

The coarse pass (every phantom of every design on the coarse level) is a third of the paper map's time, and the
coarse level's nonlinear solve (load steps, Newton, 2 factorizations and about 60 back-substitutions per press)
nearly all of it. A linear press costs one factorization: the stack's undeformed tangent (the same operator, so
the same mean-dilatation patches and materials), the punch's displacement prescribed at full depth, one solve,
then the electrics on the fine mesh as the coarse level does. This reads, from a finished paper map's store, the
fine (F) and coarse (C) V_rel of every phantom that ran fine for each design, presses them linearly on the coarse
level's mesh (L) and prints the share of var(F) left in the corrections (pooled within touch counts):
``r = var(F - C) / var(F)`` against ``var(F - L) / var(F)`` and, with a fitted coefficient,
``var(F - beta L) / var(F)``; the fine count a design needs for an SE of 1.1 x the plain one grows with r (about
``300 r / (0.21 + r)``). A linear displacement that folds the hydrogel has no V_rel: counted as failed.

    python benchmarks/linear_coarse.py runs/paper_fig4_takeall --designs 4,3 2,1 0,3 6,3 4,1
"""

from __future__ import annotations

import argparse
import os
import sqlite3
import sys
import time
from pathlib import Path

for _v in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import numpy as np  # noqa: E402
from middle_level import STUDY, _pairs, paper_designs, sweep_store  # noqa: E402  (this folder's neighbour)


def _linear_press(solver, touches) -> np.ndarray:
    """Displacement (N, 3) mm of the linear press: the undeformed tangent with the punch at full depth."""
    from latticeopt.mechanics.indenters import Constraints, conform_punch_edges

    s = solver.settings
    solver._clock = {"assembly": 0.0, "factorization": 0.0, "solve": 0.0, "krylov": 0.0}
    solver._n_krylov = solver._n_shifted = solver._n_solves = solver._n_factor = 0
    ref, ev = solver.mesh.nodes_mm, solver._ev0
    if s.indenter == "flat" and s.punch_edge == "conforming":  # the rim the nonlinear press conforms too
        ref = conform_punch_edges(ref, solver.mesh.tets, solver.mesh.facets["top"], solver._movable, touches)
        if np.any(ref != solver.mesh.nodes_mm):
            ev = solver.op.with_reference(ref).evaluate(np.zeros_like(ref))
    cons = Constraints(ref, solver.top_nodes, solver.bottom_nodes, touches, s.indenter, s.in_plane)
    D, vals = cons.dirichlet(1.0)
    isD = np.zeros(solver.op.n_dofs, dtype=bool)
    isD[D] = True
    return solver._linear_solve(ev, isD, D, vals, np.zeros(solver.op.n_dofs)).reshape(-1, 3)


def _pooled_ratio(x: np.ndarray, f: np.ndarray, strata: np.ndarray) -> float:
    num = sum(np.var(x[strata == k]) * np.sum(strata == k) for k in np.unique(strata))
    den = sum(np.var(f[strata == k]) * np.sum(strata == k) for k in np.unique(strata))
    return float(num / den)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path, help="a finished two-level paper map's folder (holding results.sqlite)")
    ap.add_argument("--designs", nargs="+", default=["4,3", "2,1", "0,3", "6,3", "4,1"], help="W,T pairs (mm)")
    args = ap.parse_args(argv)
    store = sweep_store("linear_coarse", args.folder)
    if store is None:
        return 2
    from latticeopt.coupled import CoupledModel
    from latticeopt.errors import MeshError
    from latticeopt.metric import relative_change
    from latticeopt.study.config import load_study
    from latticeopt.study.settings import coarse_level_settings

    study = load_study(STUDY, ["multilevel.pilot=15"])
    fine = study.settings
    coarse = coarse_level_settings(fine, study.multilevel)
    designs = paper_designs("linear_coarse", study, args.designs)
    if designs is None:
        return 2
    by_key = {p.key: p for p in study.phantoms}
    con = sqlite3.connect(f"file:{store}?mode=ro", uri=True)
    print("| design | fine phantoms | linear folded | r coarse | r linear | r linear, fitted beta | beta | "
          "linear s per press | mean F | mean C | mean L |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for design in designs:
        f, c = _pairs(con, fine.key, design.content_hash()), _pairs(con, coarse.key, design.content_hash())
        keys = sorted(k for k in f if k in c)
        if len(keys) < 6:
            print(f"linear_coarse: {design.width_mm:g},{design.thickness_mm:g}: fewer than 6 fine phantoms in {store}",
                  file=sys.stderr)
            return 2
        model = CoupledModel(design, fine.mesh, coarse.physics_settings, fine.cache_dir, coarse.mechanics_mesh)
        lin, seconds, folded = {}, [], 0
        for k in keys:
            t0 = time.process_time()
            u = _linear_press(model.mechanics, list(by_key[k].touches))
            nodes = model.mesh.nodes_mm.copy()
            nodes[model.reference.node_ids] += model._transfer @ u
            try:
                volts = model._electrics.voltages(nodes)
                lin[k] = relative_change(volts, model.reference_voltages, model.physics.measurement_floor_rel)
            except MeshError:
                folded += 1
            seconds.append(time.process_time() - t0)
        ok = [k for k in keys if k in lin]
        F, C, L = (np.array([d[k] for k in ok]) for d in (f, c, lin))
        strata = np.array([by_key[k].n_touches for k in ok])
        beta = float(np.cov(F, L)[0, 1] / np.var(L, ddof=1))
        print(f"| w = {design.width_mm:g}, t = {design.thickness_mm:g} | {len(keys)} | {folded} | "
              f"{_pooled_ratio(F - C, F, strata):.3f} | {_pooled_ratio(F - L, F, strata):.3f} | "
              f"{_pooled_ratio(F - beta * L, F, strata):.3f} | {beta:.2f} | {np.mean(seconds):.3f} | "
              f"{F.mean():.4f} | {C.mean():.4f} | {L.mean():.4f} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
