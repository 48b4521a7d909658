"""The report of a ``kind = "probes"`` sweep: how uniform each design's response is over the probe grid.

Every design is pressed at the centre of every cell of the probe grid (:class:`~.phantoms.ProbePresses`: probe
``i`` in column ``i % n`` and row ``i // n``, counted from the corner at the origin), the grid the optimizers'
``uniformity`` term and the density studies' probes press. Per design (:func:`probe_summary`):

- ``uniformity``: ``1 - std / mean`` of the probes' V_rel with the population std (:func:`~.phantoms.uniformity`);
- ``worst_to_best``: the smallest probe V_rel over the largest (:func:`~.phantoms.worst_to_best`);
- the mean probe V_rel and the weakest probe (its cell and centre; the first in probe order when several tie, as
  mirror images do on a symmetric design).

These describe the whole grid. A design with a failed probe gets NaN for all of them (``n/a, k probes failed`` in
``report.txt``), not values over the probes that happened to succeed: those would leave out the very places where
the design fails, often its weakest. Its solved probes stay in ``results.csv`` and on the figure.

Outputs (:func:`write_probe_outputs`): ``results.csv`` (one row per design x probe, with the probe's cell),
``summary.csv`` (one row per design, in design order, with its ``rank`` by uniformity), ``probes.png`` (a heat map
of probe V_rel on the grid per design, one colour scale: :func:`~.plots.plot_probes`) and ``report.txt`` (the
designs ranked by uniformity, then those that cannot be ranked, and which hash is which layout file).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..captions import counted
from . import plots  # at import, as in .report (matplotlib only when figures are drawn)
from ._rows import _by_design, _names, _value
from .config import Study
from .phantoms import uniformity, worst_to_best
from .report import _layout_legend, results_rows, write_csv
from .report_lines import _first_line
from .store import Evaluation

__all__ = ["probe_maps", "probe_rows", "probe_summary", "write_probe_outputs"]

#: Failed probes a report line names by their cells (``results.csv`` has them all).
_LISTED = 6


def probe_maps(study: Study, evaluations: Sequence[Evaluation]) -> list[np.ndarray]:
    """Per design its probe V_rel as an ``(n, n)`` array indexed ``[row, column]`` (row 0 at y = 0), NaN where a
    probe failed."""
    n = study.phantom_set.grid
    return [np.array([e.v_rel if e.ok else math.nan for e in rows], dtype=float).reshape(n, n)
            for rows in _by_design(study, evaluations)]


def probe_rows(study: Study, evaluations: Sequence[Evaluation]) -> list[dict]:
    """``results.csv``: the sweep's rows (:func:`~.report.results_rows`) with each probe's column and row, and
    without the grid studies' ``compared`` (every design here is summarized over its own probes)."""
    grid = study.phantom_set
    out = []
    for r in results_rows(study, evaluations):
        row = {}
        for k, val in r.items():
            if k == "compared":
                continue
            row[k] = val
            if k == "phantom_index":
                row["probe_col"], row["probe_row"] = grid.cell(val)
        out.append(row)
    return out


def probe_summary(study: Study, evaluations: Sequence[Evaluation]) -> list[dict]:
    """Per design, in design order: probes solved and failed, mean probe V_rel, uniformity, worst-to-best, the
    weakest probe and the design's rank by uniformity (1: the most uniform; ``None`` when it is not defined).

    Every statistic is NaN (the weakest probe ``None``) unless every probe of the design succeeded (module
    docstring).
    """
    grid = study.phantom_set
    names = _names(study)
    out = []
    for i, (design, rows) in enumerate(zip(study.designs, _by_design(study, evaluations))):
        v = np.array([e.v_rel if e.ok else math.nan for e in rows], dtype=float)
        solved = sum(e.ok for e in rows)
        complete = solved == len(rows)
        row = {"design": names[i], **{f: _value(design, f) for f in study.grid_fields},
               "probes": len(rows), "solved": solved, "failed": len(rows) - solved,
               "v_rel_mean": float(np.mean(v)) if complete else math.nan,
               "uniformity": uniformity(v), "worst_to_best": worst_to_best(v),
               "v_rel_min": float(np.min(v)) if complete else math.nan,
               "v_rel_max": float(np.max(v)) if complete else math.nan}
        weakest = int(np.argmin(v)) if complete else None
        touch = study.phantoms[weakest].touches[0] if weakest is not None else None
        col, r = grid.cell(weakest) if weakest is not None else (None, None)
        row.update(weakest_probe=weakest, weakest_col=col, weakest_row=r,
                   weakest_x_mm=touch.x_mm if touch else math.nan, weakest_y_mm=touch.y_mm if touch else math.nan,
                   rank=None, design_key=design.content_hash())
        out.append(row)
    ranked = sorted((i for i, s in enumerate(out) if math.isfinite(s["uniformity"])),
                    key=lambda i: -out[i]["uniformity"])
    for k, i in enumerate(ranked, start=1):
        out[i]["rank"] = k
    return out


