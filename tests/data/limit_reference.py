#!/usr/bin/env python3
"""Independent reference of `bench design`'s performance limit (cvxpy with
its Clarabel backend, numpy, scipy; the SR4DoF model of make_reference.py).

For each case (a bench's lumped model, Eq. 2-5 of the thesis, its current
amplifier and loop rate) it builds the true discrete plant from scratch:
the mechanics and the first-order amplifier (force constant kf, -3 dB
bandwidth bw_hz) through a zero-order hold at rate_hz
(scipy.signal.cont2discrete, 'zoh'), times z^-d for the computation delay
of d periods. It then computes the largest performance bandwidth w* of
the weight W_P(s) = (s/M + w*)/s (Skogestad & Postlethwaite, Multivariable
Feedback Control, 2nd ed., Eq. 2.105) that any stabilising LTI controller
reaches: the plant is stable, so every such controller is C = Q/(1 - P Q)
with Q stable and S = 1 - P Q is affine in Q (Youla; Boyd & Barratt,
Linear Controller Design: Limits of Performance, 1991). On a dense grid
of lines up to 0.98 of the Nyquist frequency,

    gamma(w*) = min_Q max_k |W_P(j w_k)| |1 - P(z_k) Q(z_k)|

is a second-order cone program; the limit is the w* where gamma = 1, by
bisection. Two bounds hold every Q, as in `bench design` (LoopBounds):
the control effort |K S| = |Q| <= peak_current_a / step_m on every line
(a setpoint step's edge within the coil's peak current), and
|T| = |P Q| <= edge_t_max from edge_fraction * band_top_hz up (the loop
does not rely on the plant above the default chirp's highest coherent
line). Q is a real combination of an FIR of `taps` taps and, as a
Kautz-like set of partial fractions, poles at e^{sT} for every zero s of
the true mechanics below the Nyquist frequency (a right-half-plane one
mirrored into the left) and at n_log real and n_log complex (zeta 0.5)
poles spaced in log frequency: a basis chosen here,
not the one of the Rust code. The program is solved in the basis' own
orthonormal coordinates on the lines (the SVD of the stacked real and
imaginary parts of P B, singular values below 1e-12 of the largest
dropped): the partial fractions are nearly collinear there, and in the raw
coefficients the interior point stopped short of the optimum by 3-12 %
(a richer basis gave a *lower* limit, which at the optimum cannot be). In
these coordinates the limit grows with the basis as it must and has
converged: held-out a without bounds 1803 / 1805 / 1810 / 1812 rad/s with
(taps, n_log) = (30, 16) / (60, 16) / (30, 32) / (60, 32); the stored
values are of (60, 32). It also reports the analytic bound of each
right-half-plane zero z of the continuous mechanics, |1/M + w*/z| <= 1
(Skogestad & Postlethwaite Eq. 5.49).

Input (JSON): {"cases": [{"name", "m_kg": [m1..m5], "k4_n_per_m",
"k5_n_per_m", "kp_n_per_m", "y1o_fraction_of_l", "mass_asymmetry",
"zeta_rigid", "zeta_csm", "force_constant_n_per_a", "amplifier_bandwidth_hz",
"rate_hz", "delay_periods", "s_max", "peak_current_a", "step_m",
"band_top_hz", "edge_fraction", "edge_t_max"}]}
Optional "workspaces": [{"name", "base" (a case's name),
"y1o_fraction_of_l": [...], "mass_asymmetry"}]: the base case at each
operating point (a campaign's cells); its joint limit has one Q for every
cell's true plant, each cell's lines and bounds in one program (issue 41,
item 5: "the same problem with all inputs' constraints"), with 300 lines
a cell.
Output (JSON): {"cases": [{"name", "limit_rad_s", "infeasible_above_rad_s",
"limit_without_bounds_rad_s" (the same problem without the two bounds),
"rhp_zero_bounds": [{"re_hz", "im_hz", "bound_rad_s"}], "zeros_hz"}],
"workspaces": [{"name", "limit_rad_s", "infeasible_above_rad_s",
"cells": [{"name", "y1o_fraction_of_l", "limit_rad_s" (the cell's own)}]}]}

Run: python3 tests/data/limit_reference.py cases.json [out.json]
Dependencies: pip install cvxpy clarabel 'control>=0.10,<0.11' (numpy, scipy).
"""
import json
import os
import sys

import cvxpy as cp
import numpy as np
from scipy import signal

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from make_reference import BEAM_CH5, L, mechanics_ss, sr4dof  # noqa: E402


