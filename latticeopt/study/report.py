"""Tables and figures of a finished sweep, computed from the stored evaluations only.

Because everything here is a function of the store's rows (in the study's task order), a resumed sweep and
an uninterrupted one produce the same files. Standard errors are ``std(ddof=1) / sqrt(n)`` over phantoms.

Failed phantoms (:func:`comparison_set`). Designs are compared on the phantoms that succeeded for *every*
design compared, the same set for all. Dropping each design's own failures instead would score each design on
a different phantom set: a design whose hardest presses fail would be averaged over easier ones and could rank
above a design that solved them all, and the common-random-numbers pairing of the comparison would break. A
design none of whose phantoms succeeded is left out of the comparison (and named), so one unmeshable design
does not empty the set. ``report.txt`` says how many phantoms were used and lists the excluded ones with the
design(s) that failed them and why (all of them in ``excluded.csv``); ``results.csv`` marks the rows used
(``compared``).

Outputs (:func:`write_outputs`): ``results.csv`` (one row per design x phantom), ``summary.csv`` (per design:
mean V_rel, standard error and ``n`` over the common phantoms, the design's own successes ``n_ok`` and failures,
and the mean per touch count), ``vrel_lines.png`` (V_rel against the first of ``width_mm``/the first grid field,
one line per value of the other grid fields, error bars = SE, the layout of the paper's Fig. 4),
``vrel_heatmap.png`` (two-field grids; the figures are drawn by :mod:`.plots`), ``paired.csv`` (every design's
paired difference to the best, overall and per touch count: :func:`paired_to_best`), ``excluded.csv`` (when a
phantom was excluded) and ``report.txt`` (the
best design with its uncertainty and a paired comparison with the runner-up — paired because all designs see
the same phantoms). Press studies write ``press.csv``, ``press.png`` and the ratios at the deepest depth instead
of the summary and grid figures.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..captions import counted

# imported with the report, not when it is written: a run that outlives an upgrade of the package still writes
# its outputs with the code it started with (both import matplotlib only when they draw)
from . import plots
from ._rows import _by_design, _fmt, _grid_column, _value
from .config import Study
from .layout_plot import plot_layouts
from .report_lines import (
    _LISTED,
    _first_line,
    floor_text,
    phantom_name,
    rerun_lines,
    round_off_lines,
    smallest_reference,
)
from .store import Evaluation

__all__ = ["best_design", "comparison_set", "mean_se", "paired_to_best", "press_curves", "press_ratios", "results_rows",
           "summarize", "write_csv", "write_outputs", "write_tables_and_figures"]


def mean_se(values: Sequence[float]) -> tuple[float, float]:
    """Mean and standard error ``std(ddof=1) / sqrt(n)`` (NaN SE for fewer than two values, NaN both for none)."""
    x = np.asarray(values, dtype=float)
    if x.size == 0:
        return math.nan, math.nan
    se = float(np.std(x, ddof=1) / math.sqrt(x.size)) if x.size > 1 else math.nan
    return float(np.mean(x)), se


def comparison_set(study: Study, evaluations: Sequence[Evaluation]) -> dict:
    """The phantoms the designs are compared on: those that succeeded for every design compared.

    Returns
    -------
    dict
        ``compared``: indices of the designs compared (those with at least one successful phantom);
        ``not_compared``: the others; ``used``: positions in ``study.phantoms`` that succeeded for every compared
        design; ``excluded``: one dict per other phantom, ``{"phantom": position, "failed": [(design index,
        first line of the error), ...]}`` naming every compared design that failed it.
    """
    groups = _by_design(study, evaluations)
    compared = [i for i, rows in enumerate(groups) if any(e.ok for e in rows)]
    used, excluded = [], []
    for j in range(len(study.phantoms)):
        failed = [(i, _first_line(groups[i][j].error)) for i in compared if not groups[i][j].ok]
        if failed:
            excluded.append({"phantom": j, "failed": failed})
        else:
            used.append(j)
    if not compared:
        used = []
    return {"compared": compared, "not_compared": [i for i in range(len(groups)) if i not in compared],
            "used": used, "excluded": excluded}


def results_rows(study: Study, evaluations: Sequence[Evaluation]) -> list[dict]:
    """One row per (design, phantom) in task order: grid fields, phantom, outcome, whether compared, keys."""
    cmp = comparison_set(study, evaluations)
    compared, used = set(cmp["compared"]), set(cmp["used"])
    n = len(study.phantoms)
    rows = []
    for k, ((design, phantom), e) in enumerate(zip(study.tasks(), evaluations)):
        row = {f: _value(design, f) for f in study.grid_fields}
        row.update(phantom_index=phantom.index, n_touches=phantom.n_touches,
                   touches=json.dumps([[t.x_mm, t.y_mm, t.radius_mm, t.depth_mm] for t in phantom.touches]),
                   status=e.status, v_rel=e.v_rel, force_total_N=sum(e.forces_N) if e.forces_N else None,
                   forces_N=json.dumps(list(e.forces_N)), seconds=e.seconds,
                   error=_first_line(e.error), compared=k // n in compared and k % n in used,
                   design_key=e.design_key, phantom_key=e.phantom_key, settings_key=e.settings_key)
        rows.append(row)
    return rows


def summarize(study: Study, evaluations: Sequence[Evaluation]) -> list[dict]:
    """Per design: mean V_rel, standard error and n over the common phantoms (:func:`comparison_set`), the
    design's own successes (``n_ok``) and failures, and mean V_rel per touch count over the common phantoms.

    A design that is not compared (no successful phantom) gets NaN means and ``n = 0``.
    """
    counts = sorted({p.n_touches for p in study.phantoms})
    cmp = comparison_set(study, evaluations)
    compared = set(cmp["compared"])
    out = []
    for i, (design, rows) in enumerate(zip(study.designs, _by_design(study, evaluations))):
        used = cmp["used"] if i in compared else []
        n_ok = sum(e.ok for e in rows)
        mean, se = mean_se([rows[j].v_rel for j in used])
        row = {f: _value(design, f) for f in study.grid_fields}
        row.update(v_rel_mean=mean, v_rel_se=se, n=len(used), n_ok=n_ok, failed=len(rows) - n_ok)
        for k in counts:
            vals = [rows[j].v_rel for j in used if study.phantoms[j].n_touches == k]
            row[f"v_rel_mean_{k}touch"] = mean_se(vals)[0]
        row["design_key"] = design.content_hash()
        out.append(row)
    return out


def best_design(study: Study, evaluations: Sequence[Evaluation]) -> dict | None:
    """The design with the highest mean V_rel over the common phantoms, its SE, a paired comparison to the runner-up.

    Every mean is over the same phantoms, those that succeeded for every compared design
    (:func:`comparison_set`, returned under ``"comparison"``). Returns ``None`` when no phantom succeeded for
    every compared design. ``paired_diff``/``paired_se`` are the mean and SE of ``V_rel(best) -
    V_rel(runner-up)`` over those phantoms: with common random numbers this difference is far less noisy than
    the two SEs suggest.
    """
    summary = summarize(study, evaluations)
    groups = _by_design(study, evaluations)
    cmp = comparison_set(study, evaluations)
    order = sorted((i for i, s in enumerate(summary) if s["n"] > 0), key=lambda i: -summary[i]["v_rel_mean"])
    if not order:
        return None
    best = {"design": study.designs[order[0]], "summary": summary[order[0]], "comparison": cmp}
    if len(order) > 1:
        a, b = groups[order[0]], groups[order[1]]
        diffs = [a[j].v_rel - b[j].v_rel for j in cmp["used"]]
        d, se = mean_se(diffs)
        best.update(runner_up=study.designs[order[1]], runner_up_summary=summary[order[1]], paired_diff=d,
                    paired_se=se, paired_n=len(diffs))
    return best


def paired_to_best(study: Study, evaluations: Sequence[Evaluation]) -> list[dict]:
    """Every compared design against the best: the paired difference ``V_rel(design) - V_rel(best)`` over the
    common phantoms, its SE and that difference as a fraction of the best's mean, overall and per touch count.

    Rows in the order of the designs' means (best first, its own row zero); ``[]`` when fewer than two designs
    are compared. Paired differences are what common random numbers make precise: their SE is usually far below
    the two means' SEs.
    """
    summary = summarize(study, evaluations)
    groups = _by_design(study, evaluations)
    cmp = comparison_set(study, evaluations)
    order = sorted(cmp["compared"], key=lambda i: -summary[i]["v_rel_mean"])
    if len(order) < 2 or not cmp["used"]:
        return []
    best = groups[order[0]]
    counts = sorted({study.phantoms[j].n_touches for j in cmp["used"]})
    rows = []
    for i in order:
        row = {"design": _fmt(study.designs[i], study.grid_fields),
               **{f: _value(study.designs[i], f) for f in study.grid_fields}}
        d, se = mean_se([groups[i][j].v_rel - best[j].v_rel for j in cmp["used"]])
        row.update(v_rel_mean=summary[i]["v_rel_mean"], diff_to_best=d, diff_se=se,
                   diff_fraction=d / summary[order[0]]["v_rel_mean"], n=len(cmp["used"]))
        for k in counts:
            dk, sek = mean_se([groups[i][j].v_rel - best[j].v_rel for j in cmp["used"]
                               if study.phantoms[j].n_touches == k])
            row[f"diff_{k}_touch"], row[f"diff_{k}_touch_se"] = dk, sek
        rows.append(row)
    return rows


def write_csv(path: Path, rows: Sequence[dict]) -> Path:
    """Write dict rows (same keys) as CSV; floats in full precision (``repr``)."""
    with open(path, "w", newline="") as fh:
        if rows:
            w = csv.DictWriter(fh, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
    return path


# -- press studies -----------------------------------------------------------------------------------------
def press_curves(study: Study, evaluations: Sequence[Evaluation]) -> list[dict]:
    """Rows ``(grid fields, depth_mm, v_rel, force_N, status)`` per design and depth."""
    rows = []
    for design, group in zip(study.designs, _by_design(study, evaluations)):
        for phantom, e in zip(study.phantoms, group):
            row = {f: _value(design, f) for f in study.grid_fields}
            row.update(depth_mm=phantom.touches[0].depth_mm, v_rel=e.v_rel,
                       force_N=e.forces_N[0] if e.forces_N else None, status=e.status,
                       design_key=e.design_key)
            rows.append(row)
    return rows


def press_ratios(study: Study, evaluations: Sequence[Evaluation]) -> list[dict]:
    """The study's ``[[press.compare]]`` ratios at the deepest depth, beside their reference values."""
    groups = _by_design(study, evaluations)
    out = []
    for c in study.phantom_set.compare:
        vals = []
        for sel in (c.numerator, c.denominator):
            i = next(i for i, d in enumerate(study.designs) if all(getattr(d, k) == val for k, val in sel))
            last = groups[i][-1]
            vals.append(last.v_rel if last.ok else math.nan)
        ratio = vals[0] / vals[1] if vals[1] else math.nan
        out.append({"label": c.label, "depth_mm": study.phantoms[-1].touches[0].depth_mm, "numerator": vals[0],
                    "denominator": vals[1], "ratio": ratio, "reference": c.reference})
    return out


