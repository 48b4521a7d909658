"""Extruded mesher (2D conforming triangulation x z levels) against analytic geometry and conformity facts,
the ``auto`` mesher choice, mean-dilatation cells of every mesher, and a locking check against Hayes et al."""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import numpy as np
import pytest
import shapely

from latticeopt.design import REGION_IDS, LatticeDesign
from latticeopt.errors import ParameterError
from latticeopt.layout import electrode_contact_mm
from latticeopt.layout_files import read_geojson, write_geojson
from latticeopt.mechanics.assembly import dilatation_patches
from latticeopt.mesh import MeshSettings, TetMesh, mesh_design
from latticeopt.mesh.extruded import extrude, extruded_mesh, pair_triangles, prism_block_mesh, triangulate_layout
from latticeopt.mesh.grid import grid_mesh, z_coordinates
from latticeopt.mesh.tetmesh import TET_FACES, face_keys

SIZE = 5.0  # mm: coarse, fast meshes


def _custom_design(tmp_path) -> LatticeDesign:
    """A custom layout that is not axis-aligned: the diagonal lattice plus a 48-gon disc, read from GeoJSON."""
    base = LatticeDesign(pattern="diagonal", width_mm=3.0)
    gel = shapely.union_all([base.footprint(), shapely.Point(50.0, 50.0).buffer(12.0, quad_segs=12)])
    path = tmp_path / "disc.geojson"
    write_geojson(gel, path)
    return LatticeDesign(pattern="custom", thickness_mm=3.0, custom_polygons_mm=read_geojson(path))


DESIGNS = {
    "square-none": LatticeDesign(width_mm=4.0, thickness_mm=3.0),
    "square-channel": LatticeDesign(width_mm=4.0, thickness_mm=3.0, rim="channel"),
    "square-frame": LatticeDesign(width_mm=3.0, thickness_mm=2.0, rim="channel", frame_mm=6.0),
    "square-frame-leads": LatticeDesign(width_mm=2.0, thickness_mm=2.0, frame_mm=8.0, pitch_mm=20.0),
    "hexagonal": LatticeDesign(pattern="hexagonal", width_mm=3.0, thickness_mm=3.0),
    "triangular": LatticeDesign(pattern="triangular", width_mm=3.0, thickness_mm=1.0),
    "diagonal": LatticeDesign(pattern="diagonal", width_mm=4.0, thickness_mm=5.0, rim="channel"),
    "uniform": LatticeDesign(width_mm=0.0, thickness_mm=7.0),  # no substrate
}


@pytest.fixture(scope="module", params=[*DESIGNS, "custom"])
def design_mesh(request, tmp_path_factory):
    if request.param == "custom":
        d = _custom_design(tmp_path_factory.mktemp("layout"))
    else:
        d = DESIGNS[request.param]
    return d, extruded_mesh(d, SIZE)


def test_region_volumes_are_exact(design_mesh):
    d, mesh = design_mesh
    vols, t = mesh.region_volumes_mm3(), d.thickness_mm
    gel = (d.footprint().area if d.has_lattice else d.size_mm ** 2) * t
    assert vols["hydrogel"] == pytest.approx(gel, rel=1e-9)
    assert vols["islands"] == pytest.approx(d.size_mm ** 2 * t - gel, rel=1e-9, abs=1e-9)
    assert vols["substrate"] == pytest.approx(d.size_mm ** 2 * d.substrate_mm, rel=1e-12, abs=1e-9)
    assert vols["sealing"] == pytest.approx(d.size_mm ** 2 * d.sealing_mm, rel=1e-12, abs=1e-9)
    assert sum(vols.values()) == pytest.approx(d.size_mm ** 2 * d.total_thickness_mm, rel=1e-12)


def test_labels_agree_with_the_layout_and_tets_are_positive(design_mesh):
    d, mesh = design_mesh
    assert np.array_equal(mesh.region, d.region_at(mesh.nodes_mm[mesh.tets].mean(axis=1)))
    vol = mesh.tet_volumes_mm3()
    assert vol.min() > 1e-9 * vol.mean()  # positively oriented, no zero-volume sliver


