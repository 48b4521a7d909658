"""Tables and ``report.txt`` of a sweep with adaptive phantom counts (:mod:`.adaptive_sweep`), from the stored
evaluations only (a resumed run writes the same files).

``summary.csv`` per design: ``v_rel_mean``, ``v_rel_se`` and ``n`` over the design's own prefix of the common
phantom order (so the figures of :mod:`.plots` show them), ``n_max`` (the phantoms it could have run),
``target_met`` (``v_rel_se <= target_se``), failures among the phantoms it ran and the mean per touch count.
``results.csv`` has one row per evaluation made, ``compared`` marking those that enter the design's mean.

Paired comparison. The designs run prefixes of one order, so the best design and the runner-up share the first
``min(n_a, n_b)`` phantoms: their difference is the mean and SE of ``V_rel(a) - V_rel(b)`` over those (the
shorter prefix), common random numbers as in the plain sweep.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from ..captions import counted
from .adaptive_sweep import AdaptiveRun
from .config import Study
from .report import _fmt, _value, mean_se, write_tables_and_figures
from .report_lines import _LISTED, floor_text, phantom_name, rerun_lines, round_off_lines, smallest_reference

__all__ = ["adaptive_summary", "paired_difference", "write_adaptive_outputs"]


def adaptive_summary(study: Study, run: AdaptiveRun) -> list[dict]:
    """One row per design (module docstring); NaN and ``n = 0`` for a design that is not compared."""
    counts = sorted({p.n_touches for p in study.phantoms})
    target = study.adaptive.target_se
    rows = []
    for i, design in enumerate(study.designs):
        used = run.order[:run.n[i]]
        mean, se = mean_se(run.values(i))
        own = [e for (d, _), e in run.evaluations.items() if d == i]
        row = {f: _value(design, f) for f in study.grid_fields}
        row.update(v_rel_mean=mean, v_rel_se=se, n=len(used), n_max=len(run.order), target_se=target,
                   target_met=bool(se <= target), n_run=len(own), failed=sum(not e.ok for e in own))
        for k in counts:
            vals = [run.evaluations[(i, j)].v_rel for j in used if study.phantoms[j].n_touches == k]
            row[f"v_rel_mean_{k}touch"] = mean_se(vals)[0]
        row["design_key"] = design.content_hash()
        rows.append(row)
    return rows


def paired_difference(run: AdaptiveRun, a: int, b: int) -> tuple[float, float, int]:
    """Mean and SE of ``V_rel(a) - V_rel(b)`` over the phantoms both designs ran, and how many."""
    m = min(run.n[a], run.n[b])
    diffs = [x - y for x, y in zip(run.values(a, m), run.values(b, m))]
    return (*mean_se(diffs), m)


def _result_rows(study: Study, run: AdaptiveRun) -> list[dict]:
    rows = []
    for (i, j), e in sorted(run.evaluations.items()):
        p, design = study.phantoms[j], study.designs[i]
        row = {f: _value(design, f) for f in study.grid_fields}
        row.update(phantom_index=p.index, n_touches=p.n_touches,
                   touches=json.dumps([[t.x_mm, t.y_mm, t.radius_mm, t.depth_mm] for t in p.touches]),
                   status=e.status, v_rel=e.v_rel, force_total_N=sum(e.forces_N) if e.forces_N else None,
                   forces_N=json.dumps(list(e.forces_N)), seconds=e.seconds,
                   error=(e.error or "").splitlines()[0] if e.error else "",
                   compared=i in run.compared and j in set(run.order[:run.n[i]]), design_key=e.design_key,
                   phantom_key=e.phantom_key, settings_key=e.settings_key)
        rows.append(row)
    return rows


def _exclusion_lines(study: Study, run: AdaptiveRun) -> list[str]:
    lines = []
    for i in range(len(study.designs)):
        if i not in run.compared:
            first = next((e.error for (d, _), e in sorted(run.evaluations.items()) if d == i), "") or ""
            lines.append(f"not compared: {_fmt(study.designs[i], study.grid_fields)}: every phantom it ran failed "
                         f"(first: {first.splitlines()[0] if first else ''})")
    if run.excluded:
        lines.append(f"{len(run.excluded)} phantoms excluded because a compared design failed them (left out for "
                     "every design, so all prefixes are of one order); the failed rows are in results.csv")
        for j in run.excluded[:_LISTED]:
            p = study.phantoms[j]
            who = [_fmt(study.designs[i], study.grid_fields) for i in run.compared
                   if (i, j) in run.evaluations and not run.evaluations[(i, j)].ok]
            lines.append(f"excluded phantom {phantom_name(p)} ({p.n_touches} touches): failed for {'; '.join(who)}")
        if len(run.excluded) > _LISTED:
            lines.append(f"... and {len(run.excluded) - _LISTED} more excluded phantoms")
        lines += rerun_lines(study, list(run.excluded))
    return lines


def write_adaptive_outputs(study: Study, run: AdaptiveRun, out: Path) -> tuple[dict, list[str]]:
    """Write ``results.csv``, ``summary.csv``, the figures and ``report.txt`` of an adaptive sweep.

    Returns
    -------
    files : dict
        Output name -> path.
    lines : list of str
        The text report (also in ``report.txt``).
    """
    out = Path(out)
    ad = study.adaptive
    summary = adaptive_summary(study, run)
    files = write_tables_and_figures(study, _result_rows(study, run), summary, out)
    nph = len(study.phantoms)
    used = [run.n[i] for i in run.compared]
    floor = study.settings.physics_settings.measurement_floor_rel
    lines = [f"{study.name}: {counted(len(study.designs), 'design')} x up to {counted(nph, 'phantom')}; "
             "adaptive counts: "
             f"{ad.min_per_design} first, then {ad.batch_size} more at a time until SE <= {ad.target_se:g} (V_rel) "
             "or every phantom is run; one common order, touch counts interleaved",
             f"phantoms per design: {min(used, default=0)}-{max(used, default=0)} of {len(run.order)}; "
             f"{len(run.evaluations)} evaluations ({run.computed} computed now), "
             f"{sum(not e.ok for e in run.evaluations.values())} failed" + floor_text(floor)]
    order = sorted((i for i in run.compared if summary[i]["n"] > 0), key=lambda i: -summary[i]["v_rel_mean"])
    for rank, i in enumerate(order, 1):
        s = summary[i]
        met = "target met" if s["target_met"] else "target NOT met: every phantom run"
        lines.append(f"{rank}. {_fmt(study.designs[i], study.grid_fields)}: mean V_rel = {s['v_rel_mean']:.5f} ± "
                     f"{s['v_rel_se']:.5f} (SE, n = {s['n']} of {s['n_max']}; {met})")
    if len(order) > 1:
        d, se, m = paired_difference(run, order[0], order[1])
        z = d / se if se else math.nan
        lines.append(f"best minus runner-up (paired over the {m} phantoms both ran): {d:.5f} ± {se:.5f} (z = {z:.1f})")
    elif not order:
        lines.append("no design compared: every phantom failed for every design")
    lines += round_off_lines([(_fmt(d, study.grid_fields),
                               smallest_reference([e for (i, _), e in run.evaluations.items() if i == k]))
                              for k, d in enumerate(study.designs)], floor)
    lines += _exclusion_lines(study, run)
    (out / "report.txt").write_text("\n".join(lines) + "\n")
    files["report"] = out / "report.txt"
    stale = out / "excluded.csv"
    if stale.exists():  # the plain sweep's list does not describe this run
        stale.unlink()
    return files, lines
