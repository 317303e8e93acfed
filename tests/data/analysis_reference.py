#!/usr/bin/env python3
"""Independent reference for `bench::analysis` (issue 14): random SR4DoF
benches around the Chapter 5 bench, computed with numpy/scipy from the
thesis' Eq. 2-5 (transcribed here from the thesis, not from the Rust code):

* natural frequencies and mass-normalised modes from scipy.linalg.eigh(K, M);
* modal residues alpha_i = (c^T phi_i)(phi_i^T Q) (Eq. 2-7 / 4-15);
* the zeros of the damped and the undamped force -> x1 transfer function
  from the state-space model (scipy.signal.ss2zpk), not from the modal sum;
* their types (thesis 3.2.1).

Rayleigh damping C = a M + b K fitted as bench documents it
(bench_hal::model): zeta_rigid at the X rigid-body mode (of modes 1 and 2,
the one with the larger |x1| in its mass-normalised shape) and zeta_csm at
the mean natural frequency of modes 3 and 4.

Run from the repository root:  python3 tests/data/analysis_reference.py
It writes tests/data/analysis_reference.json (numpy 2, scipy 1.17 here).
"""
import json
import pathlib
import tomllib

import numpy as np
import scipy.linalg

HERE = pathlib.Path(__file__).resolve().parent
ROOT = HERE.parent.parent
N_BENCHES = 60
SEED = 14


def matrices(p):
    """M, K, Q of Eq. 2-5 (thesis Chapter 2)."""
    L = p["length_m"]
    a = 0.6 * p["operating_point_m"] / L  # Eq. 2-6
    m1, m3, m4, m5 = p["m1_kg"], p["m3_kg"], p["m4_kg"], p["m5_kg"]
    m2 = p["m2_kg"] * (1.0 + p["mass_asymmetry"])
    k4, k5 = p["k4_n_per_m"], p["k5_n_per_m"]
    k12 = k24 = k13 = k35 = p["parallelogram_stiffness_n_per_m"]
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
    Q = np.array([1.0, a, -2 * a, 0.0])
    return M, K, Q


def zero_type(s, partner_of=None):
    """Type of a zero s (rad/s) of a real structural transfer function."""
    if abs(s.imag) <= 1e-6 * abs(s):
        return "RMP-RNMP" if s.real != 0 else "MMP"
    if abs(s.real) <= 1e-6 * abs(s):
        return "MMP"
    return "CMP-CNMP"


def typed_damped(zs):
    out = []
    rhp = [w for w in zs if w.real > 0]
    for s in zs:
        if s.real > 0:
            kind = "CMP-CNMP" if abs(s.imag) > 1e-4 * abs(s) else "RMP-RNMP"
        else:
            partner = [w for w in rhp if abs(-np.conj(w) - s) <= 0.1 * abs(s)]
            if partner:
                w = partner[0]
                kind = "CMP-CNMP" if abs(w.imag) > 1e-4 * abs(w) else "RMP-RNMP"
            else:
                kind = "MMP"
        out.append([s.real, s.imag, kind])
    return out


def tf_zeros(M, K, C, Q):
    """Invariant zeros of the state-space model: the finite generalised
    eigenvalues of the Rosenbrock pencil ([[A, B], [C, 0]], diag(I, 0))."""
    n = M.shape[0]
    Minv = np.linalg.inv(M)
    A = np.block([[np.zeros((n, n)), np.eye(n)], [-Minv @ K, -Minv @ C]])
    B = np.concatenate([np.zeros(n), Minv @ Q]).reshape(-1, 1)
    Cout = np.zeros((1, 2 * n))
    Cout[0, 0] = 1.0
    P = np.block([[A, B], [Cout, np.zeros((1, 1))]])
    E = scipy.linalg.block_diag(np.eye(2 * n), np.zeros((1, 1)))
    z = scipy.linalg.eigvals(P, E)
    z = z[np.isfinite(z) & (np.abs(z) < 1e8)]
    return sorted(z, key=abs)


def bench(p):
    M, K, Q = matrices(p)
    lam, phi = scipy.linalg.eigh(K, M)  # phi^T M phi = I
    w = np.sqrt(lam)
    c = np.array([1.0, 0.0, 0.0, 0.0])
    residues = [(c @ phi[:, i]) * (phi[:, i] @ Q) for i in range(4)]
    rigid = 0 if abs(phi[0, 0]) >= abs(phi[0, 1]) else 1
    wr, wc = w[rigid], 0.5 * (w[2] + w[3])
    zr, zc = p["zeta_rigid"], p["zeta_csm"]
    a, b = np.linalg.solve([[1 / (2 * wr), wr / 2], [1 / (2 * wc), wc / 2]], [zr, zc])
    C = a * M + b * K
    und = tf_zeros(M, K, np.zeros_like(M), Q)
    damp = tf_zeros(M, K, C, Q)
    return {
        "frequencies_hz": list(w / (2 * np.pi)),
        "residues_per_kg": residues,
        "zeros_undamped": [[s.real, s.imag, zero_type(s)] for s in und],
        "zeros_damped": typed_damped(damp),
    }


def main():
    cfg = tomllib.loads((ROOT / "bench-config" / "sr4dof-ch5.toml").read_text())["plant"]
    beam = cfg["beam"]
    I = beam["height_m"] * beam["thickness_m"] ** 3 / 12
    kp0 = 24 * beam["youngs_modulus_pa"] * I / beam["length_m"] ** 3
    rng = np.random.default_rng(SEED)
    out = []
    for _ in range(N_BENCHES):
        f = lambda: rng.uniform(0.75, 1.25)  # noqa: E731
        p = {
            "m1_kg": cfg["m1_kg"] * f(),
            "m2_kg": cfg["m2_kg"] * f(),
            "m3_kg": cfg["m3_kg"] * f(),
            "m4_kg": cfg["m4_kg"] * f(),
            "m5_kg": cfg["m5_kg"] * f(),
            "k4_n_per_m": cfg["k4_n_per_m"] * f(),
            "k5_n_per_m": cfg["k5_n_per_m"] * f(),
            "parallelogram_stiffness_n_per_m": kp0 * f(),
            "length_m": beam["length_m"],
            "operating_point_m": rng.uniform(0.0, 0.10) * beam["length_m"],
            "mass_asymmetry": rng.uniform(-0.15, 0.15),
            "zeta_rigid": cfg["damping"]["zeta_rigid"],
            "zeta_csm": cfg["damping"]["zeta_csm"],
        }
        out.append({"params": p, **bench(p)})
    (HERE / "analysis_reference.json").write_text(json.dumps(out, indent=1) + "\n")
    print(f"wrote {len(out)} benches")


if __name__ == "__main__":
    main()