def plant(c):
    m = c["m_kg"]
    M, K, C, q, w, zeta = sr4dof(m[0], m[1], m[2], m[3], m[4], c["k4_n_per_m"], c["k5_n_per_m"],
                                 c["y1o_fraction_of_l"] * L, c["mass_asymmetry"], BEAM_CH5,
                                 c["zeta_rigid"], c["zeta_csm"], kp=c["kp_n_per_m"])
    A, B, Cm = mechanics_ss(M, C, K, q)
    zeros, _, _ = signal.ss2zpk(A, B, Cm, np.zeros((1, 1)))
    wa = 2 * np.pi * c["amplifier_bandwidth_hz"]
    Aa = np.zeros((9, 9)); Aa[:8, :8] = A; Aa[:8, 8] = B[:, 0] * c["force_constant_n_per_a"]; Aa[8, 8] = -wa
    Ba = np.zeros((9, 1)); Ba[8, 0] = wa
    Ca = np.zeros((1, 9)); Ca[0, 0] = 1.0
    T = 1.0 / c["rate_hz"]
    Ad, Bd, Cd, _, _ = signal.cont2discrete((Aa, Ba, Ca, np.zeros((1, 1))), T, method="zoh")
    d = c["delay_periods"]

    def at(z):
        return np.array([(Cd @ np.linalg.solve(zi * np.eye(9) - Ad, Bd))[0, 0] * zi ** (-d) for zi in z])

    return at, zeros, w, T


def basis(T, zeros, taps, lowest, n_log=16):
    """Columns: the basis functions' values at z (a function of z)."""
    nyq = np.pi / T
    poles = []
    for zi in zeros:
        # Each zero of the mechanics below the Nyquist frequency, mirrored
        # into the left half plane, as a pole of Q: e^{sT}.
        if not np.isfinite(zi) or abs(zi) >= nyq or zi.imag < 0:
            continue
        poles.append(np.exp(complex(-abs(zi.real), zi.imag) * T))
    for f in np.logspace(np.log10(lowest), np.log10(0.8 * nyq), n_log):
        poles.append(np.exp(-f * T))
        poles.append(np.exp((-0.5 * f + 1j * f * np.sqrt(0.75)) * T))

    def cols(z):
        out = [z ** (-k) for k in range(taps)]
        for p in poles:
            if abs(p.imag) < 1e-12:
                out.append((1 - p.real) / (z - p.real))
            else:
                g = 1 - abs(p)
                a, b = 1 / (z - p), 1 / (z - np.conj(p))
                out.append(g * (a + b))
                out.append(1j * g * (a - b))
        return np.array(out).T

    return cols


def rhp_bound(z, M):
    u = 1 / z
    a, b, c = abs(u) ** 2, 2 * u.real / M, 1 / M ** 2 - 1
    return (-b + np.sqrt(b * b - 4 * a * c)) / (2 * a)


def lines_of(c, T, wn, zeros, lines):
    nyq = np.pi / T
    w = np.logspace(np.log10(2 * np.pi * 0.5), np.log10(0.98 * nyq), lines)
    # Every resonance and antiresonance resolved: 41 lines over +-5 % of each.
    near = [abs(x) for x in list(wn) + list(zeros) if 0 < abs(x) < 0.98 * nyq]
    for x in near:
        w = np.concatenate([w, x * np.linspace(0.95, 1.05, 41)])
    return np.unique(w)


