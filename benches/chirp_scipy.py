#!/usr/bin/env python3
"""The default `bench chirp` pipeline in numpy / scipy, for the end-to-end
comparison of issue 16 (benches/chirp-vs-scipy.sh times both as processes).

Same work, same sample count (327 500 ticks at 5 kHz for the shipped
bench-config/sr4dof-ch5.toml):
1. the excitation: lead-in, exponential sweep with the amplitude profile and
   the raised-cosine tapers, tail (README, `[chirp]`);
2. the plant: the thesis' SR4DoF model with Rayleigh damping and the current
   amplifier (tests/data/make_reference.py builds it), discretised with a
   zero-order hold (scipy.signal.cont2discrete) and simulated over the record
   with scipy.signal.dlsim (state space, as bench steps it), plus the probe's
   white noise. (The transfer-function route, ss2zpk -> zpk2sos -> sosfilt,
   is faster but scipy warns "Badly conditioned filter coefficients" for
   this 9-state plant and its |H| comes out 60 % low at DC: not an option);
3. the record written to disk (t, u, y as float64, numpy .npy);
4. the FRF: probe offset from the lead-in, one FFT of the zero-padded record
   (scipy.fft), H1 and coherence from Hann-weighted bin averages on the same
   log grid and resolution, written as the same CSV.
It does not fit modes, draw the Bode plot or keep the supervisor's checks;
bench does all of those in its time.

Run: python3 benches/chirp_scipy.py [--config TOML] [--out DIR]
Prints the compute time (after the imports) on stderr.
"""
import argparse
import os
import sys
import time
import tomllib

import numpy as np
from scipy import fft, signal

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "tests", "data"))
from make_reference import mechanics_ss, sr4dof  # noqa: E402


def ticks(s, period_s):
    return int(round(s / period_s))


def chirp(c, period_s):
    lead, sweep, tail = (ticks(c["lead_in_s"], period_s), max(ticks(c["duration_s"], period_s), 1),
                         ticks(c["tail_s"], period_s))
    big_t = sweep * period_s
    t = np.arange(sweep) * period_s
    f0, f1 = c["f_start_hz"], c["f_end_hz"]
    ln_r = np.log(f1 / f0)
    theta = 2 * np.pi * f0 * big_t / ln_r * (np.exp(t / big_t * ln_r) - 1.0)
    f = f0 * np.exp(t / big_t * ln_r)
    prof = np.array(c.get("amplitude_profile", []), dtype=float)
    scale = np.interp(np.log(f), np.log(prof[:, 0]), prof[:, 1]) if len(prof) else 1.0
    edge = np.minimum(t, big_t - t)
    tp = c["taper_s"]
    w = np.where(edge >= tp, 1.0, 0.5 * (1 - np.cos(np.pi * np.maximum(edge, 0) / tp))) if tp > 0 else 1.0
    u = np.zeros(lead + sweep + tail)
    u[lead:lead + sweep] = c["amplitude_a"] * scale * w * np.sin(theta)
    return u, lead


def plant(cfg, rate_hz):
    p, a = cfg["plant"], cfg["actuator"]
    beam = dict(length_m=p["beam"]["length_m"], height_m=p["beam"]["height_m"],
                thickness_m=p["beam"]["thickness_m"], E=p["beam"]["youngs_modulus_pa"])
    M, K, C, q, _, _ = sr4dof(p["m1_kg"], p["m2_kg"], p["m3_kg"], p["m4_kg"], p["m5_kg"],
                              p["k4_n_per_m"], p["k5_n_per_m"], p["operating_point_m"],
                              p["mass_asymmetry"], beam, p["damping"]["zeta_rigid"],
                              p["damping"]["zeta_csm"], kp=p["parallelogram_stiffness_n_per_m"])
    A, B, _ = mechanics_ss(M, C, K, q)
    wa = 2 * np.pi * a["bandwidth_hz"]
    Aa = np.zeros((9, 9)); Aa[:8, :8] = A; Aa[:8, 8] = B[:, 0] * a["force_constant_n_per_a"]
    Aa[8, 8] = -wa
    Ba = np.zeros((9, 1)); Ba[8, 0] = wa
    Ca = np.zeros((1, 9)); Ca[0, 0] = 1.0
    return signal.cont2discrete((Aa, Ba, Ca, np.zeros((1, 1))), 1.0 / rate_hz, method="zoh")


def frf(u, y, rate_hz, ident, f_lo, f_hi):
    n = fft.next_fast_len(len(u), real=True)
    U, Y = fft.rfft(u, n), fft.rfft(y, n)
    bin_hz = rate_hz / n
    ppd, rho, min_bins = ident["points_per_decade"], ident["relative_resolution"], ident.get("min_bins", 5)
    m = max(int(np.ceil(np.log10(f_hi / f_lo) * ppd)), 1)
    grid = f_lo * (f_hi / f_lo) ** (np.arange(m + 1) / m)
    out = np.empty((len(grid), 4))
    for i, f in enumerate(grid):
        hw = max(0.5 * rho * f, 0.5 * min_bins * bin_hz)
        lo, hi = max(int(np.ceil((f - hw) / bin_hz)), 0), min(int(np.floor((f + hw) / bin_hz)), len(U) - 1)
        k = np.arange(lo, hi + 1)
        w = np.cos(0.5 * np.pi * (k * bin_hz - f) / hw) ** 2
        uk, yk = U[lo:hi + 1], Y[lo:hi + 1]
        suu, syy, syu = np.sum(w * np.abs(uk) ** 2), np.sum(w * np.abs(yk) ** 2), np.sum(w * yk * np.conj(uk))
        h = syu / suu
        out[i] = (f, abs(h), np.angle(h), min(abs(syu) ** 2 / (suu * syy), 1.0))
    out[:, 2] = np.degrees(np.unwrap(out[:, 2]))
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--config", default=os.path.join(HERE, "..", "bench-config", "sr4dof-ch5.toml"))
    ap.add_argument("--out", default=".")
    args = ap.parse_args()
    t0 = time.perf_counter()
    with open(args.config, "rb") as fh:
        cfg = tomllib.load(fh)
    rate_hz = cfg["loop"]["rate_hz"]
    period_s = 1.0 / rate_hz
    u, lead = chirp(cfg["chirp"], period_s)
    Ad, Bd, Cd, Dd, _ = plant(cfg, rate_hz)
    _, x1, _ = signal.dlsim((Ad, Bd, Cd, Dd, period_s), u)
    x1 = x1[:, 0]
    rng = np.random.default_rng(cfg["sim"]["seed"])
    y = x1 + rng.normal(0.0, cfg["probe"]["noise_rms_m"], len(u))
    t = np.arange(len(u)) * period_s
    np.save(os.path.join(args.out, "chirp-scipy.npy"), np.stack([t, u, y]))
    y = y - y[:lead].mean()
    h = frf(u, y, rate_hz, cfg["identification"], cfg["chirp"]["f_start_hz"], cfg["chirp"]["f_end_hz"])
    np.savetxt(os.path.join(args.out, "chirp-scipy.frf.csv"), h, delimiter=",",
               header="frequency_hz,magnitude_m_per_a,phase_deg,coherence", comments="",
               fmt=["%.6f", "%.6e", "%.3f", "%.5f"])
    print(f"{len(u)} ticks, {len(h)} grid points, compute {time.perf_counter() - t0:.3f} s "
          f"(dlsim)", file=sys.stderr)


if __name__ == "__main__":
    main()
