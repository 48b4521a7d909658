"""Sweep figures: the uniform layer drawn apart from the lattice widths; every figure names its mesh and
phantom count."""

from __future__ import annotations

import numpy as np

from latticeopt.study.config import study_from_dict
from latticeopt.study.plots import plot_heatmap, plot_lines


def _study(tmp_path, mesh=None):
    return study_from_dict({"name": "map", "out": str(tmp_path / "out"), "design": {"pitch_mm": 12.5},
                            "grid": {"thickness_mm": [1.0, 3.0], "width_mm": [0, 2, 4]},
                            "phantoms": {"seed": 1, "counts": {"1": 2, "2": 1}},
                            "mesh": mesh or {"mesher": "grid", "size_mm": 4.0, "channel_cells": 1}})


def _summary(study):
    return [{"v_rel_mean": 0.01 * (1 + d.width_mm + d.thickness_mm), "v_rel_se": 0.001, "n": len(study.phantoms)}
            for d in study.designs]


def test_uniform_layer_is_not_joined_to_the_lattice_widths(tmp_path, saved_figures):
    study = _study(tmp_path)
    plot_lines(study, _summary(study), tmp_path / "lines.png")
    fig, = saved_figures
    ax = fig.axes[0]
    joined = [ln for ln in ax.lines if len(ln.get_xdata()) > 1 and ln.get_linestyle() != "None"]
    assert joined, "the lattice widths are joined by lines"
    for ln in joined:
        x = np.asarray(ln.get_xdata(), dtype=float)
        assert 0.0 not in x, x  # w = 0 (a different topology) never on a line with w = 2
    isolated = [ln for ln in ax.lines if ln.get_marker() == "s" and list(ln.get_xdata()) == [0]]
    assert len(isolated) == 2  # one uniform-layer point per thickness
    assert any("uniform" in t.get_text() for t in ax.get_legend().get_texts())
    title = ax.get_title()
    assert "3 phantoms per design" in title and "grid mesh, 4 mm" in title and ">= 1 cell across a channel" in title


def test_heatmap_title_names_mesh_and_phantoms(tmp_path, saved_figures):
    study = _study(tmp_path, mesh={"size_mm": 5.0})  # "auto" resolves to the grid mesher for the square lattice
    assert plot_heatmap(study, _summary(study), tmp_path / "heat.png") is not None
    title = saved_figures[0].axes[0].get_title()
    assert "3 phantoms per design" in title and "grid mesh, 5 mm" in title


def test_figures_say_whether_the_mesh_is_converged(tmp_path, saved_figures):
    coarse = _study(tmp_path)  # 4 mm, one cell across a channel: coarser than the default
    default = _study(tmp_path, mesh={"size_mm": 2.0})
    finer = _study(tmp_path, mesh={"size_mm": 1.4, "channel_cells": 3, "layer_cells": 3})
    for study in (coarse, default, finer):
        plot_heatmap(study, _summary(study), tmp_path / "map.png")
    titles = [fig.axes[0].get_title() for fig in saved_figures]
    assert "NOT converged" in titles[0]
    assert "NOT converged" not in titles[1] and "converged" in titles[1]
    assert "NOT converged" not in titles[2] and "converged" in titles[2]


def test_a_long_two_level_title_stays_inside_the_figure(tmp_path, saved_figures):
    study = study_from_dict({"name": "paper_width_by_thickness_map", "out": str(tmp_path / "out"),
                             "grid": {"thickness_mm": [1.0, 3.0], "width_mm": [0, 2, 4]},
                             "phantoms": {"seed": 1, "counts": {"1": 2, "2": 2}}, "multilevel": {"pilot": 4}})
    summary = [dict(s, n_fine=n) for s, n in zip(_summary(study), (2, 3, 3, 2, 3, 3))]
    plot_lines(study, summary, tmp_path / "lines.png")
    plot_heatmap(study, summary, tmp_path / "heat.png")
    for fig in saved_figures:
        fig.canvas.draw()  # lays the title out (constrained layout) before it is measured
        title = fig.axes[0].title.get_window_extent()
        assert "2-3 on this mesh" in " ".join(fig.axes[0].get_title().split())
        assert title.x0 >= 0 and title.x1 <= fig.bbox.x1, (title, fig.bbox)


