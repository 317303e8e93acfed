#!/usr/bin/env python3
"""Independent loop-margin reference for `bench` controllers (python-control).

Recomputes, from scratch and without any of the Rust code, the margins of
the loop a `[controller.NAME]` closes around the SR4DoF model, so that the
tests can check what `bench` designs and checks (issue 27) against a second
implementation.

Input (argv[1], JSON): {"cases": [case, ...]} with each case

    {"name": str,
     "plant": the [plant] table as bench serialises it (m1_kg..m5_kg,
              k4_n_per_m, k5_n_per_m, operating_point_m, mass_asymmetry,
              parallelogram_stiffness_n_per_m (optional), beam {length_m,
              height_m, thickness_m, youngs_modulus_pa}, damping {zeta_rigid,
              zeta_csm}; disturbance is ignored),
     "actuator": {"force_constant_n_per_a", "bandwidth_hz", ...},
     "rate_hz": loop rate f_s = 1/T, Hz,
     "computation_delay_s": tau, s (default 0),
     "link_delay_periods": d, whole loop periods of pure delay the link
              adds (EtherCAT's process data: 1; default 0),
     "controller": a [controller.NAME] table (error_unit "m"|"um"|"nm",
              form "monic"|"unity_dc", gain, integrators, real_zeros_rad_s,
              real_poles_rad_s, complex_zeros / complex_poles
              [{omega_rad_s, zeta}]; discretization is ignored: the
              reference takes the continuous design as the specification),
     "hold": bool (default true), "amplifier": bool (default true),
     "discrete_margins": bool (default false: the margins of the sampled
              loop too, see `discrete` below; they double the time)}

Output (stdout, or argv[2]): {"python_control": version, "cases": [...]},
per case the figures below. Run:

    python3 tests/data/loop_reference.py cases.json [out.json]

Needs numpy, scipy and python-control 0.10 (`pip install 'control>=0.10,<0.11'`;
`.ci/run` installs it into a venv and `tests/common/loop_reference.rs` runs
this script with `$BENCH_PYTHON`, else `python3`).

The loop (negative feedback, error in metres):

    L(s) = C(s) * u * k_f * G(s) * A(s) * H(s) * exp(-s tau) * exp(-s d T)

- G(s): force (N) -> x1 (m) of Eq. (2-5), M z'' + C z' + K z = q P, built by
  `make_reference.sr4dof` (this directory's independent model reference:
  the thesis' mass and stiffness matrices, Rayleigh damping C = aM + bK
  fitted to zeta_rigid on the X rigid-body mode and zeta_csm at the mean of
  the closely spaced pair) as a `control.ss`.
- A(s) = w_a / (s + w_a), w_a = 2 pi bandwidth_hz: the current amplifier
  (left out with "amplifier": false). k_f: force constant, N/A.
- C(s) = g s^-n prod(s + z_i) / prod(s + p_j) prod(s^2 + 2 zeta w s + w^2)^(+-1)
  (Eq. 6-6/6-7 in general form); "unity_dc" divides every factor except the
  integrators by its value at s = 0. u: error units per metre (1, 1e6, 1e9).
- H(s) = (1 - exp(-sT)) / (sT): the zero-order hold, exact in the frequency
  domain (left out with "hold": false). exp(-s tau): computation delay.
  exp(-s d T): the link's pure delay of d periods (sampled: z^-d, the
  same on the unit circle).

Figures (Skogestad & Postlethwaite, Multivariable Feedback Control, 2nd ed.,
§2.4.3: gain, phase and modulus margins and the peak M_S of |S|; §2.4.5:
the bandwidth w_B where |S| first crosses 1/sqrt(2) from below), all from
the exact L(jw) on a log grid of 20 001 points from 0.1 rad/s to 0.999 x
the Nyquist frequency pi/T (the grid of `bench`'s own check), through
python-control's own `frequency_response`, an interpolating `frd` and
`stability_margins` (its FRD method: brentq on a cubic spline through the
grid; https://python-control.readthedocs.io/en/stable/generated/control.stability_margins.html):

- crossovers_rad_s: every gain crossover |L| = 1, ascending; with each,
  phase_margins_deg = 180 + arg L, wrapped to (-180, 180];
- phase_crossovers_rad_s: every crossing of the negative real axis, with
  gain_margins_db = -20 log10 |L| there; gain_margin_db is the smallest of
  those with |L| < 1 (the gain increase the loop tolerates; null if none,
  as `bench`'s loop check reports it), gain_margin_at_rad_s where;
- sensitivity_peak = ||S||inf = max |1 / (1 + L)| = 1 / (modulus margin),
  and where (the refined minima of |1 + L| of `stability_margins`, checked
  against the grid's maximum);
- sensitivity_bandwidth_rad_s, w_B: the lowest frequency at which |S|
  reaches 1/sqrt(2) (-3 dB) from below (brentq on the exact |S|);
- stable_continuous_pade, largest_real_part_rad_s: the closed-loop poles
  (`control.feedback`, `control.poles`) of the continuous loop with the
  total delay theta = T/2 (the hold, to first order: H(s) ~ exp(-sT/2)) +
  tau + d T replaced by a Padé approximant (`control.pade`) of the lowest order
  whose phase is within 1 degree of exp(-jw theta) up to the Nyquist
  frequency (pade_order; 0 when theta = 0). The hold's sinc magnitude
  (-3.9 dB at Nyquist) is left out of this check; the discrete one has it;
- stable_discrete, largest_pole_magnitude (only with the hold): the exact
  sampled loop: the plant k_f G A discretised with a zero-order hold
  (`control.sample_system`, 'zoh'), the controller with Tustin
  (`control.sample_system`, 'tustin', no pre-warping), the computation
  delay tau = (k + f) T as z^-k, the link's delay as a further discrete
  z^-d (`control.tf([1], [1, 0, ..., 0], T)`), and, for a fractional part f, the
  zero-order-hold plant with that input delay (Phi, Gamma_0 =
  int_0^{(1-f)T} e^{As} ds B, Gamma_1 = e^{A(1-f)T} int_0^{fT} e^{As} ds B:
  Åström & Wittenmark, Computer-Controlled Systems, 3rd ed., ch. 2,
  sampling a system with a time delay), closed with `control.feedback`,
  stable when every pole has |z| < 1;
- discrete (with the hold and "discrete_margins": true, else null): the
  margins above of that sampled loop L(e^{jwT}) on the same grid, the loop
  `bench`'s own check evaluates (but with a Tustin controller where `bench`
  may run another discretisation).

Cost: about 1 s per case and CPU (2 s with discrete margins), mostly the
spline evaluations of `stability_margins`; the cases run on all CPUs.
"""
import json
import math
import os
import sys
from concurrent.futures import ProcessPoolExecutor

