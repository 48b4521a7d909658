"""The nlopt optimizer: algorithms on analytic objectives, the store path, resume, outputs, CLI.

``analytic_evaluate`` below is a TEST DOUBLE of ``latticeopt.coupled.evaluate_phantom``: a cheap deterministic
function of the design and the phantom with a known optimum, for the machinery only (not physics). The run with
the real coupled model is at the end of the file.
"""

from __future__ import annotations

import csv
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from doubles import logged_calls, record_call

from latticeopt.design import LatticeDesign
from latticeopt.errors import (
    AllFailedError,
    ConvergenceError,
    FolderLockedError,
    LatticeoptError,
    ModelBugError,
    ParameterError,
)
from latticeopt.optimize import (
    ALGORITHMS,
    CONSTRAINED,
    Assessment,
    Constraints,
    OptimizeConfig,
    Problem,
    Variable,
    load_optimization,
    minimize,
    optimization_from_dict,
    run_optimization,
)
from latticeopt.optimize.objectives import Objective
from latticeopt.study.store import ResultStore

TESTS = Path(__file__).parent
LOG_ENV = "LATTICEOPT_TEST_OPT_LOG"
STOP_ENV = "LATTICEOPT_TEST_OPT_INTERRUPT_AFTER"
W_OPT, T_OPT = 4.2, 2.7


def _f(w: float, t: float) -> float:
    return 0.05 - 0.002 * (w - W_OPT) ** 2 - 0.003 * (t - T_OPT) ** 2


def _phantom_factor(phantom) -> float:
    return 1.0 + 0.04 * sum(t.depth_mm for t in phantom.touches) - 0.1 * (phantom.n_touches - 1)


def analytic_evaluate(design, phantom, settings) -> dict:
    """TEST DOUBLE of latticeopt.coupled.evaluate_phantom: V_rel = f(w, t) * c(phantom), optimum at (4.2, 2.7).

    Logs every call to ``$LATTICEOPT_TEST_OPT_LOG``; raises KeyboardInterrupt (like Ctrl-C) once the log has
    ``$LATTICEOPT_TEST_OPT_INTERRUPT_AFTER`` lines.
    """
    record_call(f"{design.content_hash()} {phantom.key}", LOG_ENV, STOP_ENV)
    v = _f(design.width_mm, design.thickness_mm) * _phantom_factor(phantom)
    return {"v_rel": v, "forces_N": [0.1] * phantom.n_touches, "timings": {"double": 0.0},
            "max_hydrogel_stretch": 1.0 + 0.1 * design.width_mm + 0.01 * sum(t.depth_mm for t in phantom.touches)}


STUDY = """
name = "opt"
out = "{out}"
jobs = 1
[design]
pitch_mm = 12.5
[phantoms]
seed = 3
counts = {{ 1 = 2, 2 = 1 }}
[mesh]
size_mm = 5.0
[optimize]
algorithm = "{alg}"
max_evals = {max_evals}
xtol_abs_mm = 0.01
[optimize.variables]
width_mm = {{ lower = 0.5, upper = 8.0, start = 2.0 }}
thickness_mm = {{ lower = 1.0, upper = 5.0, start = 4.5 }}
"""


def _write(tmp_path: Path, alg="LN_BOBYQA", max_evals=40, out="out", extra="") -> Path:
    p = tmp_path / "opt.toml"
    p.write_text(STUDY.format(out=(tmp_path / out).as_posix(), alg=alg, max_evals=max_evals) + extra)
    return p


# -- the driver on analytic objectives (no store) --------------------------------------------------------------
WT = (Variable("width_mm", 0.5, 8.0, 3.0), Variable("thickness_mm", 1.0, 5.0, 2.0))


def _assess_wt(design) -> Assessment:
    return Assessment(score=_f(design.width_mm, design.thickness_mm))


def _inside(history, variables) -> bool:
    return all(v.lower <= s.x[v.name] <= v.upper for s in history for v in variables)


@pytest.mark.parametrize("alg", list(ALGORITHMS))
def test_each_algorithm_honours_bounds_and_finds_the_known_optimum(alg):
    problem = Problem.build(LatticeDesign(width_mm=3.0, thickness_mm=2.0), WT, Constraints())
    cfg = OptimizeConfig(variables=WT, algorithm=alg, max_evals=300, xtol_abs_mm=1e-4)
    res = minimize(problem, cfg, _assess_wt)
    assert _inside(res.history, WT)
    assert res.history[0].x == {"width_mm": 3.0, "thickness_mm": 2.0} or ALGORITHMS[alg] == "global"
    assert len(res.history) <= 300 + 5  # CRS2 may overshoot maxeval by a few calls
    if ALGORITHMS[alg] == "local":
        assert res.best.x["width_mm"] == pytest.approx(W_OPT, abs=0.01)
        assert res.best.x["thickness_mm"] == pytest.approx(T_OPT, abs=0.01)
    else:  # within 1 % of the objective's range over the box after 300 calls
        assert res.best.score >= _f(W_OPT, T_OPT) - 0.01 * (_f(W_OPT, T_OPT) - _f(8.0, 1.0))