# -- everything at once --------------------------------------------------------------------------------------
def _comparison_lines(study: Study, evaluations: Sequence[Evaluation]) -> tuple[list[str], list[dict]]:
    """Report lines on which phantoms the designs were compared on, and the rows of ``excluded.csv``."""
    cmp = comparison_set(study, evaluations)
    groups = _by_design(study, evaluations)
    n = len(study.phantoms)
    lines = []
    for i in cmp["not_compared"]:
        lines.append(f"not compared: {_fmt(study.designs[i], study.grid_fields)}: every phantom failed (first: "
                     f"{_first_line(groups[i][0].error)})")
    if not cmp["compared"]:
        return lines, []
    if not cmp["excluded"]:
        lines.insert(0, f"designs compared on all {n} phantoms (no compared design failed one)")
        return lines, []
    lines.insert(0, f"designs compared on the {len(cmp['used'])} of {n} phantoms that every compared design "
                    f"solved; {len(cmp['excluded'])} excluded because a design failed them (a phantom one design "
                    "fails is left out for all, so every mean and difference is over the same phantoms)")
    rows = []
    for k, ex in enumerate(cmp["excluded"]):
        p = study.phantoms[ex["phantom"]]
        why = "; ".join(f"{_fmt(study.designs[i], study.grid_fields)}: {err}" for i, err in ex["failed"])
        if k < _LISTED:
            lines.append(f"excluded phantom {phantom_name(p)} ({p.n_touches} touches): failed for {why}")
        for i, err in ex["failed"]:
            rows.append({"phantom_index": p.index, "n_touches": p.n_touches, "phantom_key": p.key,
                         "design": _fmt(study.designs[i], study.grid_fields),
                         "design_key": study.designs[i].content_hash(), "error": err})
    if len(cmp["excluded"]) > _LISTED:
        lines.append(f"... and {len(cmp['excluded']) - _LISTED} more excluded phantoms, all in excluded.csv")
    return lines + rerun_lines(study, [ex["phantom"] for ex in cmp["excluded"]]), rows


