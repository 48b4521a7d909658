"""Point-electrode mode against pyEIT 1.2.4 on the same tetrahedral mesh."""

import numpy as np
import pytest
from pyeit.eit import protocol as pyeit_protocol
from pyeit.eit.fem import EITForward
from pyeit.mesh import PyEITMesh

from latticeopt.design import LatticeDesign
from latticeopt.electrics import ForwardModel
from latticeopt.mesh import MeshSettings, mesh_design


@pytest.fixture(scope="module")
def pair():
    mesh = mesh_design(LatticeDesign(width_mm=4, thickness_mm=3), MeshSettings(size_mm=5), cache_dir=False)
    base = ForwardModel(mesh, electrode_mode="point", current_A=1.0)
    rng = np.random.default_rng(6)
    sigma = rng.uniform(0.5, 2.0, base.mesh.n_tets)
    ours = base.with_conductivity(sigma)
    el_pos = ours.point_nodes
    ref = int(np.setdiff1d(np.arange(ours.mesh.n_nodes), el_pos)[0])
    # pyEIT's tet stiffness uses the opposite vertex order for a positive volume: swap two vertices.
    tets = ours.mesh.tets[:, [0, 2, 1, 3]]
    pm = PyEITMesh(node=ours.mesh.nodes_mm * 1e-3, element=tets, perm=sigma, el_pos=el_pos, ref_node=ref)
    fwd = EITForward(pm, pyeit_protocol.create(16, 1, 1, "std"))
    return ours, fwd, sigma


def test_voltages_match_pyeit(pair):
    ours, fwd, sigma = pair
    v = fwd.solve_eit(perm=sigma)  # unit current, metres: volts per ampere
    rel = np.max(np.abs(ours.voltages - v)) / np.max(np.abs(v))
    print(f"point electrodes vs pyEIT: max relative difference {rel:.1e}")
    assert rel < 1e-6


def test_jacobian_matches_pyeit(pair):
    ours, fwd, sigma = pair
    jac, v0 = fwd.compute_jac(perm=sigma)
    # pyEIT's compute_jac returns r K_e f, i.e. -dV/dsigma in our sign convention.
    rel = np.linalg.norm(ours.jacobian() + jac) / np.linalg.norm(jac)
    print(f"point-electrode Jacobian vs -pyEIT: relative difference {rel:.1e}")
    assert rel < 1e-6
