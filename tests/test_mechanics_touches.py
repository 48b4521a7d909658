"""Indentation with several touches and with the spherical tip."""

import numpy as np
import pytest

from latticeopt.errors import ConvergenceError, ParameterError
from latticeopt.mechanics import IndentationSolver, IndentSettings, indenters


def test_far_apart_touches_act_almost_independently(stack_solver):
    touches = [(12, 12, 6.25, 1.0), (38, 12, 6.25, 1.5), (25, 38, 6.25, 0.75)]
    together = stack_solver.solve(touches).forces_N
    alone = np.array([stack_solver.solve([t]).forces_N[0] for t in touches])
    assert len(together) == 3
    assert together == pytest.approx(alone, rel=0.05)


def test_sphere_presses_less_than_the_flat_punch_and_only_pushes(stack_mesh, stack_solver):
    sphere = IndentationSolver(stack_mesh, IndentSettings(indenter="sphere"))
    flat = stack_solver.solve([(25, 25, 7.5, 1.5)])
    res = sphere.solve([(25, 25, 7.5, 1.5)])
    assert 0 < res.forces_N[0] < flat.forces_N[0]
    assert res.solver["contact_nodes"][0] < flat.solver["contact_nodes"][0]
    deeper = sphere.solve([(25, 25, 7.5, 2.5)])
    assert deeper.forces_N[0] > res.forces_N[0]
    assert deeper.solver["contact_nodes"][0] >= res.solver["contact_nodes"][0]


def test_a_punch_rounded_all_the_way_in_is_the_sphere(stack_mesh):
    # the rounded rim's profile with e = r is the hemisphere's: the same contact problem, node for node
    sphere = IndentationSolver(stack_mesh, IndentSettings(indenter="sphere")).solve([(25, 25, 7.5, 2.0)])
    rounded = IndentationSolver(stack_mesh, IndentSettings(edge_radius_mm=7.5)).solve([(25, 25, 7.5, 2.0)])
    assert rounded.forces_N == pytest.approx(sphere.forces_N, rel=1e-9)
    assert np.abs(rounded.displacement_mm - sphere.displacement_mm).max() < 1e-9


@pytest.mark.parametrize("edge_mm", [1.0, 3.0])
def test_rounded_edge_contact_is_unilateral_and_softer_than_the_sharp_punch(stack_mesh, stack_solver, edge_mm):
    touch = (25, 25, 7.5, 2.0)
    sharp = stack_solver.solve([touch])
    res = IndentationSolver(stack_mesh, IndentSettings(edge_radius_mm=edge_mm)).solve([touch])
    assert 0 < res.forces_N[0] < sharp.forces_N[0]  # less material under the punch is pushed the full depth
    # KKT of the contact under the rounding, checked on the result: no top node inside the disc lies above the
    # punch's surface, and those it holds (on the surface) are pushed down, never pulled
    ref = res.deformed_mesh.nodes_mm - res.displacement_mm
    top = np.unique(stack_mesh.facets["top"])
    rho = np.hypot(ref[top, 0] - 25, ref[top, 1] - 25)
    inside = top[rho <= 7.5]
    r_in = rho[rho <= 7.5]
    beyond = np.maximum(r_in - (7.5 - edge_mm), 0.0)
    surface = -(2.0 - (edge_mm - np.sqrt(edge_mm ** 2 - beyond ** 2)))  # the punch's u_z above each node
    assert np.all(res.displacement_mm[inside, 2] <= surface + 1e-9)
    held = res.state.contact_nodes[0]
    assert np.isin(inside[beyond == 0], held).all()  # the flat face holds all its nodes
    curved = np.intersect1d(held, inside[beyond > 0])
    assert len(curved)  # the rounding touches
    on = np.isin(inside, curved)
    assert np.abs(res.displacement_mm[inside[on], 2] - surface[on]).max() < 1e-9
    R = res.state.evaluation.residual_N
    assert np.all(-R[3 * curved + 2] >= -1e-6 * res.forces_N[0])


def test_edge_radius_is_checked():
    with pytest.raises(ParameterError, match="edge_radius_mm.*-1"):
        IndentSettings(edge_radius_mm=-1)
    with pytest.raises(ParameterError, match="only the flat punch"):
        IndentSettings(indenter="sphere", edge_radius_mm=1.0)


def test_a_contact_set_that_never_settles_fails_the_step_with_a_named_reason(stack_mesh, monkeypatch):
    # the primal-dual update reports a changed set at every converged iterate, up to the last one allowed: the
    # step must fail (and the press give up) naming why, not fall out of the Newton loop
    monkeypatch.setattr(indenters.Constraints, "update_active", lambda self, *args: True)
    solver = IndentationSolver(stack_mesh, IndentSettings(indenter="sphere"))
    with pytest.raises(ConvergenceError, match=r"no convergence in \d+ iterations \(the contact set still changing"):
        solver.solve([(25, 25, 7.5, 1.0)])


def test_a_rounding_no_node_lies_under_is_reported_once(stack_mesh, caplog):
    # 2.5 mm top elements: a 0.25 mm rounding holds no node (the conforming map puts the flat face's rim nodes on
    # r - e and keeps free nodes 0.3 elements away from it), a 3 mm one holds a ring of them
    touch = (25, 25, 7.5, 1.0)
    thin = IndentationSolver(stack_mesh, IndentSettings(edge_radius_mm=0.25))
    with caplog.at_level("WARNING", logger="latticeopt.mechanics.indent"):
        thin.solve([touch])
        thin.solve([touch])
    said = [r.getMessage() for r in caplog.records if "no top-surface node" in r.getMessage()]
    assert len(said) == 1 and "touch #1" in said[0] and "sharp punch of radius 7.25 mm" in said[0], said
    caplog.clear()
    wide = IndentationSolver(stack_mesh, IndentSettings(edge_radius_mm=3.0))
    with caplog.at_level("WARNING", logger="latticeopt.mechanics.indent"):
        res = wide.solve([touch])
    assert not [r for r in caplog.records if "no top-surface node" in r.getMessage()]
    assert res.solver["contact_nodes"][0] > 0
