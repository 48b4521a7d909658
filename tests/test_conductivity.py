"""Conductivity laws under load: patch kinematics against affine maps, the laws' closed forms, and the coupled
model's response to k (k = 0 is the geometry law; V_rel is smooth in k)."""

from __future__ import annotations

import numpy as np
import pytest

from latticeopt import LatticeDesign, MeshSettings, Touch
from latticeopt.conductivity import ConductivityError, conductivity_factor, patch_measures
from latticeopt.coupled import CoupledModel, PhysicsSettings
from latticeopt.errors import ModelFailure, ParameterError
from latticeopt.mesh import mesh_design

COARSE = MeshSettings(size_mm=5.0, channel_cells=1, layer_cells=1)
DESIGN = LatticeDesign(width_mm=4, thickness_mm=3, size_mm=50)
PRESS = [Touch(25, 25, 7.5, 2.5)]


@pytest.fixture(scope="module")
def mesh():
    return mesh_design(DESIGN, COARSE, cache_dir=False)


def test_affine_maps_give_the_closed_form_measures_in_every_patch(mesh):
    rng = np.random.default_rng(3)
    A = np.eye(3) + 0.2 * rng.standard_normal((3, 3))
    A[2, 2] = 0.7  # compressed through the thickness
    moved = mesh.nodes_mm @ A.T + np.array([1.0, -2.0, 0.5])
    patch = rng.integers(0, 40, mesh.n_tets)  # any grouping: an affine map has the same F in every tet
    J, lt = patch_measures(mesh.nodes_mm, moved, mesh.tets, patch)
    np.testing.assert_allclose(J, np.linalg.det(A), rtol=1e-10)
    # the distance between the images of the planes z = 0 and z = 1: the z-component of A^-1 maps the deformed
    # point back, so the deformed planes are {x : (A^-1 x)_z = c}, 1 / |row 3 of A^-1| apart
    np.testing.assert_allclose(lt, 1 / np.linalg.norm(np.linalg.inv(A)[2]), rtol=1e-10)


@pytest.mark.parametrize("name, A, expected", [
    ("simple shear in x-z", np.array([[1, 0, 0.6], [0, 1, 0], [0, 0, 1.0]]), 1.0),
    ("shear in the plane", np.array([[1, 0.5, 0], [0, 1, 0], [0, 0, 1.0]]), 1.0),
    ("rotation about x", np.array([[1, 0, 0], [0, np.cos(0.4), -np.sin(0.4)], [0, np.sin(0.4), np.cos(0.4)]]), 1.0),
    ("through-thickness compression with lateral bulge", np.diag([1.2, 1.1, 0.7]), 0.7),
])
def test_the_thickness_stretch_sees_thinning_only(mesh, name, A, expected):
    """Shear and rotation leave the layer's thickness alone (a vertical fibre's stretch |F e_z| would read
    sqrt(1 + 0.36) = 1.17 under the first shear); compression through the thickness is read as it is."""
    moved = mesh.nodes_mm @ A.T
    _, lt = patch_measures(mesh.nodes_mm, moved, mesh.tets, np.zeros(mesh.n_tets, dtype=int))
    np.testing.assert_allclose(lt, expected, rtol=1e-12)


def test_patch_volume_ratio_is_the_patch_volume_change_whatever_its_tets_do(mesh):
    """Random node jitter: each patch's J is its deformed over its reference volume (volumes from the mesh's own
    volume routine), while single tets scatter around it."""
    from latticeopt.mechanics.assembly import dilatation_patches

    rng = np.random.default_rng(0)
    moved = mesh.nodes_mm + 0.3 * rng.standard_normal(mesh.nodes_mm.shape)
    patch = dilatation_patches(mesh)
    J, _ = patch_measures(mesh.nodes_mm, moved, mesh.tets, patch)
    v0, v1 = mesh.tet_volumes_mm3(), mesh.with_nodes(moved).tet_volumes_mm3()
    expected = np.bincount(patch, v1) / np.bincount(patch, v0)
    np.testing.assert_allclose(J, expected[patch], rtol=1e-10)
    assert np.std(v1 / v0) > 1.5 * np.std(J)  # the patch average removes much of the per-tet scatter


