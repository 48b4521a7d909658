"""Coupled simulation: V_rel definition, reference consistency and physical trends on a coarse mesh."""

import dataclasses

import numpy as np
import pytest

from latticeopt import LatticeDesign, MeshSettings
from latticeopt.coupled import CoupledModel, PhysicsSettings, evaluate_phantom, relative_change
from latticeopt.errors import ParameterError
from latticeopt.phantoms import Phantom
from latticeopt.study import PHYSICS_KEYS, EvalSettings
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


def test_untouched_reference_matches_an_independent_forward_solve(model):
    from latticeopt.electrics import ForwardModel

    direct = ForwardModel(model.mesh).voltages
    np.testing.assert_allclose(model.reference_voltages, direct, rtol=1e-10)


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
