#!/usr/bin/env python3
"""NumPy implementation of `bench map`'s computation, for the comparison in
`benches/map.rs` (issue 14): the CNMP map of the Chapter 5 bench on an
N x N grid of operating point (0 ... 10 % of L) x mass asymmetry
(-10 % ... +10 %). Per cell, as `bench::analysis::map::map_cell` does:

* M, K, q of Eq. 2-5 (`matrices` of tests/data/analysis_reference.py,
  transcribed from the thesis);
* the generalised eigenproblem K phi = w^2 M phi through a Cholesky factor
  (phi^T M phi = I), the residues beta_i = phi_i[x1] (phi_i^T q) (Eq. 2-7);
* Rayleigh damping through the X rigid-body mode and the pair's mean;
* the undamped numerator N(u) = sum_i beta_i prod_{j!=i} (u + w_j^2) and
  its roots (np.roots), typed (complex u -> CMP-CNMP);
* the damped numerator sum_i beta_i prod_{j!=i} (s^2 + 2 z_j w_j s + w_j^2)
  and its roots, CMP-CNMP if a right-half-plane zero is complex.

Two implementations: `loop` (one cell at a time, as a script would write
it) and `batched` (numpy's stacked eigh / eigvals over all cells at once:
numpy at its best). Prints one JSON line: seconds and CNMP cell counts.

    python3 benches/map_numpy.py [N]      (N = 200 by default)
"""
import json
import pathlib
import sys
import time
import tomllib

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests" / "data"))
from analysis_reference import matrices  # noqa: E402

REAL_TOLERANCE = 1e-9  # bench_hal::model::ZeroType::REAL_TOLERANCE


def base_params():
    cfg = tomllib.loads((ROOT / "bench-config" / "sr4dof-ch5.toml").read_text())["plant"]
    beam = cfg["beam"]
    kp = cfg.get("parallelogram_stiffness_n_per_m")
    if kp is None:
        second_moment = beam["height_m"] * beam["thickness_m"] ** 3 / 12
        kp = 24 * beam["youngs_modulus_pa"] * second_moment / beam["length_m"] ** 3
    return {
        "m1_kg": cfg["m1_kg"], "m2_kg": cfg["m2_kg"], "m3_kg": cfg["m3_kg"],
        "m4_kg": cfg["m4_kg"], "m5_kg": cfg["m5_kg"],
        "k4_n_per_m": cfg["k4_n_per_m"], "k5_n_per_m": cfg["k5_n_per_m"],
        "parallelogram_stiffness_n_per_m": kp, "length_m": beam["length_m"],
        "zeta_rigid": cfg["damping"]["zeta_rigid"], "zeta_csm": cfg["damping"]["zeta_csm"],
    }


def rayleigh(w, phi, zr, zc):
    rigid = 0 if abs(phi[0, 0]) >= abs(phi[0, 1]) else 1
    wr, wc = w[rigid], 0.5 * (w[2] + w[3])
    a, b = np.linalg.solve([[1 / (2 * wr), wr / 2], [1 / (2 * wc), wc / 2]], [zr, zc])
    return a / (2 * w) + b * w / 2


def cell(p):
    M, K, q = matrices(p)
    Linv = np.linalg.inv(np.linalg.cholesky(M))
    lam, v = np.linalg.eigh(Linv @ K @ Linv.T)
    phi = Linv.T @ v
    w = np.sqrt(lam)
    beta = phi[0, :] * (q @ phi)
    zeta = rayleigh(w, phi, p["zeta_rigid"], p["zeta_csm"])
    n_u = np.zeros(4)
    n_s = np.zeros(7)
    for i in range(4):
        pu, ps = np.array([beta[i]]), np.array([beta[i]])
        for j in range(4):
            if j != i:
                pu = np.convolve(pu, [1.0, w[j] ** 2])
                ps = np.convolve(ps, [1.0, 2 * zeta[j] * w[j], w[j] ** 2])
        n_u += pu
        n_s += ps
    u = np.roots(n_u)
    s = np.roots(n_s)
    cnmp = bool(np.any(np.abs(u.imag) > REAL_TOLERANCE * np.abs(u)))
    rhp = s[s.real > 0]
    cnmp_damped = bool(np.any(np.abs(rhp.imag) > np.sqrt(REAL_TOLERANCE) * np.abs(rhp)))
    return cnmp, cnmp_damped


