"""The two-level estimator's control-variate coefficient: fixed ``beta = 1`` against ``beta`` fitted per design.

    python benchmarks/multilevel_control.py [--replicates 2000] [--pilot 15] [--se-factor 1.1] [--seed 1]

Synthetic maps shaped like the paper's (the generator of ``benchmarks/multilevel_pilot.py``): 300 phantoms, 100
per touch count, fine V_rel lognormal (coefficient of variation about 0.8, stratum means 0.03 / 0.06 / 0.09),
coarse V_rel ``0.92 F + 0.002`` plus noise of 5 % of the stratum mean (correlation about 0.99). On top, a heavy
tail as the paper map's 4 mm coarse level shows under deep presses near a corner: among the phantoms whose fine
value lies in the top fifth of their touch count's distribution, some read ``C = 3 F`` on the coarse level
(overshoot) and some ``C = F / 2`` (undershoot); the fine values, and so the true mean, are untouched. Tail
severities: the fraction of all phantoms that overshoot / undershoot, from none to 4 % / 2 % (the paper map's
w = 2 mm designs: 5 and 3 of about 300 phantoms, about 2 % / 1 %).

Each replicate draws one map and runs the sweep's stopping rule (:func:`~latticeopt.study.multilevel.next_fine_count`)
from the pilot to its end with each control on the same map. Printed per severity and control: the fine count
(mean, median), ``var(D) / var(F)`` over the whole map (mean over replicates, for scale), the root-mean-square
error of the two-level mean over the standard deviation of the plain all-fine mean (the SE ratio achieved;
the target is ``se_factor``), the mean stated SE over that SD, how often mean +- 2 SE covers the true mean (0.954
for a normal estimate with an exact SE; the Monte Carlo SE of a coverage is about 0.005 at 2000 replicates) and
the bias over the spread of the estimate (Monte Carlo SE ``1 / sqrt(replicates)``, 0.022 at 2000).

A second table takes the stopping rule out: every replicate stops at the same ``--fixed-n`` fine phantoms, so
what remains is the estimator's own bias (``O(1 / n)`` for a fitted ``beta``) and its SE's coverage.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np
from multilevel_pilot import MEANS, STRATA, _draw, run_rule

from latticeopt.study.multilevel import CONTROLS, fine_order, multilevel_estimate

#: (label, fraction of phantoms whose coarse value overshoots, fraction that undershoots)
SEVERITIES = (("none", 0.0, 0.0), ("mild", 0.005, 0.0025), ("moderate", 0.01, 0.005), ("paper w = 2", 0.02, 0.01),
              ("severe", 0.04, 0.02))
ORDER = fine_order(STRATA)
#: the top fifth of a touch count's fine values: lognormal(-sigma^2 / 2, sigma) above its 80th percentile
TOP = MEANS[STRATA - 1] * np.exp(-0.7 ** 2 / 2 + 0.7 * 0.8416)


def draw(rng, over: float, under: float):
    """One map: ``(coarse, fine)`` with the tail described in the module docstring."""
    c, f = _draw(rng, 0.05)
    big = f > TOP
    u = rng.random(f.size)
    over_p, under_p = over / 0.2, under / 0.2  # per phantom in the top fifth, so over / under of all phantoms
    c = np.where(big & (u < over_p), 3.0 * f, c)
    c = np.where(big & (u >= over_p) & (u < over_p + under_p), 0.5 * f, c)
    return c, f


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--replicates", type=int, default=2000)
    ap.add_argument("--pilot", type=int, default=15)
    ap.add_argument("--se-factor", type=float, default=1.1)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--fixed-n", type=int, default=60, help="fine phantoms of the second table")
    a = ap.parse_args(argv)
    if a.replicates < 10:
        print(f"multilevel_control.py: error: --replicates: expected an integer >= 10, got {a.replicates}",
              file=sys.stderr)
        return 2
    if not 2 <= a.pilot <= STRATA.size:
        print(f"multilevel_control.py: error: --pilot: expected an integer 2..{STRATA.size}, got {a.pilot}",
              file=sys.stderr)
        return 2
    if not a.se_factor >= 1:
        print(f"multilevel_control.py: error: --se-factor: expected a number >= 1, got {a.se_factor}", file=sys.stderr)
        return 2
    if not 6 <= a.fixed_n <= STRATA.size:
        print(f"multilevel_control.py: error: --fixed-n: expected an integer 6..{STRATA.size}, got {a.fixed_n}",
              file=sys.stderr)
        return 2
    rng = np.random.default_rng(a.seed)
    truth = float(MEANS.mean())
    start = time.perf_counter()
    print(f"pilot {a.pilot}, se_factor {a.se_factor:g}, {a.replicates} replicates per row")
    print("| tail (over / under) | var(D)/var(F) | control | fine n mean / median | RMS error / plain SD | "
          "stated SE / plain SD | coverage of +-2 SE | bias / SD | mean beta |")
    print("|---|---|---|---|---|---|---|---|---|")
    for label, over, under in SEVERITIES:
        res = {k: ([], [], [], []) for k in CONTROLS}
        plain, ratio = [], []
        for _ in range(a.replicates):
            c, f = draw(rng, over, under)
            d = f - c
            ratio.append(np.var(d) / np.var(f))
            plain.append(multilevel_estimate(c, f, STRATA).mean - truth)
            for control in CONTROLS:
                n, e = run_rule(c, f, a.pilot, a.se_factor, control)
                for lst, v in zip(res[control], (n, e.mean - truth, e.se, e.beta)):
                    lst.append(v)
        sd = float(np.std(plain))
        for control in CONTROLS:
            ns, err, se, beta = (np.array(v) for v in res[control])
            print(f"| {label} ({100 * over:g} % / {100 * under:g} %) | {np.mean(ratio):.3f} | {control} | "
                  f"{ns.mean():.0f} / {np.median(ns):.0f} | {np.sqrt(np.mean(err ** 2)) / sd:.3f} | "
                  f"{np.mean(se) / sd:.3f} | {np.mean(np.abs(err) <= 2 * se):.3f} | {err.mean() / err.std():+.3f} | "
                  f"{beta.mean():.3f} |", flush=True)
    print(f"\nfixed n = {a.fixed_n} (no stopping rule), {a.replicates} replicates per row")
    print("| tail (over / under) | control | RMS error / plain SD | stated SE / plain SD | coverage of +-2 SE | "
          "bias / SD |")
    print("|---|---|---|---|---|---|")
    fine_n = np.full(STRATA.size, False)
    fine_n[ORDER[:a.fixed_n]] = True
    for label, over, under in SEVERITIES:
        res = {k: ([], []) for k in CONTROLS}
        plain = []
        for _ in range(a.replicates):
            c, f = draw(rng, over, under)
            plain.append(multilevel_estimate(c, f, STRATA).mean - truth)
            for control in CONTROLS:
                e = multilevel_estimate(c, np.where(fine_n, f, np.nan), STRATA, control=control)
                res[control][0].append(e.mean - truth)
                res[control][1].append(e.se)
        sd = float(np.std(plain))
        for control in CONTROLS:
            err, se = (np.array(v) for v in res[control])
            print(f"| {label} ({100 * over:g} % / {100 * under:g} %) | {control} | "
                  f"{np.sqrt(np.mean(err ** 2)) / sd:.3f} | {np.mean(se) / sd:.3f} | "
                  f"{np.mean(np.abs(err) <= 2 * se):.3f} | {err.mean() / err.std():+.3f} |",
                  flush=True)
    print(f"{time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
