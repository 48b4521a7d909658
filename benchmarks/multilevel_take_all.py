"""Take-all phantoms in the two-level estimator: the share of each touch count with the largest coarse V_rel run
fine whatever the pilot says (``[multilevel] take_all``), against sampling every phantom.

    python benchmarks/multilevel_take_all.py [--replicates 1000] [--shares 0 0.03 0.05 0.1] [--seed 1]
    python benchmarks/multilevel_take_all.py --shares 0.05 --min-growth 0.25 0

The synthetic maps of ``benchmarks/multilevel_control.py`` (300 phantoms shaped like the paper map's, a heavy
tail of the fine-minus-coarse correction from none to 4 % / 2 % of the phantoms reading ``C = 3 F`` / ``C = F / 2``
on the coarse level). Each replicate draws one map and runs the sweep's stopping rule
(:func:`~latticeopt.study.multilevel.next_fine_count`, pilot 15, ``se_factor`` 1.1, control fixed) from the pilot
to its end for every share on the same map: the take-all phantoms (:func:`~latticeopt.study.multilevel.take_all_mask`
of the map's coarse values) first, then the others in :func:`~latticeopt.study.multilevel.fine_order`. Printed per
tail and share: the fine count with the take-all phantoms (mean, median), the root-mean-square error of the
two-level mean over the standard deviation of the plain all-fine mean (the target is ``se_factor``), the mean
stated SE over that SD, how often mean +- 2 SE covers the true mean (0.954 ideal; Monte Carlo SE about 0.007 at
1000 replicates) and the bias over the estimate's spread (Monte Carlo SE ``1 / sqrt(replicates)``).
``--min-growth`` runs the rule with each smallest step (a share of the prefix; 0: grow to the predicted count,
at least one phantom) on the same maps.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np
from multilevel_control import SEVERITIES, draw
from multilevel_pilot import MEANS, STRATA, run_rule

from latticeopt.study.multilevel import multilevel_estimate


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--replicates", type=int, default=1000)
    ap.add_argument("--shares", type=float, nargs="+", default=[0.0, 0.03, 0.05, 0.1])
    ap.add_argument("--pilot", type=int, default=15)
    ap.add_argument("--se-factor", type=float, default=1.1)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--min-growth", type=float, nargs="+", default=[0.0],
                    help="the stopping rule's smallest step as a share of the prefix, 0..1 (default 0: the rule's)")
    a = ap.parse_args(argv)
    if a.replicates < 10:
        print(f"multilevel_take_all.py: error: --replicates: expected an integer >= 10, got {a.replicates}",
              file=sys.stderr)
        return 2
    bad_growth = [g for g in a.min_growth if not 0 <= g <= 1]
    if bad_growth:
        print(f"multilevel_take_all.py: error: --min-growth: expected shares 0..1, got {bad_growth[0]}",
              file=sys.stderr)
        return 2
    bad = [s for s in a.shares if not 0 <= s <= 0.5]
    if bad:
        print(f"multilevel_take_all.py: error: --shares: expected shares 0..0.5, got {bad[0]}", file=sys.stderr)
        return 2
    rng = np.random.default_rng(a.seed)
    truth = float(MEANS.mean())
    start = time.perf_counter()
    print(f"pilot {a.pilot}, se_factor {a.se_factor:g}, control fixed, {a.replicates} replicates per tail")
    print("| tail (over / under) | take_all | min growth | fine n mean / median | RMS error / plain SD | "
          "stated SE / plain SD | coverage of +-2 SE | bias / SD |")
    print("|---|---|---|---|---|---|---|---|")
    runs = [(s, g) for s in a.shares for g in a.min_growth]
    for label, over, under in SEVERITIES:
        res = {r: ([], [], []) for r in runs}
        plain = []
        for _ in range(a.replicates):
            c, f = draw(rng, over, under)
            plain.append(multilevel_estimate(c, f, STRATA).mean - truth)
            for s, g in runs:
                n, e = run_rule(c, f, a.pilot, a.se_factor, share=s, min_growth=g)
                for lst, v in zip(res[s, g], (n, e.mean - truth, e.se)):
                    lst.append(v)
        sd = float(np.std(plain))
        for s, g in runs:
            ns, err, se = (np.array(v) for v in res[s, g])
            print(f"| {label} ({100 * over:g} % / {100 * under:g} %) | {s:g} | {g:g} | {ns.mean():.0f} / "
                  f"{np.median(ns):.0f} | "
                  f"{np.sqrt(np.mean(err ** 2)) / sd:.3f} | {np.mean(se) / sd:.3f} | "
                  f"{np.mean(np.abs(err) <= 2 * se):.3f} | {err.mean() / err.std():+.3f} |", flush=True)
    print(f"{time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
