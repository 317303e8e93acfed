#!/usr/bin/env python3
"""Independent reference for the bench's SR4DoF simulator (scipy / numpy).

Builds Eq. (2-5) of the thesis from scratch, fits Rayleigh damping as
the README (*Configuration reference*, Rayleigh damping) defines, adds the first-order current amplifier, discretises with a
zero-order hold (scipy.signal.cont2discrete, method 'zoh') and writes
`sr4dof_reference.json` beside this script:

- natural frequencies (Hz) and damping ratios;
- zeros of the force -> x1 transfer function (scipy.signal.ss2zpk on the
  continuous mechanics, no amplifier), in Hz (s / 2 pi);
- the discrete FRF current demand -> x1 at the loop rate on a log grid,
  magnitude (m/A) and phase (deg, unwrapped).

Run: python3 tests/data/make_reference.py   (numpy, scipy)
"""
import json
import os

import numpy as np
from scipy import linalg, signal

L = 0.0475
BEAM_CH5 = dict(length_m=L, height_m=0.0254, thickness_m=0.000625, E=6.9e10)
# The parallelogram stiffness of the shipped sr4dof-ch5.toml, N/m: 1.093 x the
# beam's 24 E I / L^3 (README, Calibration of the shipped benches).
KP_CH5 = 8727.0


def sr4dof(m1, m2, m3, m4, m5, k4, k5, y1o, dm23, beam, zeta_rigid, zeta_csm, kp=None):
    a = 0.6 * y1o / beam["length_m"]                       # Eq. (2-6)
    m2 = m2 * (1.0 + dm23)
    inertia = beam["height_m"] * beam["thickness_m"] ** 3 / 12.0
    if kp is None:
        kp = 24.0 * beam["E"] * inertia / beam["length_m"] ** 3
    k12 = k24 = k13 = k35 = kp
    M = np.array([
        [m1 + m2 + m3 + m4 + m5, a * (m2 + m4 - m3 - m5), -a * (m2 + 2 * m4), a * (m3 + 2 * m5)],
        [a * (m2 + m4 - m3 - m5), m1 + a**2 * (m2 + m3 + m4 + m5), -a**2 * (m2 + 2 * m4), -a**2 * (m3 + 2 * m5)],
        [-a * (m2 + 2 * m4), -a**2 * (m2 + 2 * m4), m2 + a**2 * m2 + 4 * a**2 * m4, 0.0],
        [a * (m3 + 2 * m5), -a**2 * (m3 + 2 * m5), 0.0, m3 + a**2 * m3 + 4 * a**2 * m5],
    ])
    K = np.array([
        [k4 + k5, a * (k4 - k5), -2 * a * k4, 2 * a * k5],
        [a * (k4 - k5), k12 + k13 + a**2 * (k4 + k5), -2 * a**2 * k4 - k12, -2 * a**2 * k5 - k13],
        [-2 * a * k4, -2 * a**2 * k4 - k12, 4 * a**2 * k4 + k24 + k12, 0.0],
        [2 * a * k5, -2 * a**2 * k5 - k13, 0.0, 4 * a**2 * k5 + k13 + k35],
    ])
    q = np.array([1.0, a, -2 * a, 0.0])
    w2, phi = linalg.eigh(K, M)                             # mass-normalised
    w = np.sqrt(w2)
    rigid = 0 if abs(phi[0, 0]) >= abs(phi[0, 1]) else 1
    wr, wc = w[rigid], 0.5 * (w[2] + w[3])
    A = np.array([[1 / (2 * wr), wr / 2], [1 / (2 * wc), wc / 2]])
    ra, rb = np.linalg.solve(A, [zeta_rigid, zeta_csm])
    C = ra * M + rb * K
    zeta = ra / (2 * w) + rb * w / 2
    return M, K, C, q, w, zeta


def mechanics_ss(M, C, K, q):
    Minv = np.linalg.inv(M)
    A = np.block([[np.zeros((4, 4)), np.eye(4)], [-Minv @ K, -Minv @ C]])
    B = np.concatenate([np.zeros(4), Minv @ q]).reshape(8, 1)
    Cm = np.zeros((1, 8)); Cm[0, 0] = 1.0
    return A, B, Cm


def case(dm23, y1o_frac=0.08, rate_hz=5000.0, kf=11.12, bw_hz=1000.0):
    M, K, C, q, w, zeta = sr4dof(0.4, 0.06, 0.06, 0.8, 0.8, 36e3, 36e3, y1o_frac * L, dm23,
                                 BEAM_CH5, 0.009, 0.004, kp=KP_CH5)
    A, B, Cm = mechanics_ss(M, C, K, q)
    z, p, k = signal.ss2zpk(A, B, Cm, np.zeros((1, 1)))
    z = z[np.argsort(np.abs(z))]
    # Plant with amplifier: states [z, zdot, i], input current demand (A).
    wa = 2 * np.pi * bw_hz
    Aa = np.zeros((9, 9)); Aa[:8, :8] = A; Aa[:8, 8] = B[:, 0] * kf; Aa[8, 8] = -wa
    Ba = np.zeros((9, 1)); Ba[8, 0] = wa
    Ca = np.zeros((1, 9)); Ca[0, 0] = 1.0
    Ad, Bd, Cd, Dd, _ = signal.cont2discrete((Aa, Ba, Ca, np.zeros((1, 1))), 1.0 / rate_hz, method="zoh")
    f = np.logspace(np.log10(0.5), np.log10(400.0), 1200)
    zz = np.exp(1j * 2 * np.pi * f / rate_hz)
    h = np.array([(Cd @ np.linalg.solve(zi * np.eye(9) - Ad, Bd))[0, 0] for zi in zz])
    return {
        "mass_asymmetry": dm23,
        "operating_point_fraction_of_l": y1o_frac,
        "rate_hz": rate_hz,
        "natural_frequencies_hz": list(w / (2 * np.pi)),
        "damping_ratios": list(zeta),
        "zeros_hz": [[zi.real / (2 * np.pi), zi.imag / (2 * np.pi)] for zi in z],
        "frf": {
            "frequency_hz": list(f),
            "magnitude_m_per_a": list(np.abs(h)),
            "phase_deg": list(np.degrees(np.unwrap(np.angle(h)))),
        },
    }


if __name__ == "__main__":
    out = {"ch5_plus10": case(0.10), "ch5_minus10": case(-0.10)}
    path = os.path.join(os.path.dirname(os.path.abspath(__file__)), "sr4dof_reference.json")
    with open(path, "w") as fh:
        json.dump(out, fh, indent=1)
    for name, c in out.items():
        print(name, "f_n =", np.round(c["natural_frequencies_hz"], 3),
              "zeros =", np.round(c["zeros_hz"], 3).tolist())