def test_electrode_areas_are_the_gel_contact_times_thickness(design_mesh):
    d, mesh = design_mesh
    contact = electrode_contact_mm(d.footprint(), d.electrodes()) if d.has_lattice else np.full(16, 4.0)
    assert mesh.electrode_areas_mm2() == pytest.approx(contact * d.thickness_mm, rel=1e-12)
    assert not mesh.facet_weights  # the triangulation conforms to every electrode edge: all weights 1
    if d.pattern == "square" and d.rim == "channel" and d.frame_mm == 0:  # the rim channel covers them
        assert mesh.electrode_areas_mm2() == pytest.approx(np.full(16, d.electrode_width_mm * d.thickness_mm))


def test_mesh_is_conforming(design_mesh):
    """Every face is shared by exactly two tets or lies on the box surface (no hanging faces, no overlaps)."""
    d, mesh = design_mesh
    faces = mesh.tets[:, TET_FACES].reshape(-1, 3)
    _, counts = np.unique(face_keys(faces, mesh.n_nodes), return_counts=True)
    assert counts.max() == 2
    _, inv, counts = np.unique(face_keys(faces, mesh.n_nodes), return_inverse=True, return_counts=True)
    outer = faces[counts[inv.ravel()] == 1]
    p = mesh.nodes_mm[outer]
    L, H = d.size_mm, d.total_thickness_mm
    on_box = np.zeros(len(outer), dtype=bool)
    for axis, hi in ((0, L), (1, L), (2, H)):
        for v in (0.0, hi):
            on_box |= np.all(np.abs(p[:, :, axis] - v) < 1e-9, axis=1)
    assert on_box.all()
    # the outer surface's area is the box's: it is closed and nothing sticks out
    a, b, c = p[:, 0], p[:, 1], p[:, 2]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1).sum()
    assert area == pytest.approx(2 * L * L + 4 * L * H, rel=1e-12)


def test_cells_pair_prisms_of_one_region_and_layer(design_mesh):
    _, mesh = design_mesh
    cells = mesh.cells
    assert cells is not None and cells.shape == (mesh.n_tets,)
    _, inv, size = np.unique(cells, return_inverse=True, return_counts=True)
    assert set(np.unique(size).tolist()) <= {3, 6}  # one prism or two
    for arr in (mesh.region, mesh.nodes_mm[mesh.tets][:, :, 2].min(axis=1)):
        lo = np.full(size.size, np.inf)
        hi = np.full(size.size, -np.inf)
        np.minimum.at(lo, inv.ravel(), arr)
        np.maximum.at(hi, inv.ravel(), arr)
        assert np.array_equal(lo, hi)  # one region; one z layer (each tet of a prism has a node on its bottom)
    # a pair of prisms shares a quad face: 8 distinct nodes, like a grid hexahedron
    pair = np.nonzero(size == 6)[0][:200]
    for c in pair:
        assert len(np.unique(mesh.tets[inv.ravel() == c])) == 8
    assert mesh.info["paired_fraction"] > 0.85
    # the mechanics takes them as its patches
    patch = dilatation_patches(mesh)
    assert np.array_equal(np.unique(np.c_[patch, inv.ravel()], axis=0)[:, 0], np.arange(size.size))