try:
    import numpy as np
    import scipy
    from scipy import linalg, optimize
    import control as ct
except ImportError as e:  # pragma: no cover - the message is the point
    sys.stderr.write(
        "loop_reference.py needs numpy, scipy and python-control 0.10: "
        f"{e}\ninstall with `pip install 'control>=0.10,<0.11'` (brings numpy "
        "and scipy), or run .ci/run, which makes a venv and sets BENCH_PYTHON\n"
    )
    sys.exit(3)

_ver = tuple(int(x) for x in ct.__version__.split(".")[:2])
if _ver < (0, 10):
    sys.stderr.write(
        f"loop_reference.py needs python-control >= 0.10, found {ct.__version__}: "
        "pip install 'control>=0.10,<0.11'\n"
    )
    sys.exit(3)

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from make_reference import mechanics_ss, sr4dof  # noqa: E402

PER_METRE = {"m": 1.0, "um": 1e6, "nm": 1e9}
GRID_POINTS = 20_001
PADE_PHASE_ERROR_DEG = 1.0


def force_to_x1(plant):
    """G(s): actuator force (N) -> x1 (m), `control.ss`, 8 states."""
    b = plant["beam"]
    beam = dict(length_m=b["length_m"], height_m=b["height_m"],
                thickness_m=b["thickness_m"], E=b["youngs_modulus_pa"])
    M, K, C, q, _w, _zeta = sr4dof(
        plant["m1_kg"], plant["m2_kg"], plant["m3_kg"], plant["m4_kg"], plant["m5_kg"],
        plant["k4_n_per_m"], plant["k5_n_per_m"], plant["operating_point_m"],
        plant["mass_asymmetry"], beam,
        plant["damping"]["zeta_rigid"], plant["damping"]["zeta_csm"],
        kp=plant.get("parallelogram_stiffness_n_per_m"),
    )
    A, B, Cm = mechanics_ss(M, C, K, q)
    return ct.ss(A, B, Cm, np.zeros((1, 1)))


