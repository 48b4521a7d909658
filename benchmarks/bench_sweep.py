"""Seconds per coupled phantom, and the wall time and precision of the paper map with the plain and the two-level
estimator on this machine.

    python benchmarks/bench_sweep.py [--size 2.0] [--channel-cells 2] [--phantoms 6] [--workers 1 2]
                                     [--designs 4,3 0,1 6,1 0,5 6,5 | --designs paper]
                                     [--estimators plain multilevel] [--coarse 4:1] [--coarse-electrics fine]
                                     [--se-factor 1.1] [--pilot 15] [--target-h 2]

For each design (width,thickness in mm; default: the default design only; ``paper``: all 30 designs of
studies/paper_fig4.toml, the honest figure for the map) it times the first ``--phantoms`` phantoms of
paper_fig4.toml's set, touch counts 1, 2, 3 in turn, on two levels: the fine mesh (paper_fig4.toml's, the
converged one; ``--size`` and ``--channel-cells`` override it) and, for ``multilevel``, the coarse level: the
mechanics on the mesh ``--coarse SIZE:CELLS`` (the fine settings with grid size and channel cells replaced;
default 4 mm and 1 cell) with the coarse physics (``mechanics_rtol = 1e-2``), as a sweep's ``[multilevel]``, and
the electrics on the fine mesh, or with ``--coarse-electrics coarse`` on the coarse one. The nodes column gives
the mechanics mesh. Each level runs with one worker and then with two processes (one BLAS thread each). A table
row per design, level and worker count gives set-up (mesh read, mechanics operator, reference electrics),
mechanics and electrics seconds, and per phantom the operation counts the time follows: Newton increments (linear
solves), factorizations (shifted retries included) and Krylov iterations (one back-substitution each). The
machine's load moves the seconds; the counts are stable.

Precision (latticeopt.study.multilevel): from the phantoms solved on both levels, per touch count var(F) and
var(D = F - C); the plain SE of a design's mean over the map's 300 phantoms (sqrt(var(F) / N), stratified); the
fine count n a two-level run needs for SE <= ``--se-factor`` x that (``predicted_fine_count``, raised to the
sweep's ``--pilot``); the two-level SE at that n; the coarse/fine correlation. These extrapolate to 300 phantoms
from the few measured: with 2 per touch count the variances have one degree of freedom each.

Map wall time (30 designs x 300 phantoms), per worker count, from the throughput -- mean seconds per phantom /
workers, measured while all workers run: plain = 300 fine phantoms + one fine set-up per design; two-level = 300
coarse + n fine phantoms + both set-ups per design. The best worker count is reported against ``--target-h``.
Designs not measured take the mean cost of the measured ones; the cost depends on the design (a narrow channel
or gap adds grid lines across the whole sensor), so time ``--designs paper`` for an honest figure. A phantom
whose mechanics fails counts as failed, its time still counted, and has no pair. Run it on a quiet machine: it
prints the load average before and after.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

from latticeopt import LatticeDesign  # noqa: E402
from latticeopt.coupled import model_for_settings  # noqa: E402
from latticeopt.errors import (  # noqa: E402
    ConvergenceError,
    MeshError,
    ParameterError,  # noqa: E402
)
from latticeopt.mesh import mesh_design  # noqa: E402
from latticeopt.study.config import load_study  # noqa: E402
from latticeopt.study.multilevel import predicted_fine_count  # noqa: E402
from latticeopt.study.settings import (  # noqa: E402
    COARSE_ELECTRICS,
    EvalSettings,
    MultilevelSettings,
    coarse_level_settings,
)

ROOT = Path(__file__).resolve().parent.parent
CACHE = ROOT / "meshes"
# columns of a phantom's row; NaN but the seconds when its mechanics fails
MECH, ELEC, VREL, NEWTON, FACTOR, KRYLOV, SECONDS = range(7)


def _bench_order(strata: np.ndarray) -> np.ndarray:
    """Study positions in benchmark order: the j-th phantom of every touch count, touch counts in turn."""
    rank = np.empty(strata.size, dtype=int)
    for k in np.unique(strata):
        rank[strata == k] = np.arange(np.sum(strata == k))
    return np.lexsort((strata, rank))


def _run(args):
    (w, t), level, chunk = args
    t0 = time.perf_counter()
    model = model_for_settings(LatticeDesign(width_mm=w, thickness_mm=t), level)
    setup = time.perf_counter() - t0
    rows = {}
    for i, ph in chunk:
        t1 = time.perf_counter()
        try:
            res = model.simulate(ph.touches)
        except (ConvergenceError, MeshError):  # counted, and its time still counts (a sweep spends it too)
            rows[i] = (np.nan,) * SECONDS + (time.perf_counter() - t1,)
            continue
        ops = res.indentation.solver
        rows[i] = (res.timings["mechanics"], res.timings["electrics"], res.v_rel, res.newton_steps,
                   ops["n_factorizations"], ops["krylov_iterations"], time.perf_counter() - t1)
    return setup, rows, model.mechanics_mesh.n_nodes


def _measure(design, level: EvalSettings, phantoms, workers: int) -> dict:
    """Run ``phantoms`` with ``level``'s meshes and physics, split over ``workers`` processes; rows in order."""
    indexed = list(enumerate(phantoms))
    with ProcessPoolExecutor(workers) as ex:
        out = list(ex.map(_run, [(design, level, indexed[i::workers]) for i in range(workers)]))
    rows = {i: r for _, rr, _ in out for i, r in rr.items()}
    table = np.array([rows[i] for i in range(len(phantoms))])
    return {"setup": float(np.mean([s for s, _, _ in out])), "rows": table, "nodes": out[0][2],
            "rate": float(table[:, SECONDS].mean()) / workers}  # throughput: s / phantom with all workers busy