def _narrowest_island_mm(design) -> float:
    """Diameter of the largest circle inside the roomiest silicone island away from the sensor's edge (shapely)."""
    import shapely

    gel = design.footprint()
    holes = [shapely.Polygon(ring) for g in getattr(gel, "geoms", [gel]) for ring in g.interiors]
    return max(2 * shapely.maximum_inscribed_circle(h, 1e-4).length for h in holes)


def _rim_channel_mm(design) -> float:
    """Depth of hydrogel from the y = 0 edge, least over x between the lattice's lines (shapely)."""
    import shapely

    gel = design.footprint()
    depths = []
    for x in np.linspace(1.0, design.size_mm - 1.0, 397):
        cut = gel.intersection(shapely.LineString([(x, 0.0), (x, design.size_mm / 2)]))
        first = min(getattr(cut, "geoms", [cut]), key=lambda seg: seg.bounds[1])
        depths.append(first.length)
    return min(depths)


@pytest.mark.parametrize("pattern, rim", [("square", "none"), ("square", "channel"), ("triangular", "none"),
                                          ("hexagonal", "channel")])
def test_fabrication_limits_fold_to_the_widths_where_the_layout_meets_them(pattern, rim):
    # measured on the laid-out footprint, not from the constraint's formula: at the folded lower bound the
    # narrowest channel (the rim channel, w / 2, when there is one) is min_channel_mm; at the upper bound the
    # islands are min_island_mm across their inscribed circle (the triangular lattice's 2/3 p - w)
    limits = Constraints(min_channel_mm=1.5, min_island_mm=2.0)
    start = LatticeDesign(pattern=pattern, rim=rim, width_mm=4.0, pitch_mm=12.5)
    problem = Problem.build(start, (Variable("width_mm", 0.5, 12.0, 4.0),), limits)
    (lo,), (hi,) = problem.lower, problem.upper
    narrowest = _rim_channel_mm(problem.design(np.array([lo]))) if rim == "channel" else lo
    assert narrowest == pytest.approx(limits.min_channel_mm, abs=0.01)
    assert _narrowest_island_mm(problem.design(np.array([hi]))) == pytest.approx(limits.min_island_mm, abs=0.01)


WP = (Variable("width_mm", 1.0, 8.0, 2.0), Variable("pitch_mm", 4.0, 14.0, 10.0))


def _assess_wp(design) -> Assessment:  # unconstrained optimum w = 5, p = 6 violates p - w >= 2
    return Assessment(score=0.05 - 0.002 * (design.width_mm - 5) ** 2 - 0.002 * (design.pitch_mm - 6) ** 2)


@pytest.mark.parametrize("alg", list(ALGORITHMS))
def test_coupled_constraint_is_honoured_by_each_algorithm(alg):
    problem = Problem.build(LatticeDesign(width_mm=2.0, pitch_mm=10.0), WP, Constraints(min_island_mm=2.0))
    assert [c.name for c in problem.general] == ["min_island_mm"]  # w and p both free: not a bound
    if alg not in CONSTRAINED:
        with pytest.raises(ParameterError, match="'penalty' or 'auglag'.*LN_COBYLA, GN_ISRES"):
            OptimizeConfig(variables=WP, algorithm=alg).check_constraint_method(problem)
    method = "auto" if alg in CONSTRAINED else ("auglag" if ALGORITHMS[alg] == "local" else "penalty")
    cfg = OptimizeConfig(variables=WP, algorithm=alg, max_evals=400, xtol_abs_mm=1e-4, constraint_method=method,
                         penalty_weight=100.0)
    res = minimize(problem, cfg, _assess_wp)
    assert _inside(res.history, WP)
    best = res.best
    assert best.x["pitch_mm"] - best.x["width_mm"] >= 2.0 - 1e-9  # the reported optimum is feasible
    for s in res.history:  # feasibility flags agree with the constraint
        assert s.feasible == (s.x["pitch_mm"] - s.x["width_mm"] >= 2.0 - 1e-9)
    if ALGORITHMS[alg] == "local":  # the constrained optimum: p - w = 2, w = 4.5
        assert best.x["width_mm"] == pytest.approx(4.5, abs=0.01)
        assert best.x["pitch_mm"] == pytest.approx(6.5, abs=0.01)
    else:
        assert best.score >= 0.049 - 0.001


