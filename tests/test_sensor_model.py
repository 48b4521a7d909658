"""Sensor-model files: exact round trip, numpy-only reading, Jacobian against finite differences of the rebuilt
forward model, the contact-impedance scaling, and clear errors for bad files."""

import json
import zipfile

import numpy as np
import pytest

from latticeopt.design import LatticeDesign
from latticeopt.electrics import DEFAULT_CONTACT_IMPEDANCE_OHM_M2, DEFAULT_SIGMA_S_PER_M, ForwardModel
from latticeopt.errors import LatticeoptError
from latticeopt.mesh import MeshSettings, mesh_design
from latticeopt.sensor_model import (
    FORMAT_VERSION,
    SIGMA0_S_PER_M,
    SensorModelError,
    SensorSimulator,
    build_sensor_model,
    load_sensor_model,
    save_sensor_model,
)

DESIGN = LatticeDesign(width_mm=4, thickness_mm=3)
COARSE = MeshSettings(size_mm=5)


@pytest.fixture(scope="module")
def built():
    return build_sensor_model(DESIGN, COARSE, cache_dir=False)


@pytest.fixture(scope="module")
def path(built, tmp_path_factory):
    return save_sensor_model(built, tmp_path_factory.mktemp("sm") / "sensor.npz")


@pytest.fixture(scope="module")
def sim(path):
    return SensorSimulator(load_sensor_model(path))


def _same(a, b):
    assert a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b)


def test_round_trip_is_exact(built, path, tmp_path):
    m = load_sensor_model(path)
    for name in ("electrodes", "v_ref", "jacobian", "pixel_gel_fraction", "sigma_S_per_m", "contact_impedance_ohm_m2"):
        _same(getattr(m, name), getattr(built, name))
    for name in ("drive_currents", "measure", "row_drive", "meas_pairs", "independent", "reciprocal"):
        _same(getattr(m.protocol, name), getattr(built.protocol, name))
    _same(m.mesh.nodes_mm, built.mesh.nodes_mm)
    _same(m.mesh.tets, built.mesh.tets)
    for k in range(1, 17):
        name = f"electrode_{k}"
        _same(m.mesh.facets[name], built.mesh.facets[name])
        _same(m.mesh.weights(name), built.mesh.weights(name))
    assert (m.pixel_matrix != built.pixel_matrix).nnz == 0
    assert m.design == built.design and m.extent_mm == built.extent_mm and m.n_pixels == 48
    assert (m.sigma0_S_per_m, m.current_A, m.fingerprint) == (built.sigma0_S_per_m, built.current_A, built.fingerprint)
    again = load_sensor_model(save_sensor_model(m, tmp_path / "again.npz"))
    _same(again.jacobian, built.jacobian)
    assert again.fingerprint == built.fingerprint


def test_readable_with_numpy_alone(path, built):
    """The documented recipe of docs/sensor_model.md."""
    with np.load(path, allow_pickle=False) as z:
        meta = json.loads(str(z["metadata"]))
        J, v_ref, indep = z["jacobian"], z["v_ref"], z["independent"]
        edges = z["pixel_edges_x_mm"]
    assert meta["format_version"] == FORMAT_VERSION and meta["units"]["jacobian"] == "V per (S/m)"
    assert meta["design"]["width_mm"] == 4.0 and J.shape == (208, 48 * 48) and indep.shape == (104,)
    assert edges[0] == 0.0 and edges[-1] == 100.0 and len(edges) == 49
    _same(v_ref, built.v_ref)


def test_simulator_reproduces_reference_and_batches(sim):
    m = sim.model
    s0 = m.sigma0_S_per_m
    V = sim.voltages(np.full((3, 48, 48), s0))
    assert V.shape == (3, 208)
    np.testing.assert_allclose(V, np.tile(m.v_ref, (3, 1)), rtol=1e-10, atol=1e-12 * np.abs(m.v_ref).max())
    # Reciprocity of the rebuilt model on a heterogeneous image.
    img = np.full((48, 48), s0)
    img[10:20, 25:40] = 0.3 * s0
    Vi = sim.voltages(img)[0]
    p = m.protocol
    has = p.reciprocal >= 0
    np.testing.assert_allclose(Vi[has], p.reciprocal_sign[has] * Vi[p.reciprocal[has]], rtol=1e-9)


def test_file_jacobian_matches_finite_differences(sim):
    m = sim.model
    s0 = m.sigma0_S_per_m
    base = np.full(48 * 48, s0)
    norms = np.linalg.norm(m.jacobian, axis=0)
    rng = np.random.default_rng(1)
    gel = np.flatnonzero(m.pixel_gel_fraction > 0.2)
    pixels = np.r_[np.argsort(norms)[-2:], rng.choice(gel, 4, replace=False)]
    worst = 0.0
    for p in pixels:
        h = 1e-4 * s0
        up, down = base.copy(), base.copy()
        up[p] += h
        down[p] -= h
        fd = (sim.voltages(up.reshape(48, 48))[0] - sim.voltages(down.reshape(48, 48))[0]) / (2 * h)
        worst = max(worst, np.linalg.norm(fd - m.jacobian[:, p]) / np.linalg.norm(m.jacobian[:, p]))
    print(f"file Jacobian vs central differences of the rebuilt model: worst column error {worst:.1e}")
    assert worst < 1e-5
    # Pixels over silicone islands have no hydrogel below them and no sensitivity.
    island = np.flatnonzero(m.pixel_gel_fraction == 0)
    assert len(island) > 0 and np.all(m.jacobian[:, island] == 0)


