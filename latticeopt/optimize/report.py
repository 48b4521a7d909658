"""Outputs of an optimization: history table, convergence plot, path over the stored V_rel map, report.

Files (prefixed with the study name, so an optimization can share its folder and store with sweeps and other
optimizations): ``<name>_history.csv`` (one row per nlopt call), ``<name>_convergence.png`` (score per call
with its SE, and the best feasible score so far), ``<name>_path.png`` (two variables only: the path over the
map of mean V_rel of the sweep in the same folder when it has the same settings — :func:`stored_map` — or,
without one, over the visited points coloured by score), ``<name>_report.txt`` and ``<name>_result.json``.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from .._jsonout import jsonable
from ..fabrication import spans_text
from ..study.imaging import FIGURES
from ..study.report import write_csv
from ..study.report_lines import floor_text, round_off_lines
from ..study.store import STORE_NAME, ResultStore
from .problem import effective_bounds_text

__all__ = ["features_text", "history_rows", "plot_convergence", "plot_path", "stored_map",
           "write_optimization_outputs"]


def _label(name: str) -> str:
    return name.replace("_mm", " (mm)").replace("_", " ")


def _title(result, what: str) -> str:
    """``what``, then the layout (fields the optimizer varies left out), the phantoms and the mesh."""
    from ..captions import layout_caption, wrap_title
    from ..study.plots import _mesh_caption

    opt = result.optimization
    n = len(opt.study.phantoms)
    probes = f" and {len(opt.probes)} probe presses" if opt.probes else ""
    layout = layout_caption(opt.study.designs, thickness="thickness_mm" not in opt.problem.names)
    return wrap_title(f"{opt.study.name}: {what}, {len(result.history)} calls\n{layout}; {n} phantoms per "
                      f"design{probes}\n{_mesh_caption(opt.study)}")


def press_spread(a) -> tuple[float, float, float]:
    """Median and largest V_rel over a design's solved random phantoms, and the largest one's share of their sum.

    A mean carried by one or two presses (a press that nearly cuts an electrode off) reads very differently from
    one every press supports; the median and the share tell which.
    """
    v = np.asarray(a.random_v, dtype=float) if a is not None else np.empty(0)
    v = v[np.isfinite(v)]
    if not len(v):
        return math.nan, math.nan, math.nan
    total = float(np.abs(v).sum())
    return float(np.median(v)), float(v.max()), float(np.abs(v).max() / total) if total > 0 else math.nan


def history_rows(result) -> list[dict]:
    """One dict per nlopt call: variables, score ± SE, terms, V_rel, constraints, bookkeeping."""
    rows = []
    terms = [k for k, _ in result.optimization.config.objective.weights]
    for s in result.history:
        a = s.assessment
        row = {"eval": s.index, "start": s.start, **s.x, "score": s.score, "score_se": s.se}
        for k in terms:
            row[f"term_{k}"] = a.terms.get(k, math.nan) if a is not None else math.nan
        if result.optimization.config.objective.needs_images:  # reported beside image_cc, never scored
            for k in FIGURES:
                row[f"image_{k}"] = a.image_figures.get(k, math.nan) if a is not None else math.nan
        row.update(v_rel_mean=a.v_rel_mean if a else math.nan, v_rel_se=a.v_rel_se if a else math.nan,
                   n_ok=a.n_ok if a else 0, n_failed=a.n_failed if a else 0,
                   max_stretch=a.max_stretch if a and a.max_stretch is not None else math.nan)
        row.update(zip(("v_rel_median", "v_rel_max", "v_rel_max_share"), press_spread(a)))
        row.update({f"g_{k}": g for k, g in s.constraints.items()})
        row.update(feasible=s.feasible, repeat=s.repeat, computed=a.computed if a and not s.repeat else 0,
                   seconds=a.seconds if a and not s.repeat else 0.0, nlopt_f=s.f, note=s.note,
                   design_key=a.design_key if a else "")
        rows.append(row)
    return rows


def plot_convergence(result, path: Path) -> Path:
    """Score of every call (± SE), infeasible calls marked, best feasible score so far, start boundaries."""
    from matplotlib.figure import Figure

    h = result.history
    idx = np.array([s.index for s in h])
    score = np.array([s.score for s in h])
    se = np.array([s.se if math.isfinite(s.se) else 0.0 for s in h])
    feas = np.array([s.feasible for s in h])
    best, run = [], -math.inf
    for s in h:
        if s.feasible:
            run = max(run, s.score)
        best.append(run if math.isfinite(run) else math.nan)
    fig = Figure(figsize=(6.4, 4.2), layout="constrained")
    ax = fig.add_subplot()
    if feas.any():
        ax.errorbar(idx[feas], score[feas], yerr=se[feas], fmt="o", ms=3, capsize=2, alpha=0.7,
                    label="evaluation (± SE)")
    if (~feas).any():
        ax.plot(idx[~feas], score[~feas], "x", color="tab:red", label="infeasible")
    ax.step(idx, best, where="post", color="black", label="best feasible so far")
    for k in sorted({s.start for s in h})[1:]:
        ax.axvline(next(s.index for s in h if s.start == k) - 0.5, color="grey", ls=":", lw=1)
    opt = result.optimization
    ax.set_xlabel("objective call")
    ax.set_ylabel(opt.config.objective.describe())
    ax.set_title(_title(result, opt.config.algorithm), fontsize=8.5)
    ax.grid(alpha=0.3)
    ax.legend(fontsize="small")
    fig.savefig(path, dpi=130)
    return path


def stored_map(out_dir: Path, settings_key: str, phantom_keys, problem) -> dict | None:
    """Mean V_rel over the grid of the sweep stored in ``out_dir``, in the plane of the two variables.

    The sweep is the one whose ``study.json`` (written by :func:`latticeopt.study.sweep.run_sweep`) is in the folder
    and has the same settings key; its designs that agree with the problem's fixed fields give the grid, and
    their stored rows on *these* phantoms the values (a cell stays empty unless every phantom is stored).
    Returns ``None`` when there is no such sweep or the grid is not at least 2 x 2.
    """
    meta = Path(out_dir) / "study.json"
    if len(problem.names) != 2 or not meta.exists() or not (Path(out_dir) / STORE_NAME).exists():
        return None
    data = json.loads(meta.read_text())
    if data.get("settings_key") != settings_key:
        return None
    from ..design import LatticeDesign

    xf, yf = problem.names
    fixed = {k: val for k, val in problem.fixed if k not in problem.names}
    cells = {}
    for d in data.get("designs", []):
        if all(d.get(k) == val for k, val in fixed.items()):
            cells[(d[xf], d[yf])] = LatticeDesign(**d).content_hash()
    xs, ys = sorted({x for x, _ in cells}), sorted({y for _, y in cells})
    if len(xs) < 2 or len(ys) < 2:
        return None
    wanted = list(phantom_keys)
    grid = np.full((len(ys), len(xs)), np.nan)
    with ResultStore(out_dir, readonly=True) as store:
        for (x, y), key in cells.items():
            got = {e.phantom_key: e.v_rel for e in store.evaluations_for(key, settings_key, wanted) if e.ok}
            if len(got) == len(wanted):
                grid[ys.index(y), xs.index(x)] = float(np.mean([got[k] for k in wanted]))
    if not np.isfinite(grid).any():
        return None
    return {"x_field": xf, "y_field": yf, "x": np.array(xs), "y": np.array(ys), "v_rel_mean": grid}


def _edges(c: np.ndarray) -> np.ndarray:
    mid = (c[1:] + c[:-1]) / 2
    return np.concatenate([[c[0] - (mid[0] - c[0])], mid, [c[-1] + (c[-1] - mid[-1])]])


def plot_path(result, path: Path, vmap: dict | None) -> Path | None:
    """The optimizer's path in the plane of its two variables, over ``vmap`` when there is one."""
    problem = result.optimization.problem
    if len(problem.names) != 2:
        return None
    from matplotlib.figure import Figure

    xf, yf = problem.names
    h = [s for s in result.history if not s.repeat]
    x = np.array([s.x[xf] for s in h])
    y = np.array([s.x[yf] for s in h])
    fig = Figure(figsize=(6.4, 4.8), layout="constrained")
    ax = fig.add_subplot()
    if vmap is not None:
        im = ax.pcolormesh(_edges(vmap["x"]), _edges(vmap["y"]), vmap["v_rel_mean"], cmap="viridis",
                           shading="flat")
        fig.colorbar(im, ax=ax, label="mean $V_{rel}$ (stored sweep rows)")
        ax.plot(x, y, "-", color="white", lw=0.8, alpha=0.8)
        ax.scatter(x, y, c="white", s=12, edgecolors="black", linewidths=0.4, zorder=3, label="evaluations")
    else:
        sc = ax.scatter(x, y, c=[s.score for s in h], cmap="viridis", s=18, zorder=3, label="evaluations")
        ax.plot(x, y, "-", color="grey", lw=0.8, alpha=0.7)
        fig.colorbar(sc, ax=ax, label=f"{result.optimization.config.objective.describe()} of each evaluation")
    ax.plot(problem.start[0], problem.start[1], "s", color="tab:orange", ms=8, label="start", zorder=4)
    if result.best is not None:
        ax.plot(result.best.x[xf], result.best.x[yf], "*", color="tab:red", ms=15, label="optimum", zorder=5)
    if vmap is None:  # the bounds, padded so that a point on a bound is drawn whole
        for setter, lo, hi in ((ax.set_xlim, problem.lower[0], problem.upper[0]),
                               (ax.set_ylim, problem.lower[1], problem.upper[1])):
            pad = 0.04 * (hi - lo)
            setter(lo - pad, hi + pad)
    ax.set_xlabel(_label(xf))
    ax.set_ylabel(_label(yf))
    ax.set_title(_title(result, f"{result.optimization.config.algorithm} path"), fontsize=8.5)
    ax.legend(fontsize="small", loc="best")
    fig.savefig(path, dpi=130)
    return path


