#!/usr/bin/env python3
"""Independent reference for the statistics of a multisine's BLA with few
realizations, and of a fit weighted by its variance (issue 45, item 1).

With M realizations the variance of the BLA, sigma^2, is estimated with
d = 2 (M - 1) real degrees of freedom, independently of the BLA itself
(Gaussian noise: sample mean and sample variance), so that per line

    t = |G_hat - G|^2 / sigma_hat^2  ~  F(2, d)

exactly (Pintelon & Schoukens, *System Identification*, 2nd ed. 2012,
ch. 4 and section 10.3), not chi2_2 / 2 as for a known variance; and a
cost summed over L independent lines, C = sum 2 t, follows the law of a
sum of L independent 2 F(2, d).

Input (argv[1], JSON):

    {"dof": d, "lines": L, "per_line": [t, ...] (pooled over lines and
     seeds), "truth_cost": [C, ...] (one per seed), "draws": int,
     "seed": int}

Output (stdout):

    {"scipy": version, "per_line_ks_p": the Kolmogorov-Smirnov p-value of
     per_line against F(2, d) (scipy.stats.kstest), "per_line_mean": its
     mean, "f_mean": d / (d - 2), "f_ppf_95": scipy.stats.f.ppf(0.95, 2, d),
     "inside_95": the fraction of per_line at or below it, "cost_ks_p": the
     two-sample KS p-value of truth_cost against `draws` draws of the sum
     of L independent 2 F(2, d) (scipy.stats.f.rvs), "cost_mean_law":
     2 L d / (d - 2)}

Needs numpy and scipy (`.ci/run` installs them into a venv; the tests run
this script with `$BENCH_PYTHON`, else `python3`).
"""

import json
import sys

import numpy as np
import scipy
from scipy import stats


def main() -> None:
    with open(sys.argv[1]) as f:
        case = json.load(f)
    d = float(case["dof"])
    lines = int(case["lines"])
    per_line = np.asarray(case["per_line"], dtype=float)
    truth_cost = np.asarray(case["truth_cost"], dtype=float)
    law = stats.f(2.0, d)
    rng = np.random.default_rng(int(case["seed"]))
    draws = int(case["draws"])
    sums = np.zeros(draws)
    # In blocks, to keep the memory small.
    block = 1000
    for start in range(0, draws, block):
        n = min(block, draws - start)
        sums[start : start + n] = 2.0 * law.rvs(size=(n, lines), random_state=rng).sum(axis=1)
    q95 = float(law.ppf(0.95))
    out = {
        "scipy": scipy.__version__,
        "per_line_ks_p": float(stats.kstest(per_line, law.cdf).pvalue),
        "per_line_mean": float(per_line.mean()),
        "f_mean": d / (d - 2.0),
        "f_ppf_95": q95,
        "inside_95": float(np.mean(per_line <= q95)),
        "cost_ks_p": float(stats.ks_2samp(truth_cost, sums).pvalue),
        "cost_mean_law": 2.0 * lines * d / (d - 2.0),
    }
    json.dump(out, sys.stdout)


if __name__ == "__main__":
    main()
