"""``latticeopt forward``: the 16-electrode voltages of a design at rest, with optional field output."""

from __future__ import annotations

import time

from ._common import (
    add_design_args,
    add_mesh_args,
    check_mesh_args,
    check_output_path,
    design_from_args,
    emit_json,
    mesh_from_args,
    sigma_help,
)

PROTOCOLS = ("adjacent", "opposite")


def register(sub) -> None:
    from ..electrics.forward import DEFAULT_CONTACT_IMPEDANCE_OHM_M2, DEFAULT_CURRENT_A, DEFAULT_SIGMA_S_PER_M

    p = sub.add_parser(
        "forward", help="solve the current flow of a design and print its electrode voltages",
        description="Mesh a design, solve steady current flow in its hydrogel (complete electrode model) for "
                    "every drive and print the measurements (pyEIT 'std' order for the adjacent protocol).")
    add_design_args(p)
    add_mesh_args(p)
    g = p.add_argument_group("electrics")
    g.add_argument("--sigma", type=float, default=DEFAULT_SIGMA_S_PER_M, help=sigma_help(DEFAULT_SIGMA_S_PER_M))
    g.add_argument("--contact-impedance", type=float, default=DEFAULT_CONTACT_IMPEDANCE_OHM_M2,
                   help=f"contact impedance z_c (ohm m^2); default {DEFAULT_CONTACT_IMPEDANCE_OHM_M2:g}")
    g.add_argument("--current", type=float, default=DEFAULT_CURRENT_A,
                   help=f"drive current (A); default {DEFAULT_CURRENT_A:g}")
    g.add_argument("--electrode-mode", default="cem", help="cem (complete electrode model, default) or point")
    g.add_argument("--protocol", default="adjacent", help=f"one of {', '.join(PROTOCOLS)}; default adjacent")
    o = p.add_argument_group("output")
    o.add_argument("--json", action="store_true", help="print one JSON object")
    o.add_argument("--plot", default=None, help="PNG of |J| and potential on the mid-layer slice")
    o.add_argument("--plot-uniform", action="store_true",
                   help="with --plot: also solve the uniform layer (w = 0) and draw it above (the paper's Fig. 2)")
    o.add_argument("--vtu", default=None, help="VTU of the hydrogel with potentials and current density")
    o.add_argument("--drive", type=int, default=1, help="drive shown by --plot/--vtu (1-based); default 1")
    p.set_defaults(func=run_forward)


def run_forward(args) -> int:
    import numpy as np

    from .. import _validate as v
    from ..electrics import ForwardModel, Protocol
    from ..metric import ROUND_OFF_REL, smallest_reference_rel

    t0 = time.perf_counter()
    png = check_output_path("--plot", args.plot, suffixes=(".png",))
    vtu = check_output_path("--vtu", args.vtu, suffixes=(".vtu",))
    check_mesh_args(args)
    v.choice("--protocol", args.protocol, PROTOCOLS)
    v.choice("--electrode-mode", args.electrode_mode, ("cem", "point"))
    for flag, value in (("--sigma", args.sigma), ("--contact-impedance", args.contact_impedance),
                        ("--current", args.current)):
        v.real(flag, value, lo=0, lo_open=True)
    design = design_from_args(args)
    n_e = design.n_electrodes
    drive = v.integer("--drive", args.drive, lo=1, hi=n_e) - 1
    protocol = Protocol.adjacent(n_e) if args.protocol == "adjacent" else Protocol.opposite(n_e)
    mesh = mesh_from_args(args)
    t_mesh = time.perf_counter() - t0
    model = ForwardModel(mesh, sigma_S_per_m=args.sigma, contact_impedance_ohm_m2=args.contact_impedance,
                         protocol=protocol, current_A=args.current, electrode_mode=args.electrode_mode)
    V = model.voltages
    seconds = time.perf_counter() - t0
    out = {
        "design": design.as_dict(), "protocol": protocol.name,
        "voltages": V, "independent": V[protocol.independent], "independent_rows": protocol.independent,
        "meas_pairs": protocol.meas_pairs, "row_drive": protocol.row_drive,
        "reciprocity_error": model.reciprocity_error(), "min_reference_rel": smallest_reference_rel(V),
        "sigma_S_per_m": args.sigma, "contact_impedance_ohm_m2": args.contact_impedance,
        "current_A": args.current, "contact_number": model.contact_number,
        "electrode_mode": args.electrode_mode,
        "mesh": {"mesher": mesh.info.get("mesher"), "nodes": mesh.n_nodes, "tets": mesh.n_tets,
                 "gel_nodes": model.mesh.n_nodes, "gel_tets": model.mesh.n_tets, "cached": mesh.info.get("cached")},
        "timings_s": {"mesh": t_mesh, **model.timings}, "seconds": seconds,
    }
    if vtu is not None:
        from ..electrics.fields import write_vtu

        out["vtu"] = str(write_vtu(model, vtu, drive))
    if png is not None:
        from ..electrics.fields import plot_fields

        models = [model]
        if args.plot_uniform and design.width_mm > 0:
            args.width_mm = 0.0
            uniform = ForwardModel(mesh_from_args(args), sigma_S_per_m=args.sigma,
                                   contact_impedance_ohm_m2=args.contact_impedance, protocol=protocol,
                                   current_A=args.current, electrode_mode=args.electrode_mode)
            models.insert(0, uniform)
        out["plot"] = str(plot_fields(models, png, drive=drive))
    if args.json:
        emit_json(out)
        return 0
    print(f"{design.describe()}")
    print(f"hydrogel mesh: {model.mesh.n_nodes} nodes, {model.mesh.n_tets} tets; {args.electrode_mode}, "
          f"sigma {args.sigma:g} S/m, z_c {args.contact_impedance:g} ohm m^2 "
          f"(z_c sigma / w = {model.contact_number:.3g}), I = {args.current * 1e3:g} mA")
    print(f"{protocol.name} protocol: {protocol.n_rows} measurements ({len(protocol.independent)} independent), "
          f"reciprocity error {out['reciprocity_error']:.2e}")
    small = out["min_reference_rel"]
    print(f"smallest measurement: {small:.1e} of the largest"
          + (" (round-off: electrodes on a dead-end channel, whose V_rel rows eq. 5 cannot read; see the "
             "[physics] key measurement_floor_rel)" if small < ROUND_OFF_REL else ""))
    with np.printoptions(precision=5, suppress=False, linewidth=110):
        print("voltages (V), one row per drive:")
        for d in range(protocol.n_drives):
            print(f"  drive {d + 1:2d}: {np.array2string(V[protocol.row_drive == d], separator=' ')}")
    t = model.timings
    print(f"solved in {seconds:.2f} s (mesh {t_mesh:.2f} s, factorization {t['factorization']:.3f} s, "
          f"{n_e} solves {t['solve']:.3f} s)")
    for key in ("vtu", "plot"):
        if key in out:
            print(f"wrote {out[key]}")
    return 0