def _fmt_x(x: dict) -> str:
    return ", ".join(f"{_label(k).replace(' (mm)', '')} = {val:.4g} mm" for k, val in x.items())


def features_text(features, constraints, castable: list | None = None) -> list[str]:
    """What a mould has to make for the optimum, which fabrication limit its edges break, and (``castable``:
    ``(first, last)`` intervals, :attr:`OptimizationResult.castable_widths`) the widths that break none."""
    text = f"layout of the optimum: {features.describe()} (measured on the footprint)"
    below = features.below(constraints.min_channel_mm, constraints.min_island_mm)
    if below:
        text += ("; BELOW the fabrication limits where the sensor's edge clips the pattern, which the width bounds "
                 "do not see: " + "; ".join(below))
    if castable is None:
        return [text]
    return [text, f"widths whose layout meets both limits everywhere (0.1 mm grid in the bounds, the other "
                  f"variables at the optimum): {spans_text(castable)} mm"]


def _checks_text(result, n_ph: int) -> str:
    """The castable widths scored after the search (``check_castable``, ``n_ph`` phantoms and probes each),
    counted like its calls."""
    checks = [c.assessment for c in result.castable_checks]
    if not checks:
        return ""
    return (f"; then {len(checks)} castable width(s) x {n_ph} phantoms: "
            f"{sum(a.computed for a in checks)} computed, {sum(a.n_failed for a in checks)} failed")


