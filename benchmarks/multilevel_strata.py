"""Could a two-level map sample its fine phantoms more cheaply? Depth strata, Neyman allocation, the rule's steps.

A two-level map samples its fine phantoms (besides the take-all ones) as nested prefixes spread over the touch
counts in proportion to their sizes, and grows the prefix in steps until ``se <= se_factor * plain SE``. The
corrections ``G = F - C`` vary far more on deep presses than on shallow ones, so sampling deep presses more
often (strata split by depth, with an allocation that gives the strata with the larger spread more phantoms)
might reach the same SE with fewer fine phantoms; and the rule's last step may run past the count the criterion
needed. The plain SE the criterion compares with stays the map's (stratified by touch count, whose sizes the
phantom set fixes); sampling strata only split the map's phantoms into fixed sets chosen from the phantoms
alone, so a stratified estimate stays unbiased.

This reads a finished map (computing nothing, like ``docs/paper_map_paired.py``) and per design, from the
variances of the corrections the map ran (at least 2 pairs per sampling stratum, else the touch count's), gives
the sampled fine count ``m`` each plan needs:

* ``rule``: the map's own prediction (:func:`~latticeopt.study.multilevel.predicted_fine_count`, proportional
  over touch counts); ``first``: the shortest prefix of the map's order that meets the criterion on the map's
  values (what a rule with perfect steps would have stopped at; optimistic, as the criterion fluctuates);
* ``x depth``: touch count x deep (deepest touch beyond ``--depth-mm``), proportional (what the sweep now does by
  default, ``multilevel.depth_split_mm``; the maps quoted were run without it, hence their ``--set``);
* ``Neyman``: the same strata, ``m_h`` proportional to ``u_h sd_h`` with the spreads measured on the map's own
  pairs (a bound: a rule would have to estimate them, and one order common to all designs cannot suit each);
* ``deep x r``: one order for every design that samples deep phantoms ``r`` times as often as shallow ones.

``m = (sum_h u_h^2 var_h / pi_h) / ((f^2 - 1) var_plain + sum_h u_h^2 var_h / M_h)`` for sampling fractions
``pi_h`` (proportional: ``M_h / M``), ``u_h`` the stratum's share of all ``N`` phantoms. The last rows total
``max(pilot, m)`` plus the take-all phantoms over the designs, in evaluations and in fine worker hours, pricing
each evaluation at the map's own mean model seconds of a deep and of a shallow fine phantom (a deep press takes
longer, which eats what sampling deep presses more often saves)::

    PYTHONPATH=. python benchmarks/multilevel_strata.py runs/paper_fig4_takeall --set multilevel.depth_split_mm=0 \
        [--depth-mm 4] [--rates 1.5 2 3]
    PYTHONPATH=. python benchmarks/multilevel_strata.py runs/paper_fig4_rim_takeall --set design.rim=channel \
        --set multilevel.depth_split_mm=0
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "docs"))
from paper_map_paired import finished_map  # noqa: E402

from latticeopt.study.multilevel import multilevel_estimate, predicted_fine_count  # noqa: E402


def plan_count(c, f, touches, sampling, take_all, se_factor: float, weight=None) -> tuple[float, dict]:
    """Sampled fine count ``m`` for ``se <= se_factor * plain SE`` (module docstring).

    Parameters
    ----------
    c, f : ndarray, shape (N,)
        Coarse V_rel of every phantom; fine V_rel, NaN where not run.
    touches : ndarray of int, shape (N,)
        Touch count per phantom: the map's strata, which the plain SE is stratified by.
    sampling : ndarray of int, shape (N,)
        Sampling stratum per phantom, nested in ``touches``.
    take_all : ndarray of bool, shape (N,)
        The take-all phantoms (all fine, outside the sampling).
    se_factor : float
        The criterion's ratio to the plain SE.
    weight : callable or str, optional
        Sampling rate of a stratum relative to the others, ``weight(label)``; ``None`` samples in proportion to
        the strata's sizes, ``"neyman"`` in proportion to ``M_h sd_h``.

    Returns
    -------
    m : float
        At most the ``M`` phantoms that are not take-all.
    fractions : dict
        Sampling stratum label -> its share ``pi_h`` of the sampled phantoms.
    """
    var_plain = multilevel_estimate(c, f, touches, take_all=take_all).plain_fine_se ** 2
    g = f - c
    rest = ~take_all
    labels = np.unique(sampling[rest])
    size = np.array([(rest & (sampling == h)).sum() for h in labels], dtype=float)
    var = np.empty(labels.size)
    for i, h in enumerate(labels):
        pairs = g[rest & (sampling == h) & np.isfinite(g)]
        if pairs.size < 2:  # too few pairs here: the spread of the touch count's sampled corrections
            k = touches[rest & (sampling == h)][0]
            pairs = g[rest & (touches == k) & np.isfinite(g)]
        var[i] = np.var(pairs, ddof=1)
    if weight is None:
        rate = np.ones(labels.size)
    elif weight == "neyman":
        rate = np.sqrt(var)
    else:
        rate = np.array([weight(h) for h in labels], dtype=float)
    pi = size * rate / np.sum(size * rate)
    u = size / c.size
    s_term = float(np.sum(u * u * var / size))
    m = float(np.sum(u * u * var / pi)) / ((se_factor ** 2 - 1.0) * var_plain + s_term)
    return min(m, rest.sum()), dict(zip(labels.tolist(), pi))


def first_meeting(c, f, touches, take_all, order, start: int, se_factor: float) -> int:
    """Shortest prefix of ``order`` (at least ``start``) meeting the criterion with the map's fine values; the
    whole prefix the map ran if none shorter does."""
    ran = int(np.isfinite(f[order]).sum())
    for n in range(start, ran):
        sub = np.where(take_all, f, np.nan)
        sub[order[:n]] = f[order[:n]]
        if multilevel_estimate(c, sub, touches, take_all=take_all).meets(se_factor):
            return n
    return ran


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path, help="a finished two-level paper map's folder (holding results.sqlite)")
    ap.add_argument("--set", action="append", default=[], help="a study override the map ran with (key=value)")
    ap.add_argument("--depth-mm", type=float, default=4.0,
                    help="a phantom is deep when its deepest touch presses further than this (mm; default 4)")
    ap.add_argument("--rates", type=float, nargs="+", default=[1.5, 2.0, 3.0],
                    help="how many times as often a common order samples deep phantoms (default 1.5 2 3)")
    args = ap.parse_args(argv)
    if not args.depth_mm > 0 or not all(r > 0 for r in args.rates):
        print(f"multilevel_strata: --depth-mm and --rates: numbers > 0, got {args.depth_mm} and {args.rates}",
              file=sys.stderr)
        return 2
    loaded = finished_map("multilevel_strata", args.folder, args.set)
    if loaded is None:
        return 2
    study, run = loaded
    ml = study.multilevel
    used = list(run.used)
    is_deep = [max(t.depth_mm for t in p.touches) > args.depth_mm for p in study.phantoms]
    deep = np.array([is_deep[j] for j in used])
    secs = {True: [], False: []}
    for (_, j), e in run.fine.items():
        if e.status == "ok" and "total" in e.timings:
            secs[is_deep[j]].append(e.timings["total"])
    cost = {k: float(np.mean(v)) for k, v in secs.items()}
    order_pos = {j: k for k, j in enumerate(used)}
    order = np.array([order_pos[j] for j in run.order[len(run.take_all):]])
    plans = ["rule", "first", "x depth", "Neyman", *[f"deep x {r:g}" for r in args.rates]]
    print(f"{args.folder}: {len(run.compared)} designs x {len(used)} phantoms ({deep.mean():.0%} deeper than "
          f"{args.depth_mm:g} mm), {len(run.take_all)} take-all, pilot {ml.pilot}, se_factor {ml.se_factor}; "
          f"a fine phantom's model seconds: deep {cost[True]:.2f}, shallow {cost[False]:.2f}")
    print("| design | sampled fine n (map) | " + " | ".join(plans) + " |")
    print("|---|---|" + "---|" * len(plans))
    evals = np.zeros(len(plans) + 1)
    hours = np.zeros(len(plans) + 1)
    for i in run.compared:
        c, f, touches, take_all = run.level_arrays(study, i)
        lab = touches * 2 + deep
        ran = int(np.isfinite(f[~take_all]).sum())
        rule = predicted_fine_count(c, f, touches, se_factor=ml.se_factor, take_all=take_all)
        prop, fr = plan_count(c, f, touches, lab, take_all, ml.se_factor)
        natural = sum(v for h, v in fr.items() if h % 2)  # deep share of a proportional sample
        if not math.isclose(plan_count(c, f, touches, touches, take_all, ml.se_factor)[0], rule, rel_tol=1e-9):
            raise AssertionError(f"proportional over touch counts != the map's rule {rule}")
        first = first_meeting(c, f, touches, take_all, order, ml.pilot, ml.se_factor)
        plans_m = [(ran, natural), (rule, natural), (first, natural), (prop, natural)]
        for weight in ["neyman", *[lambda h, r=r: r if h % 2 else 1.0 for r in args.rates]]:
            m, fr = plan_count(c, f, touches, lab, take_all, ml.se_factor, weight)
            plans_m.append((m, sum(v for h, v in fr.items() if h % 2)))
        counts = [m for m, _ in plans_m[1:]]
        for p, (m, share) in enumerate(plans_m):
            m = max(ml.pilot, m)
            evals[p] += m + take_all.sum()
            hours[p] += (m * (share * cost[True] + (1 - share) * cost[False])
                         + take_all.sum() * cost[True]) / 3600
        d = study.designs[i]
        print(f"| w = {d.width_mm:g}, t = {d.thickness_mm:g} | {ran} | "
              + " | ".join(f"{m:.0f}" for m in counts) + " |")
    print("| fine evaluations (pilot at least, plus take-all) | " + " | ".join(f"{v:.0f}" for v in evals) + " |")
    print("| fine worker hours, priced by depth | " + " | ".join(f"{v:.2f}" for v in hours) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
