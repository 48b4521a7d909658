"""``latticeopt mesh`` and ``latticeopt render``."""

from __future__ import annotations

import dataclasses
import time

from ._common import (
    add_design_args,
    add_mesh_args,
    check_mesh_args,
    check_output_path,
    design_from_args,
    emit_json,
    mesh_from_args,
    mesh_settings_from_args,
)

#: ``render`` writes this file unless ``-o`` names another.
RENDER_OUTPUT = "sensor.png"


def register(sub) -> None:
    p = sub.add_parser("mesh", help="mesh a design and print a summary",
                       description="Mesh a design (cached by content hash in the mesh cache, see --cache-dir) and "
                                   "print a summary; writes no other file unless -o or --stl names one.")
    add_design_args(p)
    add_mesh_args(p)
    p.add_argument("-o", "--output", default=None, help="write the mesh as VTU (ParaView) to this file")
    p.add_argument("--stl", default=None, metavar="FOLDER",
                   help="also write every region solid as <FOLDER>/<region>.stl (mm) for fabrication: the hydrogel "
                        "channels, the silicone islands and substrate that form their mould, the sealing layer")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    p.set_defaults(func=run_mesh)

    r = sub.add_parser("render", help="render a design's mesh to a PNG (off-screen)",
                       description=f"Render the meshed lattice with the sealing layer cut away and write the picture "
                                   f"to {RENDER_OUTPUT} in the working directory (another file with -o).")
    add_design_args(r)
    add_mesh_args(r)
    r.add_argument("-o", "--output", default=RENDER_OUTPUT, help=f"PNG file (default {RENDER_OUTPUT})")
    r.add_argument("--show-sealing", action="store_true", help="draw the sealing layer (translucent)")
    r.set_defaults(func=run_render)


def run_mesh(args) -> int:
    out = check_output_path("-o", args.output, suffixes=(".vtu",))
    stl = check_output_path("--stl", args.stl, kind="dir")
    check_mesh_args(args)
    t0 = time.perf_counter()
    mesh = mesh_from_args(args)
    design = design_from_args(args)
    summary = mesh.summary()
    summary.update({"design": design.as_dict(),
                    "mesh_settings": dataclasses.asdict(mesh_settings_from_args(args).resolved(design)),
                    "mesher": mesh.info["mesher"], "cached": mesh.info.get("cached", False),
                    "seconds": time.perf_counter() - t0, "build_seconds": mesh.info.get("build_seconds")})
    if out is not None:
        mesh.to_vtu(out)
        summary["output"] = str(out)
    if stl is not None:
        from ..geometry import build_solids, write_stl

        summary["stl"] = {k: str(v) for k, v in write_stl(build_solids(design), stl).items()}
    if args.json:
        emit_json(summary)
        return 0
    vols = summary["region_volumes_mm3"]
    areas = summary["electrode_areas_mm2"]
    print(f"{summary['mesher']} mesh: {summary['nodes']} nodes, {summary['tets']} tets "
          f"({'cache' if summary['cached'] else 'built'} in {summary['seconds']:.2f} s)")
    print("region volumes (mm^3): " + ", ".join(f"{k} {v:.1f}" for k, v in vols.items()))
    print(f"electrode areas (mm^2): min {min(areas):.3f}, max {max(areas):.3f} over {len(areas)}")
    print(f"min tet quality (mean ratio): {summary['min_quality']:.3f}")
    if out is not None:
        print(f"wrote {out}")
    for name, path in summary.get("stl", {}).items():
        print(f"wrote {path} ({name} solid, mm)")
    return 0


def run_render(args) -> int:
    from ..render import render_mesh

    out = check_output_path("-o", args.output, suffixes=(".png",))
    check_mesh_args(args)
    mesh = mesh_from_args(args)
    render_mesh(mesh, out, show_sealing=args.show_sealing)
    print(f"wrote {out}")
    return 0