def _print_row(design, level: str, workers: int, m: dict) -> None:
    r = m["rows"]
    ok = r[np.isfinite(r[:, VREL])]
    mean = ok.mean(axis=0) if len(ok) else np.full(r.shape[1], np.nan)
    print(f"| {design[0]:g},{design[1]:g} | {level} | {m['nodes']} | {workers} | {m['setup']:.2f} | "
          f"{mean[MECH]:.2f} | {mean[NEWTON]:.1f} | {mean[FACTOR]:.1f} | {mean[KRYLOV]:.0f} | {mean[ELEC]:.3f} | "
          f"{r[:, SECONDS].mean():.2f} | {m['rate']:.2f} | {len(r) - len(ok)} |", flush=True)


def _precision(fine, coarse, at, map_strata, se_factor: float, pilot: int) -> dict:
    """Plain and two-level precision of one design's mean over the map's phantoms, from the measured phantoms.

    ``fine``, ``coarse``: V_rel of the measured phantoms (``coarse`` None without the coarse level), at study
    positions ``at``. Returns the per-touch-count variances, the plain SE over all map phantoms and, with
    ``coarse``, the fine count ``n`` for the two-level SE <= ``se_factor`` x plain, that SE and corr(C, F).
    """
    n_map = map_strata.size
    labels, sizes = np.unique(map_strata, return_counts=True)
    weights = sizes / n_map
    touches = map_strata[at]
    ok = np.isfinite(fine) & (np.isfinite(coarse) if coarse is not None else True)

    def per_stratum(x):
        return np.array([np.var(x[ok & (touches == k)], ddof=1) if np.sum(ok & (touches == k)) > 1 else np.nan
                         for k in labels])

    var_f = per_stratum(fine)
    plain = math.sqrt(float(weights @ var_f) / n_map)  # proportional strata: sum w^2 var / (w N)
    out = {"pairs": int(ok.sum()), "var_f": var_f, "plain_se": plain}
    if coarse is None:
        return out
    var_d = per_stratum(fine - coarse)
    # the measured phantoms at their own positions among the map's N; the other phantoms' coarse values only
    # enter the coarse mean, which the count does not use, so 0 stands in for them
    c_map, f_map = np.zeros(n_map), np.full(n_map, np.nan)
    c_map[at[ok]], f_map[at[ok]] = coarse[ok], fine[ok]
    try:
        n_pred = predicted_fine_count(c_map, f_map, map_strata, se_factor=se_factor)
    except ValueError:  # fewer than two pairs in some touch count: assume every phantom fine
        n_pred = float(n_map)
    n = min(n_map, max(pilot, math.ceil(n_pred)))
    # Var = var_plain + B (1 / n - 1 / N) with B = sum_k w_k var_k(D) (multilevel.py, proportional allocation)
    se = math.sqrt(plain ** 2 + float(weights @ var_d) * (1.0 / n - 1.0 / n_map))
    corr = float(np.corrcoef(coarse[ok], fine[ok])[0, 1]) if ok.sum() > 1 else np.nan
    return {**out, "var_d": var_d, "n_pred": n_pred, "n": n, "se": se, "corr": corr}