def test_laws_have_their_closed_forms():
    J = np.array([0.8, 1.0, 1.2])
    lt = np.array([0.9, 1.0, 0.7])
    np.testing.assert_array_equal(conductivity_factor("geometry", "thickness", 7.0, J, lt), 1.0)
    np.testing.assert_allclose(conductivity_factor("linear", "thickness", 2.0, J, lt), 1 + 2 * (1 - lt))
    np.testing.assert_allclose(conductivity_factor("linear", "J", -1.5, J, lt), 1 - 1.5 * (1 - J))
    np.testing.assert_allclose(conductivity_factor("power", "J", -1.0, J, lt), 1 / J)
    np.testing.assert_allclose(conductivity_factor("power", "thickness", 2.5, J, lt), lt ** 2.5)
    with pytest.raises(ConductivityError, match="sigma / sigma0 = -"):
        conductivity_factor("linear", "thickness", -10.0, J, lt)  # 1 - 10 * 0.3 < 0 where lambda_t = 0.7
    with pytest.raises(ConductivityError):
        conductivity_factor("power", "J", 1.0, np.array([-0.1]), lt[:1])  # an inverted patch


@pytest.fixture(scope="module")
def v_rel():
    cache = {}

    def run(law="geometry", k=0.0, measure="thickness"):
        key = (law, k, measure)
        if key not in cache:
            physics = PhysicsSettings(conductivity_law=law, conductivity_k=k, conductivity_measure=measure)
            cache[key] = CoupledModel(DESIGN, COARSE, physics, cache_dir=False).simulate(PRESS).v_rel
        return cache[key]

    return run


def test_k_zero_is_the_geometry_law(v_rel):
    # each call solves the mechanics afresh: with more than one MKL thread PARDISO's rounding varies from solve
    # to solve, Newton takes another path to a state within the coupled model's tolerance (mechanics_rtol 1e-4)
    # and V_rel moves by up to a few 1e-5 (seen: 2e-6, 3.6e-5); with one thread the values agree bit for bit
    assert v_rel("linear", 0.0) == pytest.approx(v_rel("geometry"), rel=2e-4)
    assert v_rel("power", 0.0, "J") == pytest.approx(v_rel("geometry"), rel=2e-4)


def test_v_rel_is_smooth_in_k(v_rel):
    """Central differences at k = +-0.05: the second difference is second order in k, far below the first."""
    base, k = v_rel("geometry"), 0.05
    up, down = v_rel("linear", k), v_rel("linear", -k)
    assert up != down
    assert abs(up + down - 2 * base) < 0.05 * abs(up - down)


def test_a_law_that_breaks_is_a_model_failure_not_a_crash(mesh):
    physics = PhysicsSettings(conductivity_law="linear", conductivity_k=-50.0)
    model = CoupledModel(DESIGN, COARSE, physics, cache_dir=False)
    with pytest.raises(ModelFailure, match="conductivity law linear"):
        model.simulate([Touch(25, 25, 7.5, 4.0)])


def test_settings_are_checked_with_the_key_named():
    with pytest.raises(ParameterError, match="conductivity_law: expected one of 'geometry', 'linear', 'power'"):
        PhysicsSettings(conductivity_law="exponential")
    with pytest.raises(ParameterError, match="conductivity_measure: expected one of 'thickness', 'J'"):
        PhysicsSettings(conductivity_measure="strain")
    with pytest.raises(ParameterError, match="conductivity_k"):
        PhysicsSettings(conductivity_k=100.0)


def test_a_law_on_a_coarse_mesh_is_warned_about_and_the_geometry_law_is_not(caplog):
    with caplog.at_level("WARNING", logger="latticeopt.coupled"):
        CoupledModel(DESIGN, COARSE, PhysicsSettings(), cache_dir=False)
    assert not caplog.records
    with caplog.at_level("WARNING", logger="latticeopt.coupled"):
        CoupledModel(DESIGN, COARSE, PhysicsSettings(conductivity_law="linear", conductivity_k=1.0), cache_dir=False)
    assert "size_mm = 5 (needs <= 1.4), channel_cells = 1 (needs >= 3), layer_cells = 1 (needs >= 3)" in caplog.text


def test_the_law_mesh_floor_is_exactly_the_documented_one():
    from latticeopt.conductivity import law_mesh_shortfall

    assert law_mesh_shortfall(1.4, 3, 3) == []
    assert law_mesh_shortfall(1.0, 4, 4) == []
    assert law_mesh_shortfall(2.0, 3, 3) == ["size_mm = 2 (needs <= 1.4)"]
    assert law_mesh_shortfall(1.4, 2, 3) == ["channel_cells = 2 (needs >= 3)"]
