"""Figure captions: the layout and mesh wording every figure uses."""

from __future__ import annotations

from latticeopt.captions import layout_caption, mesh_caption
from latticeopt.design import LatticeDesign
from latticeopt.mesh import MeshSettings, mesh_design
from latticeopt.render import caption


def test_layout_caption_names_families_rim_and_a_shared_thickness():
    both = [LatticeDesign(width_mm=3, pattern=p, rim=r) for p in ("square", "hexagonal") for r in ("none", "channel")]
    assert layout_caption(both) == "square/hexagonal lattices (p = 12.5 mm), without and with the rim channel, t = 3 mm"
    assert layout_caption([LatticeDesign(width_mm=0, thickness_mm=2)]) == "uniform layer, t = 2 mm"
    framed = LatticeDesign(width_mm=4, frame_mm=5, rim="channel", thickness_mm=1)
    assert layout_caption([framed]) == "square lattice (p = 12.5 mm), rim channel, frame 5 mm, t = 1 mm"


def test_mesh_caption_counts_cells_only_for_the_structured_meshers():
    assert mesh_caption({"mesher": "tetwild", "size_mm": 3.0}) == "tetwild mesh, 3 mm"
    assert mesh_caption({"mesher": "extruded", "size_mm": 2.0, "channel_cells": 1, "layer_cells": 3}) == \
        "extruded mesh, 2 mm, 1 cell across a channel, 3 through the layer"


def test_render_caption_names_layout_width_and_mesh(tmp_path):
    mesh = mesh_design(LatticeDesign(width_mm=4, thickness_mm=3, rim="channel"), MeshSettings(size_mm=5.0),
                       cache_dir=tmp_path)
    assert caption(mesh) == ("square lattice (p = 12.5 mm), rim channel, t = 3 mm, w = 4 mm\n"
                             f"grid mesh, 5 mm, 2 cells across a channel, 2 through the layer, {mesh.n_nodes} nodes")
