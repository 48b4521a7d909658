"""``latticeopt export / reconstruct / recon-train / recon-eval`` end to end on a coarse mesh."""

import json

import numpy as np
import pytest

from latticeopt.cli import main
from latticeopt.recon.dataset import add_noise, render_touches
from latticeopt.sensor_model import SensorSimulator, load_sensor_model

COARSE = ["--width", "4", "--thickness", "3", "--size", "5", "--no-cache"]


@pytest.fixture(scope="module")
def model_path(tmp_path_factory):
    path = tmp_path_factory.mktemp("cli") / "sensor.npz"
    assert main(["export", *COARSE, "-o", str(path), "--json"]) == 0
    return path


def test_export_writes_a_loadable_model(model_path, capsys):
    m = load_sensor_model(model_path)
    assert m.jacobian.shape == (208, 2304) and m.design.width_mm == 4.0 and m.sigma0_S_per_m == 0.00312
    assert main(["export", *COARSE, "--pixels", "32", "-o", str(model_path.with_name("s32.npz"))]) == 0
    out = capsys.readouterr().out
    assert "Jacobian 208 x 1024" in out and "z_c sigma / w = 0.5" in out


def test_reconstruct_simulated_touch(model_path, tmp_path, capsys):
    png, npy = tmp_path / "r.png", tmp_path / "r.npy"
    assert main(["reconstruct", "--model", str(model_path), "--touch", "50,50,20,0.2", "--snr-db", "50",
                 "--method", "tikhonov", "--prior", "laplacian", "-o", str(png), "--save-images", str(npy),
                 "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    (xy, value), = out["peak_mm"]
    assert np.hypot(xy[0] - 50, xy[1] - 50) <= 10 and value < 0
    assert png.stat().st_size > 5000 and np.load(npy).shape == (1, 48, 48)


def test_reconstruct_frames_file_with_gn(model_path, tmp_path, capsys):
    m = load_sensor_model(model_path)
    V = SensorSimulator(m).voltages(render_touches(np.array([[30.0, 70.0, 22.0, 1.9]]), m.sigma0_S_per_m))
    V = add_noise(V, 55, np.random.default_rng(0))
    csv = tmp_path / "frames.csv"
    np.savetxt(csv, V[:, m.independent], delimiter=",", header="104 independent rows", comments="# ")
    assert main(["reconstruct", "--model", str(model_path), "--frames", str(csv), "--method", "gn",
                 "--max-iter", "3", "-o", str(tmp_path / "g.png")]) == 0
    text = capsys.readouterr().out
    assert "frame 0: largest change +" in text and "gn / laplacian" in text


@pytest.mark.parametrize("case", ["frames_shape", "model_corrupt", "method", "lambda", "touch"])
def test_bad_input_is_one_line_exit_2(model_path, tmp_path, capsys, case):
    args = ["reconstruct", "--model", str(model_path), "--touch", "50,50,20,0.2", "-o", str(tmp_path / "x.png")]
    if case == "frames_shape":
        np.save(tmp_path / "f.npy", np.zeros((3, 100)))
        args = ["reconstruct", "--model", str(model_path), "--frames", str(tmp_path / "f.npy"), "-o",
                str(tmp_path / "x.png")]
        expect = "shape (3, 100)"
    elif case == "model_corrupt":
        bad = tmp_path / "bad.npz"
        bad.write_bytes(model_path.read_bytes()[:5000])
        args[2] = str(bad)
        expect = "--model"
    elif case == "method":
        args += ["--method", "svd"]
        expect = "'tikhonov', 'gn', 'dnn'"
    elif case == "lambda":
        args += ["--lambda", "big"]
        expect = "--lambda"
    else:
        args[4] = "50,50"
        expect = "X,Y,DIAMETER,RATIO"
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert expect in err and len(err.splitlines()) == 1 and "Traceback" not in err


def test_train_then_evaluate_every_method(model_path, tmp_path, capsys):
    pytest.importorskip("torch")
    net, ds, fig = tmp_path / "net.npz", tmp_path / "ds.npz", tmp_path / "cmp.png"
    assert main(["recon-train", "--model", str(model_path), "--per-count", "10", "--touch-counts", "1,2",
                 "--dataset", str(ds), "--epochs", "2", "--threads", "1", "-o", str(net)]) == 0
    text = capsys.readouterr().out
    assert "simulated test set" in text and "paper (real data" in text and ds.exists()
    assert main(["recon-eval", "--model", str(model_path), "--dataset", str(ds), "--net", str(net),
                 "--prior", "noser,laplacian", "--gn-per-count", "1", "--figure", str(fig), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    names = set(out["methods"])
    assert names == {"background", "tikhonov/noser", "tikhonov/laplacian", "gn/noser", "gn/laplacian", "dnn"}
    assert out["methods"]["gn/noser"]["n"] == 2 and out["methods"]["dnn"]["n"] == 2  # 10 % of 10 per count
    assert set(out["methods"]["dnn"]["by_touches"]) == {"1", "2"}
    assert fig.stat().st_size > 10_000