def _inside(fig, artist) -> bool:
    fig.canvas.draw()  # lays the text out (constrained layout) before it is measured
    box = artist.get_window_extent()
    return box.x0 >= 0 and box.x1 <= fig.bbox.x1


def blank_border(path, width: int = 2) -> bool:
    """True when the saved image's outer ``width`` pixels are all background: nothing drawn runs off the
    figure (a clipped title or label leaves ink on the edge)."""
    import matplotlib.image as mpimg

    a = mpimg.imread(path)[..., :3].mean(axis=-1)
    edge = np.concatenate([a[:width].ravel(), a[-width:].ravel(), a[:, :width].ravel(), a[:, -width:].ravel()])
    return bool(edge.min() > 0.9)


def test_map_titles_name_the_layout(tmp_path, saved_figures):
    plain = _study(tmp_path)
    rim = study_from_dict({"name": "map", "out": str(tmp_path / "rim"), "design": {"rim": "channel"},
                           "grid": {"thickness_mm": [1.0, 3.0], "width_mm": [0, 2, 4]},
                           "phantoms": {"seed": 1, "counts": {"1": 2, "2": 1}}})
    for study in (plain, rim):
        plot_lines(study, _summary(study), tmp_path / "lines.png")
        plot_heatmap(study, _summary(study), tmp_path / "heat.png")
    titles = [" ".join(fig.axes[0].get_title().split()) for fig in saved_figures]
    for title in titles[:2]:
        assert "square lattice (p = 12.5 mm) and uniform layer, no rim channel" in title
    for title in titles[2:]:
        assert "square lattice (p = 12.5 mm) and uniform layer, rim channel" in title
        assert "no rim channel" not in title
    for fig in saved_figures:
        assert _inside(fig, fig.axes[0].title)
    assert blank_border(tmp_path / "lines.png") and blank_border(tmp_path / "heat.png")


def test_press_title_names_layout_thickness_mesh_and_press_and_stays_inside(tmp_path, saved_figures):
    from pathlib import Path

    from latticeopt.study.config import load_study
    from latticeopt.study.plots import plot_press
    from latticeopt.study.store import Evaluation

    study = load_study(Path(__file__).parents[1] / "studies" / "paper_press.toml")
    evaluations = [Evaluation(design_key=d.content_hash(), phantom_key=str(i), settings_key="s", status="ok",
                              v_rel=0.01 * p.touches[0].depth_mm) for d in study.designs
                   for i, p in enumerate(study.phantoms)]
    plot_press(study, evaluations, tmp_path / "press.png")
    fig, = saved_figures
    title = " ".join(fig.axes[0].get_title().split())
    assert "without and with the rim channel, t = 3 mm" in title
    assert "one press, r = 8.75 mm at (50, 50) mm, 9 depths" in title and "grid mesh, 2 mm" in title
    assert _inside(fig, fig.axes[0].title) and blank_border(tmp_path / "press.png")


def test_a_sweep_loads_its_report_code_before_it_runs():
    """Everything that writes a sweep's outputs is imported with the sweep, not after hours of work, so a run that
    outlives an upgrade of the package writes its outputs with the code it started with (a lazily imported plot
    module that asks an already loaded module for a new name fails with ImportError at the end). matplotlib
    itself stays deferred to the drawing."""
    import subprocess
    import sys

    code = ("import sys, latticeopt.study.sweep; "
            "print(sorted(m for m in sys.modules if m.startswith('latticeopt.study.') and 'plot' in m)); "
            "print('matplotlib' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split("\n")
    assert out[0] == "['latticeopt.study.layout_plot', 'latticeopt.study.plots']"
    assert out[1] == "False"
