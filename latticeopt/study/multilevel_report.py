"""Tables and ``report.txt`` of a two-level sweep (:mod:`.multilevel_sweep`), from the stored evaluations only.

``summary.csv`` per design: ``v_rel_mean`` and ``v_rel_se`` are the two-level estimate of the fine mean and its
SE (so the figures of :mod:`.plots` show it), then the coarse mean and SE over ``n_coarse`` phantoms, the mean
fine-minus-coarse correction and its SE over ``n_fine``, the estimated SE of the plain fine mean over all
``n_coarse`` phantoms it is compared with and their ratio, and ``beta``, the control-variate coefficient
(1 with ``control = "fixed"``, the design's fitted one with ``"fitted"``). ``results.csv`` has one row per
evaluation of either level (``level``), ``used`` marking those that enter the estimate.

Paired differences. Designs see the same phantoms at both levels, so the difference of two designs is itself a
two-level estimate: coarse ``C_a - C_b`` over every used phantom plus the correction ``D_a - D_b`` over the
phantoms both designs have fine, the first ``min(n_a, n_b)`` of the common fine order
(:func:`~latticeopt.study.multilevel.multilevel_estimate` applied to the differences, with the study's
``control``; a fitted ``beta`` is then the difference's own). With ``beta = 1`` it is unbiased for the
difference of the fine means and its SE is exact in the same sense as a design's own; it may differ slightly
from the difference of the two designs' estimates, which use more fine phantoms for one of them.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..captions import counted
from .config import Study
from .multilevel import multilevel_estimate
from .multilevel_sweep import MultilevelRun
from .report import _fmt, _value, write_tables_and_figures
from .report_lines import failed_lines, floor_text, round_off_lines, smallest_reference

__all__ = ["model_seconds", "multilevel_summary", "paired_difference", "write_multilevel_outputs"]


def multilevel_summary(study: Study, run: MultilevelRun) -> list[dict]:
    """One row per design (see the module docstring); NaN for a design that is not compared."""
    nph = len(study.phantoms)
    rows = []
    for i, design in enumerate(study.designs):
        e = run.estimates[i]
        own = run.coarse[i * nph:(i + 1) * nph]
        fine = [ev for (d, _), ev in run.fine.items() if d == i]
        row = {f: _value(design, f) for f in study.grid_fields}
        nan = math.nan
        row.update(v_rel_mean=e.mean if e else nan, v_rel_se=e.se if e else nan,
                   coarse_mean=e.coarse_mean if e else nan, coarse_se=e.coarse_se if e else nan,
                   correction_mean=e.correction_mean if e else nan, correction_se=e.correction_se if e else nan,
                   n_fine=e.n_fine if e else 0, n_coarse=e.n_coarse if e else 0,
                   plain_fine_se_est=e.plain_fine_se if e else nan, se_ratio=e.se_ratio if e else nan,
                   beta=e.beta if e else nan,
                   n=e.n_coarse if e else 0, failed_coarse=sum(not ev.ok for ev in own),
                   failed_fine=sum(not ev.ok for ev in fine),
                   seconds_coarse=sum(ev.seconds or 0.0 for ev in own),
                   seconds_fine=sum(ev.seconds or 0.0 for ev in fine), design_key=design.content_hash())
        rows.append(row)
    return rows


def paired_difference(study: Study, run: MultilevelRun, a: int, b: int):
    """Two-level estimate of ``mean V_rel(a) - mean V_rel(b)`` on the fine mesh (module docstring).

    Returns
    -------
    MultilevelEstimate
        Of the per-phantom difference, fine over the first ``min(n_a, n_b)`` phantoms of the common order.
    """
    m = min(run.n_fine[a], run.n_fine[b])
    nph = len(study.phantoms)
    pos = {j: k for k, j in enumerate(run.used)}
    c = np.array([run.coarse[a * nph + j].v_rel - run.coarse[b * nph + j].v_rel for j in run.used])
    f = np.full(len(run.used), np.nan)
    for j in run.order[:m]:
        f[pos[j]] = run.fine[(a, j)].v_rel - run.fine[(b, j)].v_rel
    strata = np.array([study.phantoms[j].n_touches for j in run.used])
    return multilevel_estimate(c, f, strata, control=study.multilevel.control, take_all=run.take_all_mask(),
                               parts=run.parts())


def model_seconds(study: Study, run: MultilevelRun) -> dict[str, float]:
    """Model seconds the two-level run cost and what running every phantom fine would have cost.

    Returns
    -------
    dict
        ``coarse`` and ``fine``: seconds of every stored evaluation of the level (failures included);
        ``two_level``: their sum; ``plain``: per design with fine phantoms, the seconds of its take-all
        phantoms plus the mean seconds of its other fine evaluations times the other phantoms, summed (those are
        a sample of every touch count, so their mean cost is that of the phantoms not taken whole).
    """
    nph = len(study.phantoms)
    coarse = sum(e.seconds or 0.0 for e in run.coarse)
    fine = sum(e.seconds or 0.0 for e in run.fine.values())
    plain = 0.0
    whole = set(run.take_all)
    for i in range(len(study.designs)):
        own = [e.seconds or 0.0 for (d, j), e in run.fine.items() if d == i and j not in whole]
        taken = [e.seconds or 0.0 for (d, j), e in run.fine.items() if d == i and j in whole]
        if own or taken:
            plain += sum(taken) + (nph - len(taken)) * float(np.mean(own) if own else np.mean(taken))
    return {"coarse": coarse, "fine": fine, "two_level": coarse + fine, "plain": plain}


def _fell_back(e) -> bool:
    """True if a coarse evaluation's interpolated hydrogel folded and its electrics ran on the mechanics mesh
    (:class:`latticeopt.coupled.CoupledModel`)."""
    return (e.extra or {}).get("electrics_mesh") == "mechanics"


def _electrics_on(level: str, ml, e) -> str:
    """The mesh an evaluation's electrics ran on: ``"fine"``, or ``"coarse"`` (coarse electrics, or a coarse
    level whose interpolated hydrogel folded)."""
    if level == "fine":
        return "fine"
    if ml.coarse_electrics == "coarse" or _fell_back(e):
        return "coarse"
    return "fine"


def _result_rows(study: Study, run: MultilevelRun) -> list[dict]:
    nph = len(study.phantoms)
    used = set(run.used)
    levels = [("coarse", run.coarse_settings, {(i, j): run.coarse[i * nph + j] for i in range(len(study.designs))
                                               for j in range(nph)}),
              ("fine", run.fine_settings, run.fine)]
    rows = []
    for level, settings, evals in levels:
        for (i, j), e in sorted(evals.items()):
            p = study.phantoms[j]
            in_fine = level == "coarse" or j in set(run.order[:run.n_fine[i]])
            row = {"level": level, "mesh_size_mm": (settings.mechanics_mesh or settings.mesh).size_mm,
                   "electrics_on": _electrics_on(level, study.multilevel, e)}
            row.update({f: _value(study.designs[i], f) for f in study.grid_fields})
            row.update(phantom_index=p.index, n_touches=p.n_touches, status=e.status, v_rel=e.v_rel,
                       seconds=e.seconds, error=(e.error or "").splitlines()[0] if e.error else "",
                       used=i in run.compared and j in used and in_fine, design_key=e.design_key,
                       phantom_key=e.phantom_key, settings_key=e.settings_key)
            rows.append(row)
    return rows


def write_multilevel_outputs(study: Study, run: MultilevelRun, out: Path) -> tuple[dict, list[str]]:
    """Write ``results.csv``, ``summary.csv``, the figures and ``report.txt`` of a two-level sweep.

    Returns
    -------
    files : dict
        Output name -> path.
    lines : list of str
        The text report (also in ``report.txt``).
    """
    out = Path(out)
    ml = study.multilevel
    summary = multilevel_summary(study, run)
    files = write_tables_and_figures(study, _result_rows(study, run), summary, out)
    nph = len(study.phantoms)
    c, f = ml.coarse, run.fine_settings.mesh
    extra = "".join(f", {k} = {v}" for k, v in ml.coarse_physics)
    floor = run.fine_settings.physics_settings.measurement_floor_rel
    lines = [f"{study.name}: {counted(len(study.designs), 'design')} x {counted(nph, 'phantom')}; "
             "two-level estimator: coarse mesh "
             f"{c.size_mm:g} mm ({c.channel_cells} channel cells, electrics on the {ml.coarse_electrics} mesh{extra}) "
             f"on every phantom, fine mesh {f.size_mm:g} mm "
             f"on the take-all phantoms ({len(run.take_all)}: the share {ml.take_all:g} of each touch count with the "
             f"highest coarse V_rel) and a nested subset of the others"
             + (f" (sampled as shallow and deep parts, {len(run.deep)} deeper than {ml.depth_split_mm:g} mm)"
                if run.deep else "")
             + f" until SE <= {ml.se_factor:g} x the "
             f"estimated plain fine SE (pilot {ml.pilot}); "
             + ("control fixed: beta = 1 (coarse mean plus the mean fine-minus-coarse correction)"
                if ml.control == "fixed" else "control fitted: beta = cov(F, C) / var(C) per design, pooled over "
                "the touch counts' fine phantoms"),
             f"phantoms used: {len(run.used)} of {nph} (those every compared design solved at both levels where "
             f"run); fine phantoms per design: {min(run.n_fine[i] for i in run.compared) if run.compared else 0}"
             f"-{max(run.n_fine) if run.compared else 0}; computed now: {run.computed_coarse} coarse, "
             f"{run.computed_fine} fine" + floor_text(floor)]
    cost = model_seconds(study, run)
    if cost["fine"] > 0:
        lines.append(f"model time: {cost['coarse'] / 3600:.2f} h coarse + {cost['fine'] / 3600:.2f} h fine = "
                     f"{cost['two_level'] / 3600:.2f} h; every phantom fine would take about "
                     f"{cost['plain'] / 3600:.2f} h (each design's mean fine seconds x its phantoms), a ratio of "
                     f"{cost['two_level'] / cost['plain']:.2f} (seconds of one worker each, summed)")
    if ml.coarse_electrics == "fine":
        folded = sum(_fell_back(e) for e in run.coarse)
        if folded:
            lines.append(f"coarse level: the interpolated hydrogel folded in {folded} of {len(run.coarse)} "
                         "evaluations, whose electrics ran on the coarse mesh instead (results.csv electrics_on)")
    for i in range(len(study.designs)):
        if i not in run.compared:
            lines.append(f"not compared: {_fmt(study.designs[i], study.grid_fields)}: every coarse phantom failed")
    failures = [(*divmod(k, nph), "coarse", e.error) for k, e in enumerate(run.coarse) if not e.ok]
    failures += [(i, j, "fine", e.error) for (i, j), e in sorted(run.fine.items()) if not e.ok]
    lines += failed_lines(study, failures)
    order = sorted((i for i in run.compared if run.estimates[i] is not None), key=lambda i: -run.estimates[i].mean)
    for rank, i in enumerate(order, 1):
        e = run.estimates[i]
        lines.append(f"{rank}. {_fmt(study.designs[i], study.grid_fields)}: mean V_rel = {e.mean:.5f} ± {e.se:.5f} "
                     f"(coarse {e.coarse_mean:.5f} ± {e.coarse_se:.5f} over N = {e.n_coarse}, correction "
                     f"{e.correction_mean:+.5f} ± {e.correction_se:.5f} over n = {e.n_fine}; plain fine SE est. "
                     f"{e.plain_fine_se:.5f}, ratio {e.se_ratio:.2f}"
                     + (f"; fitted beta {e.beta:.3f})" if ml.control == "fitted" else ")"))
    if len(order) > 1:
        d = paired_difference(study, run, order[0], order[1])
        z = d.mean / d.se if d.se else math.nan
        lines.append(f"best minus runner-up (two-level, paired over common phantoms: coarse over {d.n_coarse}, "
                     f"fine over {d.n_fine}): {d.mean:.5f} ± {d.se:.5f} (z = {z:.1f})")
    fine_by_design = [[e for (i, _), e in run.fine.items() if i == k] for k in range(len(study.designs))]
    lines += round_off_lines([(_fmt(d, study.grid_fields), smallest_reference(evs))
                              for d, evs in zip(study.designs, fine_by_design)], floor)
    (out / "report.txt").write_text("\n".join(lines) + "\n")
    files["report"] = out / "report.txt"
    stale = out / "excluded.csv"
    if stale.exists():  # the plain sweep's list does not describe this estimate
        stale.unlink()
    return files, lines