def grid(n):
    p = base_params()
    ops = np.linspace(0.0, 0.10 * p["length_m"], n)
    dms = np.linspace(-0.10, 0.10, n)
    return p, ops, dms


def run_loop(n):
    p, ops, dms = grid(n)
    t = time.perf_counter()
    counts = [0, 0]
    for dm in dms:
        for op in ops:
            c, d = cell({**p, "operating_point_m": op, "mass_asymmetry": dm})
            counts[0] += c
            counts[1] += d
    return time.perf_counter() - t, counts


def companion_roots(coeffs):
    """Roots of a stack of polynomials (rows, highest power first)."""
    n = coeffs.shape[1] - 1
    comp = np.zeros((coeffs.shape[0], n, n))
    comp[:, 0, :] = -coeffs[:, 1:] / coeffs[:, :1]
    comp[:, np.arange(1, n), np.arange(n - 1)] = 1.0
    return np.linalg.eigvals(comp)


def run_batched(n):
    p, ops, dms = grid(n)
    t = time.perf_counter()
    cells = [(op, dm) for dm in dms for op in ops]
    Ms, Ks, qs = zip(*(matrices({**p, "operating_point_m": op, "mass_asymmetry": dm})
                       for op, dm in cells))
    M, K, q = np.array(Ms), np.array(Ks), np.array(qs)
    Linv = np.linalg.inv(np.linalg.cholesky(M))
    lam, v = np.linalg.eigh(Linv @ K @ np.swapaxes(Linv, 1, 2))
    phi = np.swapaxes(Linv, 1, 2) @ v
    w = np.sqrt(lam)
    beta = phi[:, 0, :] * np.einsum("ck,ckm->cm", q, phi)
    rigid = np.where(np.abs(phi[:, 0, 0]) >= np.abs(phi[:, 0, 1]), 0, 1)
    wr = w[np.arange(len(cells)), rigid]
    wc = 0.5 * (w[:, 2] + w[:, 3])
    zr, zc = p["zeta_rigid"], p["zeta_csm"]
    det = (wc / wr - wr / wc) / 4
    ra = (zr * wc / 2 - zc * wr / 2) / det
    rb = (zc / (2 * wr) - zr / (2 * wc)) / det
    zeta = ra[:, None] / (2 * w) + rb[:, None] * w / 2
    n_u = np.zeros((len(cells), 4))
    n_s = np.zeros((len(cells), 7))
    for i in range(4):
        pu = np.zeros((len(cells), 4))
        ps = np.zeros((len(cells), 7))
        pu[:, 0] = 1.0
        ps[:, 0] = 1.0
        deg_u = deg_s = 0
        for j in range(4):
            if j == i:
                continue
            w2 = w[:, j] ** 2
            deg_u += 1
            for k in range(deg_u, 0, -1):
                pu[:, k] += w2 * pu[:, k - 1]
            b, c = 2 * zeta[:, j] * w[:, j], w2
            deg_s += 2
            for k in range(deg_s, 0, -1):
                ps[:, k] += b * ps[:, k - 1] + (c * ps[:, k - 2] if k >= 2 else 0.0)
        n_u += beta[:, i:i + 1] * pu
        n_s += beta[:, i:i + 1] * ps
    u = companion_roots(n_u)
    s = companion_roots(n_s)
    cnmp = np.any(np.abs(u.imag) > REAL_TOLERANCE * np.abs(u), axis=1)
    complex_rhp = (s.real > 0) & (np.abs(s.imag) > np.sqrt(REAL_TOLERANCE) * np.abs(s))
    cnmp_damped = np.any(complex_rhp, axis=1)
    return time.perf_counter() - t, [int(cnmp.sum()), int(cnmp_damped.sum())]


def main():
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 200
    t_loop, c_loop = run_loop(n)
    t_batched, c_batched = run_batched(n)
    print(json.dumps({
        "n": n, "numpy": np.__version__,
        "loop_s": t_loop, "loop_cnmp": c_loop,
        "batched_s": t_batched, "batched_cnmp": c_batched,
    }))


if __name__ == "__main__":
    main()