def report_lines(result) -> list[str]:
    """The text report: optimum with its uncertainty, comparison with the start, stopping reasons."""
    opt, h = result.optimization, result.history
    obj = opt.config.objective
    n_ph = len(opt.study.phantoms) + len(opt.probes)
    fresh = [s for s in h if not s.repeat and s.assessment is not None]
    lines = [f"{opt.study.name}: {opt.config.algorithm}, {len(result.optimum.starts)} start(s), {len(h)} objective "
             f"calls, "
             f"{len(fresh)} designs x {n_ph} phantoms: {result.computed} phantoms computed, "
             f"{len(fresh) * n_ph - result.computed} read from the store; "
             f"{sum(s.assessment.n_failed for s in fresh)} phantoms failed (a design with a failed phantom is "
             f"infeasible: {sum(s.assessment.n_failed > 0 for s in fresh)} designs)" + _checks_text(result, n_ph),
             f"objective: maximize {obj.describe()}; effective bounds {effective_bounds_text(opt.problem)}"
             + floor_text(opt.study.settings.physics_settings.measurement_floor_rel)]
    lines += [f"bound tightened: {t}" for t in opt.problem.folded]
    if opt.problem.general or opt.config.constraints.max_hydrogel_stretch is not None:
        lines.append(f"nonlinear constraints via {opt.config.resolved_constraint_method(opt.problem)}")

    def describe(s) -> str:
        a = s.assessment
        failed = (f"; {a.n_failed} phantoms failed, so infeasible (the mean is over the {a.n_ok} others)"
                  if a.n_failed else "")
        median, top, share = press_spread(a)
        spread = f"; median press {median:.4g}, strongest {top:.4g} ({share:.0%} of the sum)"
        if obj.weights == (("mean", 1.0),):
            return (f"{_fmt_x(s.x)}: mean V_rel {a.v_rel_mean:.5g} ± {a.v_rel_se:.2g} (SE over phantoms, "
                    f"n = {a.n_ok}{failed}{spread})")
        image = ""
        if obj.needs_images:
            pe, off = (a.image_figures.get(k, math.nan) for k in ("position_error_mm", "position_offset_mm"))
            image = (f", image CC {a.terms.get('image_cc', math.nan):.4g}, mean position error {pe:.3g} mm "
                     f"(offset {off:.3g} mm) over the probes")
        # V_rel mean and SE are over the random phantoms (assess_design); n_ok also counts the probes
        n_random = int(np.isfinite(np.asarray(a.random_v, dtype=float)).sum())
        return (f"{_fmt_x(s.x)}: score {s.score:.5g} ± {s.se:.2g}{image}, mean V_rel {a.v_rel_mean:.5g} ± "
                f"{a.v_rel_se:.2g} (SE over the random phantoms, n = {n_random}{failed}{spread})")

    if result.optimum.start_step is not None and result.optimum.start_step.assessment is not None:
        lines.append("start:   " + describe(result.optimum.start_step))
    if result.best is None:
        lines.append("no feasible design was evaluated")
    else:
        lines.append(f"optimum: {describe(result.best)} at call {result.best.index}")
        if result.paired is not None:
            d, se = result.paired
            start = result.optimum.start_step.assessment
            common = (f"the phantoms the start solved ({start.n_failed} failed for it)" if start.n_failed
                      else "the common phantoms")
            lines.append(f"improvement over the start: {d:+.5g} ± {se:.2g} (paired SE over {common}; "
                         "the SEs above are not independent, every design sees the same phantoms)")
        active = [k for k, g in result.best.constraints.items() if g > -1e-3]
        if active:
            lines.append("constraints active at the optimum: " + ", ".join(active))
        lines += features_text(result.optimum_layout, opt.config.constraints, result.castable_widths)
        for chk in result.castable_checks:  # scored like a call: the same describe()
            line = "castable: " + describe(SimpleNamespace(x={**result.best.x, "width_mm": chk.width_mm},
                                                           assessment=chk.assessment))
            if chk.minus_optimum is not None:
                line += "; minus the optimum {:+.5g} ± {:.2g} (paired)".format(*chk.minus_optimum)
            lines.append(line)
    lines += round_off_lines([(_fmt_x(s.x), s.assessment.min_reference_rel) for s in fresh],
                             opt.study.settings.physics_settings.measurement_floor_rel)
    for st in result.optimum.starts:
        lines.append(f"start {st.index} from {_fmt_x(st.x0)}: {st.result} after {st.evaluations} calls"
                     + (f" ({st.message})" if st.message else ""))
    lines.append("the SE is the phantom-sampling uncertainty of the score at a design; the location of the "
                 "optimum is known to about the stopping tolerance (xtol) only, not better")
    return lines


