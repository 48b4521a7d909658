"""Argument groups and output helpers shared by the subcommands."""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
from pathlib import Path

from ..design import PATTERNS, RIMS, LatticeDesign, design_from_table
from ..errors import ParameterError


def _positions(text: str) -> tuple[float, ...]:
    try:
        return tuple(float(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError("expected comma-separated centres in mm, e.g. 12.5,37.5,62.5,87.5, "
                                         f"got {text!r}") from None


_DESIGN_ARGS = [
    # flag, field, type, help
    ("--width", "width_mm", float, "channel width w (mm); 0 = uniform hydrogel layer"),
    ("--thickness", "thickness_mm", float, "conductive-layer thickness t (mm)"),
    ("--pitch", "pitch_mm", float, "distance between the channel centre lines either side of an island (mm)"),
    ("--pattern", "pattern", str, f"layout family ({', '.join(PATTERNS)}; custom comes from --layout)"),
    ("--rim", "rim", str, f"hydrogel channel round the rim ({', '.join(RIMS)})"),
    ("--frame", "frame_mm", float, "silicone border round the lattice (mm); leads cross it to the electrodes"),
    ("--sensor-size", "size_mm", float, "sensor side L (mm; design.size_mm in a study), not the mesh element size "
     "(--mesh-size)"),
    ("--total-thickness", "total_thickness_mm", float, "stack thickness H (mm)"),
    ("--sealing", "sealing_mm", float, "sealing-layer thickness (mm)"),
    ("--electrodes", "n_electrodes", int, "number of electrodes (multiple of 4)"),
    ("--electrode-width", "electrode_width_mm", float, "electrode width (mm)"),
    ("--electrode-positions", "electrode_positions_mm", _positions,
     "electrode centres along each side, counter-clockwise from its first corner (mm, comma-separated)"),
]


def add_design_args(parser: argparse.ArgumentParser) -> None:
    """Add the :class:`LatticeDesign` fields as options (unset ones keep the design defaults)."""
    defaults = LatticeDesign()
    g = parser.add_argument_group("design (mm)")
    for flag, field, typ, text in _DESIGN_ARGS:
        default = getattr(defaults, field)
        g.add_argument(flag, dest=field, type=typ, default=None,
                       help=f"{text}; default {'evenly spaced' if default is None else default}")
    g.add_argument("--no-leads", dest="electrode_leads", action="store_false", default=None,
                   help="do not join electrodes that no channel reaches by straight leads (reject such layouts)")
    g.add_argument("--layout", type=Path, default=None, metavar="FILE",
                   help="custom layout: hydrogel polygons (mm) from a GeoJSON or DXF file (closed curves; sets "
                        "--pattern custom)")
    g.add_argument("--hydrogel-fraction", type=float, default=None, metavar="F",
                   help="solve the channel width so that this fraction of the layer is hydrogel (instead of --width)")


def design_from_args(args: argparse.Namespace) -> LatticeDesign:
    """The design the options describe, validated (a ``--layout`` file is read and checked here)."""
    table = {f: getattr(args, f) for _, f, _, _ in _DESIGN_ARGS if getattr(args, f, None) is not None}
    for key in ("electrode_leads", "layout", "hydrogel_fraction"):
        if getattr(args, key, None) is not None:
            table[key] = getattr(args, key)
    flags = {f: flag for flag, f, _, _ in _DESIGN_ARGS}
    flags.update(custom_polygons_mm="--layout", layout="--layout", electrode_leads="--no-leads",
                 hydrogel_fraction="--hydrogel-fraction")
    try:
        return design_from_table(table)
    except ParameterError as exc:
        raise ParameterError(flags.get(exc.name.split("[")[0], exc.name), exc.expected, exc.got) from None


def add_touch_args(group) -> None:
    """``--touch`` (repeatable) and the indenter options, shared by ``indent`` and ``simulate``."""
    from ..mechanics import IndentSettings
    from ..mechanics.indenters import IN_PLANE, INDENTERS, PUNCH_EDGES

    d = IndentSettings()
    group.add_argument("--touch", action="append", required=True, metavar="X,Y,R,D",
                       help="indenter centre x, y, radius and depth in mm (repeat for up to three touches)")
    group.add_argument("--indenter", choices=INDENTERS, default=d.indenter,
                       help=f"indenter tip (default {d.indenter})")
    group.add_argument("--in-plane", choices=IN_PLANE, default=d.in_plane,
                       help=f"flat punch: in-plane condition under the punch (default {d.in_plane})")
    group.add_argument("--punch-edge", choices=PUNCH_EDGES, default=d.punch_edge,
                       help="flat punch rim: top nodes moved onto it (conforming) or the nodes inside (nodal); "
                            f"default {d.punch_edge}")
    group.add_argument("--edge-radius", type=float, default=d.edge_radius_mm, metavar="MM",
                       help="flat punch: radius of its rounded rim in mm, 0-20 (default "
                            f"{d.edge_radius_mm:g}: a sharp edge)")


def touches_from_args(args: argparse.Namespace, design: LatticeDesign) -> tuple:
    """The ``--touch`` values, parsed and checked against ``design`` (before any meshing or solving)."""
    from ..touches import Touch, touch_name, validate_touches

    touches = [Touch.parse(text, name=touch_name(i, "--touch")) for i, text in enumerate(args.touch)]
    return validate_touches(design, touches, name="--touch")


@contextlib.contextmanager
def touches_named_by_flag():
    """Errors the mechanics raise about ``touch #k`` once it meets the mesh (a contact disc holding no node)
    name the option: ``--touch #k``, as the checks before any work do."""
    try:
        yield
    except ParameterError as exc:
        if not exc.name.startswith("touch #"):
            raise
        raise ParameterError(f"--{exc.name}", exc.expected, exc.got) from None


@contextlib.contextmanager
def press_progress(touches):
    """A progress bar of one press on stderr, the deepest touch's depth reached against its final depth, drawn
    only on a terminal (a deep press can take minutes); yields the ``progress`` callback of
    :meth:`~latticeopt.mechanics.IndentationSolver.solve`."""
    from tqdm import tqdm

    with tqdm(total=max(t.depth_mm for t in touches), desc="pressing", unit="mm", disable=None, leave=False,
              bar_format="{desc}: {n:.3f} of {total:.3f} mm |{bar}| {elapsed}") as bar:
        def progress(depth_mm: float, final_mm: float) -> None:
            bar.n = depth_mm
            bar.refresh()

        yield progress


def sigma_help(default: float) -> str:
    """``--sigma`` of forward and simulate: their default and how export's differs (one text, two commands)."""
    from ..sensor_model import SIGMA0_S_PER_M

    return (f"hydrogel conductivity (S/m); default {default:g} (LiCl hydrogels conduct 1-10 S/m). 'export' "
            f"defaults to the paper's image-model sigma0 = {SIGMA0_S_PER_M:g} S/m instead, with z_c * sigma kept: "
            f"the same V_rel, voltages {default / SIGMA0_S_PER_M:.0f} times these (docs/sensor_model.md)")


def _int_or_auto(text: str) -> int | str:
    """``--channel-cells``: an integer or ``auto`` (the range is MeshSettings' to check)."""
    if text == "auto":
        return text
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected 'auto' or an integer, got {text!r}") from None


def add_mesh_args(parser: argparse.ArgumentParser) -> None:
    from ..mesh import CHANNEL_CELLS_AUTO, CHANNEL_CELLS_DEFAULT, MESHERS, MeshSettings

    d = MeshSettings()
    auto = ", ".join([f"{k} {n}" for k, n in CHANNEL_CELLS_AUTO.items()] + [f"else {CHANNEL_CELLS_DEFAULT}"])
    g = parser.add_argument_group("mesh")
    g.add_argument("--mesher", default=None, help=f"one of {', '.join(MESHERS)}; default {d.mesher}")
    g.add_argument("--mesh-size", "--size", dest="mesh_size_mm", type=float, default=None,
                   help=f"mesh element size: the target edge length of the elements (mm; mesh.size_mm in a study), "
                        f"not the sensor side (--sensor-size); --size is the old name; default {d.size_mm}")
    g.add_argument("--channel-cells", type=_int_or_auto, default=None,
                   help=f"grid and extruded: minimum cells across a channel, or 'auto' (the family's converged "
                        f"count: {auto}); default {d.channel_cells}")
    g.add_argument("--layer-cells", type=int, default=None,
                   help=f"grid: minimum cells through the conductive layer; default {d.layer_cells}")
    g.add_argument("--epsilon", dest="epsilon_rel", type=float, default=None,
                   help=f"tetwild: envelope relative to the bounding-box diagonal; default {d.epsilon_rel}")
    g.add_argument("--no-cache", action="store_true", help="do not read or write the mesh cache")
    g.add_argument("--cache-dir", type=Path, default=None,
                   help="mesh cache folder (default $LATTICEOPT_MESH_CACHE, else the user cache's latticeopt/meshes)")


def mesh_settings_from_args(args: argparse.Namespace):
    from ..mesh import MeshSettings

    names = {"mesher": "mesher", "mesh_size_mm": "size_mm", "channel_cells": "channel_cells",
             "layer_cells": "layer_cells", "epsilon_rel": "epsilon_rel"}
    return MeshSettings(**{f: getattr(args, a) for a, f in names.items() if getattr(args, a, None) is not None})


def mesh_from_args(args: argparse.Namespace):
    from ..mesh import mesh_design

    cache = False if args.no_cache else args.cache_dir
    return mesh_design(design_from_args(args), mesh_settings_from_args(args), cache_dir=cache)


def parse_output(path: str | None, suffixes: tuple[str, ...], name: str = "-o") -> Path | None:
    if path is None:
        return None
    p = Path(path)
    if p.suffix.lower() not in suffixes:
        raise ParameterError(name, f"a file name ending in {' or '.join(suffixes)}", path)
    return p


def emit_json(obj: dict) -> None:
    """Print one JSON object on stdout (strict JSON: a NaN or infinite value is printed as ``null``)."""
    from .._jsonout import dumps

    sys.stdout.write(dumps(obj) + "\n")


def study_overrides(args: argparse.Namespace) -> list[str]:
    """The ``--set`` overrides plus those implied by ``--evaluate`` and ``--out`` (sweep and optimize)."""
    overrides = list(args.overrides)
    if args.evaluate is not None:
        overrides.append(f"model={json.dumps(args.evaluate)}")
    if args.out is not None:
        overrides.append(f"out={json.dumps(args.out)}")
    return overrides


def check_parallel_args(args: argparse.Namespace) -> None:
    """Reject ``--jobs < 1``, a ``--scheduler`` without ``--backend dask`` and ``--backend dask`` without
    dask.distributed installed, before any work (``--dry-run`` included)."""
    from .._extras import require_extra

    if args.jobs is not None and args.jobs < 1:
        raise ParameterError("--jobs", "an integer >= 1", args.jobs)
    if args.scheduler is not None and args.backend != "dask":
        raise ParameterError("--scheduler", "no scheduler unless --backend dask", args.scheduler)
    if args.backend == "dask":
        require_extra("distributed", "it runs the phantoms on a dask cluster; or use --backend local",
                      name="--backend dask")


# -- output paths checked before any work ------------------------------------------------------------------
def check_output_path(flag: str, path, kind: str = "file", suffixes: tuple[str, ...] | None = None):
    """Check that ``path`` can be written as a ``kind`` (``"file"`` or ``"dir"``) before any work starts.

    A file must end in one of ``suffixes`` (if given), must not be an existing folder, and its parent folder
    must exist and be writable. A folder must not be an existing file; it must be writable
    if it exists, else its nearest existing ancestor must be a writable folder (it is created later).
    Returns the :class:`~pathlib.Path` (``None`` for ``None``); raises :class:`ParameterError` named ``flag``.
    """
    import os
    import tempfile

    if path is None:
        return None
    text = str(path)
    what = "a writable folder (created if missing)" if kind == "dir" else (
        "a writable file path" + (f" ending in {' or '.join(suffixes)}" if suffixes else ""))
    if not text.strip() or "\x00" in text:
        raise ParameterError(flag, what, text)
    p = Path(text).expanduser()
    if kind != "dir" and suffixes is not None and p.suffix.lower() not in suffixes:
        raise ParameterError(flag, f"a file name ending in {' or '.join(suffixes)}", text)
    try:
        if kind == "dir":
            if p.exists() and not p.is_dir():
                raise ParameterError(flag, what, f"{text} (an existing file)")
            probe = p
        else:
            if p.is_dir():
                raise ParameterError(flag, what, f"{text} (an existing folder)")
            if p.exists() and not os.access(p, os.W_OK):
                raise ParameterError(flag, what, f"{text} (not writable)")
            probe = p.parent
            if not probe.exists():
                raise ParameterError(flag, what + " in an existing folder", f"{text} ({probe} does not exist)")
        # the nearest existing ancestor must be a writable folder (missing folders are created later)
        while not probe.exists():
            if probe.parent == probe:
                break
            probe = probe.parent
        if not probe.is_dir():
            raise ParameterError(flag, what, f"{text} ({probe} is a file)")
        if not os.access(probe, os.W_OK | os.X_OK):
            raise ParameterError(flag, what, f"{text} ({probe} is not writable)")
        # os.access says yes to root on a read-only file system: create (and remove) a file there
        with tempfile.TemporaryFile(dir=probe, prefix=".latticeopt-write-test-"):
            pass
        if kind != "dir" and len(p.name.encode()) > 255:
            raise OSError(36, "File name too long")
    except OSError as exc:  # a read-only file system, a name too long, ...
        short = text if len(text) <= 120 else text[:100] + "..." + text[-16:]
        raise ParameterError(flag, what, f"{short} ({exc.strerror or exc})") from None
    return p


def check_mesh_args(args: argparse.Namespace) -> None:
    """The mesh options, named by their flags, and ``--cache-dir`` (unless ``--no-cache``: a writable folder or
    one that can be created), before any meshing."""
    flags = {"mesher": "--mesher", "size_mm": "--mesh-size", "channel_cells": "--channel-cells",
             "layer_cells": "--layer-cells", "epsilon_rel": "--epsilon"}
    try:
        mesh_settings_from_args(args)
    except ParameterError as exc:
        raise ParameterError(flags.get(exc.name, exc.name), exc.expected, exc.got) from None
    if not getattr(args, "no_cache", False) and getattr(args, "cache_dir", None) is not None:
        check_output_path("--cache-dir", args.cache_dir, kind="dir")
    check_sensor_size(args)


#: Largest --sensor-size in lattice pitches: the layout is built channel by channel (a 1e308 mm side was a
#: traceback, 1e6 mm took gigabytes before any check); 400 pitches is 5 m at the default 12.5 mm.
MAX_PITCHES_PER_SIDE = 400


def check_sensor_size(args: argparse.Namespace) -> None:
    """``--sensor-size`` at most :data:`MAX_PITCHES_PER_SIDE` lattice pitches (before the layout is built)."""
    import math

    d = LatticeDesign()
    size = getattr(args, "size_mm", None)
    pitch = getattr(args, "pitch_mm", None) or d.pitch_mm
    if size is None or not (isinstance(pitch, float | int) and math.isfinite(pitch) and pitch > 0):
        return  # the design's own checks name a bad pitch
    if math.isfinite(size) and size > MAX_PITCHES_PER_SIDE * pitch:
        raise ParameterError("--sensor-size", f"a side of at most {MAX_PITCHES_PER_SIDE} pitches "
                             f"({MAX_PITCHES_PER_SIDE * pitch:g} mm at --pitch {pitch:g})", size)


#: ``--touch`` may be given this often (``indent`` and ``simulate``; their --help says "up to three touches").
MAX_CLI_TOUCHES = 3


def check_touch_count(args: argparse.Namespace) -> None:
    """At most :data:`MAX_CLI_TOUCHES` ``--touch`` options (checked before any meshing)."""
    n = len(getattr(args, "touch", None) or [])
    if n > MAX_CLI_TOUCHES:
        raise ParameterError("--touch", f"1 to {MAX_CLI_TOUCHES} touches (one --touch X,Y,R,D each)", f"{n} touches")


def check_study_file(path) -> None:
    """The STUDY argument: an existing, readable UTF-8 text file (before the study is parsed)."""
    p = Path(str(path))
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise ParameterError("STUDY", "a readable TOML study file", f"{path} ({exc.strerror or exc})") from None
    try:
        data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ParameterError("STUDY", "a UTF-8 text TOML study file",
                             f"{path} (byte {exc.start}: not UTF-8 text)") from None


def check_study_outputs(args: argparse.Namespace, study) -> None:
    """A loaded study's output folder, cache folder and model, named by the flag that set them (or the study
    key), before any run (also for ``--dry-run``)."""
    from ..study.sweep import resolve_model

    check_output_path("--out" if getattr(args, "out", None) is not None else "out", study.out_dir, kind="dir")
    cache = study.settings.cache_dir
    if cache is not None:
        check_output_path("cache_dir", cache, kind="dir")
    flag = "--evaluate" if getattr(args, "evaluate", None) is not None else "model"
    try:
        fn = resolve_model(study.settings.model)
    except ParameterError as exc:
        raise ParameterError(flag, exc.expected, exc.got) from None
    if not callable(fn):
        raise ParameterError(flag, "a 'module:function' naming a callable that evaluates one phantom",
                             f"{study.settings.model} (a {type(fn).__name__})")


def check_input_file(flag: str, path, suffixes: tuple[str, ...] | None = None, what: str = "an existing file"):
    """An input file named by ``flag``: the right suffix, existing, a file (not a folder), readable."""
    import os

    if path is None:
        return None
    text = str(path)
    expected = what + (f" ending in {' or '.join(suffixes)}" if suffixes else "")
    short = text if len(text) <= 120 else text[:100] + "..." + text[-16:]
    if not text.strip() or "\x00" in text:
        raise ParameterError(flag, expected, text)
    p = Path(text).expanduser()
    if suffixes is not None and p.suffix.lower() not in suffixes:
        raise ParameterError(flag, expected, short)
    try:
        if not p.is_file():
            raise ParameterError(flag, expected, f"{short} ({'a folder' if p.is_dir() else 'missing'})")
        if not os.access(p, os.R_OK):
            raise ParameterError(flag, expected, f"{short} (not readable)")
    except OSError as exc:  # a name too long, ...
        raise ParameterError(flag, expected, f"{short} ({exc.strerror or exc})") from None
    return p
