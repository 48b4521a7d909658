"""``latticeopt simulate --density``: a density layout's V_rel, force and stretch with their adjoint gradients;
``latticeopt export-density``: the density of any parametric or custom layout, to start from."""

from __future__ import annotations

import time
from pathlib import Path

from ..errors import ParameterError
from ._common import (
    add_design_args,
    check_mesh_args,
    check_output_path,
    design_from_args,
    emit_json,
    mesh_settings_from_args,
)
from ._physics import key_value_options


def _interpolation(args):
    import dataclasses

    from ..density import InterpolationLaw

    keys = [f.name for f in dataclasses.fields(InterpolationLaw)]
    values = key_value_options(args.interpolation, "--interpolation", keys)
    try:
        return InterpolationLaw.from_dict(values)
    except ParameterError as exc:
        raise ParameterError(f"--interpolation {exc.name}", exc.expected, exc.got) from None


def run_density(args) -> int:
    """``simulate --density``: every input checked before meshing (module docstring)."""
    from ..density import DensityModel, load_density, save_density
    from .simulate import simulate_inputs

    if args.density is None:
        raise ParameterError("--density", "a density file for --gradient, --interpolation and --plot", None)
    density = load_density(args.density)
    if args.gradient is not None:
        check_output_path("--gradient", args.gradient, suffixes=(".npz",))
    if args.plot is not None:
        if args.gradient is None:
            raise ParameterError("--plot", "--gradient too (the picture shows the gradient)", str(args.plot))
        check_output_path("--plot", args.plot, suffixes=(".png",))
    law = _interpolation(args)
    check_mesh_args(args)
    design, touches, physics = simulate_inputs(args)
    if physics.conductivity_law != "geometry":
        raise ParameterError("--physics conductivity_law", "'geometry' with --density", physics.conductivity_law)
    settings = mesh_settings_from_args(args)
    t0 = time.perf_counter()
    # the file's sharp edges are grid lines (a small change of the density keeps them: differences stay consistent)
    model = DensityModel(design, density.shape[0], settings, physics, law, sharp_from=density)
    ev = model.evaluate(density, [touches], gradient=args.gradient is not None)
    press = ev.presses[0]
    out = {"v_rel": ev.v_rel, "force_N": ev.force_N, "stretch": ev.stretch, "cells": density.shape[0],
           "hydrogel_fraction": float(density.mean()), "nodes": model.mesh.n_nodes,
           "newton_steps": press.newton_steps, "touches": [t.as_dict() for t in touches],
           "thickness_mm": design.thickness_mm, "mesh_size_mm": settings.size_mm, "physics": physics.as_dict(),
           "interpolation": law.__dict__.copy(), "setup_seconds": model.setup_seconds,
           "timings": press.timings, "seconds": time.perf_counter() - t0}
    if args.gradient is not None:
        save_density(args.gradient, density, dv_rel_ddensity=ev.dv_rel_ddensity, dforce_ddensity=ev.dforce_ddensity,
                     dstretch_ddensity=ev.dstretch_ddensity)
        out["gradient"] = str(args.gradient)
        if args.plot is not None:
            from ..density.plot import plot_sensitivity

            title = (f"density layout {Path(args.density).name} ({density.shape[0]}x{density.shape[0]} cells), "
                     f"t = {design.thickness_mm:g} mm, {settings.size_mm:g} mm mesh, one press "
                     f"({', '.join(f'{t.x_mm:g},{t.y_mm:g} r {t.radius_mm:g} d {t.depth_mm:g}' for t in touches)})")
            plot_sensitivity(density, ev.dv_rel_ddensity, args.plot, title, design.size_mm, touches)
            out["plot"] = str(args.plot)
    if args.json:
        emit_json(out)
        return 0
    print(f"density layout {args.density} ({density.shape[0]} x {density.shape[0]} cells, hydrogel fraction "
          f"{out['hydrogel_fraction']:.3f}), t = {design.thickness_mm:g} mm; mesh {model.mesh.n_nodes} nodes")
    print(f"V_rel = {ev.v_rel:.6g}, force {ev.force_N:.4g} N, gel stretch (p-norm) {ev.stretch:.4g}")
    if args.gradient is not None:
        print(f"gradients written to {args.gradient} (dv_rel_ddensity, dforce_ddensity, dstretch_ddensity)"
              + (f"; picture {args.plot}" if args.plot is not None else ""))
    print(f"{out['seconds']:.2f} s (set-up {model.setup_seconds:.2f} s, press {press.timings['total']:.2f} s)")
    return 0


def register(sub) -> None:
    p = sub.add_parser("export-density", help="write the density of a layout (a start for density layouts)",
                       description="Write the hydrogel density of a parametric or custom layout on n x n cells over "
                                   "the sensor square, in the format 'simulate --density' reads.")
    add_design_args(p)
    p.add_argument("--cells", type=int, default=50, help="cells per side, 4 to 400 (default 50)")
    p.add_argument("--smoothing-mm", type=float, default=0.0,
                   help="0 (default): each cell's exact hydrogel area fraction; > 0: a smoothed step of the signed "
                        "distance to the layout's outline over this length (mm)")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="FILE.npz", help="density file to write")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    p.set_defaults(func=run_export_density)


def run_export_density(args) -> int:
    from .. import _validate as v
    from ..density import density_of_design, save_density
    from ..density.field import MAX_CELLS, MIN_CELLS

    n = v.integer("--cells", args.cells, lo=MIN_CELLS, hi=MAX_CELLS)
    smoothing = v.real("--smoothing-mm", args.smoothing_mm, lo=0.0, hi=50.0)
    check_output_path("-o", args.output, suffixes=(".npz",))
    design = design_from_args(args)
    density = density_of_design(design, n, smoothing)
    save_density(args.output, density)
    out = {"output": str(args.output), "cells": n, "smoothing_mm": smoothing, "design": design.as_dict(),
           "hydrogel_fraction": float(density.mean()), "grey_cells": int(((density > 0) & (density < 1)).sum())}
    if args.json:
        emit_json(out)
    else:
        print(f"wrote {args.output}: {design.describe()} on {n} x {n} cells, hydrogel fraction "
              f"{out['hydrogel_fraction']:.4f}, {out['grey_cells']} grey cells")
    return 0
