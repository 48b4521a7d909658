"""Mesh convergence of the default design's reference voltages on three nested-ish grid meshes."""

import numpy as np

from latticeopt.design import LatticeDesign
from latticeopt.electrics import ForwardModel
from latticeopt.mesh import MeshSettings, mesh_design

# Each level halves every cell: the largest cell, the cells across a channel and through the layer.
LEVELS = [MeshSettings(size_mm=4, channel_cells=1, layer_cells=1),
          MeshSettings(size_mm=2, channel_cells=2, layer_cells=2),  # the default mesh
          MeshSettings(size_mm=1, channel_cells=4, layer_cells=4)]


def test_reference_voltages_converge():
    design = LatticeDesign()  # w = 4, t = 3: the paper's optimum and the default
    V, sizes = [], []
    for s in LEVELS:
        model = ForwardModel(mesh_design(design, s, cache_dir=False))
        V.append(model.voltages)
        sizes.append(model.mesh.n_nodes)
    change = [np.linalg.norm(V[i + 1] - V[i]) / np.linalg.norm(V[i + 1]) for i in range(2)]
    worst = np.max(np.abs(V[2] - V[1]) / np.abs(V[2]))
    print(f"\nreference voltages, hydrogel nodes {sizes}: relative change {change[0]:.4f} (h 4 -> 2 mm), "
          f"{change[1]:.4f} (h 2 -> 1 mm); worst channel {worst:.4f}")
    assert change[1] < change[0]
    assert change[1] < 0.05