def _ranking_lines(study: Study, evaluations: Sequence[Evaluation], summary: Sequence[dict]) -> list[str]:
    groups = _by_design(study, evaluations)
    grid = study.phantom_set
    lines = []
    for s in sorted((s for s in summary if s["rank"] is not None), key=lambda s: s["rank"]):
        lines.append(f"  {s['rank']}. {s['design']}: uniformity {s['uniformity']:.4f}, worst-to-best "
                     f"{s['worst_to_best']:.4f}, mean V_rel {s['v_rel_mean']:.5f} (probes {s['v_rel_min']:.5f} to "
                     f"{s['v_rel_max']:.5f}), weakest probe at ({s['weakest_x_mm']:.4g}, {s['weakest_y_mm']:.4g}) mm "
                     f"(cell {s['weakest_col']}, {s['weakest_row']})")
    for i, s in enumerate(summary):
        if s["rank"] is not None:
            continue
        if s["failed"]:
            failed = [e for e in groups[i] if not e.ok]
            cells = [grid.cell(j) for j, e in enumerate(groups[i]) if not e.ok]
            where = ", ".join(f"({c}, {r})" for c, r in cells[:_LISTED]) + (", ..." if len(cells) > _LISTED else "")
            lines.append(f"  not ranked: {s['design']}: uniformity n/a, {s['failed']} of {s['probes']} probes failed "
                         f"(cells {where}; first error: {_first_line(failed[0].error)})")
        else:
            lines.append(f"  not ranked: {s['design']}: uniformity n/a, mean probe V_rel {s['v_rel_mean']:.5g} "
                         "(not > 0)")
    return lines


def write_probe_outputs(study: Study, evaluations: Sequence[Evaluation], out: Path) -> tuple[dict, list[str]]:
    """Write ``results.csv``, ``summary.csv``, ``probes.png`` and ``report.txt`` of a probes study into ``out``.

    Returns
    -------
    files : dict
        Output name -> path.
    lines : list of str
        The text report (also in ``report.txt``), for the CLI to print.
    """

    out = Path(out)
    grid = study.phantom_set
    summary = probe_summary(study, evaluations)
    files = {"results": write_csv(out / "results.csv", probe_rows(study, evaluations)),
             "summary": write_csv(out / "summary.csv", summary),
             "probes_plot": plots.plot_probes(study, probe_maps(study, evaluations), summary, out / "probes.png")}
    failed = sum(not e.ok for e in evaluations)
    lines = [f"{study.name}: {counted(len(study.designs), 'design')} x {grid.n_probes} probes "
             f"({grid.grid} x {grid.grid} grid, "
             f"radius {grid.radius_mm:g} mm, {grid.depth_mm:g} mm deep, at the cell centres) = {len(evaluations)} "
             f"presses, {failed} failed",
             "uniformity = 1 - std/mean of a design's probe V_rel (population std), worst-to-best = smallest / "
             "largest probe V_rel; both over every probe of the design, so only when all of them succeeded",
             "designs by uniformity (most uniform first):", *_ranking_lines(study, evaluations, summary)]
    lines += _layout_legend(study)
    (out / "report.txt").write_text("\n".join(lines) + "\n")
    files["report"] = out / "report.txt"
    return files, lines
