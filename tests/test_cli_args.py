"""Each bad argument of issue #17 gives one line on stderr naming the flag, exit status 2, before any work.

The expensive stages are patched to raise (``test_cli_fuzz.Accepted``): a case that reaches one failed to reject
its argument before meshing, simulation or training.
"""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
from test_cli_fuzz import _stub_model, make_files, run_cli

from latticeopt.cli import main


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    return make_files(tmp_path_factory.mktemp("args"))


#: /proc refuses new files even to root (a chmod 555 folder does not: root writes anyway)
UNWRITABLE = "/proc/latticeopt-fuzz"


def _rejected(argv, files, flag: str, *also: str) -> str:
    outcome, status, err = run_cli([str(a) for a in argv], files.root)
    lines = err.splitlines()
    assert outcome == "returned" and status == 2 and len(lines) == 1, (argv, outcome, status, err)
    assert "Traceback" not in err and flag in lines[0], (flag, lines)
    for text in also:
        assert text in lines[0], (text, lines[0])
    return lines[0]


def _accepted(argv, files) -> None:
    outcome, status, err = run_cli([str(a) for a in argv], files.root)
    assert outcome == "accepted" or (outcome == "returned" and status == 0), (argv, outcome, status, err)


@pytest.fixture
def under_file(files):
    """A path whose parent is a file (no folder can be made there)."""
    return files.file