def controller_ss(c):
    """C(s), A per error unit, as a series of proper first- and second-order
    `ss` blocks (each zero factor with a pole factor: no high-order
    polynomial is ever formed)."""
    unity = c["form"] == "unity_dc"
    rz = [ct.tf([1.0, z], [z if unity else 1.0]) for z in c.get("real_zeros_rad_s", [])]
    rp = [ct.tf([1.0], [1.0, 0.0])] * int(c.get("integrators", 0))
    rp += [ct.tf([p if unity else 1.0], [1.0, p]) for p in c.get("real_poles_rad_s", [])]
    cz, cp = [], []
    for pair in c.get("complex_zeros", []):
        w, zeta = pair["omega_rad_s"], pair["zeta"]
        cz.append(ct.tf([1.0, 2 * zeta * w, w * w], [w * w if unity else 1.0]))
    for pair in c.get("complex_poles", []):
        w, zeta = pair["omega_rad_s"], pair["zeta"]
        cp.append(ct.tf([w * w if unity else 1.0], [1.0, 2 * zeta * w, w * w]))
    blocks = []
    while cz and cp:
        blocks.append(cz.pop(0) * cp.pop(0))
    while rz and rp:
        blocks.append(rz.pop(0) * rp.pop(0))
    # What is left is proper only in groups: two real zeros over a complex
    # pole pair, or a complex zero pair over two real poles.
    while rz:
        if not cp:
            raise ValueError("improper controller: more zeros than poles")
        b = cp.pop(0) * rz.pop(0)
        if rz:
            b = b * rz.pop(0)
        blocks.append(b)
    while cz:
        if len(rp) < 2:
            raise ValueError("improper controller: more zeros than poles")
        blocks.append(cz.pop(0) * rp.pop(0) * rp.pop(0))
    blocks += cp + rp
    sys_ = ct.ss([], [], [], [[c["gain"]]])
    for b in blocks:
        sys_ = sys_ * ct.ss(b)
    return sys_


def amplifier(actuator):
    wa = 2 * math.pi * actuator["bandwidth_hz"]
    return ct.ss(ct.tf([wa], [1.0, wa]))


def grid(period_s):
    top = 0.999 * math.pi / period_s
    return np.geomspace(0.1, top, GRID_POINTS)


def wrap180(d):
    w = np.remainder(np.asarray(d) + 180.0, 360.0) - 180.0
    return np.where(w <= -180.0, w + 360.0, w)


