"""``latticeopt export / reconstruct / recon-train / recon-eval`` end to end on a coarse mesh."""

import json

import numpy as np
import pytest

from latticeopt.cli import main
from latticeopt.recon.dataset import add_noise, render_touches
from latticeopt.sensor_model import SensorSimulator, load_sensor_model

COARSE = ["--width", "4", "--thickness", "3", "--size", "5", "--no-cache"]


def _reject_constant(name):
    raise ValueError(f"not JSON: {name}")




def _colorbars(fig):
    return [ax for ax in fig.axes if ax.get_label() == "<colorbar>"]


def _inside(fig, artist) -> bool:
    fig.canvas.draw()  # lay out again at the figure's own dpi (savefig drew it at another)
    renderer = fig.canvas.get_renderer()
    box, page = artist.get_window_extent(renderer), fig.bbox
    return box.x0 >= page.x0 - 1 and box.x1 <= page.x1 + 1 and box.y0 >= page.y0 - 1 and box.y1 <= page.y1 + 1


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
    assert main(["reconstruct", "--model", str(model_path), "--disc", "50,50,20,0.2", "--snr-db", "50",
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
    args = ["reconstruct", "--model", str(model_path), "--disc", "50,50,20,0.2", "-o", str(tmp_path / "x.png")]
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
    captured = capsys.readouterr()
    text = captured.out
    assert "simulated test set" in text and "paper (real data" in text and ds.exists()
    # what it does before the progress bars (on stderr, stdout keeps the results)
    assert "building the dataset: 10 samples for each of 2 touch counts" in captured.err
    assert "preparing 14 training samples x 8" in captured.err
    assert main(["recon-eval", "--model", str(model_path), "--dataset", str(ds), "--net", str(net),
                 "--prior", "noser,laplacian", "--gn-per-count", "1", "--figure", str(fig), "--json"]) == 0
    out = json.loads(capsys.readouterr().out, parse_constant=_reject_constant)  # strict JSON: null, never NaN
    assert out["methods"]["background"]["overall"]["cc"] is None  # the correlation of a constant image
    names = set(out["methods"])
    assert names == {"background", "tikhonov/noser", "tikhonov/laplacian", "gn/noser", "gn/laplacian", "dnn"}
    assert out["methods"]["gn/noser"]["n"] == 2 and out["methods"]["dnn"]["n"] == 2  # 10 % of 10 per count
    assert set(out["methods"]["dnn"]["by_touches"]) == {"1", "2"}
    greit = out["methods"]["tikhonov/noser"]["greit"]  # over the test part's one-touch frames
    assert greit["n"] == 1 and 0 < greit["resolution"] <= 1 and greit["ringing"] >= 0
    assert out["methods"]["background"]["greit"] == {"n": 1}  # a blank image has nothing to score
    assert fig.stat().st_size > 10_000


def test_reconstruct_figure_has_truth_beside_the_image_with_colour_bars(model_path, tmp_path, capsys,
                                                                       saved_figures):
    assert main(["reconstruct", "--model", str(model_path), "--disc", "50,50,20,0.2", "--disc", "25,75,15,1.8",
                 "-o", str(tmp_path / "r.png")]) == 0
    capsys.readouterr()
    fig, = saved_figures
    width, height = fig.get_size_inches()
    assert width > 1.5 * height  # side by side, not stacked
    images = [ax for ax in fig.axes if ax.images]
    assert [ax.get_title().split(",")[0] for ax in images] == ["truth", "reconstruction"]
    assert images[0].get_position().y0 == pytest.approx(images[1].get_position().y0)
    assert all(ax.get_xlabel() == "x (mm)" and ax.get_ylabel() == "y (mm)" for ax in images)
    bars = _colorbars(fig)
    assert len(bars) == 2
    for bar in bars:
        label = bar.yaxis.label
        assert "sigma_0" in label.get_text() and _inside(fig, label)  # units, not clipped


def test_recon_eval_figure_has_a_colour_bar_per_column(model_path, tmp_path, capsys, saved_figures):
    from latticeopt.recon.dataset import DatasetConfig, generate_dataset

    ds = tmp_path / "ds.npz"
    generate_dataset(load_sensor_model(model_path), DatasetConfig(per_count=10, touch_counts=(1, 2))).save(ds)
    assert main(["recon-eval", "--model", str(model_path), "--dataset", str(ds), "--methods", "background,tikhonov",
                 "--figure", str(tmp_path / "c.png"), "--no-progress"]) == 0
    captured = capsys.readouterr()
    assert captured.err == ""  # --no-progress
    fig, = saved_figures
    images = [ax for ax in fig.axes if ax.images]
    assert len(images) == 2 * 3  # two touch counts x (truth, background, tikhonov)
    bars = _colorbars(fig)
    assert len(bars) == 3 and all("sigma_0" in b.xaxis.label.get_text() and _inside(fig, b.xaxis.label)
                                  for b in bars)
    assert "normalized" not in fig.get_suptitle()
    # unnormalized: the truth column's scale is the truth's largest change, not 1
    truth_limit = max(abs(ax.images[0].get_array()).max() for ax in images[::3])
    assert images[0].images[0].get_clim()[1] == pytest.approx(truth_limit)


def test_recon_train_writes_nothing_into_the_working_folder(model_path, tmp_path, monkeypatch, capsys):
    pytest.importorskip("torch")
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    net = tmp_path / "net.npz"
    assert main(["recon-train", "--model", str(model_path), "--per-count", "10", "--touch-counts", "1",
                 "--epochs", "1", "--threads", "1", "-o", str(net), "--json"]) == 0
    out = json.loads(capsys.readouterr().out, parse_constant=_reject_constant)
    assert out["output"] == str(net) and net.is_file()
    assert list(work.iterdir()) == []
