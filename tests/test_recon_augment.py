"""Eight-fold symmetry augmentation against re-solving the transformed phantom."""

import numpy as np
import pytest

from latticeopt.design import LatticeDesign
from latticeopt.electrics import ForwardModel, Protocol
from latticeopt.errors import ParameterError
from latticeopt.mesh import MeshSettings, TetMesh, mesh_design
from latticeopt.mesh.facets import tag_facets
from latticeopt.recon.augment import SQUARE_GROUP, electrode_permutation, square_symmetries
from latticeopt.recon.dataset import DatasetConfig, generate_dataset, render_touches, training_arrays
from latticeopt.sensor_model import CONTACT_LENGTH_M, SIGMA0_S_PER_M, build_sensor_model

DESIGN = LatticeDesign(width_mm=4, thickness_mm=3)
S0 = SIGMA0_S_PER_M
ZC = CONTACT_LENGTH_M / S0
# An asymmetric phantom: two touches of different size and sign, off every symmetry axis.
TOUCHES = np.array([[30.0, 20.0, 16.0, 0.2], [72.0, 57.0, 12.0, 1.8]])


@pytest.fixture(scope="module")
def setup():
    mesh = mesh_design(DESIGN, MeshSettings(size_mm=5), cache_dir=False)
    fwd = ForwardModel(mesh, S0, ZC)
    img = render_touches(TOUCHES, S0)
    V = fwd.with_conductivity(fwd.pixel_matrix(48) @ img.ravel()).voltages
    return mesh, fwd, img, V


def _transformed_mesh(mesh: TetMesh, sym) -> TetMesh:
    """The mirror/rotated mesh of the same sensor, its electrode facets found by the mesher's own tagging."""
    nodes = mesh.nodes_mm.copy()
    nodes[:, :2] = sym.points(nodes[:, :2], DESIGN.size_mm)
    tets = mesh.tets[:, [0, 2, 1, 3]] if sym.orientation_reversing else mesh.tets
    facets, weights = tag_facets(nodes, tets, mesh.region, DESIGN, 1e-7 * DESIGN.size_mm)
    return TetMesh(nodes, tets, mesh.region, facets, weights, mesh.info)


@pytest.mark.parametrize("name", list(SQUARE_GROUP))
def test_augmentation_equals_resolving_the_transformed_phantom(setup, name):
    mesh, fwd, img, V = setup
    (sym,) = square_symmetries(DESIGN, fwd.protocol, 48, names=(name,))
    moved = ForwardModel(_transformed_mesh(mesh, sym), S0, ZC)
    img_g = sym.images(img)
    V_resolved = moved.with_conductivity(moved.pixel_matrix(48) @ img_g.ravel()).voltages
    err = np.max(np.abs(sym.voltages(V) - V_resolved)) / np.max(np.abs(V))
    print(f"{name}: permuted vs re-solved {err:.1e}")
    assert err < 1e-8
    # Relative changes need no signs (both V and V_ref flip together).
    y = (V - fwd.voltages) / fwd.voltages
    np.testing.assert_allclose(sym.relative(y), (V_resolved - moved.voltages) / moved.voltages, rtol=1e-7, atol=1e-9)


@pytest.mark.parametrize("name", ["rot180", "transpose", "antitranspose"])
def test_same_mesh_resolve_for_the_mesh_symmetries(setup, name):
    """The grid's Kuhn tets are invariant under these three: re-solve on the very same mesh."""
    _, fwd, img, V = setup
    (sym,) = square_symmetries(DESIGN, fwd.protocol, 48, names=(name,))
    V_resolved = fwd.with_conductivity(fwd.pixel_matrix(48) @ sym.images(img).ravel()).voltages
    assert np.max(np.abs(sym.voltages(V) - V_resolved)) / np.max(np.abs(V)) < 1e-8


def test_image_transform_moves_touches_like_points():
    for sym in square_symmetries(DESIGN, Protocol.adjacent(16), 48):
        moved = TOUCHES.copy()
        moved[:, :2] = sym.points(TOUCHES[:, :2], 100.0)
        np.testing.assert_allclose(sym.images(render_touches(TOUCHES, S0)), render_touches(moved, S0), rtol=1e-12)


def test_permutations_match_the_counter_clockwise_numbering():
    """Independent of the geometry matching: rotations roll the numbers by 4, reflections map e to c - e."""
    e = np.arange(16)
    assert np.array_equal(electrode_permutation(DESIGN, "rot90"), (e + 4) % 16)
    assert np.array_equal(electrode_permutation(DESIGN, "flip_x"), (3 - e) % 16)
    assert np.array_equal(electrode_permutation(DESIGN, "transpose"), (15 - e) % 16)
    perms = {tuple(electrode_permutation(DESIGN, n)) for n in SQUARE_GROUP}
    assert len(perms) == 8


def test_asymmetric_design_is_refused():
    odd = LatticeDesign(width_mm=4, thickness_mm=3, pitch_mm=15.0)  # lines 0, 15, ..., 90, 100
    with pytest.raises(ParameterError, match="symmetry"):
        electrode_permutation(odd, "flip_x")
    assert len(electrode_permutation(odd, "transpose")) == 16  # the diagonal mirror still holds


def test_training_arrays_are_eightfold_with_the_paper_noise_levels():
    model = build_sensor_model(DESIGN, MeshSettings(size_mm=5), cache_dir=False)
    data = generate_dataset(model, DatasetConfig(per_count=20, touch_counts=(1, 3)))
    x, img = training_arrays(data, model)
    k = len(data.train)
    assert x.shape == (8 * k, 208) and img.shape == (8 * k, 48, 48)
    y = (data.voltages[data.train] - model.v_ref) / model.v_ref
    np.testing.assert_allclose(x[::8], y, rtol=1e-6, atol=1e-9)  # identity copy kept clean
    np.testing.assert_array_equal(img[::8], data.images[data.train])
    syms = square_symmetries(DESIGN, model.protocol, 48)
    for g in range(1, 8):
        clean = syms[g].relative(y) * model.v_ref
        noise = x[g::8] * model.v_ref - clean
        V = model.v_ref + clean
        snr = 10 * np.log10(np.mean(V ** 2) / np.mean(noise ** 2))
        assert snr == pytest.approx(30 + 5 * g, abs=0.5)
        np.testing.assert_array_equal(img[g::8], syms[g].images(data.images[data.train]))