def test_algorithm_names_accepted_and_unknown_rejected_with_the_list():
    for alg in ALGORITHMS:
        assert OptimizeConfig(variables=WT, algorithm=alg).algorithm == alg
    with pytest.raises(ParameterError) as exc:
        OptimizeConfig(variables=WT, algorithm="LN_BOBYQUA")
    assert all(a in str(exc.value) for a in ALGORITHMS) and "LN_BOBYQUA" in str(exc.value)
    with pytest.raises(ParameterError, match="local_algorithm"):
        OptimizeConfig(variables=WT, algorithm="G_MLSL_LDS", local_algorithm="GN_DIRECT_L")


def test_multistart_is_seeded_and_respects_the_budget():
    problem = Problem.build(LatticeDesign(width_mm=3.0, thickness_mm=2.0), WT, Constraints())
    cfg = OptimizeConfig(variables=WT, algorithm="LN_NELDERMEAD", max_evals=60, xtol_abs_mm=1e-3, starts=3, seed=5)
    a, b = minimize(problem, cfg, _assess_wt), minimize(problem, cfg, _assess_wt)
    assert [s.x for s in a.history] == [s.x for s in b.history]  # deterministic
    assert len(a.history) <= 60 and len(a.starts) == 3
    x0s = [tuple(s.x0.values()) for s in a.starts]
    assert x0s[0] == (3.0, 2.0) and len(set(x0s)) == 3
    other = minimize(problem, OptimizeConfig(variables=WT, algorithm="LN_NELDERMEAD", max_evals=60, starts=3, seed=6),
                     _assess_wt)
    assert [tuple(s.x0.values()) for s in other.starts][1:] != x0s[1:]


def test_objective_terms_and_standard_errors():
    rng = np.random.default_rng(1)
    r = rng.normal(0.05, 0.01, 400)
    mean = Objective()
    val = mean.evaluate(r)
    assert val.score == pytest.approx(r.mean()) and val.se == pytest.approx(r.std(ddof=1) / 20)
    robust = Objective(weights=(("robust", 1.0),), quantile=0.5)
    val = robust.evaluate(r)
    assert val.score == pytest.approx(np.median(r))
    # bootstrap SE of the median of normal data ~ sqrt(pi / 2) sigma / sqrt(n)
    assert val.se == pytest.approx(math.sqrt(math.pi / 2) * 0.01 / 20, rel=0.2)
    uni = Objective(weights=(("uniformity", 1.0),), probe_grid=4, probe_radius_mm=7.5)
    probes = uni.probes(100.0)
    assert len(probes) == 16 and {t.touches[0].x_mm for t in probes} == {12.5, 37.5, 62.5, 87.5}
    assert uni.evaluate([], np.full(16, 0.03)).score == pytest.approx(1.0)
    p = np.linspace(0.02, 0.04, 16)
    assert uni.evaluate([], p).score == pytest.approx(1 - p.std() / p.mean())
    with pytest.raises(ParameterError, match="probe_radius_mm"):
        Objective(weights=(("uniformity", 1.0),), probe_grid=8, probe_radius_mm=7.5).probes(100.0)
    # paired difference: for the mean, the SE of the per-phantom differences
    b = r - 0.002 + rng.normal(0, 0.001, 400)
    d, se = mean.paired_difference((r, ()), (b, ()))
    assert d == pytest.approx(np.mean(r - b)) and se == pytest.approx(np.std(r - b, ddof=1) / 20)
    assert se < 0.2 * mean.evaluate(r).se  # common random numbers: far below the unpaired SE


def test_shipped_optimize_square_study():
    from latticeopt.study.config import load_study

    opt = load_optimization(TESTS.parent / "studies" / "optimize_square.toml")
    assert opt.config.algorithm in ("LN_BOBYQA", "LN_COBYLA") and opt.config.names == ("width_mm", "thickness_mm")
    assert (opt.problem.lower, opt.problem.upper, opt.problem.start) == ((0.5, 1.0), (8.0, 5.0), (3.0, 2.0))
    assert opt.study.settings.mesh.cell_counts == "fixed"
    # the quick sweep run with the same cell counts shares its settings key and phantoms: reuse and the path map
    quick = load_study(TESTS.parent / "studies" / "quick.toml",
                       ["mesh.mesher=\"grid\"", "mesh.size_mm=4", "mesh.channel_cells=1", "mesh.cell_counts=fixed"])
    assert quick.settings.key == opt.study.settings.key and quick.phantoms == opt.study.phantoms


