"""Loads a model exported by `bench fit --export-model` in python-control and
compares its frequency response with the measured FRF it was fitted to.

Usage: model_export_check.py MODEL FRF_CSV

MODEL is one of the export's formats:
- `.json`: the JSON export; the model is built here from its `tf`, `zpk` or
  `ss` with `control.tf`, `control.zpk`, `control.ss`;
- `.py`: the python-control script, run with `runpy` (it defines `G` and
  `delay_s`);
- `.m`: the MATLAB script, read here (its assignments `name = [ ... ];`,
  complex numbers as `a+bi`, rows split by `;`) and built with the same
  python-control calls as MATLAB's `tf(num, den)`, `zpk(z, p, k)`,
  `ss(A, B, C, D)`.

The response compared with the FRF is the one the export documents:
    Ĥ(jω) = G(jω) · e^{−jωτ} · sinc(ωT/2)
with τ the exported input delay and T the hold period (`hold_period_s` of
the JSON; for scripts it is read from the header comment "T = ... s").

Prints one JSON object: the number of coherent lines (γ² ≥ 0.5), the RMS of
|Ĥ − H| / σ over them (σ the FRF's 1σ of the complex response, so a model
that explains the data to its noise gives about 1), the median relative
error |Ĥ − H| / |H|, and the model's order and poles in Hz.
"""

import json
import re
import runpy
import sys

import numpy as np
import control


def load_matlab(path):
    text = open(path).read()
    values = {}
    for name, body in re.findall(r"^(\w+) = \[?([^;\]\n]*(?:;[^\]\n]*)*)\]?;$", text, re.M):
        if name == "G":
            continue
        rows = [r.strip() for r in body.split(";")]
        parsed = []
        for r in rows:
            items = [x for x in r.split() if x]
            parsed.append([complex(x.replace("i", "j")) for x in items])
        values[name] = parsed
    g = None
    if "G = tf(" in text:
        num = [c.real for c in values["num"][0]]
        den = [c.real for c in values["den"][0]]
        g = control.tf(num, den)
    elif "G = zpk(" in text:
        z = [row[0] for row in values["z"]]
        p = [row[0] for row in values["p"]]
        k = values["k"][0][0].real
        g = control.zpk(z, p, k)
    elif "G = ss(" in text:
        mats = [np.array([[c.real for c in row] for row in values[n]]) for n in "ABCD"]
        g = control.ss(*mats)
    delay = values["delay_s"][0][0].real
    return g, delay, hold_period(text, "%")


def hold_period(text, comment):
    m = re.search(re.escape(comment) + r" Hold sinc\(wT/2\) of T = ([0-9.eE+-]+) s", text)
    return float(m.group(1))


def load_json(path):
    m = json.load(open(path))
    if m.get("tf"):
        g = control.tf(m["tf"]["num"], m["tf"]["den"])
    elif m.get("zpk"):
        z = [complex(a, b) for a, b in m["zpk"]["zeros"]]
        p = [complex(a, b) for a, b in m["zpk"]["poles"]]
        g = control.zpk(z, p, m["zpk"]["gain"])
    else:
        s = m["ss"]
        g = control.ss(np.array(s["a"]), np.array(s["b"]), np.array(s["c"]), np.array(s["d"]))
    return g, m["delay_s"], m["hold_period_s"]


def load_python(path):
    ns = runpy.run_path(path)
    return ns["G"], ns["delay_s"], hold_period(open(path).read(), "#")


def main():
    model, csv = sys.argv[1], sys.argv[2]
    if model.endswith(".json"):
        g, delay, t = load_json(model)
    elif model.endswith(".py"):
        g, delay, t = load_python(model)
    else:
        g, delay, t = load_matlab(model)
    data = np.genfromtxt(csv, delimiter=",", names=True)
    f = data["frequency_hz"]
    h = data["magnitude_m_per_a"] * np.exp(1j * np.deg2rad(data["phase_deg"]))
    sigma = data["sigma_m_per_a"]
    keep = data["coherence"] >= 0.5
    w = 2 * np.pi * f
    gj = np.array([complex(g(1j * wk)) for wk in w])
    x = 0.5 * w * t
    h_model = gj * np.exp(-1j * w * delay) * np.sin(x) / x
    err = np.abs(h_model - h)[keep]
    poles = np.asarray(control.poles(g))
    out = {
        "lines": int(keep.sum()),
        "rms_normalised": float(np.sqrt(np.mean((err / sigma[keep]) ** 2))),
        "median_relative": float(np.median(err / np.abs(h[keep]))),
        "order": int(len(poles)),
        "pole_hz": sorted(float(abs(p) / (2 * np.pi)) for p in poles if p.imag > 0),
    }
    print(json.dumps(out))


main()
