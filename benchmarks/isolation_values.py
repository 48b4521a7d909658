"""The isolation measure of density layouts (``DensityModel.isolation``): a table for docs/gradients.md.

    python benchmarks/isolation_values.py                                   # parametric layouts, default mesh
    python benchmarks/isolation_values.py runs/optimize_freeform/state.json runs/optimize_freeform_iso/state.json

Per layout (t = 3 mm, 50 x 50 cells, 2 mm mesh as in studies/optimize_freeform.toml unless changed): the pieces
of its thresholded outline that hold electrodes; the measure the bound uses (8-norm over the 120 electrode pairs of
the two-terminal resistance relative to the uniform layer's, on the network of the cells), its worst pair's ratio
and electrodes; the same 8-norm with the finite-element electrics' pair resistances (which conduct across cell
corners); and the 8-norm over the 208 adjacent measurement rows of ``Vref / Vuniform`` that the first bound used.
A free-form run's ``state.json`` is read at its last iterate, projected at the last stage's sharpness (the run's
``density.npz``), at the sharpness the bound reads there (``isolation_sharpening`` times it), and so sharpened and
eroded to ``isolation_threshold`` (what the bound reads). About a second per
layout after a 10 s set-up on a loaded machine (the network alone: 0.03 s).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from latticeopt import LatticeDesign, MeshSettings
from latticeopt.density import DensityModel, density_of_design, load_density
from latticeopt.density.outline import density_outline
from latticeopt.density.projection import FreeForm
from latticeopt.optimize.freeform import FreeformConfig


def row_measure(model: DensityModel, density: np.ndarray, p: float = 8.0) -> float:
    """The first bound's measure: 8-norm over the measurement rows of ``Vref / Vuniform``."""
    _, (_, _, sigma), _ = model.materials(density)
    q = model.electrics.with_conductivity(sigma).voltages / model.electrics.voltages
    return float(np.mean(np.abs(q) ** p) ** (1.0 / p))


def fe_pair_measure(model: DensityModel, density: np.ndarray, p: float = 8.0) -> float:
    """The pair measure with the finite-element electrics' resistances."""
    _, (_, _, sigma), _ = model.materials(density)
    q = model.electrics.with_conductivity(sigma).pair_resistances / model.electrics.pair_resistances
    return float(np.mean(q ** p) ** (1.0 / p))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("layouts", nargs="*", help="density .npz files or free-form state.json files (cells must match "
                    "--cells)")
    ap.add_argument("--size", type=float, default=2.0, help="mesh size (mm)")
    ap.add_argument("--cells", type=int, default=50)
    ap.add_argument("--thickness", type=float, default=3.0)
    args = ap.parse_args()
    design = LatticeDesign(thickness_mm=args.thickness)
    t0 = time.perf_counter()
    model = DensityModel(design, args.cells, MeshSettings(size_mm=args.size))
    print(f"model set-up {time.perf_counter() - t0:.1f} s, {model.mesh.n_nodes} nodes")
    layouts = {f"square w = {w:g}": density_of_design(LatticeDesign(width_mm=w, thickness_mm=args.thickness),
                                                       args.cells) for w in (1.0, 2.0, 4.0, 8.0)}
    layouts["uniform layer"] = np.ones((args.cells, args.cells))
    for path in args.layouts:
        if Path(path).suffix != ".json":
            layouts[path] = load_density(path)
            continue
        state = json.loads(Path(path).read_text())
        fields = {f.name for f in dataclasses.fields(FreeformConfig)}
        cfg = FreeformConfig(**{k: v for k, v in state["identity"]["config"].items() if k in fields})
        ff = FreeForm(design, cfg.cells, cfg.symmetry, cfg.min_feature_mm, cfg.pad_mm)
        x, last, sharp = np.asarray(state["x"]), cfg.betas[-1], cfg.isolation_sharpness(cfg.betas[-1])
        layouts[f"{path} eroded to {cfg.isolation_threshold:g} at beta {sharp:g}"] = dataclasses.replace(
            ff, eta=cfg.isolation_threshold).density(x, sharp)
        for beta in (last, sharp):
            layouts[f"{path} at beta {beta:g}"] = ff.density(x, beta)
    pairs = np.transpose(np.triu_indices(design.n_electrodes, 1)) + 1
    print("| layout | gel fraction | pieces (with electrodes) | isolation | worst pair ratio (electrodes) "
          "| finite-element pairs | rows | seconds |")
    print("|---|---|---|---|---|---|---|---|")
    for name, d in layouts.items():
        t = time.perf_counter()
        value, _ = model.isolation(d)
        q = model.network.pair_resistances(d) / model.network.uniform_resistances
        k = int(np.argmax(q))
        _, report = density_outline(design, d, 0.5, 0.5)
        print(f"| {name} | {d.mean():.3f} | {report['pieces']} | {value:.3g} | {q[k]:.3g} ({pairs[k][0]}, "
              f"{pairs[k][1]}) | {fe_pair_measure(model, d):.3g} | {row_measure(model, d):.3g} "
              f"| {time.perf_counter() - t:.1f} |", flush=True)


if __name__ == "__main__":
    main()
