"""``latticeopt indent``: press one to three rigid indenters into a design and report forces and stretch."""

from __future__ import annotations

import time

from ._common import (
    add_design_args,
    add_mesh_args,
    add_touch_args,
    check_mesh_args,
    check_output_path,
    check_touch_count,
    design_from_args,
    emit_json,
    mesh_from_args,
    mesh_settings_from_args,
    press_progress,
    touches_from_args,
    touches_named_by_flag,
)
from ._physics import add_physics_arg, physics_settings, physics_values


def register(sub) -> None:
    p = sub.add_parser("indent", help="hyperelastic indentation of a design",
                       description="Indent the top surface with rigid round indenters (neo-Hookean stack, "
                                   "bottom fixed, sides free) and report forces, Newton steps and stretch.")
    add_design_args(p)
    add_mesh_args(p)
    g = p.add_argument_group("indentation")
    add_touch_args(g)
    g.add_argument("--max-step", type=float, default=None, help="largest depth increment per load step (mm)")
    add_physics_arg(g)
    p.add_argument("-o", "--output", default=None, help="write the deformed mesh as VTU (ParaView)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    p.set_defaults(func=run_indent)


def run_indent(args) -> int:
    import dataclasses

    from ..mechanics import indent

    out = check_output_path("-o", args.output, suffixes=(".vtu",))
    check_mesh_args(args)
    check_touch_count(args)
    design = design_from_args(args)
    touches = touches_from_args(args, design)
    # the mechanics of the [physics] settings (materials, indenter); the standalone indentation keeps its own
    # tolerance unless --physics mechanics_rtol=... is given
    given = {"indenter": ("--indenter", args.indenter), "in_plane": ("--in-plane", args.in_plane),
             "punch_edge": ("--punch-edge", args.punch_edge),
             "edge_radius_mm": ("--edge-radius", args.edge_radius)}
    settings = physics_settings(args, given).indent_settings()
    extra = {} if args.max_step is None else {"max_step_mm": args.max_step}
    if "mechanics_rtol" not in physics_values(args):
        extra["rtol"] = type(settings)().rtol
    settings = dataclasses.replace(settings, **extra)
    t0 = time.perf_counter()
    mesh = mesh_from_args(args)
    t_mesh = time.perf_counter() - t0
    with touches_named_by_flag(), press_progress(touches) as progress:
        res = indent(mesh, touches, settings, progress=progress)
    summary = res.summary()
    summary.update({"design": design.as_dict(),
                    "mesh_settings": dataclasses.asdict(mesh_settings_from_args(args).resolved(design)),
                    "nodes": mesh.n_nodes, "tets": mesh.n_tets,
                    "mesh_seconds": t_mesh, "seconds": time.perf_counter() - t0})
    if out is not None:
        res.to_vtu(out)
        summary["output"] = str(out)
    if args.json:
        emit_json(summary)
        return 0
    print(f"{design.describe()}; mesh {mesh.n_nodes} nodes, {mesh.n_tets} tets")
    for i, (t, f) in enumerate(zip(res.touches, res.forces_N)):
        print(f"touch {i + 1}: ({t.x_mm:g}, {t.y_mm:g}) mm, r = {t.radius_mm:g} mm, d = {t.depth_mm:g} mm -> "
              f"force {f:.4g} N")
    print(f"{res.load_steps} load steps, {res.newton_steps} Newton steps ({res.step_halvings} halvings), "
          f"{summary['seconds']:.2f} s")
    print(f"hydrogel principal stretch {res.min_hydrogel_stretch:.3f} .. {res.max_hydrogel_stretch:.3f}; "
          f"min det F {res.min_det_F:.3f}")
    if out is not None:
        print(f"wrote {out}")
    return 0
