"""How the pilot size of the two-level estimator sets its fine count, precision and coverage (Monte Carlo).

    python benchmarks/multilevel_pilot.py [--replicates 1500] [--pilots 6 9 15 30] [--seed 1]
    python benchmarks/multilevel_pilot.py --pilots 15 --noise 0.15 0.3 --min-growth 0.25 0

Synthetic maps shaped like the paper's: 300 phantoms, 100 per touch count, fine V_rel right-skewed (lognormal,
coefficient of variation about 0.8, stratum means 0.03 / 0.06 / 0.09), coarse V_rel ``0.92 F + 0.002`` plus
independent noise of 5 % or 15 % of the stratum mean (coarse/fine correlation about 0.99 and 0.95, the range the
paper designs show). Each replicate draws a new set of phantoms and runs the sweep's stopping rule
(:func:`~latticeopt.study.multilevel.next_fine_count`, ``se_factor`` 1.1) from the pilot on. Printed per noise
level and pilot: the fine count (median, mean), the root-mean-square error of the two-level mean over the
standard deviation of the plain all-fine mean (the target is at most ``se_factor``), how often mean +- 2 SE
covers the true mean (0.954 for a normal estimate with an exact SE), and the bias in units of the spread.
``--noise`` sets the coarse noise levels (0.3: correlation about 0.85, 100-200 fine phantoms of 300);
``--min-growth`` runs the rule with each smallest step (a share of the prefix) on the same maps.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from latticeopt.study.multilevel import fine_order, multilevel_estimate, next_fine_count, take_all_mask

STRATA = np.repeat([1, 2, 3], 100)
MEANS = np.array([0.03, 0.06, 0.09])


def _draw(rng, noise: float):
    base = MEANS[STRATA - 1]
    sigma = 0.7  # lognormal with mean 1: coefficient of variation about 0.8
    f = base * rng.lognormal(-sigma ** 2 / 2, sigma, STRATA.size)
    c = 0.92 * f + 0.002 + noise * base * rng.standard_normal(STRATA.size)
    return c, f


def run_rule(c, f, pilot: int, se_factor: float, control: str = "fixed", share: float = 0.0,
             min_growth: float = 0.0):
    """The sweep's stopping rule from the pilot to its end on one map whose fine values ``f`` are all known: the
    take-all phantoms (``share`` of each touch count, :func:`~latticeopt.study.multilevel.take_all_mask` of ``c``)
    first, then the others in :func:`~latticeopt.study.multilevel.fine_order`. Returns ``(fine phantoms in all,
    estimate)``; shared by the pilot, control and take-all benchmarks. ``min_growth``: the rule's smallest step
    as a share of the prefix."""
    whole = take_all_mask(c, STRATA, share)
    rest = np.flatnonzero(~whole)
    order = rest[fine_order(STRATA[rest])]
    n = 0
    while True:
        fine = np.where(whole, f, np.nan)
        fine[order[:n]] = f[order[:n]]
        nxt = next_fine_count(c, fine, STRATA, n, pilot=pilot, se_factor=se_factor, control=control,
                              take_all=whole, order=order, min_growth=min_growth)
        if nxt == n:
            return n + int(whole.sum()), multilevel_estimate(c, fine, STRATA, whole, control=control)
        n = nxt


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--replicates", type=int, default=1500)
    ap.add_argument("--pilots", type=int, nargs="+", default=[6, 9, 15, 30])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--noise", type=float, nargs="+", default=[0.05, 0.15],
                    help="coarse noise, shares of the stratum mean (default 0.05 0.15)")
    ap.add_argument("--min-growth", type=float, nargs="+", default=[0.0],
                    help="the stopping rule's smallest step as a share of the prefix, 0..1 (default 0: the rule's)")
    a = ap.parse_args(argv)
    if a.replicates < 10:
        print(f"multilevel_pilot.py: error: --replicates: expected an integer >= 10, got {a.replicates}",
              file=sys.stderr)
        return 2
    bad = [p for p in a.pilots if p < 2 or p > STRATA.size]
    if bad:
        print(f"multilevel_pilot.py: error: --pilots: expected integers 2..{STRATA.size}, got {bad[0]}",
              file=sys.stderr)
        return 2
    if not all(0 <= g <= 1 for g in a.min_growth) or not all(x >= 0 for x in a.noise):
        print(f"multilevel_pilot.py: error: --min-growth: shares 0..1 and --noise: >= 0, got {a.min_growth} and "
              f"{a.noise}", file=sys.stderr)
        return 2
    rng = np.random.default_rng(a.seed)
    truth = float(MEANS.mean())
    print("| coarse noise | pilot | min growth | fine n median / mean | RMS error / plain SD | coverage of +-2 SE | "
          "bias / SD |")
    print("|---|---|---|---|---|---|---|")
    for noise in a.noise:
        for pilot in a.pilots:  # each pilot on its own maps, every step on the same ones
            res = {g: ([], [], []) for g in a.min_growth}
            plain = []
            for _ in range(a.replicates):
                c, f = _draw(rng, noise)
                plain.append(multilevel_estimate(c, f, STRATA).mean - truth)
                for growth in a.min_growth:
                    n, e = run_rule(c, f, pilot, 1.1, min_growth=growth)
                    for lst, v in zip(res[growth], (e.mean - truth, e.se, n)):
                        lst.append(v)
            plain = np.array(plain)
            for growth in a.min_growth:
                err, se, ns = (np.array(v) for v in res[growth])
                print(f"| {noise:.0%} | {pilot} | {growth:g} | {np.median(ns):.0f} / {np.mean(ns):.0f} | "
                      f"{np.sqrt(np.mean(err ** 2)) / plain.std():.3f} | {np.mean(np.abs(err) <= 2 * se):.3f} | "
                      f"{err.mean() / err.std():+.3f} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
