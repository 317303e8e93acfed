"""Reference of `bench::ident::frf::h1_radius_95`, the 95 % confidence
circle of an H1 frequency-response estimate (Bendat & Piersol, *Random
Data*, 4th ed. 2010, ch. 9):

    |H - H1|^2 <= 2/(2n - 2) * F(2, 2n - 2; 0.95) * (1 - g2)/g2 * |H1|^2

with n the number of (equivalent) averages and g2 the estimated
coherence. The F quantile comes from scipy.stats.f.ppf, not from the
closed form the Rust code uses. The script also checks by Monte Carlo, for
integer n, that the circle covers the true H in 95 % of estimates
(independent complex Gaussian input and output noise, numpy), and prints
the coverage.

Writes tests/data/h1_radius_reference.json: a list of
{"averages", "f95"} and the coverage table. By hand:
    python3 tests/data/h1_radius_reference.py
"""
import json
import pathlib

import numpy as np
from scipy.stats import f

AVERAGES = [1.5, 2.0, 3.0, 4.6, 5.0, 9.0, 13.7, 20.0, 100.0]


def coverage(n, true_g2, trials=20000, seed=1):
    rng = np.random.default_rng(seed)
    h = 1.0 + 0.5j
    # Output noise variance for the true coherence with unit input power.
    s2 = abs(h) ** 2 * (1 - true_g2) / true_g2
    x = (rng.standard_normal((trials, n)) + 1j * rng.standard_normal((trials, n))) / np.sqrt(2)
    e = (rng.standard_normal((trials, n)) + 1j * rng.standard_normal((trials, n))) * np.sqrt(s2 / 2)
    y = h * x + e
    gxx = (abs(x) ** 2).sum(1)
    gyy = (abs(y) ** 2).sum(1)
    gxy = (np.conj(x) * y).sum(1)
    h1 = gxy / gxx
    g2 = abs(gxy) ** 2 / (gxx * gyy)
    r2 = 2 / (2 * n - 2) * f.ppf(0.95, 2, 2 * n - 2) * (1 - g2) / g2 * abs(h1) ** 2
    return float(np.mean(abs(h - h1) ** 2 <= r2))


def main():
    out = {
        "cases": [
            {"averages": n, "f95": float(f.ppf(0.95, 2, 2 * n - 2))} for n in AVERAGES
        ],
        "coverage": [
            {"averages": n, "true_coherence": g, "coverage": coverage(n, g)}
            for n in [3, 5, 9, 20]
            for g in [0.3, 0.6, 0.9, 0.99]
        ],
    }
    for c in out["coverage"]:
        print(c)
    path = pathlib.Path(__file__).with_name("h1_radius_reference.json")
    path.write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