def joint_limit(cs, taps=60, lines=600, n_log=32, bounds=True):
    """The largest w* one Q reaches on every plant of `cs` at once (each
    plant's lines and bounds in one program): for one case its limit, for
    a workspace the limit of "the same problem with all inputs'
    constraints" (issue 41, item 5). Returns (w*, infeasible above,
    [zeros of each plant])."""
    plants = [plant(c) for c in cs]
    T = plants[0][3]
    M = cs[0]["s_max"]
    nyq = np.pi / T
    all_zeros = np.concatenate([p[1] for p in plants])
    cols = basis(T, all_zeros, taps, 1.0, n_log)
    rows_pb, rows_b, edges, ws = [], [], [], []
    scale = None
    for c, (at, zeros, wn, _) in zip(cs, plants):
        w = lines_of(c, T, wn, zeros, lines)
        z = np.exp(1j * w * T)
        P = at(z)
        if scale is None:
            scale = abs(P[0])
        B = cols(z)
        rows_pb.append((P / scale)[:, None] * B)
        rows_b.append(B)
        edges.append(w >= 2 * np.pi * c["edge_fraction"] * c["band_top_hz"])
        ws.append(w)
    PB, B = np.vstack(rows_pb), np.vstack(rows_b)
    edge, w = np.concatenate(edges), np.concatenate(ws)
    # The coefficients x = V y in orthonormal coordinates: P B V has
    # orthonormal (stacked real) columns on the lines.
    U, S, Vt = np.linalg.svd(np.vstack([PB.real, PB.imag]), full_matrices=False)
    keep = S > 1e-12 * S[0]
    V = Vt[keep].T / S[keep]
    PB, B = PB @ V, B @ V
    x = cp.Variable(V.shape[1])
    wt = cp.Parameter(len(w), nonneg=True)
    s = 1 - PB @ x
    t = cp.Variable()
    cons = [cp.multiply(wt, cp.abs(s)) <= t]
    if bounds:
        # Q in A/m is (B x)/scale: |Q| <= I_pk/|r| on every line (Q is one
        # function: the first plant's lines carry it).
        n0 = len(ws[0])
        cons.append(cp.abs(B[:n0] @ x) <= cs[0]["peak_current_a"] / abs(cs[0]["step_m"]) * scale)
        cons.append(cp.abs(PB[edge] @ x) <= cs[0]["edge_t_max"])
    prob = cp.Problem(cp.Minimize(t), cons)

    def gamma(ws_):
        wt.value = np.abs(1j * w / M + ws_) / w
        prob.solve(solver=cp.CLARABEL)
        if prob.status not in ("optimal", "optimal_inaccurate"):
            raise RuntimeError(f"cvxpy: {prob.status} at w* = {ws_}")
        # The Q found, evaluated exactly: its own certificate.
        return float(np.max(wt.value * np.abs(1 - PB @ x.value)))

    lo, hi = 0.0, nyq
    while hi - lo > 2e-3 * hi:
        mid = np.sqrt(lo * hi) if lo > 0 else hi / 8
        if gamma(mid) <= 1:
            lo = mid
        else:
            hi = mid
    return lo, hi, [p[1] for p in plants]


def limit(c, taps=60, lines=600, n_log=32):
    M = c["s_max"]
    lo, hi, (zeros,) = joint_limit([c], taps, lines, n_log)
    nyq = np.pi / (1.0 / c["rate_hz"])
    zeros = [zi for zi in zeros if abs(zi) < 1e6 * nyq]  # drop the numerically infinite
    zero_bounds = [{"re_hz": zi.real / (2 * np.pi), "im_hz": zi.imag / (2 * np.pi),
                    "bound_rad_s": rhp_bound(zi, M)} for zi in zeros if zi.real > 0 and zi.imag >= 0]
    return {"name": c["name"], "limit_rad_s": lo, "infeasible_above_rad_s": hi,
            "limit_without_bounds_rad_s": joint_limit([c], taps, lines, n_log, bounds=False)[0],
            "rhp_zero_bounds": zero_bounds,
            "zeros_hz": [[zi.real / (2 * np.pi), zi.imag / (2 * np.pi)] for zi in zeros]}


def workspace(ws, cases, taps=60, lines=300, n_log=32):
    """A workspace: the base case at each operating point of the list (the
    cells of a campaign over the operating point), its joint limit (one Q
    for every cell) and each cell's own limit (with the bounds): no
    single controller's w* on a cell passes that cell's own limit."""
    base = next(c for c in cases if c["name"] == ws["base"])
    cells = []
    for y in ws["y1o_fraction_of_l"]:
        c = dict(base)
        c["y1o_fraction_of_l"] = y
        c["mass_asymmetry"] = ws["mass_asymmetry"]
        c["name"] = f"{ws['name']} at {100 * y:g} % of L"
        cells.append(c)
    lo, hi, _ = joint_limit(cells, taps, lines, n_log)
    own = []
    for c in cells:
        own.append({"name": c["name"], "y1o_fraction_of_l": c["y1o_fraction_of_l"],
                    "limit_rad_s": joint_limit([c], taps, lines, n_log)[0]})
        print(c["name"], "done", file=sys.stderr, flush=True)
    return {"name": ws["name"], "limit_rad_s": lo, "infeasible_above_rad_s": hi, "cells": own}


if __name__ == "__main__":
    spec = json.load(open(sys.argv[1]))
    cases = spec["cases"]
    out = {"cases": [], "workspaces": []}
    for c in cases:
        out["cases"].append(limit(c))
        print(c["name"], "done", file=sys.stderr, flush=True)
    for ws in spec.get("workspaces", []):
        out["workspaces"].append(workspace(ws, cases))
        print(ws["name"], "done", file=sys.stderr, flush=True)
    text = json.dumps(out, indent=1)
    if len(sys.argv) > 2:
        open(sys.argv[2], "w").write(text)
    else:
        print(text)