@pytest.mark.parametrize("argv, flag", [
    (["mesh", "-o", "{under}/m.vtu"], "-o"),
    (["mesh", "-o", UNWRITABLE + ".vtu"], "-o"),
    (["mesh", "-o", "{missing}/m.vtu"], "-o"),
    (["mesh", "-o", "{dir_vtu}"], "-o"),
    (["mesh", "--cache-dir", "{file}"], "--cache-dir"),
    (["mesh", "--cache-dir", UNWRITABLE], "--cache-dir"),
    (["render", "-o", "{under}/r.png"], "-o"),
    (["forward", "--plot", "{under}/f.png"], "--plot"),
    (["forward", "--vtu", UNWRITABLE + ".vtu"], "--vtu"),
    (["export", "-o", "{under}/s.npz"], "-o"),
    (["export", "-o", "s.npz", "--cache-dir", "{file}"], "--cache-dir"),
    (["indent", "--touch", "50,50,8,2", "-o", "{under}/i.vtu"], "-o"),
    (["simulate", "--touch", "50,50,8,2", "--cache-dir", "{file}"], "--cache-dir"),
    (["reconstruct", "--model", "{sensor}", "--frames", "{frames}", "-o", "{under}/x.png"], "-o"),
    (["reconstruct", "--model", "{sensor}", "--frames", "{frames}", "-o", "x.png", "--save-images",
      UNWRITABLE + ".npy"], "--save-images"),
    (["recon-eval", "--model", "{sensor}", "--dataset", "{dataset}", "--figure", "{under}/e.png"], "--figure"),
    (["recon-train", "--model", "{sensor}", "-o", "{under}/net.npz"], "-o"),
    (["recon-train", "--model", "{sensor}", "-o", UNWRITABLE + ".npz"], "-o"),
    (["classify-train", "--model", "{sensor}", "--out", "{under}/g"], "--out"),
    (["classify-train", "--model", "{sensor}", "--out", "{file}"], "--out"),
    (["classify-train", "--model", "{sensor}", "--cache-dir", "{file}"], "--cache-dir"),
    (["sweep", "{study}", "--out", UNWRITABLE], "--out"),
    (["sweep", "{study}", "--out", UNWRITABLE, "--dry-run"], "--out"),
    (["sweep", "{study}", "--out", "{file}", "--dry-run"], "--out"),
    (["sweep", "{study}", "--set", "cache_dir={file_toml}", "--dry-run"], "cache_dir"),
    (["optimize", "{opt_study}", "--out", "{file}", "--dry-run"], "--out"),
    (["optimize", "{opt_study}", "--out", UNWRITABLE, "--dry-run"], "--out"),
    (["sensitivity", "{study}", "--vary", "rim=channel", "--set", "out={file_toml}"], "out"),
    (["calibrate", "{presses}", "--fit", "hydrogel_shear_kPa=1:50", "--out", "{file}"], "--out"),
])
def test_unwritable_outputs_are_rejected_before_any_work(argv, flag, files):
    if argv[0] == "classify-train":
        pytest.importorskip("torch")
    (files.root / "d.vtu").mkdir(exist_ok=True)
    names = {"under": files.file, "missing": files.root / "no_such_folder", "dir_vtu": files.root / "d.vtu",
             "file": files.file, "sensor": files.sensor, "frames": files.frames, "dataset": files.dataset,
             "study": files.study, "opt_study": files.opt_study, "presses": files.presses,
             "file_toml": json.dumps(str(files.file))}
    _rejected([a.format(**names) for a in argv], files, flag)


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into a read-only folder")
def test_a_read_only_folder_is_rejected(files, tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        _rejected(["sweep", files.study, "--out", ro / "run", "--dry-run"], files, "--out")
        _rejected(["mesh", "-o", ro / "m.vtu"], files, "-o")
    finally:
        ro.chmod(0o755)


def test_good_outputs_reach_the_work(files, tmp_path):
    _accepted(["mesh", "-o", tmp_path / "m.vtu", "--cache-dir", tmp_path / "new" / "cache"], files)
    _accepted(["simulate", "--touch", "50,50,8.75,2", "--touch", "20,20,5,1"], files)
    _accepted(["reconstruct", "--model", files.sensor, "--disc", "50,50,10,0.5", "-o", tmp_path / "r.png",
               "--snr-db", "40"], files)
    _accepted(["sweep", files.study, "--out", tmp_path / "runs" / "s"], files)
    _accepted(["sweep", files.study, "--out", tmp_path / "runs" / "s", "--dry-run"], files)
    assert not (tmp_path / "runs").exists()  # checking created nothing
    _accepted(["recon-train", "--model", files.sensor, "-o", tmp_path / "n.npz", "--per-count", "6"], files)


def test_study_file_not_utf8_and_evaluate_not_callable(files):
    _rejected(["sweep", files.binary], files, "STUDY", "UTF-8")
    _rejected(["optimize", files.binary, "--dry-run"], files, "STUDY", "UTF-8")
    _rejected(["sensitivity", files.binary, "--vary", "rim=channel"], files, "STUDY", "UTF-8")
    _rejected(["sweep", files.study, "--evaluate", "os:sep", "--dry-run"], files, "--evaluate", "callable")
    _rejected(["sweep", files.study, "--evaluate", "math:pi"], files, "--evaluate", "callable")
    _rejected(["sweep", files.study, "--evaluate", "no_such_module_x:f", "--dry-run"], files, "--evaluate")


def test_study_physics_and_depth_range(files):
    # the complete electrode model divides by z_c: 0 would be accepted and then fail every phantom
    _rejected(["sweep", files.study, "--set", "physics.contact_impedance_ohm_m2=0", "--dry-run"], files,
              "contact_impedance_ohm_m2")
    _rejected(["sweep", files.study, "--physics", "contact_impedance_ohm_m2=0", "--dry-run"], files,
              "--physics contact_impedance_ohm_m2")
    _rejected(["simulate", "--touch", "50,50,8,2", "--contact-impedance", "0"], files, "contact_impedance")
    # a 9 mm stack: the range [1, 12] is refused whatever the draws (here one phantom, likely drawn < 9 mm)
    line = _rejected(["sweep", files.study, "--set", "phantoms.depth_mm=[1,12]", "--dry-run"], files,
                     "phantoms.depth_mm", "< 9")
    assert "[1.0, 12.0]" in line or "[1, 12]" in line


def test_physics_settings_reject_zero_contact_impedance():
    from latticeopt.coupled import PhysicsSettings
    from latticeopt.errors import ParameterError

    with pytest.raises(ParameterError, match="contact_impedance_ohm_m2"):
        PhysicsSettings(contact_impedance_ohm_m2=0.0)


@pytest.mark.parametrize("touch", ["nan,50,10,0.5", "150,50,10,0.5", "50,-1,10,0.5", "50,50,inf,0.5",
                                   "50,50,1e9,0.5", "50,50,10,inf", "50,50,10,0", "50,50,-3,0.5", "50,50,10"])
def test_reconstruct_disc_values(touch, files):
    _rejected(["reconstruct", "--model", files.sensor, "--disc", touch, "-o", "x.png"], files, "--disc")


def test_reconstruct_touch_names_the_disc_flag(files, tmp_path):
    # --touch is X,Y,R,D (a press) everywhere else; in reconstruct it once meant a disc X,Y,DIAMETER,RATIO
    line = _rejected(["reconstruct", "--model", files.sensor, "--touch", "50,50,8.75,4", "-o", tmp_path / "r.png"],
                     files, "--touch", "--disc X,Y,DIAMETER,RATIO", "50,50,8.75,4")
    assert line.startswith("latticeopt reconstruct: error: --touch")
    assert not (tmp_path / "r.png").exists()
    _accepted(["reconstruct", "--model", files.sensor, "--disc", "50,50,8.75,4", "-o", tmp_path / "r.png"], files)


@pytest.mark.parametrize("flag, value", [("--snr-db", "nan"), ("--snr-db", "-1000"), ("--seed", "-1"),
                                         ("--max-frames", "0"), ("--prior", "x")])
def test_reconstruct_numbers(flag, value, files):
    _rejected(["reconstruct", "--model", files.sensor, "--disc", "50,50,10,0.5", "-o", "x.png", f"{flag}={value}"],
              files, flag)


def test_complex_frames_are_refused(files):
    _rejected(["reconstruct", "--model", files.sensor, "--frames", files.complex_frames, "-o", "x.png"], files,
              "--frames", "np.abs")
    _rejected(["classify", "--model", files.classifier, "--frames", files.complex_sequences], files,
              "--frames", "np.abs")


@pytest.mark.parametrize("flag, value, text", [
    ("--epochs", "0", ""), ("--batch-size", "0", ""), ("--lr", "nan", ""), ("--lr", "0", ""),
    ("--patience", "0", ""), ("--threads", "0", ""), ("--dataset", "data.txt", ".npz"),
    ("--per-count", "5", ">= 6"), ("--per-count", "0", ">= 6"), ("--touch-counts", "0,1", ""),
    ("--seed", "-1", ""), ("--jobs", "0", ""), ("--presses", "-1", ""), ("--presses", "10001", "<= 10000"),
    ("--press-seed", "-1", ""),
])
def test_recon_train_arguments(flag, value, text, files, tmp_path):
    _rejected(["recon-train", "--model", files.sensor, "-o", tmp_path / "n.npz", f"{flag}={value}"], files, flag,
              text)


def test_recon_eval_arguments(files):
    base = ["recon-eval", "--model", files.sensor, "--dataset", files.dataset]
    _rejected(base + ["--gn-per-count=-1"], files, "--gn-per-count")
    _rejected(base + ["--methods", ","], files, "--methods", "background")
    _rejected(base + ["--methods", "tikhonov,foo"], files, "--methods")
    _rejected(base + ["--prior", ","], files, "--prior")
    _rejected(base + ["--test-snr-db", "nan"], files, "--test-snr-db")
    _rejected(["recon-eval", "--model", files.sensor, "--dataset", files.root / "missing.npz"], files, "--dataset")


@pytest.mark.parametrize("argv, module, flag", [
    (["recon-train", "--model", "{sensor}", "-o", "{tmp}/n.npz", "--per-count", "6", "--dataset", "{tmp}/d.npz"],
     "torch", "PyTorch"),
    (["recon-train", "--model", "{sensor}", "-o", "{tmp}/n.npz", "--per-count", "6"], "skimage", "scikit-image"),
    (["recon-eval", "--model", "{sensor}", "--dataset", "{dataset}", "--methods", "tikhonov", "--figure",
      "{tmp}/e.png"], "skimage", "scikit-image"),
    (["recon-eval", "--model", "{sensor}", "--dataset", "{dataset}", "--methods", "tikhonov,dnn"], "torch",
     "--methods dnn"),
    (["reconstruct", "--model", "{sensor}", "--frames", "{frames}", "--method", "dnn", "-o", "{tmp}/r.png"], "torch",
     "--method dnn"),
    (["classify-train", "--model", "{sensor}", "--out", "{tmp}/g"], "torch", "PyTorch"),
    (["sweep", "{study}", "--backend", "dask", "--out", "{tmp}/run"], "distributed", "--backend dask"),
    (["sweep", "{study}", "--backend", "dask", "--out", "{tmp}/run", "--dry-run"], "distributed", "--backend dask"),
    (["optimize", "{opt_study}", "--backend", "dask", "--out", "{tmp}/run"], "distributed", "--backend dask"),
])
def test_a_missing_extra_fails_before_any_work(argv, module, flag, files, tmp_path, monkeypatch):
    """sys.modules[name] = None makes `import name` fail as if the package were not installed. Reaching a stage
    (dataset simulation, training, sweep: patched to raise) would be "accepted", not one line and exit 2."""
    import sys

    from test_cli_fuzz import _import_everything

    from latticeopt._extras import install_command

    _import_everything()  # with every package present, so that only the commands' own check meets the gap
    monkeypatch.setitem(sys.modules, module, None)
    extra = "distributed" if module == "distributed" else "learn"
    monkeypatch.chdir(files.root)  # where run_cli runs the command: the clone's path, not "."
    names = {"sensor": files.sensor, "dataset": files.dataset, "frames": files.frames, "study": files.study,
             "opt_study": files.opt_study, "tmp": tmp_path}
    line = _rejected([a.format(**names) for a in argv], files, flag, "is not installed", install_command(extra))
    assert line.startswith(f"latticeopt {argv[0]}: error: ")
    assert list(tmp_path.iterdir()) == []  # no run folder, dataset, network or figure


def test_classify_train_snr(files):
    pytest.importorskip("torch")
    _rejected(["classify-train", "--model", files.sensor, "--snr", "-1000", "-999"], files, "--snr")
    _rejected(["classify-train", "--model", files.sensor, "--snr", "nan", "40"], files, "--snr")
    _rejected(["classify-train", "--model", files.sensor, "--snr", "60", "40"], files, "--snr")


@pytest.mark.parametrize("cmd", ["indent", "simulate"])
def test_touch_count_matches_the_help(cmd, files):
    from latticeopt.cli import build_parser
    from latticeopt.cli._common import MAX_CLI_TOUCHES

    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command").choices[cmd]
    touch_help = next(a.help for a in sub._actions if a.dest == "touch")
    assert MAX_CLI_TOUCHES == 3 and "up to three touches" in touch_help
    touches = ["20,20,5,1", "80,20,5,1", "20,80,5,1", "80,80,5,1"]
    argv = [cmd]
    for t in touches:
        argv += ["--touch", t]
    _rejected(argv, files, "--touch", "1 to 3")
    _accepted(argv[:7], files)


def test_mesh_width_below_the_smallest_channel(files):
    _rejected(["mesh", "--width", "0.001"], files, "--width", "0.05")


def test_mesh_options_named_by_flag(files):
    _rejected(["mesh", "--layer-cells", "0"], files, "--layer-cells")
    _rejected(["mesh", "--size", "nan"], files, "--mesh-size")  # the old name: the error names the flag
    _rejected(["mesh", "--mesh-size", "nan"], files, "--mesh-size")
    _rejected(["mesh", "--channel-cells", "0"], files, "--channel-cells", "'auto'")
    outcome, status, err = run_cli(["mesh", "--channel-cells", "many"], files.root)  # argparse's own type check
    assert (outcome, status) == ("argparse", 2) and len(err.splitlines()) == 1
    assert "--channel-cells" in err and "'auto'" in err and "'many'" in err


def test_recon_eval_json_is_strict(monkeypatch, capsys, files):
    """--json writes null for a NaN score (e.g. SSIM of an empty image), never NaN."""
    import latticeopt.recon.dataset
    import latticeopt.recon.evaluate
    import latticeopt.sensor_model

    scores = {"n": 1, "cc": float("nan"), "psnr": float("inf"), "ssim": 0.5, "re": 1.0}
    result = {"methods": {"tikhonov/laplacian": {"overall": scores, "by_touches": {1: scores}, "n": 1,
                                                  "seconds_per_frame": 0.1, "lambda_relative": None}}}
    monkeypatch.setattr(latticeopt.sensor_model, "load_sensor_model", lambda path: _stub_model())
    monkeypatch.setattr(latticeopt.recon.dataset.ReconDataset, "load", classmethod(lambda cls, path: None))
    monkeypatch.setattr(latticeopt.recon.evaluate, "evaluate_methods", lambda *a, **k: result)
    assert main(["recon-eval", "--model", str(files.sensor), "--dataset", str(files.dataset), "--methods",
                 "tikhonov", "--json"]) == 0
    out = capsys.readouterr().out

    def reject(name):
        raise ValueError(name)

    data = json.loads(out, parse_constant=reject)
    assert data["methods"]["tikhonov/laplacian"]["overall"]["cc"] is None
    assert np.isfinite(data["methods"]["tikhonov/laplacian"]["overall"]["ssim"])


def test_documented_classify_example_names_a_file_classify_train_writes():
    """docs/gestures.md: `classify --model <classify-train --out>/gesture_lstm.npz` (a model file, not a folder;
    the README no longer shows `classify --model models/`). test_gestures_classify checks the files written."""
    import re
    import shlex
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    text = (root / "docs" / "gestures.md").read_text()
    assert "--model models/" not in (root / "README.md").read_text() + text
    train = shlex.split(re.search(r"latticeopt classify-train .*", text).group(0))
    use = shlex.split(re.search(r"latticeopt classify --model .*", text).group(0))
    model = Path(use[use.index("--model") + 1])
    assert model.parent == Path(train[train.index("--out") + 1])
    assert model.name in ("gesture_cnn.npz", "gesture_lstm.npz")


@pytest.mark.parametrize("size", ["1e308", "1e6"])
def test_huge_sensor_is_rejected_before_the_layout_is_built(size, files):
    _rejected(["render", "--sensor-size", size], files, "--sensor-size", "400 pitches")
    _rejected(["mesh", "--sensor-size", size, "--pitch", "20"], files, "--sensor-size", "8000 mm")


def test_forward_simulate_and_export_state_both_conductivity_defaults():
    from latticeopt.cli import build_parser
    from latticeopt.electrics import DEFAULT_SIGMA_S_PER_M
    from latticeopt.sensor_model import SIGMA0_S_PER_M

    commands = next(a for a in build_parser()._actions if a.dest == "command").choices
    for cmd in ("forward", "simulate", "export"):
        sigma = next(a for a in commands[cmd]._actions if a.dest == "sigma")
        own = SIGMA0_S_PER_M if cmd == "export" else DEFAULT_SIGMA_S_PER_M
        assert sigma.default == own, cmd
        for value in (SIGMA0_S_PER_M, DEFAULT_SIGMA_S_PER_M):  # its own default and the other's, in S/m
            assert f"{value:g}" in sigma.help, (cmd, sigma.help)
        assert "docs/sensor_model.md" in sigma.help and f"{DEFAULT_SIGMA_S_PER_M / SIGMA0_S_PER_M:.0f} times" in \
            sigma.help


def _help(cmd: str) -> str:
    from latticeopt.cli import build_parser

    sub = next(a for a in build_parser()._actions if a.dest == "command").choices[cmd]
    return " ".join(sub.format_help().split())


def test_help_names_the_files_written_without_being_named():
    from latticeopt.cli import build_parser
    from latticeopt.cli.calibrate import CALIBRATION_FILES
    from latticeopt.cli.mesh import RENDER_OUTPUT

    commands = next(a for a in build_parser()._actions if a.dest == "command").choices
    assert commands["render"].get_default("output") == RENDER_OUTPUT
    assert f"write the picture to {RENDER_OUTPUT}" in _help("render")
    assert all(name in _help("calibrate") for name in CALIBRATION_FILES) and "runs/calibrate-<DATA stem>" in \
        _help("calibrate")
    assert commands["classify-train"].get_default("out") == "gestures_out"
    text = _help("classify-train")
    for name in ("gestures_out", "gesture_cnn.npz", "gesture_lstm.npz", "confusion_cnn.png", "confusion_lstm.png",
                 "report.md", "summary.json", "--cache-dir"):
        assert name in text, name
    for name in ("sensitivity.csv", "tornado.png"):
        assert name in _help("sensitivity")
    for name in ("results.sqlite", "_history.csv", "_report.txt", "_result.json", "_convergence.png", "_path.png",
                 "categories.csv"):
        assert name in _help("optimize")
    assert "writes no other file unless -o or --stl" in _help("mesh")


@pytest.mark.parametrize("study, extra", [("sensitivity_press.toml", []),
                                          ("quick.toml", ["phantoms.counts={1=2}"]),
                                          ("uniformity_layouts.toml", ["probes.grid=2", "probes.radius_mm=10"])])
def test_sweep_help_names_every_file_a_sweep_writes(study, extra, tmp_path):
    from pathlib import Path

    from test_sensitivity import press_model

    from latticeopt.study.config import load_study
    from latticeopt.study.sweep import run_sweep

    root = Path(__file__).resolve().parents[1] / "studies"
    s = load_study(root / study, [f"out={(tmp_path / 'o').as_posix()!r}", *extra])
    run_sweep(s, press_model, jobs=1, progress=False)
    written = sorted(p.name for p in (tmp_path / "o").iterdir())
    assert "results.sqlite" in written
    text = _help("sweep")
    assert [name for name in written if name not in text] == []