# -- the store path with the test double ---------------------------------------------------------------------
def test_store_run_improves_on_start_writes_outputs_and_reuses(tmp_path, monkeypatch):
    monkeypatch.setenv(LOG_ENV, str(tmp_path / "evals.log"))
    opt = load_optimization(_write(tmp_path))
    res = run_optimization(opt, analytic_evaluate)
    start, best = res.optimum.start_step, res.best
    assert start.x == {"width_mm": 2.0, "thickness_mm": 4.5}
    assert best.score > start.score and best.x["width_mm"] == pytest.approx(W_OPT, abs=0.05)
    assert best.x["thickness_mm"] == pytest.approx(T_OPT, abs=0.05)
    factors = [_phantom_factor(p) for p in opt.study.phantoms]
    assert best.score == pytest.approx(_f(best.x["width_mm"], best.x["thickness_mm"]) * np.mean(factors), rel=1e-12)
    diffs = [(_f(**{"w": best.x["width_mm"], "t": best.x["thickness_mm"]}) - _f(2.0, 4.5)) * c for c in factors]
    assert res.paired[0] == pytest.approx(np.mean(diffs), rel=1e-9)
    assert res.paired[1] == pytest.approx(np.std(diffs, ddof=1) / math.sqrt(3), rel=1e-9)
    designs = {s.assessment.design_key for s in res.history}
    with ResultStore(opt.study.out_dir, readonly=True) as store:
        assert len(store) == 3 * len(designs) == len(logged_calls(tmp_path / "evals.log"))
        assert {e.design_key for e in store.rows()} == designs
    rows = list(csv.DictReader(open(res.outputs["history"])))
    assert len(rows) == len(res.history) and float(rows[0]["width_mm"]) == 2.0
    # the spread over presses, from the double's per-phantom factors: V_rel = f(w, t) * factor
    f0 = _f(2.0, 4.5)
    assert float(rows[0]["v_rel_median"]) == pytest.approx(f0 * np.median(factors), rel=1e-9)
    assert float(rows[0]["v_rel_max"]) == pytest.approx(f0 * max(factors), rel=1e-9)
    assert float(rows[0]["v_rel_max_share"]) == pytest.approx(max(factors) / sum(factors), rel=1e-9)
    for key in ("convergence", "path"):
        assert res.outputs[key].read_bytes()[:4] == b"\x89PNG"
    saved = json.loads(res.outputs["result"].read_text())
    assert saved["optimum"]["x"] == best.x and "optimum:" in "\n".join(res.report)
    # the same run again: every design is read from the store, the same path is taken
    again = run_optimization(load_optimization(tmp_path / "opt.toml"), analytic_evaluate)
    assert again.computed == 0 and len(logged_calls(tmp_path / "evals.log")) == 3 * len(designs)
    assert [(s.x, s.score) for s in again.history] == [(s.x, s.score) for s in res.history]


def test_interrupted_run_resumes_without_recomputing(tmp_path, monkeypatch):
    log1, log2 = tmp_path / "run1.log", tmp_path / "run2.log"
    monkeypatch.setenv(LOG_ENV, str(log1))
    monkeypatch.setenv(STOP_ENV, "14")  # Ctrl-C in the middle of the 5th design (3 phantoms each)
    path = _write(tmp_path)
    with pytest.raises(KeyboardInterrupt):
        run_optimization(load_optimization(path), analytic_evaluate)
    first = set(logged_calls(log1))
    assert len(first) == 14
    with ResultStore(tmp_path / "out", readonly=True) as store:
        assert len(store) == 14 and store.integrity_check() == "ok"
    monkeypatch.setenv(LOG_ENV, str(log2))
    monkeypatch.delenv(STOP_ENV)
    resumed = run_optimization(load_optimization(path), analytic_evaluate)
    second = set(logged_calls(log2))
    assert not first & second  # nothing computed twice
    assert resumed.computed == len(second)
    monkeypatch.delenv(LOG_ENV)
    clean = run_optimization(load_optimization(path), analytic_evaluate, out_dir=tmp_path / "clean")
    assert [(s.x, s.score) for s in resumed.history] == [(s.x, s.score) for s in clean.history]
    assert resumed.best.x == clean.best.x


def test_path_over_stored_sweep_map_and_sweep_rows_reused(tmp_path, monkeypatch):
    from latticeopt.study.config import load_study
    from latticeopt.study.sweep import run_sweep

    monkeypatch.setenv(LOG_ENV, str(tmp_path / "evals.log"))
    sweep = tmp_path / "sweep.toml"
    text = _write(tmp_path).read_text()
    sweep.write_text(text.split("[optimize]")[0].replace('name = "opt"', 'name = "grid"')
                     + "[grid]\nthickness_mm = [1.5, 3.0, 4.5]\nwidth_mm = [2.0, 4.0, 6.0]\n")
    run_sweep(load_study(sweep), analytic_evaluate, progress=False)
    n_sweep = len(logged_calls(tmp_path / "evals.log"))
    assert n_sweep == 27
    res = run_optimization(load_optimization(_write(tmp_path)), analytic_evaluate)
    assert res.history[0].assessment.computed == 0  # the start (2, 4.5) is a sweep design: read, not computed
    assert "over the stored V_rel map" in res.report[-1]
    assert res.outputs["path"].read_bytes()[:4] == b"\x89PNG"
    from latticeopt.optimize.report import stored_map

    vmap = stored_map(tmp_path / "out", res.settings.key, [p.key for p in res.optimization.study.phantoms],
                      res.optimization.problem)
    assert list(vmap["x"]) == [2.0, 4.0, 6.0] and list(vmap["y"]) == [1.5, 3.0, 4.5]
    factor = np.mean([_phantom_factor(p) for p in res.optimization.study.phantoms])
    assert vmap["v_rel_mean"][1, 2] == pytest.approx(_f(6.0, 3.0) * factor, rel=1e-12)


