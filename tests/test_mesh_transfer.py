"""Interpolation of nodal fields between two meshes of one sensor (latticeopt.mesh.transfer)."""

import numpy as np
import pytest

from latticeopt import LatticeDesign, MeshSettings, mesh_design
from latticeopt.mesh.transfer import interpolation_matrix

DESIGN = LatticeDesign(size_mm=50.0, width_mm=4.0, thickness_mm=3.0)


@pytest.fixture(scope="module")
def meshes():
    grid = mesh_design(DESIGN, MeshSettings(mesher="grid", size_mm=5.0, channel_cells=1), cache_dir=False)
    other = mesh_design(DESIGN, MeshSettings(mesher="extruded", size_mm=3.0), cache_dir=False)
    return grid, other


def test_linear_fields_are_reproduced_exactly_at_another_mesh_s_nodes(meshes):
    source, target = meshes  # a structured grid and an unstructured extruded mesh: the nodes do not coincide
    P = interpolation_matrix(source, target.nodes_mm)
    assert P.shape == (target.n_nodes, source.n_nodes) and P.nnz <= 4 * target.n_nodes
    assert np.allclose(np.asarray(P.sum(axis=1)).ravel(), 1.0) and P.min() > -1e-2  # the locator's tolerance
    a = np.array([[0.3, -1.2, 2.0], [0.5, 0.1, -0.7], [1.5, 0.0, 0.4]])
    field = source.nodes_mm @ a + [1.0, -2.0, 0.5]  # affine: P1 interpolation is exact for it
    assert np.max(np.abs(P @ field - (target.nodes_mm @ a + [1.0, -2.0, 0.5]))) < 1e-10


def test_a_nodal_field_at_the_source_s_own_nodes_is_itself(meshes):
    source, _ = meshes
    P = interpolation_matrix(source, source.nodes_mm)
    values = np.sin(source.nodes_mm[:, 0]) + source.nodes_mm[:, 2] ** 2  # not linear: only the nodes agree
    assert np.max(np.abs(P @ values - values)) < 1e-10


def test_round_off_outside_is_clipped_and_a_point_outside_is_refused(meshes):
    source, _ = meshes
    top = np.array([[20.0, 30.0, source.nodes_mm[:, 2].max() + 1e-9]])
    row = interpolation_matrix(source, top)
    assert np.isclose(row.sum(), 1.0) and row.min() >= 0
    with pytest.raises(ValueError, match=r"points_mm: point 1 .* outside the mesh"):
        interpolation_matrix(source, np.array([[20.0, 30.0, 1.0], [20.0, 30.0, 12.0]]))
    with pytest.raises(ValueError, match="shape"):
        interpolation_matrix(source, np.zeros((3, 2)))