def test_deterministic():
    d = DESIGNS["hexagonal"]
    a, b = extruded_mesh(d, SIZE), extruded_mesh(d, SIZE)
    for name in ("nodes_mm", "tets", "region", "cells"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert a.facets.keys() == b.facets.keys()
    assert all(np.array_equal(a.facets[k], b.facets[k]) for k in a.facets)


def test_prism_split_is_conforming_for_any_vertex_order():
    """The three-tet rule on a random triangulation: interior faces shared by exactly two tets, volume exact."""
    rng = np.random.default_rng(3)
    import triangle

    pts = np.r_[[[0, 0], [1, 0], [1, 1], [0, 1]], rng.uniform(0.05, 0.95, (60, 2))]
    tri = triangle.triangulate({"vertices": pts}, "Q")["triangles"].astype(np.int64)
    perm = rng.permutation(len(pts))  # scramble the global numbering
    inv = np.empty_like(perm)
    inv[perm] = np.arange(len(perm))
    nodes, tets, cells = extrude(pts[perm], inv[tri], np.array([0.0, 0.3, 1.0]))
    vol = np.abs(np.einsum("ij,ij->i", np.cross(nodes[tets[:, 1]] - nodes[tets[:, 0]],
                                               nodes[tets[:, 2]] - nodes[tets[:, 0]]),
                           nodes[tets[:, 3]] - nodes[tets[:, 0]]) / 6)
    assert vol.min() > 1e-9 and vol.sum() == pytest.approx(1.0, rel=1e-12)
    faces = tets[:, TET_FACES].reshape(-1, 3)
    _, counts = np.unique(face_keys(faces, len(nodes)), return_counts=True)
    assert counts.max() == 2
    assert TetMesh(nodes, tets, np.zeros(len(tets))).tet_volumes_mm3().min() > 0
    assert np.array_equal(np.bincount(cells), np.full(2 * len(tri), 3))


def test_channels_get_channel_cells_across():
    d = LatticeDesign(width_mm=2.0, thickness_mm=3.0)
    for cc in (1, 2, 3):
        pts, tri = triangulate_layout(d, 4.0, channel_cells=cc)
        polys = shapely.polygons(pts[tri])
        for y in (31.0, 56.0, 81.0):  # across the vertical channel x in [49, 51], away from crossings
            line = shapely.LineString([(49.0, y), (51.0, y)])
            crossed = np.count_nonzero(shapely.length(shapely.intersection(polys, line)) > 1e-9)
            assert crossed >= cc


def test_z_levels_follow_the_grid_rule():
    d = LatticeDesign(width_mm=4.0, thickness_mm=3.0)
    mesh = extruded_mesh(d, 2.0, layer_cells=3)
    z = np.unique(np.round(mesh.nodes_mm[:, 2], 9))
    assert np.array_equal(z, np.round(z_coordinates(d, 2.0, 3), 9))
    assert np.array_equal(z, np.unique(np.round(grid_mesh(d, 2.0, layer_cells=3).nodes_mm[:, 2], 9)))


def test_without_electrode_edges_weights_give_the_exact_areas():
    d = LatticeDesign(pattern="hexagonal", width_mm=5.0, thickness_mm=2.0)
    mesh = extruded_mesh(d, SIZE, electrode_edges=False)
    contact = electrode_contact_mm(d.footprint(), d.electrodes())
    np.testing.assert_allclose(mesh.electrode_areas_mm2(), contact * d.thickness_mm, rtol=1e-9)


def test_cells_survive_save_load_and_restrict(tmp_path):
    d = DESIGNS["triangular"]
    mesh = extruded_mesh(d, SIZE)
    mesh.save(tmp_path / "m.npz")
    back = TetMesh.load(tmp_path / "m.npz")
    assert np.array_equal(back.cells, mesh.cells)
    sub, _ = mesh.restrict(("hydrogel",))
    assert np.array_equal(sub.cells, mesh.cells[mesh.region == REGION_IDS["hydrogel"]])
    assert dataclasses.replace(mesh, cells=None).cells is None


# -- the mesher choice ----------------------------------------------------------------------------------------
def test_auto_picks_grid_for_axis_aligned_layouts_and_extruded_otherwise(tmp_path):
    s = MeshSettings(size_mm=SIZE)
    assert s.mesher == "auto"
    square = mesh_design(LatticeDesign(), s, cache_dir=False)
    hexa = mesh_design(DESIGNS["hexagonal"], s, cache_dir=False)
    assert square.info["mesher"] == "grid" and square.info["settings"]["mesher"] == "grid"
    assert hexa.info["mesher"] == "extruded"
    ring = LatticeDesign(pattern="custom", custom_polygons_mm=read_geojson("studies/data/ring_layout.geojson"))
    assert ring.is_axis_aligned and MeshSettings().resolved(ring).mesher == "grid"
    # the axis-aligned custom layout is exact on the grid too
    gm = mesh_design(ring, s, cache_dir=False)
    assert gm.region_volumes_mm3()["hydrogel"] == pytest.approx(ring.footprint().area * ring.thickness_mm, rel=1e-12)


def test_grid_refuses_a_layout_that_is_not_axis_aligned_before_any_work(tmp_path, monkeypatch):
    from latticeopt.mesh import grid as grid_module

    def boom(*args, **kwargs):
        raise AssertionError("the grid was built")

    monkeypatch.setattr(grid_module, "grid_coordinates", boom)
    t0 = time.perf_counter()
    with pytest.raises(ParameterError, match=r"^mesher: expected 'extruded'") as err:
        mesh_design(DESIGNS["diagonal"], MeshSettings(mesher="grid"), cache_dir=tmp_path)
    assert "\n" not in str(err.value) and time.perf_counter() - t0 < 1.0
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("name", ["square-frame", "square-frame-leads"])
def test_grid_is_exact_for_frames_and_leads(name):
    d = DESIGNS[name]
    mesh = grid_mesh(d, SIZE)
    assert mesh.region_volumes_mm3()["hydrogel"] == pytest.approx(d.footprint().area * d.thickness_mm, rel=1e-12)
    contact = electrode_contact_mm(d.footprint(), d.electrodes())
    assert mesh.electrode_areas_mm2() == pytest.approx(contact * d.thickness_mm, rel=1e-12)
    assert np.array_equal(mesh.region, d.region_at(mesh.nodes_mm[mesh.tets].mean(axis=1)))
    ext = extruded_mesh(d, SIZE)
    assert ext.region_volumes_mm3() == pytest.approx(mesh.region_volumes_mm3(), rel=1e-9)


def test_grid_cells_are_its_hexahedra():
    mesh = grid_mesh(LatticeDesign(), SIZE)
    nx, ny, nz = mesh.info["grid_shape"]
    assert mesh.cells.max() + 1 == (nx - 1) * (ny - 1) * (nz - 1)
    assert np.array_equal(np.bincount(mesh.cells), np.full((nx - 1) * (ny - 1) * (nz - 1), 6))
    # the six tets of a cell fill one axis-aligned box: their volumes sum to its bounding box's
    p = mesh.nodes_mm[mesh.tets]
    order = np.argsort(mesh.cells, kind="stable")
    lo = p.min(axis=1)[order].reshape(-1, 6, 3).min(axis=1)
    hi = p.max(axis=1)[order].reshape(-1, 6, 3).max(axis=1)
    vol = mesh.tet_volumes_mm3()[order].reshape(-1, 6).sum(axis=1)
    assert vol == pytest.approx(np.prod(hi - lo, axis=1), rel=1e-12)


def test_pairing_never_mixes_labels_and_leaves_few_alone():
    pts, tri = triangulate_layout(DESIGNS["hexagonal"], 3.0)
    label = (np.arange(len(tri)) % 3 == 0).astype(int)  # an adversarial labelling
    g = pair_triangles(tri, label)
    for k in np.nonzero(np.bincount(g) == 2)[0]:
        a, b = np.nonzero(g == k)[0]
        assert label[a] == label[b] and len(set(tri[a]) & set(tri[b])) == 2  # same label, share an edge
    free = pair_triangles(tri, np.zeros(len(tri), dtype=int))
    assert np.count_nonzero(np.bincount(free) == 1) < 0.1 * len(tri)


# -- locking: flat punch on a bonded layer against Hayes et al. ------------------------------------------------
@pytest.fixture(scope="module", params=[1.0, 0.625], ids=["fine1", "fine0.625"])
def prism_layer(request):
    fine = request.param
    return prism_block_mesh(60.0, np.linspace(0.0, 5.0, int(round(5.0 / fine)) + 1), fine, 4.0, 6.0)


def test_extruded_punch_force_does_not_lock(prism_layer):
    """nu = 0.499 on paired-prism patches: the force / Hayes ratio stays within the grid test's 10 % and moves
    by < 2 % from nu = 0.45 (plain P1 tets, which lock, are 1.7x too stiff at 0.49 on the grid)."""
    from latticeopt.mechanics import IndentationSolver, IndentSettings, Materials, NeoHookean
    from latticeopt.mechanics.verification import hayes_kappa

    G_kPa, a, h, d = 20.0, 5.0, 5.0, 0.025
    ratio = {}
    for nu in (0.45, 0.499):
        mats = Materials.uniform(NeoHookean(G_kPa, nu))
        settings = IndentSettings(materials=mats, in_plane="frictionless")
        res = IndentationSolver(prism_layer, settings).solve([(30.0, 30.0, a, d)])
        ratio[nu] = res.forces_N[0] / (4 * G_kPa * 1e-3 * a * hayes_kappa(a / h, nu) * d / (1 - nu))
    assert ratio[0.499] == pytest.approx(1.0, rel=0.10)
    assert ratio[0.499] / ratio[0.45] == pytest.approx(1.0, abs=0.02)


def test_auto_channel_cells_is_the_family_count_and_keys_follow_the_table(monkeypatch):
    import latticeopt.mesh as mesh_module
    from latticeopt.study.settings import EvalSettings

    auto = MeshSettings(size_mm=SIZE)
    assert auto.channel_cells == "auto"
    assert auto.resolved(DESIGNS["hexagonal"]).channel_cells == 3
    for name in ("square-none", "triangular"):
        assert auto.resolved(DESIGNS[name]).channel_cells == 2
    assert MeshSettings(channel_cells=1).resolved(DESIGNS["hexagonal"]).channel_cells == 1  # explicit kept
    # "auto" meshes the hexagonal layout exactly as an explicit 3 does (and differently from 2)
    hexa = mesh_design(DESIGNS["hexagonal"], auto, cache_dir=False)
    three = mesh_design(DESIGNS["hexagonal"], MeshSettings(size_mm=SIZE, channel_cells=3), cache_dir=False)
    two = mesh_design(DESIGNS["hexagonal"], MeshSettings(size_mm=SIZE, channel_cells=2), cache_dir=False)
    assert np.array_equal(hexa.nodes_mm, three.nodes_mm) and len(two.nodes_mm) < len(three.nodes_mm)
    # a result key made with "auto" changes when what "auto" stands for does
    before = EvalSettings(mesh=auto).key
    monkeypatch.setitem(mesh_module.CHANNEL_CELLS_AUTO, "triangular", 3)
    assert EvalSettings(mesh=auto).key != before
    with pytest.raises(ParameterError, match="channel_cells.*'auto'"):
        MeshSettings(channel_cells="many")


STUDY_LAYOUTS = sorted((Path(__file__).parents[1] / "studies" / "data").glob("*.geojson"))


@pytest.mark.parametrize("path", STUDY_LAYOUTS, ids=lambda p: p.stem)
def test_every_committed_layout_meshes_exactly(path):
    """Every outline the docs report (``studies/data``) is meshed exactly: the hydrogel tets fill the file's
    polygons times t, the polygons read straight from the GeoJSON by shapely (not through the design)."""
    raw = json.loads(path.read_text())
    features = raw["features"] if raw.get("type") == "FeatureCollection" else [raw]
    file_area = shapely.union_all([shapely.geometry.shape(f.get("geometry", f)) for f in features]).area
    design = LatticeDesign(pattern="custom", custom_polygons_mm=read_geojson(path))
    mesh = mesh_design(design, MeshSettings(size_mm=SIZE, channel_cells=1, layer_cells=1), cache_dir=False)
    assert mesh.region_volumes_mm3()["hydrogel"] == pytest.approx(file_area * design.thickness_mm, rel=1e-9)
    assert mesh.region_volumes_mm3()["hydrogel"] + mesh.region_volumes_mm3()["islands"] == pytest.approx(
        design.size_mm ** 2 * design.thickness_mm, rel=1e-12)