def test_weighted_objective_with_uniformity_probes_through_the_store(tmp_path):
    extra = '[optimize.uniformity]\ngrid = 3\nradius_mm = 7.5\ndepth_mm = 2.0\n'
    path = _write(tmp_path, max_evals=3, extra=extra)
    opt = load_optimization(path, ['optimize.objective={mean = 1.0, robust = 0.5, uniformity = 0.01}'])
    assert len(opt.probes) == 9
    res = run_optimization(opt, analytic_evaluate, outputs=False)
    a = res.history[0].assessment
    assert len(a.random_v) == 3 and len(a.probe_v) == 9
    with ResultStore(tmp_path / "out", readonly=True) as store:
        assert len(store) == 12 * len({s.assessment.design_key for s in res.history})
    # the double's probes differ only in position, to which it is blind: perfectly uniform
    assert a.terms["uniformity"] == pytest.approx(1.0)
    rv = np.array(a.random_v)
    assert a.score == pytest.approx(rv.mean() + 0.5 * np.quantile(rv, 0.1) + 0.01, rel=1e-12)
    assert 0 < a.se < 1


def test_hydrogel_stretch_constraint_through_the_store(tmp_path):
    # stretch = 1 + 0.1 w + 0.01 * sum of depths; limit 1.45 caps w below the unconstrained optimum 4.2
    path = _write(tmp_path, alg="LN_COBYLA", max_evals=60,
                  extra="[optimize.constraints]\nmax_hydrogel_stretch = 1.45\n")
    opt = load_optimization(path)
    res = run_optimization(opt, analytic_evaluate, outputs=False)
    depth = max(sum(t.depth_mm for t in p.touches) for p in opt.study.phantoms)
    w_max = (1.45 - 1.0 - 0.01 * depth) / 0.1
    assert w_max < W_OPT
    assert res.best.x["width_mm"] <= w_max + 1e-9
    assert res.best.x["width_mm"] == pytest.approx(w_max, abs=0.02)
    assert res.best.assessment.max_stretch <= 1.45
    with pytest.raises(ParameterError, match="'penalty' or 'auglag'"):
        load_optimization(path, ["optimize.algorithm=LN_BOBYQA"])


def _no_stretch_evaluate(design, phantom, settings) -> dict:
    return {"v_rel": 0.01}


FAIL_ENV = "LATTICEOPT_TEST_OPT_FAIL_PHANTOM"
W_FAIL = 3.5


def failing_evaluate(design, phantom, settings) -> dict:
    """TEST DOUBLE: analytic_evaluate, but ConvergenceError for w > 3.5 on the phantom whose key is
    ``$LATTICEOPT_TEST_OPT_FAIL_PHANTOM`` (``"*"``: every phantom of every design)."""
    chosen = os.environ[FAIL_ENV]
    if chosen == "*" or (design.width_mm > W_FAIL and phantom.key == chosen):
        raise ConvergenceError("fake: the press was too hard")
    return analytic_evaluate(design, phantom, settings)


def test_a_failed_phantom_makes_a_design_infeasible(tmp_path, monkeypatch):
    opt = load_optimization(_write(tmp_path))
    phantoms = opt.study.phantoms
    # the weakest phantom fails for w > 3.5, around the optimum w = 4.2: averaged over the others, those designs
    # would score higher than the same design with every phantom, and higher than any design that solves all
    weakest = min(phantoms, key=_phantom_factor)
    monkeypatch.setenv(FAIL_ENV, weakest.key)
    others = np.mean([_phantom_factor(p) for p in phantoms if p is not weakest])
    assert _f(W_OPT, T_OPT) * others > _f(W_FAIL, T_OPT) * np.mean([_phantom_factor(p) for p in phantoms])
    res = run_optimization(opt, failing_evaluate, outputs=False)
    best = res.best
    assert best.x["width_mm"] <= W_FAIL and best.assessment.n_failed == 0
    assert best.score == pytest.approx(_f(best.x["width_mm"], best.x["thickness_mm"])
                                       * np.mean([_phantom_factor(p) for p in phantoms]), rel=1e-12)
    failing = [s for s in res.history if s.assessment is not None and s.assessment.n_failed]
    assert failing and all(s.x["width_mm"] > W_FAIL for s in failing)
    for s in failing:
        assert not s.feasible and math.isnan(s.score) and "1 of 3 phantoms failed: infeasible" in s.note
    assert math.isnan(Objective().evaluate([0.05, math.nan, 0.04]).score)


