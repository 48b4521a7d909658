"""Coupled simulation: V_rel definition, reference consistency and physical trends on a coarse mesh."""

import dataclasses

import numpy as np
import pytest

from latticeopt import LatticeDesign, MeshSettings
from latticeopt.coupled import CoupledModel, PhysicsSettings, evaluate_phantom, relative_change
from latticeopt.errors import ParameterError
from latticeopt.study.phantoms import Phantom
from latticeopt.study.settings import PHYSICS_KEYS, EvalSettings
from latticeopt.touches import Touch

COARSE = MeshSettings(size_mm=5.0, channel_cells=1, layer_cells=1)


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    return CoupledModel(LatticeDesign(width_mm=4, thickness_mm=3), COARSE,
                        cache_dir=tmp_path_factory.mktemp("meshes"))


def test_relative_change_is_paper_eq5():
    ref = np.array([1.0, -2.0, 4.0])
    touched = np.array([1.1, -1.0, 4.0])
    # |0.1|/1, |1|/2, 0/4 -> mean of 0.1, 0.5, 0
    assert relative_change(touched, ref) == pytest.approx(0.2)


def test_pressed_voltages_match_pyeit_on_the_deformed_mesh(model):
    """The coupled chain (indentation -> deformed hydrogel -> voltages) against an independent solver.

    A copy of the model measures with point electrodes (the mode pyEIT 1.2.4 also has); pyEIT then solves on
    the hydrogel tets placed at the indentation's deformed node coordinates. Agreement checks that the
    coupling hands the deformed geometry to the electrics (node mapping, reuse of the rest-state topology) and
    that the result is the current flow on that geometry, not the rest state: the rest-state voltages differ
    from both by far more than the tolerance.
    """
    import copy

    pytest.importorskip("pyeit")
    from pyeit.eit import protocol as pyeit_protocol
    from pyeit.eit.fem import EITForward
    from pyeit.mesh import PyEITMesh

    from latticeopt.electrics import ForwardModel

    point = copy.copy(model)  # the same mechanics, point-electrode electrics
    point._electrics = copy.copy(model._electrics)
    point._electrics.reference = point.reference = ForwardModel(model.mesh, electrode_mode="point", current_A=1.0)
    point.reference_voltages = point.reference.voltages
    res = point.simulate([Touch(45, 55, 8.75, 2.0)])
    gel = point.reference
    nodes = res.indentation.deformed_mesh.nodes_mm[gel.node_ids] * 1e-3  # metres
    ref = int(np.setdiff1d(np.arange(gel.mesh.n_nodes), gel.point_nodes)[0])
    perm = np.ones(gel.mesh.n_tets)
    # pyEIT's tet stiffness uses the opposite vertex order for a positive volume: swap two vertices
    pm = PyEITMesh(node=nodes, element=gel.mesh.tets[:, [0, 2, 1, 3]], perm=perm, el_pos=gel.point_nodes,
                   ref_node=ref)
    v = EITForward(pm, pyeit_protocol.create(16, 1, 1, "std")).solve_eit(perm=perm)
    scale = np.max(np.abs(v))
    # both solve the same linear P1 system: only rounding separates them (test_electrics_pyeit: ~1e-13)
    assert np.max(np.abs(res.voltages - v)) / scale < 1e-6
    assert np.max(np.abs(res.reference_voltages - v)) / scale > 1e-4


def test_zero_depth_gives_zero_vrel_and_depth_raises_it(model):
    assert model.simulate([Touch(50, 50, 8.75, 0.0)]).v_rel == pytest.approx(0.0, abs=1e-12)
    shallow = model.simulate([Touch(50, 50, 8.75, 0.5)])
    deep = model.simulate([Touch(50, 50, 8.75, 1.5)])
    assert 0 < shallow.v_rel < deep.v_rel
    assert 0 < shallow.forces_N[0] < deep.forces_N[0]
    # Reciprocity survives deformation: the 208 rows are the 104 independent ones twice.
    from latticeopt.electrics import Protocol

    prot = Protocol.adjacent(16)
    v = deep.voltages
    np.testing.assert_allclose(v[prot.reciprocal] * prot.reciprocal_sign, v, rtol=1e-8, atol=1e-12)


def test_mirror_symmetric_touches_give_equal_vrel(model):
    """The default design is symmetric under x -> L - x, so mirrored presses change V equally on average."""
    a = model.simulate([Touch(30, 40, 7.0, 1.0)])
    b = model.simulate([Touch(70, 40, 7.0, 1.0)])
    assert a.v_rel == pytest.approx(b.v_rel, rel=1e-6)
    assert a.forces_N[0] == pytest.approx(b.forces_N[0], rel=1e-6)


