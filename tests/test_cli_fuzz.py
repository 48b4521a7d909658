"""Every argument of every subcommand is checked before any work: property-based test over the CLI.

For each subcommand, hypothesis draws a command line from the subcommand's own argparse actions (so a new
option is fuzzed without editing this file): numbers from NaN, infinities, negatives, zero, huge values and
non-numbers; paths to missing files, existing files and folders, paths under a file, wrong suffixes and empty
strings; lists, choices and touches with the same ingredients. The expensive stages (meshing, mechanics,
electrics, dataset simulation, training, sweeps) are replaced by functions raising :class:`Accepted`: reaching
one means every argument was accepted. The property: the command returns 0 or reaches a stage, or it exits with
status 2 printing exactly one line on stderr and no traceback.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import types

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from latticeopt.cli import build_parser, main


class Accepted(BaseException):
    """Raised by a patched stage: the arguments got through every check (BaseException: nothing catches it)."""


def _stage(*_args, **_kwargs):
    raise Accepted


SMALL_STUDY = """name = "fuzz"
kind = "grid"
out = "runs/fuzz"
[design]
thickness_mm = 3.0
[grid]
width_mm = [0, 4]
[phantoms]
seed = 1
counts = { 1 = 1 }
depth_mm = [1.0, 3.0]
radius_mm = [6.0, 8.0]
"""

OPT_STUDY = SMALL_STUDY.replace("[grid]\nwidth_mm = [0, 4]\n", "").replace('name = "fuzz"', 'name = "fuzzopt"') + """
[optimize]
algorithm = "LN_BOBYQA"
max_evals = 4
[optimize.variables]
width_mm = [1.0, 6.0]
"""


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    return make_files(tmp_path_factory.mktemp("fuzz"))


def make_files(root):
    """Inputs on disk in ``root``: good ones (so checks after them are reached) and bad ones."""
    f = types.SimpleNamespace(root=root)
    f.dir = root / "a_folder"
    f.dir.mkdir()
    f.file = root / "plain.txt"
    f.file.write_text("not an output folder\n")
    f.study = root / "study.toml"
    f.study.write_text(SMALL_STUDY)
    f.opt_study = root / "opt.toml"
    f.opt_study.write_text(OPT_STUDY)
    f.binary = root / "binary.toml"
    f.binary.write_bytes(b"name = \"\xff\xfe\x00\x81\"\n")
    f.sensor = root / "sensor.npz"
    f.sensor.write_bytes(b"stub: load_sensor_model is patched")
    f.classifier = root / "gesture_lstm.npz"
    f.classifier.write_bytes(b"stub: classify_sequences is patched")
    f.frames = root / "frames.npy"
    np.save(f.frames, np.linspace(1, 2, 2 * 208).reshape(2, 208))
    f.complex_frames = root / "complex.npy"
    np.save(f.complex_frames, np.ones((2, 208)) * (1 + 1j))
    f.sequences = root / "sequences.npy"
    np.save(f.sequences, np.full((2, 15, 104), 0.01))
    f.complex_sequences = root / "complex_sequences.npy"
    np.save(f.complex_sequences, np.full((2, 15, 104), 0.01 + 0.01j))
    f.layout = root / "layout.geojson"
    f.layout.write_text('{"type": "FeatureCollection", "features": [{"type": "Feature", "properties": {}, '
                        '"geometry": {"type": "Polygon", "coordinates": [[[0, 45], [100, 45], [100, 55], [0, 55], '
                        '[0, 45]]]}}]}')
    f.dataset = root / "dataset.npz"
    f.dataset.write_bytes(b"stub: ReconDataset.load is patched")
    f.presses = root / "presses.csv"
    f.presses.write_text("width_mm,thickness_mm,x_mm,y_mm,radius_mm,depth_mm,v_rel\n4,3,50,50,8.75,2,0.02\n"
                         "0,3,50,50,8.75,2,0.015\n")
    return f


def _stub_model():
    from latticeopt.electrics import Protocol

    return types.SimpleNamespace(extent_mm=(0.0, 100.0, 0.0, 100.0), n_pixels=8, protocol=Protocol.adjacent(16),
                                 v_ref=np.linspace(1.0, 2.0, 208), sigma0_S_per_m=0.00312, fingerprint="stub")


def _import_everything() -> None:
    """Import every latticeopt module before any patching: a module first imported while a stage is patched
    would keep the stand-in (``from .classical import GaussNewton``) after the patch is undone."""
    import importlib
    import pkgutil

    import latticeopt

    for info in pkgutil.walk_packages(latticeopt.__path__, "latticeopt."):
        if info.name.endswith("__main__"):
            continue
        try:
            importlib.import_module(info.name)
        except ImportError:  # an extra that is not installed (torch, dask): the CLI reports it itself
            pass


def _patch_stages(mp: pytest.MonkeyPatch) -> None:
    _import_everything()
    import latticeopt.coupled
    import latticeopt.density
    import latticeopt.gestures
    import latticeopt.gestures.experiment
    import latticeopt.mechanics
    import latticeopt.mesh
    import latticeopt.optimize
    import latticeopt.recon.classical
    import latticeopt.recon.dataset
    import latticeopt.recon.dnn
    import latticeopt.sensor_model
    import latticeopt.study.calibrate
    import latticeopt.study.sensitivity
    import latticeopt.study.sweep

    for module, name in [
        (latticeopt.mesh, "mesh_design"), (latticeopt.mechanics, "indent"), (latticeopt.coupled, "CoupledModel"),
        (latticeopt.sensor_model, "build_sensor_model"), (latticeopt.sensor_model, "SensorSimulator"),
        (latticeopt.study.sweep, "run_sweep"), (latticeopt.optimize, "run_optimization"),
        (latticeopt.study.sensitivity, "run_sensitivity"), (latticeopt.study.calibrate, "coupled_predictor"),
        (latticeopt.recon.classical, "LinearReconstructor"), (latticeopt.recon.classical, "GaussNewton"),
        (latticeopt.recon.dnn, "DNNReconstructor"), (latticeopt.recon.dataset, "generate_dataset"),
        (latticeopt.gestures, "generate_gestures"), (latticeopt.gestures.experiment, "classify_sequences"),
        (latticeopt.density, "DensityModel"), (latticeopt.density, "density_of_design"),
    ]:
        mp.setattr(module, name, _stage)
    mp.setattr(latticeopt.recon.dataset.ReconDataset, "load", classmethod(_stage))
    mp.setattr(latticeopt.sensor_model, "load_sensor_model", lambda path: _stub_model())


# -- value strategies ----------------------------------------------------------------------------------------
BAD_NUMBERS = ["nan", "NaN", "inf", "-inf", "-1", "0", "-0", "1e308", "-1000", "-999", "1e-300", "", " ", "abc",
               "1,2", "0x10", "1e999"]
GOOD_FLOATS = ["0.5", "1", "2", "3", "4", "50", "1e-3"]
floats = st.one_of(st.sampled_from(GOOD_FLOATS), st.sampled_from(BAD_NUMBERS),
                   st.floats(allow_nan=True, allow_infinity=True).map(repr))
ints = st.one_of(st.sampled_from(["1", "2", "3", "16"]),
                 st.sampled_from(["-1", "0", "abc", "", "1.5", "nan", "99999999999999999999"]),
                 st.integers(-10, 10).map(str))
texts = st.sampled_from(["", " ", ",", "a,b", "nan", "none", "square", "flat", "1,2,3", "\u00e9", "x=1"])

#: dests holding output files (with the suffix that is right for them), output folders and input files
OUT_FILES = {"output": None, "plot": ".png", "vtu": ".vtu", "save_images": ".npy", "figure": ".png"}
OUT_DIRS = {"cache_dir", "out"}


def _paths(f, suffix: str | None, good: list[str]) -> st.SearchStrategy[str]:
    bad = [str(f.dir), str(f.file), str(f.file / ("x" + (suffix or ".txt"))), str(f.root / "missing" / "deeper"
           / ("x" + (suffix or ""))), "", " ", str(f.root / "wrong.suffix"), str(f.binary), "/proc/latticeopt-x"
           + (suffix or ""), str(f.root / ("n" * 300 + (suffix or "")))]
    return st.one_of(st.sampled_from(good), st.sampled_from(bad)) if good else st.sampled_from(bad)


def _touches(disc: bool) -> st.SearchStrategy[str]:
    good = "50,50,10,0.5" if disc else "50,50,8.75,2"
    parts = st.lists(st.sampled_from(["nan", "inf", "-inf", "-5", "0", "1e9", "50", "8.75", "2", "0.5", "1e308",
                                      "150", "x", ""]), min_size=1, max_size=5).map(",".join)
    return st.one_of(st.just(good), parts)


def _value(cmd: str, action: argparse.Action, f) -> st.SearchStrategy[str]:
    dest = action.dest
    if action.choices is not None:
        good = st.sampled_from([str(c) for c in action.choices])
        return st.one_of(good, good, texts)
    if dest in ("touch", "disc"):
        return _touches(dest == "disc")
    if dest in OUT_DIRS:
        good = [str(f.root / "new_folder"), str(f.dir)]
        return _paths(f, None, good)
    if dest in OUT_FILES:
        suffix = OUT_FILES[dest] or {"mesh": ".vtu", "indent": ".vtu", "render": ".png", "export": ".npz",
                                     "reconstruct": ".png", "recon-train": ".npz"}.get(cmd, ".txt")
        return _paths(f, suffix, [str(f.root / ("out" + suffix))])
    if dest == "model":
        good = str(f.classifier) if cmd == "classify" else str(f.sensor)
        return _paths(f, ".npz", [good])
    if dest == "frames":
        good = [str(f.sequences), str(f.complex_sequences)] if cmd == "classify" else [str(f.frames),
                                                                                       str(f.complex_frames)]
        return _paths(f, ".npy", good)
    if dest == "reference":
        return _paths(f, ".npy", [str(f.frames)])
    if dest == "dataset":
        return _paths(f, ".npz", [str(f.dataset), str(f.root / "new_dataset.npz")])
    if dest == "net":
        return _paths(f, ".npz", [str(f.sensor)])
    if dest == "layout":
        return _paths(f, ".geojson", [str(f.layout)])
    if dest in ("method", "methods", "prior", "lam", "touch_counts", "pattern", "rim"):
        good = {"method": ["tikhonov", "gn", "dnn"], "methods": ["background,tikhonov", "gn", "dnn", ","],
                "prior": ["laplacian", "noser", "identity,noser"], "lam": ["lcurve", "gcv", "validation", "0.01", "-1"],
                "touch_counts": ["1,2", "1", "0", "13"], "pattern": ["square", "hexagonal", "custom"],
                "rim": ["none", "channel"]}[dest]
        return st.one_of(st.sampled_from(good), texts, floats)
    if dest == "mesher":
        return st.one_of(st.sampled_from(["auto", "grid", "extruded", "tetwild"]), texts)
    if dest == "overrides":  # sweep/optimize/sensitivity --set
        return st.sampled_from(["physics.contact_impedance_ohm_m2=0", "phantoms.depth_mm=[1,12]",
                                "phantoms.depth_mm=[1,2]", "mesh.size_mm=nan", f"cache_dir={f.file}",
                                "out=''", "model=os:sep", "=", "a..b=1", "mesh.size_mm=4"])
    if dest == "evaluate":
        return st.sampled_from(["os:sep", "nonexistent.module:f", "latticeopt.coupled:evaluate_phantom", "", ":",
                                "math:pi", "latticeopt.coupled:nothing"])
    if dest == "physics":
        return st.sampled_from(["contact_impedance_ohm_m2=0", "hydrogel_poisson_ratio=0.5", "indenter=sphere",
                                "sigma_S_per_m=nan", "nokey=1", "=", "mechanics_rtol=1e-3",
                                "mechanics_rescue_newton=-1", "mechanics_rescue_newton=2.5"])
    if action.type is float or dest == "snr":
        return floats
    if action.type is int:
        return ints
    return st.one_of(texts, floats)


def _positional(cmd: str, f) -> st.SearchStrategy[list[str]]:
    if cmd in ("sweep", "sensitivity"):
        return _paths(f, ".toml", [str(f.study)] * 3).map(lambda p: [p])
    if cmd == "optimize":
        return _paths(f, ".toml", [str(f.opt_study)] * 3).map(lambda p: [p])
    if cmd == "calibrate":
        return _paths(f, ".csv", [str(f.presses)] * 3).map(lambda p: [p])
    return st.just([])


def _subparsers() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


SUBPARSERS = _subparsers()
COMMANDS = sorted(SUBPARSERS)


@st.composite
def command_lines(draw, cmd: str, f) -> list[str]:
    parser = SUBPARSERS[cmd]
    argv = [cmd, *draw(_positional(cmd, f))]
    # one option of each required mutually exclusive group (reconstruct --frames | --disc | --touch), mostly
    forced = {draw(st.sampled_from(g._group_actions)).dest for g in parser._mutually_exclusive_groups if g.required
              and draw(st.integers(0, 9)) != 0}
    for action in parser._actions:
        if not action.option_strings or isinstance(action, (argparse._HelpAction, argparse._VersionAction)):
            continue
        flag = action.option_strings[-1] if action.option_strings[-1].startswith("--") else action.option_strings[0]
        if not (action.required or action.dest in forced) and draw(st.integers(0, 3)) != 0:  # a few options
            continue
        if action.nargs == 0:
            argv.append(flag)
            continue
        if action.dest == "fit":  # calibrate --fit KEY=LOW:HIGH
            values = [draw(st.sampled_from(["hydrogel_shear_kPa=1:50", "hydrogel_shear_kPa=nan:1", "x=1:2",
                                            "hydrogel_shear_kPa=5:1", "sigma_S_per_m=0:1"]))]
        elif action.dest == "vary":  # sensitivity --vary KEY=V1,V2
            values = [draw(st.sampled_from(["hydrogel_shear_kPa=2,15", "rim=channel", "contact_impedance_ohm_m2=0",
                                            "nokey=1", "=", "hydrogel_shear_kPa=nan"]))]
        elif isinstance(action, argparse._AppendAction):
            values = draw(st.lists(_value(cmd, action, f), min_size=1, max_size=4))
        else:
            values = [draw(_value(cmd, action, f))]
        for val in values:
            if isinstance(action.nargs, int):  # e.g. classify-train --snr LO HI
                argv += [flag, *(draw(floats) for _ in range(action.nargs))]
            else:
                argv.append(f"{flag}={val}")  # '=' so that '-1' or '-inf' reach the value checks
    return argv


def run_cli(argv: list[str], root) -> tuple[str, int, str]:
    """Run ``latticeopt argv`` with the stages patched; returns (outcome, exit status, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    with pytest.MonkeyPatch.context() as mp:
        _patch_stages(mp)
        mp.chdir(root)
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                status = main(argv)
                outcome = "returned"
            except Accepted:
                return "accepted", 0, err.getvalue()
            except SystemExit as exc:  # argparse
                status, outcome = (exc.code if isinstance(exc.code, int) else 2), "argparse"
    return outcome, status, err.getvalue()


def check_outcome(argv, outcome, status, err) -> None:
    assert "Traceback" not in err, (argv, err)
    if outcome == "accepted" or (outcome == "returned" and status == 0):
        return
    lines = err.splitlines()
    assert status == 2 and len(lines) == 1, (argv, outcome, status, err)
    assert "error" in lines[0], (argv, err)


@pytest.mark.parametrize("cmd", COMMANDS)
def test_every_argument_is_checked_before_any_work(cmd, files):
    pytest.importorskip("torch") if cmd in ("classify-train",) else None

    @settings(max_examples=20, deadline=None, derandomize=True, database=None,
              suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
    @given(command_lines(cmd, files))
    def prop(argv):
        check_outcome(argv, *run_cli(argv, files.root))

    prop()