def test_retry_failed_recomputes_the_stored_failures_once_the_model_solves_them(tmp_path, monkeypatch):
    opt = load_optimization(_write(tmp_path))
    monkeypatch.setenv(FAIL_ENV, min(opt.study.phantoms, key=_phantom_factor).key)
    first = run_optimization(opt, failing_evaluate, outputs=False)
    assert first.best.x["width_mm"] <= W_FAIL
    monkeypatch.setenv(FAIL_ENV, "none")  # the solver is mended: no phantom fails any more
    again = run_optimization(opt, failing_evaluate, outputs=False)  # the failures are read from the store
    assert again.best.x == first.best.x and any(s.assessment.n_failed for s in again.history if s.assessment)
    retried = run_optimization(opt, failing_evaluate, outputs=False, retry_failed=True)
    assert not any(s.assessment.n_failed for s in retried.history if s.assessment)
    assert retried.best.x["width_mm"] > W_FAIL and retried.best.x["width_mm"] == pytest.approx(W_OPT, abs=0.05)


def test_retry_failed_is_refused_for_a_density_study(capsys):
    from latticeopt.cli import main

    assert main(["optimize", str(TESTS.parent / "studies" / "optimize_freeform.toml"), "--retry-failed"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--retry-failed" in err and "a density study" in err


def test_every_evaluation_failed_is_an_error(tmp_path, monkeypatch):
    monkeypatch.setenv(FAIL_ENV, "*")
    path = _write(tmp_path, max_evals=4)
    with pytest.raises(AllFailedError, match="every one of the .* phantom evaluations .* failed") as info:
        run_optimization(load_optimization(path), failing_evaluate)
    assert info.value.result.best is None and "\n" not in str(info.value)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(TESTS), os.environ.get("PYTHONPATH", "")])}
    done = subprocess.run([sys.executable, "-m", "latticeopt", "optimize", str(path), "--evaluate",
                           "test_optimize:failing_evaluate", "--quiet"], env=env, capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 1 and done.stderr.count("\n") == 1 and "Traceback" not in done.stderr, done.stderr


def buggy_evaluate(design, phantom, settings) -> dict:
    """TEST DOUBLE with a programming error on phantom index 1 (must stop the optimization)."""
    if phantom.index == 1:
        raise IndexError("fake bug: index 7 is out of bounds")
    return analytic_evaluate(design, phantom, settings)


def test_a_bug_in_the_model_stops_the_optimization(tmp_path):
    path = _write(tmp_path)
    with pytest.raises(ModelBugError, match="IndexError: fake bug") as info:
        run_optimization(load_optimization(path), buggy_evaluate)
    assert "\n" not in str(info.value)
    assert "in buggy_evaluate" in (tmp_path / "out" / "error.log").read_text()
    with ResultStore(tmp_path / "out", readonly=True) as store:
        assert store.rows() and all(e.ok for e in store.rows())  # never stored as a failed phantom


def rim_failing_evaluate(design, phantom, settings) -> dict:
    """TEST DOUBLE: analytic_evaluate, but every phantom fails for the rim-channel layout (or for every layout
    when ``$LATTICEOPT_TEST_OPT_FAIL_PHANTOM`` is ``"*"``)."""
    if design.rim == "channel" or os.environ.get(FAIL_ENV) == "*":
        raise ConvergenceError("fake: this layout never converges")
    return analytic_evaluate(design, phantom, settings)


def test_a_category_where_everything_fails_does_not_hide_the_others(tmp_path):
    path = _write(tmp_path, max_evals=6, extra='[optimize.categories]\nrim = ["none", "channel"]\n')
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(TESTS), os.environ.get("PYTHONPATH", "")])}
    cmd = [sys.executable, "-m", "latticeopt", "optimize", str(path), "--quiet", "--evaluate",
           "test_optimize:rim_failing_evaluate"]
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "category rim-channel: every one of" in done.stdout
    ranked = done.stdout.split("categories ranked")[1]
    assert "rim-none: score" in ranked and "rim-channel: no feasible design" in ranked
    done = subprocess.run(cmd + ["--out", str(tmp_path / "all_fail")], env={**env, FAIL_ENV: "*"},
                          capture_output=True, text=True, timeout=300)
    # the per-phantom warnings come first; the error itself is the last line, no traceback
    assert done.returncode == 1 and "Traceback" not in done.stderr, done.stderr
    assert done.stderr.splitlines()[-1].startswith("latticeopt optimize: failed: every phantom evaluation failed in "
                                                   "every category")