def test_a_press_gives_the_same_result_whatever_the_model_ran_before(model, tmp_path):
    """A sweep worker keeps a design's model for its next chunks: a phantom must not see the earlier ones."""
    fresh = CoupledModel(LatticeDesign(width_mm=4, thickness_mm=3), COARSE, cache_dir=tmp_path)
    press = [Touch(40, 55, 7.0, 2.0), Touch(70, 30, 6.0, 1.5)]
    first = fresh.simulate(press)
    model.simulate([Touch(60, 60, 9.0, 3.0)])  # a deeper press, more load steps and another factorization
    after = model.simulate(press)
    np.testing.assert_allclose(after.voltages, first.voltages, rtol=1e-10, atol=0)
    np.testing.assert_allclose(after.indentation.displacement_mm, first.indentation.displacement_mm, rtol=0,
                               atol=1e-12)
    assert after.newton_steps == first.newton_steps


def test_evaluate_phantom_returns_store_keys(tmp_path):
    settings = EvalSettings(mesh=COARSE, cache_dir=str(tmp_path))
    out = evaluate_phantom(LatticeDesign(width_mm=0, thickness_mm=3), Phantom((Touch(50, 50, 7, 1.0),)), settings)
    assert set(out) >= {"v_rel", "voltages", "forces_N", "timings", "max_hydrogel_stretch"}
    assert len(out["voltages"]) == 208 and out["v_rel"] > 0


def test_physics_keys_match_physics_settings():
    assert set(PHYSICS_KEYS) == {f.name for f in dataclasses.fields(PhysicsSettings)}
    with pytest.raises(ParameterError, match="indenter"):
        PhysicsSettings(indenter="cone")
    with pytest.raises(ParameterError, match="physics"):
        PhysicsSettings.from_dict({"sigma": 1})


def test_mechanics_rtol_is_validated_and_does_not_move_vrel(model, tmp_path):
    with pytest.raises(ParameterError, match="mechanics_rtol"):
        PhysicsSettings(mechanics_rtol=0.5)
    assert model.mechanics.settings.rtol == PhysicsSettings().mechanics_rtol
    tight = CoupledModel(model.design, COARSE, PhysicsSettings(mechanics_rtol=1e-9), cache_dir=tmp_path)
    touches = [Touch(35, 60, 8.0, 2.5), Touch(70, 40, 6.5, 1.5)]
    loose, exact = model.simulate(touches), tight.simulate(touches)
    assert tight.mechanics.settings.rtol == 1e-9
    # the default stops well before round-off, yet V_rel agrees far below the mesh error (percent)
    assert loose.v_rel == pytest.approx(exact.v_rel, rel=1e-4)
    assert loose.forces_N == pytest.approx(exact.forces_N, rel=1e-3)


@pytest.mark.parametrize("value", [-1.0, -0.1, 0.0, 0.3, 0.49, 0.4999, 0.5, 0.7, 1e-300, 5.0, 2e7, float("nan"), "x"])
def test_physics_material_keys_accept_exactly_what_the_material_law_accepts(value):
    """One schema: the [physics] material keys have no range of their own, so a value passes both or neither."""
    from latticeopt.mechanics.materials import NeoHookean

    for key, make_law in (("hydrogel_poisson_ratio", lambda x: NeoHookean(5.0, x)),
                          ("silicone_shear_kPa", lambda x: NeoHookean(x, 0.49))):
        try:
            make_law(value)
            law_ok = True
        except ParameterError:
            law_ok = False
        try:
            PhysicsSettings(**{key: value})
            physics_ok = True
        except ParameterError as exc:
            physics_ok = False
            assert exc.name == key
        assert physics_ok == law_ok, (key, value)


@pytest.mark.parametrize("value", [-1, 0, 7, 1000, 1001, 2.5, True, "40", float("nan")])
def test_mechanics_rescue_newton_accepts_exactly_what_the_indentation_accepts(value):
    """One schema: the [physics] key has no range of its own; a value it accepts reaches the solver unchanged."""
    from latticeopt.mechanics import IndentSettings

    try:
        expected = IndentSettings(rescue_newton=value).rescue_newton
    except ParameterError:
        expected = None
    try:
        got = PhysicsSettings(mechanics_rescue_newton=value).indent_settings().rescue_newton
    except ParameterError as exc:
        got = None
        assert exc.name == "mechanics_rescue_newton"
    assert got == expected, value


def test_mechanics_rescue_newton_defaults_to_four_ordinary_budgets():
    """Unset, the rescue gets 4 x max_newton: 160 at nu = 0.49, 240 where the gel is near incompressibility."""
    assert PhysicsSettings().indent_settings().rescue_newton == 160
    assert PhysicsSettings(hydrogel_poisson_ratio=0.4999).indent_settings().rescue_newton == 240


