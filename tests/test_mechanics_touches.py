"""Indentation with several touches and with the spherical tip."""

import numpy as np
import pytest

from latticeopt import LatticeDesign, MeshSettings, mesh_design
from latticeopt.mechanics import IndentationSolver, IndentSettings

DESIGN = LatticeDesign(size_mm=50.0, width_mm=4.0, thickness_mm=3.0)


@pytest.fixture(scope="module")
def mesh():
    return mesh_design(DESIGN, MeshSettings(size_mm=2.5), cache_dir=False)


@pytest.fixture(scope="module")
def solver(mesh):
    return IndentationSolver(mesh, IndentSettings())


def test_far_apart_touches_act_almost_independently(solver):
    touches = [(12, 12, 6.25, 1.0), (38, 12, 6.25, 1.5), (25, 38, 6.25, 0.75)]
    together = solver.solve(touches).forces_N
    alone = np.array([solver.solve([t]).forces_N[0] for t in touches])
    assert len(together) == 3
    assert together == pytest.approx(alone, rel=0.05)


def test_sphere_presses_less_than_the_flat_punch_and_only_pushes(mesh, solver):
    sphere = IndentationSolver(mesh, IndentSettings(indenter="sphere"))
    flat = solver.solve([(25, 25, 7.5, 1.5)])
    res = sphere.solve([(25, 25, 7.5, 1.5)])
    assert 0 < res.forces_N[0] < flat.forces_N[0]
    assert res.solver["contact_nodes"][0] < flat.solver["contact_nodes"][0]
    deeper = sphere.solve([(25, 25, 7.5, 2.5)])
    assert deeper.forces_N[0] > res.forces_N[0]
    assert deeper.solver["contact_nodes"][0] >= res.solver["contact_nodes"][0]