def test_optimization_refuses_a_locked_folder(tmp_path):
    path = _write(tmp_path)
    holder = subprocess.Popen([sys.executable, "-c", "import sys\nfrom latticeopt.study.store import folder_lock\n"
                               "with folder_lock(sys.argv[1]):\n    print('locked', flush=True)\n    sys.stdin.read()",
                               str(tmp_path / "out")], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(FolderLockedError, match=f"PID {holder.pid}"):
            run_optimization(load_optimization(path), analytic_evaluate)
    finally:
        holder.communicate("", timeout=30)
    with ResultStore(tmp_path / "out") as store:
        assert len(store) == 0


def test_stretch_constraint_needs_the_model_to_report_it(tmp_path):
    path = _write(tmp_path, alg="LN_COBYLA", extra="[optimize.constraints]\nmax_hydrogel_stretch = 1.5\n")
    with pytest.raises(LatticeoptError, match="max_hydrogel_stretch"):
        run_optimization(load_optimization(path), _no_stretch_evaluate, outputs=False)


@pytest.mark.parametrize("change, key", [
    ({"optimize": {"algorithm": "LN_BOBYQA", "bogus": 1, "variables": {"width_mm": [1, 5]}}}, "optimize.bogus"),
    ({"grid": {"width_mm": [1, 2]}, "optimize": {"variables": {"thickness_mm": [1, 5]}}}, "grid"),
    ({"optimize": {"variables": {"width_mm": {"lower": 0, "upper": 5}}}}, "optimize.variables.width_mm.lower"),
    ({"optimize": {"variables": {"width_mm": {"lower": 1, "upper": 5, "start": 6}}}},
     "optimize.variables.width_mm.start"),
    ({"optimize": {"variables": {"size_mm": [90, 110]}}}, "optimize.variables.size_mm"),
    ({"optimize": {"variables": {"width_mm": [1, 5]}, "objective": "best"}}, "optimize.objective"),
    ({"optimize": {"variables": {"width_mm": [1, 5]}, "objective": {"mean": -1}}}, "optimize.objective.mean"),
    ({"optimize": {"variables": {"width_mm": [1, 5]}, "max_evals": 0}}, "optimize.max_evals"),
    ({"optimize": {"variables": {"thickness_mm": [1, 7]}, "constraints": {"min_substrate_mm": 3}}},
     "optimize.variables.thickness_mm.start"),
    ({"optimize": {"variables": {"width_mm": [1, 5]}, "constraints": {"min_island_mm": 10.0}}},
     "optimize.variables.width_mm.start"),
])
def test_bad_optimization_tables_are_rejected_naming_the_key(change, key):
    raw = {"design": {"width_mm": 3.0, "thickness_mm": 4.5}, "phantoms": {"counts": {"1": 1}}, **change}
    with pytest.raises(ParameterError) as exc:
        optimization_from_dict(raw, source="f.toml")
    assert exc.value.name == f"f.toml: {key}", str(exc.value)


def test_cli_runs_and_rejects_a_bad_algorithm_in_one_line(tmp_path):
    path = _write(tmp_path, max_evals=12)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(TESTS), os.environ.get("PYTHONPATH", "")])}
    cmd = [sys.executable, "-m", "latticeopt", "optimize", str(path), "--evaluate", "test_optimize:analytic_evaluate"]
    bad = subprocess.run(cmd + ["--set", "optimize.algorithm=BOBYQA"], env=env, capture_output=True, text=True)
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "--set optimize.algorithm" in bad.stderr
    assert all(a in bad.stderr for a in ALGORITHMS) and not (tmp_path / "out").exists()
    done = subprocess.run(cmd + ["--quiet"], env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "optimum:" in done.stdout and (tmp_path / "out" / "opt_history.csv").exists()


# -- the grid mesher's fixed cell counts (smooth objectives) ---------------------------------------------------
def test_fixed_cell_counts_keep_the_node_count_and_move_nodes_continuously():
    from latticeopt.mesh import MeshSettings
    from latticeopt.mesh.grid import grid_coordinates, grid_mesh

    def shape(w, t, rule):
        return tuple(len(c) for c in grid_coordinates(LatticeDesign(width_mm=w, thickness_mm=t), 4.0, 1, 2, rule))

    line = [w for w in np.linspace(0.5, 8.0, 31) if abs(w - 4.0) > 1e-9]
    assert len({shape(w, t, "fixed") for w in line for t in (1.0, 2.5, 5.0)}) == 1
    assert len({shape(w, 3.0, "size") for w in line}) > 1  # the default rule jumps: why "fixed" exists
    # through w = electrode width (4 mm) the lines converge to the merged grid of w = 4 from both sides
    x4 = grid_coordinates(LatticeDesign(width_mm=4.0), 4.0, 1, 2, "fixed")[0]
    for eps in (1e-4, -1e-4):
        x = grid_coordinates(LatticeDesign(width_mm=4.0 + eps), 4.0, 1, 2, "fixed")[0]
        assert np.max(np.min(np.abs(x[:, None] - x4[None, :]), axis=1)) <= abs(eps) / 2 + 1e-12
        assert np.max(np.min(np.abs(x4[:, None] - x[None, :]), axis=1)) <= abs(eps) / 2 + 1e-12
    d = LatticeDesign(width_mm=5.3, thickness_mm=2.2)
    mesh = grid_mesh(d, 4.0, 1, 2, "fixed")
    for name, vol in d.region_volumes_mm3().items():
        assert mesh.region_volumes_mm3()[name] == pytest.approx(vol, rel=1e-12)
    assert np.allclose(mesh.electrode_areas_mm2(), d.electrode_width_mm * d.thickness_mm)
    # the default stays implicit, so settings keys and mesh cache keys computed before the option still hold
    assert "cell_counts" not in MeshSettings().as_dict()
    assert MeshSettings(cell_counts="fixed").as_dict()["cell_counts"] == "fixed"
    with pytest.raises(ParameterError, match="cell_counts"):
        MeshSettings(cell_counts="even")


def test_dask_cluster_run_equals_local_run(tmp_path):
    distributed = pytest.importorskip("distributed")
    path = _write(tmp_path, max_evals=10)
    local = run_optimization(load_optimization(path), analytic_evaluate, outputs=False, out_dir=tmp_path / "local")
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False, host="127.0.0.1",
                                  protocol="tcp://", dashboard_address=None) as cluster:
        remote = run_optimization(load_optimization(path), analytic_evaluate, outputs=False, backend="dask",
                                  scheduler=cluster.scheduler_address, out_dir=tmp_path / "dask")
    assert [(s.x, s.score) for s in remote.history] == [(s.x, s.score) for s in local.history]
    assert remote.computed == local.computed > 0