def test_a_separate_mechanics_mesh_that_is_the_same_mesh_changes_nothing(model, tmp_path):
    # settings that differ only in a key the grid mesher ignores: a separate mechanics mesh with the same nodes,
    # so the transfer is the identity and the chain through it must reproduce the plain model
    plain_nodes = model.mesh.nodes_mm
    same = dataclasses.replace(COARSE, epsilon_rel=2e-3)  # a tetwild-only key: another identity, the same grid
    twin = CoupledModel(model.design, COARSE, cache_dir=tmp_path, mechanics_mesh=same)
    assert twin.mechanics_mesh is not twin.mesh and np.array_equal(twin.mechanics_mesh.nodes_mm, plain_nodes)
    touch = [Touch(40, 60, 8.0, 3.0)]
    a, b = model.simulate(touch), twin.simulate(touch)
    assert b.electrics_mesh == "mesh"
    assert b.v_rel == pytest.approx(a.v_rel, rel=2e-4)  # two mechanics solves (see test_conductivity)
    one = CoupledModel(model.design, COARSE, cache_dir=tmp_path, mechanics_mesh=COARSE)
    assert one.mechanics_mesh is one.mesh  # the same settings: no transfer at all


def test_coarse_mechanics_moves_the_fine_hydrogel_by_the_interpolated_displacement(tmp_path):
    design = LatticeDesign(width_mm=4, thickness_mm=3)
    coarse = dataclasses.replace(COARSE, size_mm=8.0)
    hybrid = CoupledModel(design, COARSE, cache_dir=tmp_path, mechanics_mesh=coarse)
    alone = CoupledModel(design, coarse, cache_dir=tmp_path)
    assert hybrid.mechanics_mesh.n_nodes == alone.mesh.n_nodes < hybrid.mesh.n_nodes
    touch = [Touch(50, 50, 8.75, 3.0)]
    h, c = hybrid.simulate(touch), alone.simulate(touch)
    assert h.electrics_mesh == "mesh" and h.voltages.shape == (208,)
    assert np.array_equal(h.reference_voltages, CoupledModel(design, COARSE, cache_dir=tmp_path).reference_voltages)
    assert np.allclose(h.forces_N, c.forces_N, rtol=1e-3)  # the same mechanics
    assert h.v_rel != pytest.approx(c.v_rel, rel=1e-3)  # ... measured on another electrics mesh
    # the hydrogel nodes moved exactly as the P1 interpolant of the coarse displacement
    from latticeopt.mesh.transfer import interpolation_matrix

    gel = hybrid.mesh.nodes_mm[hybrid.reference.node_ids]
    moved = gel + interpolation_matrix(hybrid.mechanics_mesh, gel) @ h.indentation.displacement_mm
    assert np.allclose(hybrid.reference.with_nodes(moved).voltages, h.voltages, rtol=0, atol=1e-12)


def test_a_coarse_mechanics_mesh_is_not_warned_about_but_a_coarse_electrics_mesh_is(tmp_path, caplog, monkeypatch):
    import latticeopt.mesh as mesh_module

    monkeypatch.setattr(mesh_module, "_WARNED_COARSE", set())
    design = LatticeDesign(width_mm=4, thickness_mm=3)
    fine, coarse = dataclasses.replace(COARSE, size_mm=4.0), dataclasses.replace(COARSE, size_mm=8.0)
    with caplog.at_level("WARNING", logger="latticeopt.mesh"):
        CoupledModel(design, fine, cache_dir=tmp_path, mechanics_mesh=coarse)  # the two-level coarse level
        assert not caplog.records
        CoupledModel(design, coarse, cache_dir=tmp_path)  # V_rel read on the 8 mm mesh: said
    record, = caplog.records
    assert "size_mm = 8 mm" in record.message and "channel width w = 4 mm" in record.message


def test_a_folded_interpolation_falls_back_to_the_mechanics_mesh_and_says_so(tmp_path, monkeypatch):
    from latticeopt import coupled
    from latticeopt.errors import MeshError

    design = LatticeDesign(width_mm=4, thickness_mm=3)
    coarse = dataclasses.replace(COARSE, size_mm=8.0)
    hybrid = CoupledModel(design, COARSE, cache_dir=tmp_path, mechanics_mesh=coarse)
    main = hybrid._electrics

    def folded(self, nodes):
        if self is main:
            raise MeshError("1 hydrogel tets are inverted or flat")
        return original(self, nodes)

    original = coupled._Electrics.voltages
    monkeypatch.setattr(coupled._Electrics, "voltages", folded)
    touch = [Touch(50, 50, 8.75, 3.0)]
    res = hybrid.simulate(touch)
    monkeypatch.undo()
    assert res.electrics_mesh == "mechanics"
    assert res.v_rel == pytest.approx(CoupledModel(design, coarse, cache_dir=tmp_path).simulate(touch).v_rel,
                                      rel=2e-4)
    stored = coupled._result_dict(res, 0.0)
    assert stored["electrics_mesh"] == "mechanics"
    assert "electrics_mesh" not in coupled._result_dict(hybrid.simulate(touch), 0.0)
