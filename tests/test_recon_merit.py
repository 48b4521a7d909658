"""GREIT figures on images whose figures are known in closed form, and the merit map's symmetry."""

from __future__ import annotations

import numpy as np
import pytest

from latticeopt.cli import main
from latticeopt.design import LatticeDesign
from latticeopt.mesh import MeshSettings
from latticeopt.recon.merit import greit_figures, merit_map
from latticeopt.sensor_model import build_sensor_model

N, L = 96, 100.0
EXTENT = (0.0, L, 0.0, L)
_c = (np.arange(N) + 0.5) * L / N
X, Y = np.meshgrid(_c, _c)


def disc(x, y, r):
    return ((X - x) ** 2 + (Y - y) ** 2 <= r * r).astype(float)


def test_a_disc_image_has_the_closed_form_figures():
    r = 8.0
    f = greit_figures(disc(30, 60, r)[None], [[30, 60]], EXTENT, contrast=1.0)
    assert f["amplitude"][0] == pytest.approx(np.pi * r * r, rel=0.03)
    assert f["position_offset_mm"][0] < L / N
    assert f["resolution"][0] == pytest.approx(np.sqrt(np.pi * r * r) / L, rel=0.02)
    assert f["shape_deformation"][0] < 0.05  # a pixelated circle against its equal-area circle
    assert f["ringing"][0] == 0.0


def test_sign_position_error_ringing_and_shape():
    img = disc(70, 50, 6)  # the target sits at (80, 50): 30 mm from the centre, the image 20 mm
    ring = disc(70, 50, 14) - disc(70, 50, 10)
    f = greit_figures(-(img - 0.1 * ring)[None], [[80, 50]], EXTENT, contrast=-0.5)  # a negative contrast
    assert f["position_error_mm"][0] == pytest.approx(10.0, abs=0.3)  # positive: towards the centre
    assert f["position_offset_mm"][0] == pytest.approx(10.0, abs=0.3)
    assert f["ringing"][0] == pytest.approx(0.1 * ring.sum() / img.sum(), rel=1e-12)
    ellipse = (((X - 50) / 20) ** 2 + ((Y - 50) / 5) ** 2 <= 1).astype(float)
    assert greit_figures(ellipse[None], [[50, 50]], EXTENT, contrast=1.0)["shape_deformation"][0] > 0.3
    # amplitude_rel is relative to the target nearest the centre
    two = np.stack([disc(50, 50, 5), 2 * disc(20, 20, 5)])
    assert greit_figures(two, [[50, 50], [20, 20]], EXTENT, contrast=1.0)["amplitude_rel"] == pytest.approx(
        [1, two[1].sum() / two[0].sum()], rel=1e-12)


@pytest.fixture(scope="module")
def model():
    return build_sensor_model(LatticeDesign(width_mm=4.0, thickness_mm=3.0), MeshSettings(size_mm=5.0),
                              n_pixels=32, cache_dir=False)


def test_merit_map_is_mirror_symmetric_and_skips_targets_on_silicone(model):
    res = merit_map(model, targets=3, lam=1e-3)
    for key in ("amplitude", "position_offset_mm", "resolution", "shape_deformation", "ringing"):
        a = res.figures[key]
        np.testing.assert_allclose(a, a[:, ::-1], rtol=1e-6, atol=1e-9, err_msg=key)  # x -> L - x
        np.testing.assert_allclose(a, a.T, rtol=1e-6, atol=1e-9, err_msg=key)  # x <-> y
    assert np.all(np.isfinite(res.figures["resolution"]))
    # 2 mm targets 6 mm from the edges: the corner ones lie on silicone (rim none) and see nothing
    small = merit_map(model, targets=2, diameter_mm=2.0, lam=1e-3)
    assert np.isnan(small.figures["resolution"]).all()


def test_merit_cli(model, tmp_path, capsys):
    from latticeopt.sensor_model import save_sensor_model

    path = save_sensor_model(model, tmp_path / "s.npz")
    assert main(["merit", str(path), "--targets", "2", "-o", str(tmp_path / "m.png"), "--no-progress"]) == 0
    assert "resolution" in capsys.readouterr().out and (tmp_path / "m.png").stat().st_size > 10_000
    assert main(["merit", str(path), "--targets", "1"]) == 2
    assert "--targets" in capsys.readouterr().err
    assert main(["merit", str(path), "--seed", "-3"]) == 2
    assert "--seed" in capsys.readouterr().err
    assert main(["merit", str(tmp_path / "missing.npz")]) == 2
    assert "MODEL" in capsys.readouterr().err


def test_merit_figure_names_the_layout_mesh_and_targets(model, tmp_path, saved_figures):
    from test_report_plots import blank_border

    from latticeopt.recon.merit import plot_merit_map

    rim = build_sensor_model(LatticeDesign(width_mm=4.0, thickness_mm=3.0, rim="channel"),
                             MeshSettings(size_mm=5.0), n_pixels=32, cache_dir=False)
    for i, m in enumerate((model, rim)):
        plot_merit_map(merit_map(m, targets=7, lam=1e-3), tmp_path / f"m{i}.png")
    titles = [" ".join(fig._suptitle.get_text().split()) for fig in saved_figures]
    assert titles[0] != titles[1]  # two layouts, two titles
    assert "no rim channel, t = 3 mm, w = 4 mm" in titles[0]
    assert ", rim channel, t = 3 mm, w = 4 mm" in titles[1] and "no rim channel" not in titles[1]
    for title in titles:
        assert "49 targets (7 x 7)" in title and "grid mesh, 5 mm" in title and "noise-free" in title
    assert blank_border(tmp_path / "m0.png") and blank_border(tmp_path / "m1.png")