# -- the real coupled model ----------------------------------------------------------------------------------------
REAL = """
name = "real_tiny"
out = "{out}"
jobs = 1
[design]
pitch_mm = 12.5
[phantoms]
seed = 2025
counts = {{ 1 = 2 }}
[mesh]
mesher = "grid"
size_mm = 10.0
channel_cells = 1
layer_cells = 1
cell_counts = "fixed"
[optimize]
algorithm = "LN_BOBYQA"
max_evals = 6
[optimize.variables]
width_mm = {{ lower = 1.0, upper = 7.0, start = 2.0 }}
thickness_mm = {{ lower = 1.5, upper = 4.5, start = 2.0 }}
"""


@pytest.mark.slow
def test_real_tiny_run_improves_on_its_start(tmp_path):
    import latticeopt.coupled  # noqa: F401  (the core model: a failed import fails the test, never skips it)

    path = tmp_path / "real.toml"
    path.write_text(REAL.format(out=(tmp_path / "out").as_posix()))
    res = run_optimization(load_optimization(path), jobs=1)
    assert res.optimum.start_step.x == {"width_mm": 2.0, "thickness_mm": 2.0}
    assert all(s.assessment.n_failed == 0 for s in res.history)
    assert res.best.score > res.optimum.start_step.score
    assert res.paired[0] > 0


def test_path_figure_names_what_it_shows_and_draws_points_on_a_bound_whole(tmp_path, saved_figures):
    from test_report_plots import blank_border

    path = _write(tmp_path, max_evals=12)
    path.write_text(path.read_text().replace("lower = 1.0, upper = 5.0, start = 4.5",
                                             "lower = 3.0, upper = 5.0, start = 3.0"))  # start on a bound
    res = run_optimization(load_optimization(path), analytic_evaluate)
    assert min(s.x["thickness_mm"] for s in res.history) == 3.0
    fig = next(f for f in saved_figures if "path" in f.axes[0].get_title())
    ax = fig.axes[0]
    title = " ".join(ax.get_title().split())
    assert "square lattice (p = 12.5 mm) and uniform layer, no rim channel" in title or \
        "square lattice (p = 12.5 mm), no rim channel;" in title
    assert "t = " not in title  # the thickness is a variable here, on the y axis
    assert "3 phantoms per design" in title and "grid mesh, 5 mm" in title
    assert fig.axes[1].get_ylabel() == "mean V_rel of each evaluation"  # the colour bar says what the colour is
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    xs = [s.x["width_mm"] for s in res.history]
    ys = [s.x["thickness_mm"] for s in res.history]
    assert x0 < min(xs) and max(xs) < x1 and y0 < min(ys) and max(ys) < y1  # nothing cut by the frame
    assert blank_border(res.outputs["path"]) and blank_border(res.outputs["convergence"])