def test_contact_impedance_keeps_zc_sigma_so_voltages_scale_as_one_over_sigma(built):
    """Default export: z_c sigma0 equals the electrics defaults' z_c sigma, hence V(sigma0) = V(1 S/m) / sigma0."""
    assert built.sigma0_S_per_m == SIGMA0_S_PER_M
    np.testing.assert_allclose(built.contact_impedance_ohm_m2 * SIGMA0_S_PER_M,
                               DEFAULT_CONTACT_IMPEDANCE_OHM_M2 * DEFAULT_SIGMA_S_PER_M, rtol=1e-12)
    unit = ForwardModel(mesh_design(DESIGN, COARSE, cache_dir=False))  # the electrics defaults, 1 S/m
    np.testing.assert_allclose(built.v_ref, unit.voltages * DEFAULT_SIGMA_S_PER_M / SIGMA0_S_PER_M, rtol=1e-9)
    assert built.summary()["contact_number"] == pytest.approx(0.5)


def test_parallel_generation_equals_serial(sim):
    s0 = sim.model.sigma0_S_per_m
    rng = np.random.default_rng(2)
    imgs = s0 * rng.uniform(0.5, 1.5, (4, 48, 48))
    np.testing.assert_allclose(sim.voltages(imgs, jobs=2, chunk=2), sim.voltages(imgs), rtol=1e-10)


def _rewrite(src, dst, **changes):
    with np.load(src, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    arrays.update(changes)
    np.savez(dst, **arrays)


@pytest.mark.parametrize("kind", ["truncated", "corrupted", "newer", "not_zip", "other_npz", "missing", "shape"])
def test_bad_files_give_clear_errors(path, tmp_path, kind):
    bad = tmp_path / "bad.npz"
    data = path.read_bytes()
    if kind == "truncated":
        bad.write_bytes(data[: len(data) // 2])
        why = "not a zip file"
    elif kind == "corrupted":
        i = len(data) // 3
        bad.write_bytes(data[:i] + bytes([data[i] ^ 0xFF]) + data[i + 1:])
        why = "crc"
    elif kind == "newer":
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["metadata"]))
        meta["format_version"] = FORMAT_VERSION + 1
        _rewrite(path, bad, metadata=np.array(json.dumps(meta)))
        why = "newer latticeopt"
    elif kind == "not_zip":
        bad.write_bytes(b"x_mm,y_mm\n1,2\n")
        why = "not an .npz"
    elif kind == "other_npz":
        np.savez(bad, a=np.zeros(3))
        why = "no 'metadata'"
    elif kind == "missing":
        bad = tmp_path / "nothere.npz"
        why = "no such"
    else:
        _rewrite(path, bad, v_ref=np.zeros(100))
        why = "v_ref has shape"
    with pytest.raises(SensorModelError) as info:
        load_sensor_model(bad)
    msg = str(info.value)
    print(msg)
    assert isinstance(info.value, LatticeoptError) and str(bad) in msg and why in msg.lower() and "\n" not in msg


def test_npz_members_are_plain_arrays(path):
    with zipfile.ZipFile(path) as zf:
        names = zf.namelist()
    assert "metadata.npy" in names and all(n.endswith(".npy") for n in names)
    with np.load(path, allow_pickle=False) as z:
        assert all(z[k].dtype != object for k in z.files)


def test_the_documented_voltage_range_is_the_default_exports():
    """docs/sensor_model.md quotes |V_ref| of `latticeopt export` at its defaults (design, 2 mm mesh, sigma0, 1 mA).

    The 1 S/m forward solve divided by sigma0 is that export's V_ref (the identity tested above), without its
    Jacobian."""
    import re
    from pathlib import Path

    from latticeopt.cli import build_parser
    from latticeopt.electrics import DEFAULT_CURRENT_A

    export = next(a for a in build_parser()._actions if a.dest == "command").choices["export"]
    assert export.get_default("sigma") == SIGMA0_S_PER_M and export.get_default("current") == DEFAULT_CURRENT_A
    doc = " ".join((Path(__file__).parents[1] / "docs" / "sensor_model.md").read_text(encoding="utf-8").split())
    lo_text, hi_text = re.search(r"\|V_ref\| from ([\d.]+) to ([\d.]+) V at 1 mA for the default design", doc).groups()
    unit = ForwardModel(mesh_design(LatticeDesign(), MeshSettings(), cache_dir=False))
    v = np.abs(unit.voltages) * DEFAULT_SIGMA_S_PER_M / SIGMA0_S_PER_M
    assert (f"{v.min():.2g}", f"{v.max():.3g}") == (lo_text, hi_text)
