#!/usr/bin/env python3
"""Independent reference for `bench`'s best linear approximation (BLA).

Recomputes, from a multisine record and without any of the Rust code, the
robust method's quantities per excited line (Pintelon & Schoukens, *System
Identification: A Frequency Domain Approach*, 2nd ed. 2012, sections 3.7
and 4.3; Schoukens, Pintelon & Rolain, Automatica 41, 2005), so that
`tests/cli/multisine.rs` can check `bench::ident::bla` against a second
implementation.

Input (argv[1], JSON):

    {"lead_in_ticks": int, "period_ticks": N, "transient_periods": int,
     "periods": P, "realizations": M, "lines": [k, ...] (DFT lines of a
     period, 0 < k < N/2), "tick_s": T_s, "u": [A, ...], "y": [m, ...]}

The record is lead-in | M x (transient periods + P periods) | anything.

Per realization m and measured period p, the DFT of the period's u and y
(numpy.fft.rfft, N points) at line k gives G[m,p] = Y/U. Then per line:

    G_m        = mean over p of G[m,p]
    var_n_m    = sum_p |G[m,p] - G_m|^2 / (P (P - 1))
    G_bla      = mean over m of G_m
    var_bla    = sum_m |G_m - G_bla|^2 / (M (M - 1))
    var_n      = sum_m var_n_m / M^2
    var_s      = max(M (var_bla - var_n), 0)
    p_value    = scipy.stats.f.sf(var_bla / var_n, 2 (M - 1), 2 M (P - 1))

and over the lines: K = #(p_value < 0.05), its chance without distortion
scipy.stats.binom.sf(K - 1, L, 0.05), "detected" below 1e-3.

Output (stdout, or argv[2]): {"numpy": version, "scipy": version,
"frequency_hz", "re", "im", "sigma_bla", "sigma_noise", "sigma_nonlinear",
"p_value" (lists over the lines), "lines", "lines_distorted",
"binomial_p", "detected"}.

Needs numpy and scipy (`pip install numpy scipy`; `.ci/run` installs them
with python-control into a venv, and the tests run this script with
`$BENCH_PYTHON`, else `python3`).
"""

import json
import sys

import numpy as np
import scipy
from scipy import stats


def bla(rec):
    n = int(rec["period_ticks"])
    lead = int(rec["lead_in_ticks"])
    t_tr = int(rec["transient_periods"])
    p_count = int(rec["periods"])
    m_count = int(rec["realizations"])
    lines = np.asarray(rec["lines"], dtype=int)
    u = np.asarray(rec["u"], dtype=float)
    y = np.asarray(rec["y"], dtype=float)
    g = np.empty((m_count, p_count, len(lines)), dtype=complex)
    for m in range(m_count):
        for p in range(p_count):
            start = lead + (m * (t_tr + p_count) + t_tr + p) * n
            uu = np.fft.rfft(u[start:start + n])[lines]
            yy = np.fft.rfft(y[start:start + n])[lines]
            g[m, p] = yy / uu
    g_m = g.mean(axis=1)
    var_n_m = (np.abs(g - g_m[:, None, :]) ** 2).sum(axis=1) / (p_count * (p_count - 1))
    g_bla = g_m.mean(axis=0)
    var_bla = (np.abs(g_m - g_bla) ** 2).sum(axis=0) / (m_count * (m_count - 1))
    var_n = var_n_m.sum(axis=0) / m_count**2
    var_s = np.maximum(m_count * (var_bla - var_n), 0.0)
    p_value = stats.f.sf(var_bla / var_n, 2 * (m_count - 1), 2 * m_count * (p_count - 1))
    k = int((p_value < 0.05).sum())
    binom_p = float(stats.binom.sf(k - 1, len(lines), 0.05))
    t_p = n * float(rec["tick_s"])
    return {
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "frequency_hz": (lines / t_p).tolist(),
        "re": g_bla.real.tolist(),
        "im": g_bla.imag.tolist(),
        "sigma_bla": np.sqrt(var_bla).tolist(),
        "sigma_noise": np.sqrt(var_n).tolist(),
        "sigma_nonlinear": np.sqrt(var_s).tolist(),
        "p_value": p_value.tolist(),
        "lines": len(lines),
        "lines_distorted": k,
        "binomial_p": binom_p,
        "detected": binom_p < 1e-3,
    }


def main():
    with open(sys.argv[1]) as f:
        rec = json.load(f)
    out = json.dumps(bla(rec))
    if len(sys.argv) > 2:
        with open(sys.argv[2], "w") as f:
            f.write(out)
    else:
        print(out)


if __name__ == "__main__":
    main()