def margins(omega, response, exact):
    """The figures of L given on `omega` (`response`, complex) and as an
    exact function `exact(w) -> complex array` for the bandwidth."""
    frd = ct.frd(response, omega, smooth=True)
    gm, pm, sm, wpc, wgc, wms = ct.stability_margins(frd, returnall=True)
    gm, pm, sm = np.atleast_1d(gm), np.atleast_1d(pm), np.atleast_1d(sm)
    wpc, wgc, wms = np.atleast_1d(wpc), np.atleast_1d(wgc), np.atleast_1d(wms)
    order = np.argsort(wgc)
    crossovers = wgc[order]
    pms = wrap180(pm[order])
    # phase crossovers on the negative real axis only
    l180 = frd(1j * wpc) if wpc.size else np.array([])
    keep = np.real(l180) < 0 if wpc.size else np.array([], dtype=bool)
    wpc, gm = wpc[keep], gm[keep]
    order = np.argsort(wpc)
    wpc, gm = wpc[order], gm[order]
    gms_db = 20 * np.log10(gm)
    up = gm > 1.0
    gm_db = float(np.min(gms_db[up])) if up.any() else None
    gm_at = float(wpc[up][np.argmin(gms_db[up])]) if up.any() else None
    # sensitivity peak: python-control's refined minima of |1 + L|, and the grid
    s_grid = 1.0 / np.abs(1.0 + response)
    i = int(np.argmax(s_grid))
    peak, peak_at = float(s_grid[i]), float(omega[i])
    if sm.size:
        j = int(np.argmin(sm))
        if 1.0 / sm[j] > peak:
            peak, peak_at = float(1.0 / sm[j]), float(wms[j])
    # sensitivity bandwidth: first |S| = 1/sqrt(2) from below
    target = 1.0 / math.sqrt(2.0)
    above = np.nonzero(s_grid >= target)[0]
    w_b = None
    if above.size and above[0] > 0:
        k = above[0]
        f = lambda w: 1.0 / abs(1.0 + exact(np.array([w]))[0]) - target  # noqa: E731
        w_b = float(optimize.brentq(f, omega[k - 1], omega[k], xtol=1e-12, rtol=1e-12))
    return {
        "crossovers_rad_s": [float(w) for w in crossovers],
        "phase_margins_deg": [float(p) for p in pms],
        "phase_crossovers_rad_s": [float(w) for w in wpc],
        "gain_margins_db": [float(g) for g in gms_db],
        "gain_margin_db": gm_db,
        "gain_margin_at_rad_s": gm_at,
        "sensitivity_peak": peak,
        "sensitivity_peak_at_rad_s": peak_at,
        "modulus_margin": 1.0 / peak,
        "sensitivity_bandwidth_rad_s": w_b,
    }


def pade_for(theta, omega):
    """Lowest-order Padé approximant of exp(-s theta) whose phase is within
    PADE_PHASE_ERROR_DEG of -w theta on `omega`; (order, ss)."""
    if theta <= 0.0:
        return 0, ct.ss([], [], [], [[1.0]])
    for n in range(1, 21):
        num, den = ct.pade(theta, n)
        p = ct.tf(num, den)
        ph = np.unwrap(np.angle(p(1j * omega)))
        if np.max(np.abs(np.degrees(ph + omega * theta))) < PADE_PHASE_ERROR_DEG:
            return n, ct.ss(p)
    raise ValueError(f"no Padé approximant of {theta} s within 1° up to Nyquist")


def zoh_with_input_delay(plant, period_s, frac):
    """The zero-order-hold sampled `plant` (continuous ss) with its input
    delayed by frac * T, 0 < frac < 1 (one extra state: the previous input)."""
    A, B, C, D = (np.asarray(plant.A), np.asarray(plant.B), np.asarray(plant.C),
                  np.asarray(plant.D))
    n = A.shape[0]

    def phi_gamma(h):
        aug = np.zeros((n + 1, n + 1))
        aug[:n, :n], aug[:n, n:] = A * h, B * h
        e = linalg.expm(aug)
        return e[:n, :n], e[:n, n:]

    phi, _ = phi_gamma(period_s)
    phi_late, gamma0 = phi_gamma((1.0 - frac) * period_s)
    _, gamma_early = phi_gamma(frac * period_s)
    gamma1 = phi_late @ gamma_early
    Ad = np.zeros((n + 1, n + 1))
    Ad[:n, :n], Ad[:n, n:] = phi, gamma1
    Bd = np.zeros((n + 1, 1))
    Bd[:n], Bd[n, 0] = gamma0, 1.0
    Cd = np.hstack([C, np.zeros((1, 1))])
    return ct.ss(Ad, Bd, Cd, D, period_s)