def write_optimization_outputs(result) -> tuple[dict, list[str]]:
    """Write the history, plots, report and result JSON; return ``(files, report lines)``."""
    opt, out = result.optimization, Path(result.out_dir)
    name = opt.study.name
    files = {"history": write_csv(out / f"{name}_history.csv", history_rows(result))}
    if result.history:
        files["convergence"] = plot_convergence(result, out / f"{name}_convergence.png")
    vmap = stored_map(out, result.settings.key, [p.key for p in opt.study.phantoms], opt.problem)
    if result.history:
        p = plot_path(result, out / f"{name}_path.png", vmap)
        if p is not None:
            files["path"] = p
    lines = report_lines(result)
    if len(opt.problem.names) == 2:
        lines.append("path plot over " + ("the stored V_rel map (sweep rows with these settings)" if vmap is not None
                                          else "the visited points (no stored sweep with these settings and phantoms)"))
    (out / f"{name}_report.txt").write_text("\n".join(lines) + "\n")
    files["report"] = out / f"{name}_report.txt"
    best = result.best
    payload = {"name": name, "settings_key": result.settings.key, "settings": result.settings.as_dict(),
               "algorithm": opt.config.algorithm, "objective": opt.config.objective.describe(),
               "optimum": None if best is None else {"x": best.x, "score": best.score, "se": best.se,
                                                     "v_rel_mean": best.assessment.v_rel_mean,
                                                     "v_rel_se": best.assessment.v_rel_se, "n": best.assessment.n_ok,
                                                     "terms": best.assessment.terms,
                                                     "image_figures": best.assessment.image_figures,
                                                     "call": best.index, "design_key": best.assessment.design_key},
               "optimum_layout": None if best is None else dataclasses.asdict(result.optimum_layout),
               "castable_widths_mm": result.castable_widths,
               "castable_checks": [{"width_mm": c.width_mm, "score": c.assessment.score, "se": c.assessment.se,
                                    "v_rel_mean": c.assessment.v_rel_mean, "v_rel_se": c.assessment.v_rel_se,
                                    "n_failed": c.assessment.n_failed, "design_key": c.assessment.design_key,
                                    "minus_optimum": None if c.minus_optimum is None
                                    else dict(zip(("diff", "se"), c.minus_optimum))} for c in result.castable_checks],
               "improvement_over_start": None if result.paired is None else dict(zip(("diff", "se"), result.paired)),
               "starts": [{"x0": s.x0, "result": s.result, "calls": s.evaluations, "message": s.message}
                          for s in result.optimum.starts],
               "calls": len(result.history), "computed_phantoms": result.computed, "seconds": result.seconds}
    (out / f"{name}_result.json").write_text(json.dumps(jsonable(payload), indent=1))
    files["result"] = out / f"{name}_result.json"
    return files, lines
