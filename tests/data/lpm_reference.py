#!/usr/bin/env python3
"""Independent reference for the local polynomial method (LPM) FRF estimate.

Written from the textbook formulas, not from bench's code:
R. Pintelon, J. Schoukens, System Identification: A Frequency Domain
Approach, 2nd ed. 2012, section 7.2; R. Pintelon, J. Schoukens,
G. Vandersteen, K. Barbe, "Estimation of nonparametric noise and FRF models
for multivariable systems - Part I: Theory", Mechanical Systems and Signal
Processing 24 (2010) 573-595. One input, one output.

Model around the DFT bin k, over the bins k + r, r = -n .. n:

    Y(k+r) = G(k+r) U(k+r) + T(k+r) + V(k+r)
    G(k+r) = sum_j g_j r^j,  T(k+r) = sum_j t_j r^j,   j = 0 .. R

(here in the plain bin offset r, not scaled), solved by linear least
squares with LAPACK's QR-based lstsq; the residual e gives the noise
variance

    s2 = |e|^2 / q,    q = 2n + 1 - 2(R + 1),

and the covariance of the coefficients s2 (K^H K)^-1 = s2 R^-1 R^-H from
the QR factor R of the regressor K. The FRF at f (between bins) is the
polynomial at the fractional offset d = f/df - k_c (k_c the window's
centre), a = [1, d, .., d^R, 0 .. 0]:  G(f) = a^T theta,
var G(f) = s2 |R^-H a|^2.  The window is centred on the bin nearest f,
shifted inward (bins 1 .. k_max) at the edges. The coherence column is the
signal-to-noise form |G U(k)|^2 / (|G U(k)|^2 + s2) at the bin k nearest f.
The window's half width is n, or where the relative resolution rho asks
for more, floor(rho f / (2 df)) (bench's documented rule: the window spans
2n + 1 bins or rho f, whichever is wider), at most what fits in 1 .. k_max.

Usage: lpm_reference.py INPUT.json OUTPUT.json
INPUT: {"rate_hz", "n_fft", "k_max", "half_width_bins", "degree",
        "relative_resolution", "frequencies_hz": [...], "u_file", "y_file"}; u_file and y_file hold
the record's samples as little-endian float64 (A and m).
OUTPUT: {"response_re", "response_im", "sigma_m_per_a", "coherence",
         "noise_variance_m2", "half_width_bins"}, one entry per frequency.
"""

import json
import sys

import numpy as np
import scipy.linalg


def lpm_line(U, Y, f, df, n, R, k_max, rho):
    x = f / df
    # The window: 2n + 1 bins, or rho f where wider (at most what fits).
    n = max(n, min(int(np.floor(rho * f / (2 * df))), (k_max - 1) // 2))
    k_near = int(np.floor(x + 0.5))
    k_near = min(max(k_near, 1), k_max)
    first = k_near - n
    first = max(first, 1)
    first = min(first, k_max - 2 * n)
    centre = first + n
    idx = np.arange(first, first + 2 * n + 1)
    r = (idx - centre).astype(float)
    powers = np.vander(r, R + 1, increasing=True)  # r^0 .. r^R
    K = np.hstack([U[idx][:, None] * powers, powers.astype(complex)])
    theta, _, rank, _ = np.linalg.lstsq(K, Y[idx], rcond=None)
    if rank < K.shape[1]:
        return complex("nan+nanj"), float("nan"), 0.0, float("nan"), n
    e = Y[idx] - K @ theta
    q = 2 * n + 1 - 2 * (R + 1)
    s2 = float(np.vdot(e, e).real) / q
    _, Rq = np.linalg.qr(K)
    d = x - centre
    a = np.zeros(K.shape[1])
    a[: R + 1] = d ** np.arange(R + 1)
    # R^-H a: solve R^H w = a.
    w = scipy.linalg.solve_triangular(Rq, a.astype(complex), trans="C", lower=False)
    var = s2 * float(np.vdot(w, w).real)
    G = complex(a @ theta)
    signal = abs(G * U[k_near]) ** 2
    coh = signal / (signal + s2) if signal + s2 > 0 else 0.0
    return G, float(np.sqrt(var)), coh, s2, n


def main():
    inp = json.load(open(sys.argv[1]))
    u = np.fromfile(inp["u_file"], dtype="<f8")
    y = np.fromfile(inp["y_file"], dtype="<f8")
    N = int(inp["n_fft"])
    U = np.fft.rfft(u, N)
    Y = np.fft.rfft(y, N)
    df = float(inp["rate_hz"]) / N
    n = int(inp["half_width_bins"])
    R = int(inp["degree"])
    k_max = min(int(inp["k_max"]), len(U) - 1)
    rho = float(inp["relative_resolution"])
    out = {k: [] for k in ("response_re", "response_im", "sigma_m_per_a",
                           "coherence", "noise_variance_m2", "half_width_bins")}
    for f in inp["frequencies_hz"]:
        G, sigma, coh, s2, n_f = lpm_line(U, Y, float(f), df, n, R, k_max, rho)
        out["response_re"].append(G.real)
        out["response_im"].append(G.imag)
        out["sigma_m_per_a"].append(sigma)
        out["coherence"].append(coh)
        out["noise_variance_m2"].append(s2)
        out["half_width_bins"].append(n_f)
    # Strict JSON: a NaN (rank-deficient window) as null.
    for v in out.values():
        v[:] = [None if x != x else x for x in v]
    json.dump(out, open(sys.argv[2], "w"))


if __name__ == "__main__":
    main()
