"""``latticeopt export``: a design's sensor-model file for reconstruction (format: docs/sensor_model.md)."""

from __future__ import annotations

import time

from ..errors import ParameterError
from ._common import (
    add_design_args,
    add_mesh_args,
    check_mesh_args,
    check_output_path,
    design_from_args,
    emit_json,
    mesh_settings_from_args,
)


def register(sub) -> None:
    from ..electrics.forward import DEFAULT_CURRENT_A, DEFAULT_SIGMA_S_PER_M
    from ..interop import FORMATS
    from ..sensor_model import SIGMA0_S_PER_M

    p = sub.add_parser("export", help="export a design as a sensor-model file for reconstruction",
                       description="Mesh a design, solve its rest state at the background conductivity and write "
                                   "the sensor-model .npz (format: docs/sensor_model.md).")
    add_design_args(p)
    add_mesh_args(p)
    g = p.add_argument_group("sensor model")
    g.add_argument("--sigma", type=float, default=SIGMA0_S_PER_M,
                   help=f"background conductivity sigma0 (S/m); default {SIGMA0_S_PER_M:g}, the paper's image model. "
                        f"forward and simulate default to {DEFAULT_SIGMA_S_PER_M:g} S/m: with z_c * sigma kept, the "
                        f"same V_rel, and this file's voltages {DEFAULT_SIGMA_S_PER_M / SIGMA0_S_PER_M:.0f} times "
                        "theirs (docs/sensor_model.md)")
    g.add_argument("--contact-impedance", type=float, default=None,
                   help="contact impedance (ohm m^2); default keeps z_c * sigma = 2e-3 ohm m^3/m (0.641 at sigma0)")
    g.add_argument("--current", type=float, default=DEFAULT_CURRENT_A, help="drive current (A); default 1e-3")
    g.add_argument("--pixels", type=int, default=48, help="pixels per side of the image grid; default 48")
    p.add_argument("--format", default="npz",
                   help="; ".join(f"{f.name}: {f.description}, {f.suffix}" for f in FORMATS.values()) +
                        " (default npz); formats: docs/sensor_model.md")
    p.add_argument("-o", "--output", required=True, help="output file, with the format's suffix")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run_export)


def run_export(args) -> int:
    from ..interop import FORMATS
    from ..sensor_model import build_sensor_model

    if args.format not in FORMATS:
        raise ParameterError("--format", "one of " + ", ".join(FORMATS), args.format)
    fmt = FORMATS[args.format]
    out = check_output_path("-o", args.output, suffixes=(fmt.suffix,))
    check_mesh_args(args)
    t0 = time.perf_counter()
    cache = False if args.no_cache else args.cache_dir
    model = build_sensor_model(design_from_args(args), mesh_settings_from_args(args), args.sigma,
                               args.contact_impedance, args.pixels, args.current, cache)
    fmt.writer(model, out)
    info = {**model.summary(), "format": args.format, "output": str(out), "seconds": time.perf_counter() - t0}
    if args.json:
        emit_json(info)
        return 0
    print(f"{model.design.describe()}")
    print(f"hydrogel mesh {info['gel_nodes']} nodes, {info['gel_tets']} tets; sigma0 {model.sigma0_S_per_m:g} S/m, "
          f"z_c {info['contact_impedance_ohm_m2']:.4g} ohm m^2 (z_c sigma / w = {info['contact_number']:.3g}), "
          f"I = {model.current_A * 1e3:g} mA")
    print(f"{info['n_rows']} rows, Jacobian {model.jacobian.shape[0]} x {model.jacobian.shape[1]} on "
          f"{model.n_pixels} x {model.n_pixels} pixels; |V_ref| {info['v_ref_range_V'][0]:.4g} to "
          f"{info['v_ref_range_V'][1]:.4g} V; fingerprint {model.fingerprint}")
    print(f"wrote {out} ({out.stat().st_size / 1e6:.1f} MB) in {info['seconds']:.1f} s")
    return 0