def _design(text: str) -> tuple[float, float] | str:
    if text == "paper":
        return text
    try:
        w, t = (float(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"--designs: expected WIDTH,THICKNESS in mm or 'paper', got {text!r}") from None
    return w, t


def _coarse(text: str) -> tuple[float, int]:
    try:
        size, cells = text.split(":")
        return float(size), int(cells)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--coarse: expected SIZE_MM:CHANNEL_CELLS, got {text!r}") from None


def _vars(v) -> str:
    return "/".join(f"{x:.2g}" for x in v)


def _report_map(a, meas, prec, n_map: int, n_designs: int) -> None:
    """Map hours per estimator at its best worker count, precision, ratio, target."""
    def hours(est, k):
        cost = []
        for d in a.designs:
            f = meas[d]["fine"][k]
            if est == "plain":
                cost.append(n_map * f["rate"] + f["setup"] / k)
            else:  # set-ups run in parallel over the workers like the phantoms
                c = meas[d]["coarse"][k]
                cost.append(n_map * c["rate"] + prec[d]["n"] * f["rate"] + (c["setup"] + f["setup"]) / k)
        return n_designs * float(np.mean(cost)) / 3600  # the sum when every design was measured

    scope = ("every design measured" if set(a.paper_designs) <= set(a.designs) else
             f"mean cost of the {len(a.designs)} measured design(s), extrapolated to {n_designs}")
    print(f"\npaper map ({n_designs} designs x {n_map} phantoms), throughput measured with all workers busy, "
          f"{scope}; fine {a.fine.as_dict()}" + (f", coarse {a.coarse_mesh.as_dict()}" if "multilevel" in
                                                    a.estimators else ""))
    plain_se = [prec[d]["plain_se"] for d in a.designs]
    total = {}
    for est in a.estimators:
        best = min(a.workers, key=lambda k, e=est: hours(e, k))
        total[est] = h = hours(est, best)
        met = "met" if h <= a.target_h else "NOT met"
        if est == "plain":
            print(f"  plain:     {n_map} fine phantoms per design, {best} worker(s): {h:.2f} h (target {a.target_h:g} "
                  f"h: {met}); SE of a design's mean V_rel {min(plain_se):.3g}-{max(plain_se):.3g}")
        else:
            ns, ratio = [prec[d]["n"] for d in a.designs], [prec[d]["se"] / prec[d]["plain_se"] for d in a.designs]
            print(f"  two-level: {n_map} coarse + n fine per design (n {min(ns)}-{max(ns)}, mean {np.mean(ns):.0f}), "
                  f"{best} worker(s): {h:.2f} h (target {a.target_h:g} h: {met}); SE {min(ratio):.2f}-"
                  f"{max(ratio):.2f} x the plain SE (<= {a.se_factor:g} by construction; below it where the pilot "
                  f"raises n)")
    if len(total) == 2:
        print(f"  two-level / plain wall time: {total['multilevel'] / total['plain']:.2f}")
    tail = "; a sweep's adaptive steps (at least +25 %) can overshoot n" if "multilevel" in total else ""
    print(f"  SEs{' and n' if tail else ''} extrapolate from {a.phantoms} phantoms per design ({a.phantoms // 3}-"
          f"{-(-a.phantoms // 3)} per touch count; a variance needs 2): noisy{tail}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=float, default=None, help="grid size (mm; default: paper_fig4.toml's)")
    ap.add_argument("--channel-cells", type=int, default=None, help="default: paper_fig4.toml's")
    ap.add_argument("--phantoms", type=int, default=6)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--designs", type=_design, nargs="+", default=[(4.0, 3.0)],
                    help="WIDTH,THICKNESS pairs in mm (default: 4,3), or 'paper' for the 30 designs of paper_fig4.toml")
    ap.add_argument("--estimators", nargs="+", choices=["plain", "multilevel"], default=["plain", "multilevel"],
                    help="map times to report (multilevel runs the coarse level too); default both")
    ap.add_argument("--coarse", type=_coarse, default=(4.0, 1), help="coarse mesh SIZE_MM:CHANNEL_CELLS (4:1)")
    ap.add_argument("--coarse-electrics", choices=COARSE_ELECTRICS, default=MultilevelSettings().coarse_electrics,
                    help="the coarse level's electrics on the fine mesh (default, as a sweep) or the coarse one")
    ap.add_argument("--se-factor", type=float, default=MultilevelSettings().se_factor)
    ap.add_argument("--pilot", type=int, default=MultilevelSettings().pilot, help="least fine count per design")
    ap.add_argument("--target-h", type=float, default=2.0, help="map wall-time target (h)")
    a = ap.parse_args()
    paper = load_study(ROOT / "studies" / "paper_fig4.toml")
    a.paper_designs = [(d.width_mm, d.thickness_mm) for d in paper.designs]
    if "paper" in a.designs:
        a.designs = a.paper_designs
    mesh = paper.settings.mesh  # the converged mesh of the map
    # every value checked by the project's own settings before any meshing: one line, exit 2
    try:
        a.fine = dataclasses.replace(mesh, size_mm=mesh.size_mm if a.size is None else a.size,
                                     channel_cells=mesh.channel_cells if a.channel_cells is None else a.channel_cells)
    except ParameterError as exc:
        ap.error(f"--size / --channel-cells: {exc}")
    try:
        a.coarse_mesh = dataclasses.replace(a.fine, size_mm=a.coarse[0], channel_cells=a.coarse[1])
    except ParameterError as exc:
        ap.error(f"--coarse: {exc}")
    try:
        MultilevelSettings(pilot=a.pilot, se_factor=a.se_factor)
    except ParameterError as exc:
        ap.error(f"--{exc.name.replace('_', '-')}: {exc}")
    if not 0 < a.target_h < float("inf"):
        ap.error(f"--target-h: expected a positive number of hours, got {a.target_h}")
    if min(a.workers) < 1:
        ap.error(f"--workers: expected integers >= 1, got {a.workers}")
    two_level = "multilevel" in a.estimators
    map_strata = np.array([p.n_touches for p in paper.phantoms])
    if not (6 if two_level else 1) <= a.phantoms <= map_strata.size:  # two-level: var(D) needs 2 per touch count
        ap.error(f"--phantoms: {6 if two_level else 1} to {map_strata.size}")
    if two_level and a.coarse_mesh == a.fine:
        ap.error("--coarse: the coarse mesh must differ from the fine one")
    at = _bench_order(map_strata)[:a.phantoms]  # study positions of the benchmark phantoms
    phantoms = [paper.phantoms[i] for i in at]
    # each level's meshes and physics as a sweep has them (the coarse level's looser mechanics_rtol included)
    fine = EvalSettings(mesh=a.fine, cache_dir=str(CACHE))
    levels = {"fine": fine, **({"coarse": coarse_level_settings(fine, MultilevelSettings(
        coarse=a.coarse_mesh, coarse_electrics=a.coarse_electrics))} if two_level else {})}
    print(f"load average before: {os.getloadavg()[0]:.2f} ({os.cpu_count()} cores)")
    print(f"{a.phantoms} phantoms (1-3 touches) per design and level; " +
          "; ".join(f"{k} mesh {(s.mechanics_mesh or s.mesh).as_dict()}, physics {s.physics}"
                    for k, s in levels.items()) +
          (f"; coarse electrics on the {a.coarse_electrics} mesh" if two_level else ""))
    print("| design w,t mm | level | nodes | workers | set-up s | mechanics s / phantom | Newton increments | "
          "factorizations | Krylov iterations | electrics s | seconds / phantom | throughput s / phantom | failed |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    meas, prec = {}, {}
    for design in a.designs:
        meas[design] = {}
        for level, m in levels.items():
            # mesh once here, so the workers read the cache instead of meshing side by side
            for each in filter(None, (m.mesh, m.mechanics_mesh)):
                mesh_design(LatticeDesign(width_mm=design[0], thickness_mm=design[1]), each, cache_dir=CACHE)
            meas[design][level] = {k: _measure(design, m, phantoms, k) for k in a.workers}
            for k in a.workers:
                _print_row(design, level, k, meas[design][level][k])
        first = {lv: meas[design][lv][a.workers[0]]["rows"][:, VREL] for lv in levels}  # same for every k
        prec[design] = _precision(first["fine"], first.get("coarse"), at, map_strata, a.se_factor, a.pilot)
    print(f"\nprecision per design over the map's {map_strata.size} phantoms (variances per touch count 1/2/3 from "
          f"the measured pairs)")
    print("| design w,t mm | pairs | var(F) | var(D) | corr(C, F) | predicted n | n run | plain SE | two-level SE | "
          "ratio |\n|---|---|---|---|---|---|---|---|---|---|")
    for d in a.designs:
        p = prec[d]
        ml = (f"{_vars(p['var_d'])} | {p['corr']:.3f} | {p['n_pred']:.1f} | {p['n']} | {p['plain_se']:.3g} | "
              f"{p['se']:.3g} | {p['se'] / p['plain_se']:.2f}") if two_level else \
            f"- | - | - | - | {p['plain_se']:.3g} | - | -"
        print(f"| {d[0]:g},{d[1]:g} | {p['pairs']} | {_vars(p['var_f'])} | {ml} |")
    _report_map(a, meas, prec, map_strata.size, len(paper.designs))
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
