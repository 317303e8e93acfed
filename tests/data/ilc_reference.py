#!/usr/bin/env python3
"""Independent reference for `bench track`'s learning (issue 44): the
monotonic-convergence condition of frequency-domain ILC and the tracking
error after N trials, on a linear model, without any of the Rust code.

Input (argv[1], JSON):

    {"true_plant": [plant] table, "model_plant": [plant] table (the model
     the feedforward and the learning filter are computed on),
     "actuator": [actuator] table, "controller": a [controller.NAME] table,
     "rate_hz": loop rate, Hz, "line_rate_hz": scan lines per second,
     "amplitude_m": the triangle's amplitude, m, "cutoff_hz": harmonics at or
     above it are removed, "learning_gain": alpha, "trials": N}

Output (stdout, or argv[2]): {"contraction": [|1 - alpha PS/PS_model| per
harmonic k = 1..K], "feedback_rms_m": RMS of S r, "rms_m": [RMS error of
trial j = 0..N], trial 0 being the model-inverse feedforward's}.

The loop, built by `loop_reference.py`'s functions (the SR4DoF model of
`make_reference.py`, the amplifier, the controller from its table):
- P(z): the force -> x1 plant times the force constant and the amplifier,
  sampled with a zero-order hold (`control.sample_system`, "zoh");
- C(z): the controller sampled by Tustin (`control.sample_system`);
- S = 1/(1 + CP), PS = P S, evaluated at z = exp(j 2 pi k f_line / f_s).

The scan: the triangle (8A/pi^2) sum_{k odd} (-1)^((k-1)/2) sin(k w t)/k^2
truncated below the cut-off, each harmonic times Lanczos' sigma
sinc(k/k_c), k_c = cutoff/line rate. As harmonics R_k (x = Re sum R_k
e^{jk w t}): R_k = -j a_k.

Frequency-domain ILC (Bristow, Tharayil and Alleyne, IEEE CSM 26(3),
2006): u = C(r - y) + f, so e = S r - PS f. The first feedforward is the
model inverse F_0 = R/P_model; each trial learns F_{j+1} = F_j + L E_j
with L = alpha/PS_model. Then E_{j+1} = (1 - alpha PS/PS_model) E_j, and
the RMS of a periodic error is sqrt(sum |E_k|^2 / 2) (Parseval).

Run: python3 tests/data/ilc_reference.py case.json [out.json]
(`tests/it/track_reference.rs` runs it with $BENCH_PYTHON).
"""

import json
import math
import os
import sys

import control as ct
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from loop_reference import PER_METRE, amplifier, controller_ss, force_to_x1  # noqa: E402


def sampled_plant(plant, actuator, period_s):
    p = force_to_x1(plant) * actuator["force_constant_n_per_a"] * amplifier(actuator)
    return ct.sample_system(p, period_s, method="zoh")


def response(sys_, f_hz, period_s):
    z = np.exp(1j * 2 * math.pi * np.asarray(f_hz) * period_s)
    return np.array([complex(sys_(zz)) for zz in z])


def main(argv):
    with open(argv[1]) as fh:
        case = json.load(fh)
    t = 1.0 / case["rate_hz"]
    c = case["controller"]
    ctrl = ct.sample_system(controller_ss(c) * PER_METRE[c["error_unit"]], t, method="tustin")
    line = case["line_rate_hz"]
    k_c = case["cutoff_hz"] / line
    k_max = int(math.ceil(k_c)) - 1
    ks = np.arange(1, k_max + 1)
    f = ks * line
    a = case["amplitude_m"]
    r = np.zeros(k_max, dtype=complex)
    for i, k in enumerate(ks):
        if k % 2 == 1:
            sign = 1.0 if (k // 2) % 2 == 0 else -1.0
            sigma = math.sin(math.pi * k / k_c) / (math.pi * k / k_c)
            r[i] = -1j * 8 * a / math.pi**2 * sign / k**2 * sigma
    p_true = response(sampled_plant(case["true_plant"], case["actuator"], t), f, t)
    p_model = response(sampled_plant(case["model_plant"], case["actuator"], t), f, t)
    cz = response(ctrl, f, t)
    s_true = 1.0 / (1.0 + cz * p_true)
    ps_true = p_true * s_true
    ps_model = p_model / (1.0 + cz * p_model)
    alpha = case["learning_gain"]
    factor = 1.0 - alpha * ps_true / ps_model
    e = s_true * (r - p_true * (r / p_model))

    def rms(x):
        return float(math.sqrt(np.sum(np.abs(x) ** 2) / 2.0))

    out = {
        "python_control": ct.__version__,
        "contraction": [float(v) for v in np.abs(factor)],
        "feedback_rms_m": rms(s_true * r),
        "rms_m": [],
    }
    for _ in range(case["trials"] + 1):
        out["rms_m"].append(rms(e))
        e = factor * e
    text = json.dumps(out, indent=1)
    if len(argv) > 2:
        with open(argv[2], "w") as fh:
            fh.write(text)
    else:
        print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
