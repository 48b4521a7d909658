"""Categorical design choices (layout family, rim layout) as an outer loop around the continuous optimizer.

nlopt works on continuous variables; a family (``pattern``) or a rim layout (``rim``) is not one. A study's
``[optimize.categories]`` table lists values for such fields::

    [optimize.categories]
    pattern = ["square", "hexagonal", "triangular", "diagonal"]
    rim = ["none", "channel"]

and every combination is optimized over the same continuous variables, phantoms, objective and stopping rules,
each in its own sub-folder of ``out`` (its own resumable store and report), named after the combination. The
winner is the combination whose optimum scores highest; the summary gives each combination's optimum with its
standard error, so a user sees whether the families' optima differ by more than their errors.
"""

from __future__ import annotations

import copy
import csv
import itertools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from ..design import PATTERNS, RIMS
from ..errors import ParameterError
from ..fabrication import spans_text
from ..study.keynames import KeyNames
from .load import optimization_from_dict
from .problem import Optimization
from .report import press_spread

__all__ = ["CATEGORICAL_FIELDS", "CategoryRun", "categorical_optimizations", "plot_categories", "run_categories",
           "write_summary"]

#: Design fields an outer loop may take, with their allowed values.
CATEGORICAL_FIELDS = {"pattern": tuple(p for p in PATTERNS if p != "custom"), "rim": RIMS,
                      "electrode_leads": (True, False)}


@dataclass(frozen=True)
class CategoryRun:
    """One combination of categorical values and its validated optimization (``out`` is its own folder)."""

    label: str
    values: tuple[tuple[str, object], ...]
    optimization: Optimization


def _label(values: Mapping[str, object]) -> str:
    return "_".join(f"{k}-{str(v).lower()}" for k, v in values.items())


def categorical_optimizations(raw: Mapping, *, source: str = "<dict>",
                              overridden: Mapping[str, str] | Sequence[str] = (),
                              default_name: str = "optimize") -> tuple[CategoryRun, ...]:
    """Validate an optimization study, one :class:`CategoryRun` per combination of ``[optimize.categories]``.

    Without that table there is one run with an empty label and the study's own ``out``.
    """
    raw = copy.deepcopy(dict(raw))
    tab = raw.get("optimize")
    cats = tab.pop("categories", None) if isinstance(tab, dict) else None
    name = KeyNames(source, overridden)
    if cats is None:
        opt = optimization_from_dict(raw, source=source, overridden=overridden, default_name=default_name)
        return (CategoryRun("", (), opt),)
    if not isinstance(cats, Mapping) or not cats:
        raise ParameterError(name("optimize.categories"), "a table: categorical design field -> list of values, "
                             "e.g. pattern = ['square', 'hexagonal']", cats)
    design = raw.get("design", {})
    for k, vals in cats.items():
        key = f"optimize.categories.{k}"
        if k not in CATEGORICAL_FIELDS:
            raise ParameterError(name(key), "a categorical design field: one of " + ", ".join(CATEGORICAL_FIELDS), k)
        allowed = CATEGORICAL_FIELDS[k]
        if (not isinstance(vals, list) or not vals or len(set(map(str, vals))) != len(vals)
                or any(x not in allowed or isinstance(x, bool) != isinstance(allowed[0], bool) for x in vals)):
            raise ParameterError(name(key), "a list of distinct values among " + ", ".join(map(repr, allowed)), vals)
        if isinstance(design, Mapping) and k in design:
            raise ParameterError(name(key), f"a field not also fixed in [design] (design.{k} = {design[k]!r})", vals)
    out = Path(str(raw.get("out", Path("runs") / str(raw.get("name", default_name)))))
    runs = []
    for combo in itertools.product(*cats.values()):
        values = dict(zip(cats, combo))
        label = _label(values)
        r = copy.deepcopy(raw)
        r["design"] = {**dict(r.get("design", {})), **values}
        r["out"] = str(out / label)
        try:
            opt = optimization_from_dict(r, source=source, overridden=overridden, default_name=default_name)
        except ParameterError as exc:
            context = " (in the category " + ", ".join(f"{k} = {v!r}" for k, v in values.items()) + ")"
            raise ParameterError(exc.name, exc.expected + context, exc.got) from None
        runs.append(CategoryRun(label, tuple(values.items()), opt))
    return tuple(runs)


def run_categories(runs: Sequence[CategoryRun], run: Callable[[Optimization], object]) -> list[tuple]:
    """Run ``run(optimization)`` for every combination; returns ``(CategoryRun, result)`` pairs in order."""
    return [(c, run(c.optimization)) for c in runs]


