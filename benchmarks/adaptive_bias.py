"""Bias and coverage of adaptive phantom counts (``[phantoms] target_se``), by Monte Carlo.

    python benchmarks/adaptive_bias.py [--replicates 4000] [--seed 1]

Stopping when the standard error first meets a target is a data-dependent rule: if a design's V_rel is
right-skewed (as over random phantoms: many light touches, a few deep ones), a prefix that happens to miss the
large values has both a low mean and a low spread, so it stops early. This script draws V_rel from lognormal
distributions (mean 0.06; coefficient of variation 0.7 and 1.0, the range of the paper map's designs over
random phantoms) and from a normal one, runs the project's stopping rule
(:func:`latticeopt.study.adaptive_sweep.next_count`: ``min_per_design`` 30, ``batch_size`` 15, at most 300) with
targets that stop at about 60 and 120 phantoms, and prints the bias of the reported mean (in units of the
plain SE at the mean stopping count) and how often ``mean +- 2 SE`` covers the true mean, beside the same
coverage for a fixed count.
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from latticeopt.study.adaptive_sweep import next_count
from latticeopt.study.report import mean_se
from latticeopt.study.settings import AdaptiveSettings

MEAN, MAX = 0.06, 300


def draw(rng: np.random.Generator, shape, cv: float | None) -> np.ndarray:
    """V_rel samples with mean MEAN and coefficient of variation ``cv`` (lognormal; ``None``: normal, cv 0.3)."""
    if cv is None:
        return rng.normal(MEAN, 0.3 * MEAN, shape)
    sig = math.sqrt(math.log(1 + cv * cv))
    return rng.lognormal(math.log(MEAN) - sig * sig / 2, sig, shape)


def stopped(values: np.ndarray, adaptive: AdaptiveSettings) -> int:
    """The count the adaptive rule stops at on one design's values (a prefix of them)."""
    n = 0
    while (m := next_count(values[:n], len(values), adaptive)) != n:
        n = m
    return n


def experiment(rng, cv, n_target: int, replicates: int) -> dict:
    """Bias (in SE units), coverage of +-2 SE and mean count of the adaptive rule; coverage at a fixed count."""
    sd = (0.3 if cv is None else cv) * MEAN
    adaptive = AdaptiveSettings(target_se=sd / math.sqrt(n_target), min_per_design=30, batch_size=15)
    means, ses, ns = np.empty(replicates), np.empty(replicates), np.empty(replicates)
    for r in range(replicates):
        x = draw(rng, MAX, cv)
        ns[r] = n = stopped(x, adaptive)
        means[r], ses[r] = mean_se(x[:n])
    se_plain = sd / math.sqrt(ns.mean())
    fixed = draw(rng, (replicates, n_target), cv)
    f_se = fixed.std(axis=1, ddof=1) / math.sqrt(n_target)
    return {"n": float(ns.mean()), "bias_se": float((means.mean() - MEAN) / se_plain),
            "bias_mc_se": float(means.std() / math.sqrt(replicates) / se_plain),
            "coverage": float(np.mean(np.abs(means - MEAN) <= 2 * ses)),
            "coverage_fixed": float(np.mean(np.abs(fixed.mean(axis=1) - MEAN) <= 2 * f_se))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--replicates", type=int, default=4000)
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args()
    if a.replicates < 2:
        ap.error(f"--replicates: expected an integer >= 2, got {a.replicates}")
    rng = np.random.default_rng(a.seed)
    print(f"{a.replicates} replicates; min_per_design 30, batch_size 15, at most {MAX}")
    print("| V_rel distribution | target stops near | mean n | bias of the mean (plain SEs) | coverage of +-2 SE | "
          "same at fixed n |")
    print("|---|---|---|---|---|---|")
    for cv in (None, 0.7, 1.0):
        for n_target in (60, 120):
            e = experiment(rng, cv, n_target, a.replicates)
            name = "normal, cv 0.3" if cv is None else f"lognormal, cv {cv:g}"
            print(f"| {name} | {n_target} | {e['n']:.0f} | {e['bias_se']:+.2f} ± {e['bias_mc_se']:.2f} | "
                  f"{e['coverage']:.3f} | {e['coverage_fixed']:.3f} |", flush=True)


if __name__ == "__main__":
    main()