def write_tables_and_figures(study: Study, result_rows: Sequence[dict], summary: Sequence[dict], out: Path) -> dict:
    """``results.csv``, ``summary.csv``, the V_rel line figure and (two-field grids) the heat map of a grid
    study whose rows and per-design summary an estimator has already computed; returns output name -> path."""
    files = {"results": write_csv(out / "results.csv", result_rows),
             "summary": write_csv(out / "summary.csv", summary),
             "lines_plot": plots.plot_lines(study, summary, out / "vrel_lines.png")}
    heat = plots.plot_heatmap(study, summary, out / "vrel_heatmap.png")
    if heat is not None:
        files["heatmap"] = heat
    drawn = plot_layouts(study, summary, out / "layouts.png")
    if drawn is not None:
        files["layouts_plot"] = drawn
    return files


def _layout_legend(study: Study) -> list[str]:
    """A grid over layout files labels each design by its content hash; say which file each hash is."""
    files = _grid_column(study, "layout")
    if files is None:
        return []
    return [f"layout {_value(d, 'layout')} = {f}" for d, f in zip(study.designs, files)]


def write_outputs(study: Study, evaluations: Sequence[Evaluation], out: Path) -> tuple[dict, list[str]]:
    """Write the tables, figures and ``report.txt`` of a study into ``out``.

    Returns
    -------
    files : dict
        Output name -> path.
    lines : list of str
        The text report (also in ``report.txt``), for the CLI to print.
    """
    out = Path(out)
    files = {"results": write_csv(out / "results.csv", results_rows(study, evaluations))}
    failed = sum(not e.ok for e in evaluations)
    lines = [f"{study.name}: {counted(len(study.designs), 'design')} x {counted(len(study.phantoms), 'phantom')} "
             f"= {counted(len(evaluations), 'evaluation')}, {failed} failed"
             + floor_text(study.settings.physics_settings.measurement_floor_rel)]
    cmp_lines, excluded_rows = _comparison_lines(study, evaluations)
    if excluded_rows:
        files["excluded"] = write_csv(out / "excluded.csv", excluded_rows)
    elif (out / "excluded.csv").exists():  # a retry fixed them: no stale list beside the new tables
        (out / "excluded.csv").unlink()
    if study.kind == "press":
        files["press"] = write_csv(out / "press.csv", press_curves(study, evaluations))
        files["press_plot"] = plots.plot_press(study, evaluations, out / "press.png")
        for r in press_ratios(study, evaluations):
            ref = f"   (paper: {r['reference']:g})" if r["reference"] is not None else ""
            lines.append(f"V_rel ratio at {r['depth_mm']:g} mm, {r['label']}: {r['numerator']:.5g} / "
                         f"{r['denominator']:.5g} = {r['ratio']:.3f}{ref}")
    else:
        summary = summarize(study, evaluations)
        files["summary"] = write_csv(out / "summary.csv", summary)
        files["lines_plot"] = plots.plot_lines(study, summary, out / "vrel_lines.png")
        heat = plots.plot_heatmap(study, summary, out / "vrel_heatmap.png")
        if heat is not None:
            files["heatmap"] = heat
        drawn = plot_layouts(study, summary, out / "layouts.png")
        if drawn is not None:
            files["layouts_plot"] = drawn
        best = best_design(study, evaluations)
        if best is None:
            lines.append("no design compared: no phantom succeeded for every design that solved any")
        else:
            s = best["summary"]
            lines.append(f"best design: {_fmt(best['design'], study.grid_fields)}: mean V_rel = "
                         f"{s['v_rel_mean']:.5f} ± {s['v_rel_se']:.5f} (SE, n = {s['n']}, {s['failed']} failed)")
            if "runner_up" in best:
                r = best["runner_up_summary"]
                z = best["paired_diff"] / best["paired_se"] if best["paired_se"] else math.nan
                lines.append(f"runner-up: {_fmt(best['runner_up'], study.grid_fields)}: {r['v_rel_mean']:.5f} ± "
                             f"{r['v_rel_se']:.5f}; paired difference {best['paired_diff']:.5f} ± "
                             f"{best['paired_se']:.5f} (SE over {best['paired_n']} common phantoms, z = {z:.1f})")
        paired = paired_to_best(study, evaluations)
        if paired:
            files["paired"] = write_csv(out / "paired.csv", paired)
            if len(paired) <= 12:
                lines.append("paired difference to the best (mean ± SE over the common phantoms):")
                lines += [f"  {r['design']}: {r['diff_to_best']:+.5f} ± {r['diff_se']:.5f} "
                          f"({100 * r['diff_fraction']:+.1f} %)" for r in paired[1:]]
    lines += round_off_lines([(_fmt(d, study.grid_fields), smallest_reference(evs))
                              for d, evs in zip(study.designs, _by_design(study, evaluations))],
                             study.settings.physics_settings.measurement_floor_rel)
    lines += cmp_lines + _layout_legend(study)
    (out / "report.txt").write_text("\n".join(lines) + "\n")
    files["report"] = out / "report.txt"
    return files, lines
