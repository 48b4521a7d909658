"""Random phantoms, press series and probe grids: ranges, placement, non-overlap, reproducibility, stream contract."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from latticeopt.design import LatticeDesign
from latticeopt.errors import ParameterError
from latticeopt.study.phantoms import (
    Phantom,
    ProbePresses,
    phantom_rng,
    press_series,
    random_phantom,
    random_phantoms,
    uniformity,
    worst_to_best,
)
from latticeopt.touches import Touch, validate_touches

L = 100.0


@pytest.fixture(scope="module")
def many() -> tuple[Phantom, ...]:
    return random_phantoms(L, {1: 400, 2: 300, 3: 300}, seed=11)


def test_ranges_on_sensor_and_no_overlap(many):
    design = LatticeDesign()
    for p in many:
        validate_touches(design, p.touches)  # the mechanics' own check: on the sensor, no overlap, depth
        for t in p.touches:
            assert 6.25 <= t.radius_mm <= 8.75 and 1.0 <= t.depth_mm <= 5.0
            assert t.radius_mm <= t.x_mm <= L - t.radius_mm and t.radius_mm <= t.y_mm <= L - t.radius_mm
        for i, a in enumerate(p.touches):
            for b in p.touches[:i]:
                assert math.hypot(a.x_mm - b.x_mm, a.y_mm - b.y_mm) >= a.radius_mm + b.radius_mm
    assert [p.n_touches for p in many] == [1] * 400 + [2] * 300 + [3] * 300


def test_single_touch_distribution_is_uniform(many):
    singles = [p.touches[0] for p in many if p.n_touches == 1]
    r = np.array([t.radius_mm for t in singles])
    d = np.array([t.depth_mm for t in singles])
    ux = np.array([(t.x_mm - t.radius_mm) / (L - 2 * t.radius_mm) for t in singles])
    for sample, (lo, hi) in ((r, (6.25, 8.75)), (d, (1.0, 5.0)), (ux, (0.0, 1.0))):
        assert stats.kstest(sample, stats.uniform(lo, hi - lo).cdf).pvalue > 1e-3


def test_min_gap_respected():
    for p in random_phantoms(L, {3: 50}, seed=3, min_gap_mm=10.0):
        a, b, c = p.touches
        for u, w in ((a, b), (a, c), (b, c)):
            assert math.hypot(u.x_mm - w.x_mm, u.y_mm - w.y_mm) >= u.radius_mm + w.radius_mm + 10.0


def test_same_seed_same_phantoms_other_seed_other_phantoms():
    a = random_phantoms(L, {1: 5, 2: 5, 3: 5}, seed=42)
    b = random_phantoms(L, {3: 5, 1: 5, 2: 5}, seed=42)
    c = random_phantoms(L, {1: 5, 2: 5, 3: 5}, seed=43)
    assert a == b
    assert {p.key for p in a}.isdisjoint(p.key for p in c)


def test_phantom_i_does_not_depend_on_how_many_are_drawn():
    few = random_phantoms(L, {1: 3, 2: 2}, seed=5)
    more = random_phantoms(L, {1: 50, 2: 40, 3: 10}, seed=5)
    assert few[:3] == more[:3]
    assert few[3:5] == more[50:52]
    assert random_phantom(L, 2, 17, seed=5) == more[50 + 17]


def test_stream_is_the_documented_one():
    """First draw = (PCG64 output >> 11) * 2^-53 mapped affinely: fixed algorithms, numpy-version independent."""
    bits = np.random.PCG64(np.random.SeedSequence(9, spawn_key=(1, 4))).random_raw(4)
    u = (bits >> np.uint64(11)).astype(float) * 2.0 ** -53
    t = random_phantom(L, 1, 4, seed=9).touches[0]
    r = 6.25 + 2.5 * u[0]
    assert (t.radius_mm, t.depth_mm) == (r, 1.0 + 4.0 * u[1])
    assert (t.x_mm, t.y_mm) == (r + (L - 2 * r) * u[2], r + (L - 2 * r) * u[3])
    assert phantom_rng(9, 1, 4).random() == u[0]


def test_key_and_json_round_trip():
    p = random_phantom(L, 3, 2, seed=1)
    back = Phantom.from_json(p.to_json())
    assert back == p and back.key == p.key and back.n_touches == 3
    moved = Phantom((Touch(1 + p.touches[0].x_mm, p.touches[0].y_mm, p.touches[0].radius_mm,
                           p.touches[0].depth_mm), *p.touches[1:]), index=p.index)
    assert moved.key != p.key
    relabelled = Phantom(p.touches, index=99)
    assert relabelled.key == p.key  # the key is the load, not the label
    tampered = {**p.as_dict(), "key": "0" * 64}
    with pytest.raises(ParameterError, match="phantom.key"):
        Phantom.from_dict(tampered)


def test_press_series():
    series = press_series(50, 40, 8.75, [0.0, 1.0, 4.0])
    assert [p.touches[0].depth_mm for p in series] == [0.0, 1.0, 4.0]
    assert [p.index for p in series] == [0, 1, 2] and {p.kind for p in series} == {"press"}
    assert len({p.key for p in series}) == 3


@pytest.mark.parametrize("kwargs, name", [
    (dict(n_touches=0), "n_touches"),
    (dict(n_touches=6), "n_touches"),
    (dict(radius_range_mm=(6.25, 51.0)), "radius_range_mm"),
    (dict(depth_range_mm=(3.0, 2.0)), "depth_range_mm"),
    (dict(min_gap_mm=-1.0), "min_gap_mm"),
    (dict(seed=-1), "seed"),
])
def test_bad_arguments_named(kwargs, name):
    args = dict(size_mm=L, n_touches=2, index=0, seed=0) | kwargs
    with pytest.raises(ParameterError, match=name):
        random_phantom(**args)


def test_impossible_packing_reported():
    with pytest.raises(ParameterError, match="non-overlapping"):
        random_phantom(40.0, 5, 0, seed=0, radius_range_mm=(9.0, 10.0))


def _independent_probes(n: int, L: float, r: float, d: float) -> list[Phantom]:
    """The probe grid as the optimizers built it before it had one definition: probe i at the centre of cell
    (i % n, i // n), in plain Python floats."""
    return [Phantom((Touch(x_mm=(i % n + 0.5) * L / n, y_mm=(i // n + 0.5) * L / n, radius_mm=r, depth_mm=d),),
                    index=i, kind="press") for i in range(n * n)]


@pytest.mark.parametrize("n, L, r, d", [(7, 100.0, 6.25, 3.0), (3, 100.0, 7.5, 3.0), (4, 100.0, 7.5, 2.5),
                                        (10, 100.0, 5.0, 1.0), (3, 80.0, 12.0, 4.0), (2, 100.0, 25.0, 3.0)])
def test_probe_presses_are_the_cell_centres_in_order(n, L, r, d):
    from latticeopt.optimize.graded import GradedConfig
    from latticeopt.optimize.objectives import Objective
    from latticeopt.optimize.probes import ProbeGrid

    probes = ProbePresses(n, r, d).generate(L)
    expected = _independent_probes(n, L, r, d)
    assert [p.touches for p in probes] == [p.touches for p in expected]  # exact floats, not approx
    assert [p.key for p in probes] == [p.key for p in expected]  # so the same content hashes, the same store rows
    assert [p.as_dict() for p in probes] == [p.as_dict() for p in expected]
    assert [ProbePresses(n, r, d).cell(p.index) for p in probes] == [(i % n, i // n) for i in range(n * n)]
    # the optimizers' probe grid and the density studies' are this one
    objective = Objective(weights=(("uniformity", 1.0),), probe_grid=n, probe_radius_mm=r, probe_depth_mm=d)
    assert [p.key for p in objective.probes(L)] == [p.key for p in expected]
    design = LatticeDesign(size_mm=L, thickness_mm=1.0)
    grid = ProbeGrid(design, GradedConfig(probes=True, probe_grid=n, probe_radius_mm=r, probe_depth_mm=d))
    assert [tuple(t) for t in grid.touches] == [p.touches for p in expected]


def test_probe_presses_defaults_and_errors():
    from latticeopt.optimize.objectives import Objective
    from latticeopt.optimize.probes import ProbeKeys

    assert (ProbePresses().grid, ProbePresses().radius_mm, ProbePresses().depth_mm) == (7, 6.25, 3.0)
    # the optimizers keep their own defaults, in the API and in a study's [optimize.uniformity] alike
    from latticeopt.optimize.load import optimization_from_dict

    o = Objective()
    assert (o.probe_grid, o.probe_radius_mm, o.probe_depth_mm) == (3, 7.5, 3.0)
    for uni, expected in (({}, (3, 7.5, 3.0)), ({"depth_mm": 2.0}, (3, 7.5, 2.0)), ({"grid": 4}, (4, 7.5, 3.0))):
        raw = {"phantoms": {"counts": {"1": 1}}, "optimize": {"variables": {"width_mm": [1, 5]},
                                                             "objective": "uniformity", "uniformity": uni}}
        o = optimization_from_dict(raw).config.objective
        assert (o.probe_grid, o.probe_radius_mm, o.probe_depth_mm) == expected
    assert (ProbeKeys.probe_grid, ProbeKeys.probe_radius_mm, ProbeKeys.probe_depth_mm) == (7, 6.25, 3.0)
    for kwargs, name in ((dict(grid=1), "grid"), (dict(grid=11), "grid"), (dict(grid=2.0), "grid"),
                         (dict(radius_mm=0), "radius_mm"), (dict(depth_mm=-1.0), "depth_mm")):
        with pytest.raises(ParameterError, match=f"^{name}: ") as info:
            ProbePresses(**kwargs)
        assert str(kwargs[name]) in str(info.value)
    assert ProbePresses(4, 12.5).generate(L)  # exactly half a cell fits
    with pytest.raises(ParameterError, match=r"^radius_mm: expected radius_mm <= L / \(2 grid\) = 12.5 mm .* 4 x 4 "
                       "grid.*got 12.6"):
        ProbePresses(4, 12.6).generate(L)
    with pytest.raises(ParameterError, match="^probe_radius_mm: .*got 12.6"):
        Objective(weights=(("uniformity", 1.0),), probe_grid=4, probe_radius_mm=12.6).probes(L)
    with pytest.raises(ParameterError, match="^probe_grid: .*2 to 10"):
        Objective(probe_grid=11)


def test_uniformity_and_worst_to_best_are_the_optimizers():
    from latticeopt.optimize.objectives import TERMS, Objective

    v = np.random.default_rng(3).uniform(0.02, 0.05, 49)
    assert uniformity(v) == pytest.approx(1 - statistics_pstdev(v) / float(np.mean(v)), rel=1e-12)
    assert worst_to_best(v) == pytest.approx(min(v) / max(v), rel=1e-15)
    none = np.zeros(0)
    assert uniformity(v) == TERMS["uniformity"].value(Objective(), none, v, none)  # one definition, same bits
    failed = v.copy()
    failed[5] = np.nan
    assert math.isnan(uniformity(failed)) and math.isnan(worst_to_best(failed))  # never over a subset
    assert math.isnan(uniformity([])) and math.isnan(uniformity([-0.01, 0.01]))
    assert uniformity([0.03] * 4) == 1.0


def statistics_pstdev(values) -> float:
    """Population standard deviation by its definition (not numpy's)."""
    m = sum(values) / len(values)
    return math.sqrt(sum((x - m) ** 2 for x in values) / len(values))