def run_case(case):
    t = 1.0 / case["rate_hz"]
    tau = float(case.get("computation_delay_s", 0.0))
    d_link = int(case.get("link_delay_periods", 0))
    hold = bool(case.get("hold", True))
    amp = bool(case.get("amplifier", True))
    c = case["controller"]
    per_metre = PER_METRE[c["error_unit"]]
    kf = case["actuator"]["force_constant_n_per_a"]

    g = force_to_x1(case["plant"])
    plant = g * kf
    if amp:
        plant = plant * amplifier(case["actuator"])
    ctrl = controller_ss(c) * per_metre
    rational = ctrl * plant

    omega = grid(t)

    def exact(w):
        s = 1j * w
        l = ct.frequency_response(rational, w).complex.reshape(-1)
        if hold:
            l = l * (-np.expm1(-s * t)) / (s * t)
        return l * np.exp(-s * (tau + d_link * t))

    out = {"name": case["name"]}
    out.update(margins(omega, exact(omega), exact))

    theta = (t / 2.0 if hold else 0.0) + tau + d_link * t
    order, pade = pade_for(theta, omega)
    cl = ct.feedback(rational * pade, 1)
    poles = ct.poles(cl)
    out["pade_order"] = order
    out["pade_delay_s"] = theta
    out["largest_real_part_rad_s"] = float(np.max(poles.real))
    out["stable_continuous_pade"] = bool(np.all(poles.real < 0.0))

    if hold:
        d = tau / t
        k = int(math.floor(d + 1e-9))
        frac = d - k
        if frac < 1e-9:
            pd = ct.sample_system(plant, t, method="zoh")
        else:
            pd = zoh_with_input_delay(plant, t, frac)
        if k:
            pd = pd * ct.ss(ct.tf([1.0], [1.0] + [0.0] * k, t))
        if d_link:
            # The link's pure delay: z^-d on the plant's input.
            pd = pd * ct.ss(ct.tf([1.0], [1.0] + [0.0] * d_link, t))
        cd = ct.sample_system(ctrl, t, method="tustin")
        ld = cd * pd
        poles_d = ct.poles(ct.feedback(ld, 1))
        out["largest_pole_magnitude"] = float(np.max(np.abs(poles_d)))
        out["stable_discrete"] = bool(np.all(np.abs(poles_d) < 1.0))

        out["discrete"] = None
        if case.get("discrete_margins", False):
            def exact_d(w):
                return ct.frequency_response(ld, w).complex.reshape(-1)

            out["discrete"] = margins(omega, exact_d(omega), exact_d)
    else:
        out["largest_pole_magnitude"] = None
        out["stable_discrete"] = None
        out["discrete"] = None
    return out


def run_all(cases):
    """Every case, on as many processes as there are CPUs (the cases are
    independent; the spline interpolation of `stability_margins` dominates)."""
    workers = min(len(cases), os.cpu_count() or 1)
    if workers <= 1:
        return [run_case(c) for c in cases]
    with ProcessPoolExecutor(max_workers=workers) as pool:
        return list(pool.map(run_case, cases))


def main(argv):
    if len(argv) < 2:
        sys.stderr.write(__doc__)
        return 2
    with open(argv[1]) as fh:
        cases = json.load(fh)["cases"]
    result = {
        "python_control": ct.__version__,
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "cases": run_all(cases),
    }
    text = json.dumps(result, indent=1)
    if len(argv) > 2:
        with open(argv[2], "w") as fh:
            fh.write(text)
    else:
        sys.stdout.write(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
