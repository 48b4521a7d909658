"""How smooth is the objective along a line in one design variable, on the structured (grid) mesher?

    python benchmarks/line_scan.py studies/optimize_square.toml --var width_mm --from 2 --to 6 --n 33 --jobs 2
    python benchmarks/line_scan.py studies/optimize_square.toml --model proxy      # electrics-only proxy

Evaluates mean V_rel over the study's fixed phantoms at ``n`` equally spaced values of ``--var`` (the other
variables at their start values), once per grid cell-count rule (``MeshSettings.cell_counts``: ``"size"``, the
default, splits every interval into ``ceil(length / size)`` cells so node counts jump as ``w`` moves; ``"fixed"``
keeps them constant), through the results store (re-runs are read back, not recomputed). Prints one row per
point (node count and mean V_rel per rule) and, per rule, the smoothness:

``roughness = max |V[i-1] - 2 V[i] + V[i+1]| / (max V - min V)``: the largest second difference relative to
the range. A smooth curve sampled at spacing ``h`` gives second differences ``h^2 |V''|``, shrinking like
``1 / n^2``; a jump ``J`` in V gives a second difference of about ``J`` whatever ``n``. So a roughness that
does not fall when ``--n`` grows, or a spike where the node count changes, is mesh noise a local optimizer
would trip over.

Models: ``--model study`` (default) is the study's model (``latticeopt.coupled:evaluate_phantom``);
``--model direct`` is :func:`direct_coupled_evaluate` below (mechanics then electrics with the library defaults,
composed here for use before ``latticeopt.coupled`` exists); ``--model proxy`` is :func:`electrics_proxy_evaluate`
(no mechanics; seconds instead of minutes); ``--model MODULE:FUNCTION`` any other.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import importlib
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))


def electrics_proxy_evaluate(design, phantom, settings) -> dict:
    """A mesh-sensitive stand-in for the coupled model, for smoothness checks only (not the touch physics).

    The undeformed mesh; the touch lowers the hydrogel conductivity smoothly,
    ``sigma = 1 - sum_k 0.5 (d_k / H) exp(-|x - c_k|^2 / r_k^2)`` at every tet centroid; V_rel between that and
    the uniform gel (paper eq. 5). A smooth function of the node positions, so any roughness along a line is the
    mesh's (cell counts), not the model's.
    """
    from latticeopt.electrics import ForwardModel
    from latticeopt.mesh import mesh_design

    mesh = mesh_design(design, settings.mesh, cache_dir=settings.cache_dir)
    ref = ForwardModel(mesh)
    c = ref.mesh.nodes_mm[ref.mesh.tets].mean(axis=1)
    factor = np.ones(len(c))
    for t in phantom.touches:
        r2 = (c[:, 0] - t.x_mm) ** 2 + (c[:, 1] - t.y_mm) ** 2
        factor -= 0.5 * t.depth_mm / design.total_thickness_mm * np.exp(-r2 / t.radius_mm ** 2)
    touched = ref.with_conductivity(ref.sigma * factor)
    v_ref, v_t = ref.voltages, touched.voltages
    return {"v_rel": float(np.mean(np.abs(v_t - v_ref) / np.abs(v_ref))), "voltages": v_t,
            "n_gel_nodes": int(ref.mesh.n_nodes)}


def direct_coupled_evaluate(design, phantom, settings) -> dict:
    """Indentation (:func:`latticeopt.mechanics.indent`) then the electrics on the deformed hydrogel
    (:class:`latticeopt.electrics.ForwardModel`); V_rel against the untouched design.

    Library defaults throughout except ``[physics] indenter`` (``"flat"`` or ``"sphere"``). A stand-in for
    ``latticeopt.coupled`` in this benchmark only.
    """
    from latticeopt.electrics import ForwardModel
    from latticeopt.mechanics import indent
    from latticeopt.mechanics.indent import IndentSettings
    from latticeopt.mesh import mesh_design

    mesh = mesh_design(design, settings.mesh, cache_dir=settings.cache_dir)
    ref = ForwardModel(mesh)
    res = indent(mesh, phantom.touches, IndentSettings(indenter=settings.physics.get("indenter", "flat")))
    touched = ref.with_nodes(res.deformed_mesh.nodes_mm)
    return {"v_rel": float(np.mean(np.abs(touched.voltages - ref.voltages) / np.abs(ref.voltages))),
            "voltages": touched.voltages, "forces_N": list(res.forces_N)}


def roughness(v: np.ndarray) -> tuple[float, int]:
    """``max |second difference| / range`` and the index of the largest one (NaN, -1 for < 3 finite points)."""
    if len(v) < 3 or not np.all(np.isfinite(v)):
        return math.nan, -1
    d2 = np.abs(v[:-2] - 2 * v[1:-1] + v[2:])
    span = float(np.max(v) - np.min(v))
    return (float(d2.max() / span) if span > 0 else 0.0), int(np.argmax(d2)) + 1


def _model(name: str, settings_model: str):
    if name in ("proxy", "direct"):
        mod = importlib.import_module("line_scan")
        return mod.electrics_proxy_evaluate if name == "proxy" else mod.direct_coupled_evaluate
    if name == "study":
        name = settings_model
    from latticeopt.study.sweep import resolve_model

    return resolve_model(name)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("study", help="an optimization study (studies/optimize_square.toml)")
    p.add_argument("--var", default="width_mm")
    p.add_argument("--from", dest="lo", type=float, default=2.0)
    p.add_argument("--to", dest="hi", type=float, default=6.0)
    p.add_argument("--n", type=int, default=17)
    p.add_argument("--modes", nargs="+", default=["size", "fixed"], choices=["size", "fixed"])
    p.add_argument("--model", default="study", help="'study', 'direct', 'proxy' or MODULE:FUNCTION")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE")
    p.add_argument("--jobs", type=int, default=1)
    p.add_argument("--out", default="runs/line_scan", help="results store folder")
    p.add_argument("--csv", default=None, help="write the table here")
    p.add_argument("--plot", default=None, help="write a PNG of V_rel against the variable here")
    args = p.parse_args(argv)

    from latticeopt.mesh.grid import grid_coordinates
    from latticeopt.optimize import load_optimization
    from latticeopt.study.sweep import evaluate_designs

    opt = load_optimization(args.study, args.overrides)
    study = opt.study
    evaluate = _model(args.model, study.settings.model)
    xs = np.round(np.linspace(args.lo, args.hi, args.n), 6)
    designs = [study.designs[0].replace(**{args.var: float(x)}) for x in xs]
    table = {"x": xs}
    print(f"{study.name}: {args.var} from {args.lo:g} to {args.hi:g} ({args.n} points), {len(study.phantoms)} "
          f"phantoms, model {evaluate.__module__}:{evaluate.__qualname__}, mesh {study.settings.mesh.as_dict()}")
    for mode in args.modes:
        mesh = dataclasses.replace(study.settings.mesh, cell_counts=mode)
        settings = dataclasses.replace(study.settings, mesh=mesh,
                                       model=f"{evaluate.__module__}:{evaluate.__qualname__}")
        t0 = time.perf_counter()
        evs, computed = evaluate_designs(designs, study.phantoms, settings, args.out, evaluate, jobs=args.jobs,
                                         progress=True, label=f"line scan ({mode})")
        n = len(study.phantoms)
        table[f"v_{mode}"] = np.array([np.mean([e.v_rel for e in evs[i * n:(i + 1) * n] if e.ok] or [np.nan])
                                       for i in range(len(designs))])
        table[f"nodes_{mode}"] = np.array([math.prod(len(c) for c in grid_coordinates(
            d, mesh.size_mm, mesh.resolved(d).channel_cells, mesh.layer_cells, mode)) for d in designs])
        print(f"  {mode}: {computed} phantoms computed in {time.perf_counter() - t0:.1f} s")
    header = f"{args.var:>10}" + "".join(f" {'nodes_' + m:>12} {'V_rel_' + m:>12}" for m in args.modes)
    print(header)
    for i, x in enumerate(xs):
        print(f"{x:10.4f}" + "".join(f" {table['nodes_' + m][i]:12d} {table['v_' + m][i]:12.6g}" for m in args.modes))
    for m in args.modes:
        r, at = roughness(table[f"v_{m}"])
        changes = int(np.sum(np.diff(table[f"nodes_{m}"]) != 0))
        where = f" (largest at {args.var} = {xs[at]:g})" if at >= 0 else ""
        print(f"{m:>6}: roughness max|d2V|/range = {r:.4f}{where}; node count changes {changes} times; "
              f"V_rel range {np.nanmin(table[f'v_{m}']):.6g} .. {np.nanmax(table[f'v_{m}']):.6g}")
    if args.csv:
        with open(args.csv, "w", newline="") as fh:
            w = csv.writer(fh)
            keys = list(table)
            w.writerow(keys)
            w.writerows(zip(*(table[k] for k in keys)))
    if args.plot:
        from matplotlib.figure import Figure

        fig = Figure(figsize=(6.4, 4.2), layout="constrained")
        ax = fig.add_subplot()
        for m in args.modes:
            ax.plot(xs, table[f"v_{m}"], "o-", ms=3, label=f"cell_counts = {m!r}")
        ax.set_xlabel(args.var.replace("_mm", " (mm)"))
        ax.set_ylabel(f"mean $V_{{rel}}$ ({len(study.phantoms)} phantoms)")
        ax.grid(alpha=0.3)
        ax.legend()
        fig.savefig(args.plot, dpi=130)
        print(f"wrote {args.plot}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
