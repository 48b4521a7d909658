"""Calibration against models with known answers: exact recovery, closed-form least-squares errors, bounds."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest

from latticeopt.cli import main
from latticeopt.errors import ParameterError
from latticeopt.study.calibrate import (
    FitParameter,
    calibrate,
    parse_fit,
    read_presses,
)

DATA = Path(__file__).resolve().parents[1] / "studies" / "data" / "paper_press_measured.csv"
K = "hydrogel_shear_kPa"


def linear_predictor(presses, fitted):
    """TEST DOUBLE of the coupled model: V_rel = k * (1 + w / 4) * depth / 100, linear in the fitted k."""
    k = fitted[K]
    return [np.array([k * (1 + p.design.width_mm / 4) * p.touch.depth_mm / 100]) for p in presses]


def _write(path: Path, rows, extra_cols=()) -> Path:
    cols = ["thickness_mm", "width_mm", "x_mm", "y_mm", "radius_mm", "depth_mm", *extra_cols]
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(cols)
        w.writerows(rows)
    return path


def _presses(tmp_path, k_true=7.0, noise=None, n_depths=(2, 3, 4)):
    rows = []
    rng = np.random.default_rng(0)
    for w in (0, 2, 4, 6):
        for d in n_depths:
            v = k_true * (1 + w / 4) * d / 100
            if noise:
                v *= 1 + noise * rng.standard_normal()
            rows.append([3, w, 50, 50, 8.75, d, v])
    return read_presses(_write(tmp_path / "d.csv", rows, ["v_rel"]))


def test_noise_free_data_are_recovered_exactly(tmp_path):
    cal = calibrate(_presses(tmp_path), [FitParameter(K, 1, 50)], linear_predictor, profile_points=5)
    # nlopt stops at x tolerance 1e-4 of the unit box (0.005 kPa here): relative error below 2e-4 per press
    assert cal.values[K] == pytest.approx(7.0, rel=2e-4)
    assert cal.rss < 12 * 2e-4 ** 2 and not cal.at_bound


def test_standard_error_equals_closed_form_least_squares(tmp_path):
    presses = _presses(tmp_path, noise=0.05)
    cal = calibrate(presses, [FitParameter(K, 1, 50)], linear_predictor, profile_points=0, max_evals=60)
    # Residuals r_i = (k a_i - m_i) / m_i are linear in k: ordinary least squares with J_i = a_i / m_i.
    a = np.array([(1 + p.design.width_mm / 4) * p.touch.depth_mm / 100 for p in presses])
    m = np.array([p.v_rel for p in presses])
    J = a / m
    k_hat = float(J @ np.ones_like(J) / (J @ J))
    r = J * k_hat - 1
    se = math.sqrt((r @ r) / (len(m) - 1) / (J @ J))
    assert cal.values[K] == pytest.approx(k_hat, rel=1e-3)
    assert cal.standard_errors[K] == pytest.approx(se, rel=1e-2)


def test_a_value_outside_the_bounds_ends_on_the_bound_and_is_flagged(tmp_path):
    cal = calibrate(_presses(tmp_path, k_true=80.0), [FitParameter(K, 1, 50)], linear_predictor, profile_points=3)
    assert cal.values[K] == pytest.approx(50.0, abs=0.05)
    assert cal.at_bound == (K,)


def test_predictive_check_fits_on_a_subset_and_predicts_the_rest(tmp_path):
    cal = calibrate(_presses(tmp_path), [FitParameter(K, 1, 50)], linear_predictor,
                    fit_on={"width_mm": ["0", "4"]}, profile_points=0)
    held = [r for r in cal.rows if not r["used_in_fit"]]
    assert len(held) == 6 and all(r["relative_residual"] < 1e-4 for r in held)


def test_voltage_frames_with_a_reference_row(tmp_path):
    base = np.linspace(1.0, 2.0, 208)

    def frame_predictor(presses, fitted):
        return [(fitted[K] * 1e-3 * p.touch.depth_mm * np.sin(np.arange(208))) for p in presses]

    rows = [[3, 4, 50, 50, 8.75, 0, *base]]
    for d in (2, 4):
        rows.append([3, 4, 50, 50, 8.75, d, *(base * (1 + 9e-3 * d * np.sin(np.arange(208))))])
    presses = read_presses(_write(tmp_path / "v.csv", rows, [f"V{i}" for i in range(1, 209)]))
    cal = calibrate(presses, [FitParameter(K, 1, 50)], frame_predictor, profile_points=0)
    assert cal.values[K] == pytest.approx(9.0, rel=1e-4)


@pytest.mark.parametrize("rows, cols, match", [
    ([[3, 4, 50, 50, 8.75, 4, "x"]], ["v_rel"], r"row 2, v_rel: expected a number"),
    ([[3, 4, 50, 50, 8.75, 0, 0.1]], ["v_rel"], r"row 2, depth_mm: expected a press"),
    ([[3, 4, 50, 50, 8.75, 4, 0.1, 2]], ["v_rel", "colour"], r"columns: expected design keys"),
    ([[3, 4, 50, 50, 8.75, 4]], [], r"columns: expected either v_rel or all of V1..V208"),
    ([[3, 13, 50, 50, 8.75, 4, 0.1]], ["v_rel"], r"row 2, width_mm: expected 0 \(no lattice\)"),
    ([[3, 4, 99, 50, 8.75, 4, 0.1]], ["v_rel"], r"row 2, "),
])
def test_bad_data_files_name_the_row_and_column(tmp_path, rows, cols, match):
    with pytest.raises(ParameterError, match=match):
        read_presses(_write(tmp_path / "bad.csv", rows, cols))


def test_fit_arguments_are_checked():
    assert parse_fit("hydrogel_shear_kPa=1:50") == FitParameter(K, 1.0, 50.0)
    for text, match in (("hydrogel_shear_kPa=50", "KEY=LOW:HIGH"), ("colour=1:2", "numeric \\[physics\\] key"),
                        ("hydrogel_shear_kPa=5:1", "LOW < HIGH"), ("hydrogel_shear_kPa=-1:5", "inside the key")):
        with pytest.raises(ParameterError, match=match):
            parse_fit(text)


def test_more_parameters_than_presses_is_refused():
    presses = read_presses(DATA)
    with pytest.raises(ParameterError, match="fewer fitted parameters than fitted presses"):
        calibrate(presses, [FitParameter(K, 1, 50), FitParameter("silicone_shear_kPa", 5, 60),
                            FitParameter("sigma_S_per_m", 0.1, 10)], linear_predictor)


def test_shipped_example_reads_as_three_presses_of_the_paper():
    presses = read_presses(DATA)
    assert [p.design.width_mm for p in presses] == [0, 4, 6]
    assert [p.v_rel for p in presses] == [0.0375, 0.0692, 0.0613]
    assert all(p.touch.depth_mm == 4 and p.design.thickness_mm == 3 for p in presses)


@pytest.mark.parametrize("argv, names", [
    (["--fit", "hydrogel_shear_kPa=1"], ["--fit", "KEY=LOW:HIGH"]),
    (["--fit", "hydrogel_shear_kPa=1:50", "--physics", "hydrogel_shear_kPa=5"], ["--physics", "other than"]),
    (["--fit", "hydrogel_shear_kPa=1:50", "--physics", "colour=5"], ["--physics", "colour"]),
    (["--fit", "hydrogel_shear_kPa=1:50", "--max-evals", "0"], ["--max-evals"]),
    (["--fit", "hydrogel_shear_kPa=1:50", "--fit-on", "width_mm"], ["--fit-on", "KEY=V1,V2"]),
])
def test_cli_rejects_bad_arguments_in_one_line(argv, names, tmp_path, capsys):
    code = main(["calibrate", str(DATA), "--out", str(tmp_path / "o"), *argv])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1, err
    assert all(n in err for n in names), err
    assert not (tmp_path / "o").exists()


def test_cli_writes_the_files_its_help_names(tmp_path, capsys, monkeypatch):
    import latticeopt.study.calibrate as cal_module
    from latticeopt.cli.calibrate import CALIBRATION_FILES

    data = _write(tmp_path / "d.csv", [[3, w, 50, 50, 8.75, d, 7.0 * (1 + w / 4) * d / 100]
                                       for w in (0, 4) for d in (2, 4)], ["v_rel"])
    monkeypatch.setattr(cal_module, "coupled_predictor", lambda *a, **k: linear_predictor)
    out = tmp_path / "o"
    assert main(["calibrate", str(data), "--fit", f"{K}=1:50", "--out", str(out), "--max-evals", "8",
                 "--profile-points", "0", "-q"]) == 0
    assert sorted(p.name for p in out.iterdir()) == sorted(CALIBRATION_FILES)
    assert f"wrote {out / CALIBRATION_FILES[0]} and {out / CALIBRATION_FILES[1]}" in capsys.readouterr().out


def test_calibration_figure_names_the_presses_layout_and_mesh(tmp_path, saved_figures):
    from test_report_plots import blank_border

    from latticeopt.mesh import MeshSettings
    from latticeopt.study.calibrate import plot_calibration

    def predictor(presses, fitted):  # the test double, carrying a mesh as coupled_predictor's does
        return linear_predictor(presses, fitted)

    predictor.mesh_settings = MeshSettings(size_mm=3.0)
    presses = _presses(tmp_path)
    cal = calibrate(presses, [FitParameter(K, 1, 50)], predictor, fit_on={"width_mm": ["0", "4"]},
                    profile_points=3)
    plot_calibration(cal, tmp_path / "c.png")
    title = " ".join(saved_figures[0]._suptitle.get_text().split())
    assert "12 measured presses (6 fitted, 6 held out), r = 8.75 mm at (50, 50) mm" in title
    assert "square lattice (p = 12.5 mm) and uniform layer, no rim channel, t = 3 mm" in title
    assert "grid mesh, 3 mm" in title
    assert blank_border(tmp_path / "c.png")