def write_summary(pairs: Sequence[tuple], path: Path) -> list[str]:
    """Write a CSV of each combination's optimum and return the report lines (best first)."""
    rows = []
    for c, res in pairs:
        best = res.best
        row = {"category": c.label, **dict(c.values), "evaluations": len(res.history)}
        if best is not None:
            median, _, share = press_spread(best.assessment)
            layout = res.optimum_layout
            row.update({"score": best.score, "se": best.se, "v_rel_median": median, "v_rel_max_share": share,
                        **{k: val for k, val in best.x.items()}, "narrowest_gel_mm": layout.gel_mm,
                        "narrowest_silicone_mm": layout.silicone_mm,
                        "castable_widths_mm": "" if res.castable_widths is None else spans_text(res.castable_widths)})
            scored = [c for c in res.castable_checks if math.isfinite(c.assessment.score)]
            if scored:  # the best castable width scored beside the optimum
                top = max(scored, key=lambda c: c.assessment.score)
                row.update({"castable_width_mm": top.width_mm, "castable_score": top.assessment.score,
                            "castable_se": top.assessment.se})
            unscored = [c.width_mm for c in res.castable_checks if not math.isfinite(c.assessment.score)]
            if unscored:  # a phantom failed there: not comparable, so not "the best castable", but named
                row["castable_unscored_mm"] = ", ".join(f"{w:g}" for w in unscored)
        rows.append(row)
    path.parent.mkdir(parents=True, exist_ok=True)
    fields = list(dict.fromkeys(k for r in rows for k in r))
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=fields)
        w.writeheader()
        w.writerows(rows)
    ranked = sorted((r for r in rows if "score" in r), key=lambda r: -r["score"])
    lines = [f"categories ranked by their optimum ({path}):"]
    names = {k for c, res in pairs if res.best is not None for k in res.best.x}
    for r in ranked:
        x = ", ".join(f"{k.removesuffix('_mm')} = {r[k]:.3f}" for k in r if k in names)
        lines.append(f"  {r['category']}: score {r['score']:.5g} ± {r['se']:.2g} at {x} ({r['evaluations']} calls; "
                     f"median press {r['v_rel_median']:.4g}, the strongest {r['v_rel_max_share']:.0%} of the sum; "
                     f"narrowest gel {r['narrowest_gel_mm']:.3g} mm, silicone {r['narrowest_silicone_mm']:.3g} mm)")
    lines += [f"  {r['category']}: no feasible design" for r in rows if "score" not in r]
    return lines


def plot_categories(pairs: Sequence[tuple], path: Path) -> Path | None:
    """Every combination's feasible calls, score (± SE) against the one continuous variable, optima starred.

    Colour follows the first categorical field (the family), line style the second (the rim layout). Returns
    ``None`` (no figure) when the optimizations vary more than one variable: their paths do not share an axis.
    """
    from matplotlib.figure import Figure

    names = {c.optimization.problem.names for c, _ in pairs}
    if len(names) != 1 or len(next(iter(names))) != 1:
        return None
    (var,) = next(iter(names))
    firsts = list(dict.fromkeys(str(c.values[0][1]) for c, _ in pairs if c.values))
    seconds = list(dict.fromkeys(str(c.values[1][1]) for c, _ in pairs if len(c.values) > 1))
    fig = Figure(figsize=(7.0, 4.4), layout="constrained")
    ax = fig.add_subplot()
    for c, res in pairs:
        calls = sorted((s for s in res.history if s.feasible and not s.repeat), key=lambda s: s.x[var])
        if not calls:
            continue
        colour = f"C{firsts.index(str(c.values[0][1])) % 10}" if c.values else "C0"
        style = ("-", "--", ":", "-.")[seconds.index(str(c.values[1][1])) % 4] if len(c.values) > 1 else "-"
        x = [s.x[var] for s in calls]
        ax.errorbar(x, [s.score for s in calls], yerr=[s.se if math.isfinite(s.se) else 0.0 for s in calls],
                    color=colour, ls=style, marker="o", ms=3, capsize=2, lw=1.2,
                    label=", ".join(f"{k} {v}" for k, v in c.values) or "optimum")
        if res.best is not None:
            ax.plot(res.best.x[var], res.best.score, "*", color=colour, ms=12, mec="black", mew=0.6)
    opt = pairs[0][0].optimization
    ax.set_xlabel(var.replace("_mm", " (mm)").replace("_", " "))
    ax.set_ylabel(opt.config.objective.describe())
    ax.set_title(f"{opt.study.name}: every call of each combination (± SE over its "
                 f"{len(opt.study.phantoms)} phantoms); * its optimum", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize="small", ncols=2)
    fig.savefig(path, dpi=130)
    return path
