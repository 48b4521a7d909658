"""``latticeopt simulate``: one coupled simulation (indentation, then the 208 voltages and V_rel)."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

from ._common import (
    add_design_args,
    add_mesh_args,
    add_touch_args,
    check_mesh_args,
    check_touch_count,
    design_from_args,
    emit_json,
    mesh_settings_from_args,
    press_progress,
    sigma_help,
    touches_from_args,
    touches_named_by_flag,
)
from ._physics import add_physics_arg, physics_settings


def register(sub) -> None:
    from ..coupled import PhysicsSettings

    d = PhysicsSettings()
    p = sub.add_parser("simulate", help="coupled indentation + electrics of one phantom: V_rel",
                       description="Indent the design, solve the 16-electrode current flow on the deformed "
                                   "hydrogel and report V_rel against the untouched reference (paper eq. 5).")
    add_design_args(p)
    add_mesh_args(p)
    g = p.add_argument_group("phantom and physics")
    add_touch_args(g)
    g.add_argument("--sigma", type=float, default=d.sigma_S_per_m, help=sigma_help(d.sigma_S_per_m))
    g.add_argument("--contact-impedance", type=float, default=d.contact_impedance_ohm_m2,
                   help="electrode contact impedance (ohm m^2)")
    add_physics_arg(g)
    d = p.add_argument_group("density layout (instead of the layout options)")
    d.add_argument("--density", type=Path, default=None, metavar="FILE.npz",
                   help="a density layout: 'density', an (n, n) array in [0, 1] over the sensor square, row i "
                        "covering y in [i L/n, (i+1) L/n), 4 <= n <= 400 (write one with 'latticeopt "
                        "export-density'); the layout options (--width, --pattern, --layout, ...) are ignored")
    d.add_argument("--gradient", type=Path, default=None, metavar="OUT.npz",
                   help="with --density: write dv_rel_ddensity, dforce_ddensity and dstretch_ddensity, shape (n, n), "
                        "by adjoints")
    d.add_argument("--interpolation", action="append", default=[], metavar="KEY=VALUE",
                   help="with --density: material interpolation (stiffness_exponent, conductivity_exponent, "
                        "conductivity_floor, stretch_exponent); repeatable")
    d.add_argument("--plot", type=Path, default=None, metavar="PNG",
                   help="with --gradient: the layout and the dV_rel/d rho map as a picture")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    p.set_defaults(func=run_simulate)


def simulate_inputs(args):
    """The design, touches and :class:`~latticeopt.coupled.PhysicsSettings` of simulate's options (also
    ``--density``'s), each checked before any meshing: the dedicated options first, then any ``--physics``."""
    check_touch_count(args)
    design = design_from_args(args)
    touches = touches_from_args(args, design)
    given = {"indenter": ("--indenter", args.indenter), "in_plane": ("--in-plane", args.in_plane),
             "punch_edge": ("--punch-edge", args.punch_edge),
             "edge_radius_mm": ("--edge-radius", args.edge_radius), "sigma_S_per_m": ("--sigma", args.sigma),
             "contact_impedance_ohm_m2": ("--contact-impedance", args.contact_impedance)}
    return design, touches, physics_settings(args, given)


def run_simulate(args) -> int:
    from ..coupled import CoupledModel

    if args.density is not None or args.gradient is not None or args.interpolation or args.plot is not None:
        from .density import run_density

        return run_density(args)
    check_mesh_args(args)
    design, touches, physics = simulate_inputs(args)
    settings = mesh_settings_from_args(args)
    t0 = time.perf_counter()
    model = CoupledModel(design, settings, physics, cache_dir=False if args.no_cache else args.cache_dir)
    with touches_named_by_flag(), press_progress(touches) as progress:
        res = model.simulate(touches, progress=progress)
    out = res.summary()
    out.update({"design": design.as_dict(), "touches": [t.as_dict() for t in touches],
                "mesh_settings": dataclasses.asdict(settings.resolved(design)), "physics": physics.as_dict(),
                "nodes": model.mesh.n_nodes,
                "reference_voltages": res.reference_voltages.tolist(), "setup_seconds": model.setup_seconds,
                "seconds": time.perf_counter() - t0})
    if args.json:
        emit_json(out)
        return 0
    print(f"{design.describe()}; mesh {model.mesh.n_nodes} nodes")
    for i, (t, f) in enumerate(zip(touches, res.forces_N)):
        print(f"touch {i + 1}: ({t.x_mm:g}, {t.y_mm:g}) mm, r = {t.radius_mm:g} mm, d = {t.depth_mm:g} mm -> "
              f"force {f:.4g} N")
    print(f"V_rel = {res.v_rel:.5f} over {len(res.voltages)} measurements "
          f"(max hydrogel stretch {res.max_hydrogel_stretch:.3f})")
    print(f"{out['seconds']:.2f} s (set-up {model.setup_seconds:.2f} s, mechanics {res.timings['mechanics']:.2f} s, "
          f"electrics {res.timings['electrics']:.2f} s)")
    return 0
