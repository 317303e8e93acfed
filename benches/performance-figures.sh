#!/usr/bin/env bash
# Regenerates the README's measured-performance rows (between its
# `<!-- performance:begin -->` and `<!-- performance:end -->` markers) and
# puts every run's whole output in docs/src/performance.md (between the
# same markers), from these measurements, run one after the other on an
# otherwise idle machine:
#   - the default chirp as a process against the same job in scipy
#     (benches/chirp-vs-scipy.sh, release build);
#   - the fast controller's tick with the supervisor, and the dead-probe
#     rules' cost on it (cargo bench --bench control);
#   - the two FRF estimators on the default record (cargo bench --bench
#     chirp);
#   - the stated 1σ against the truth on 200 hidden benches
#     (tests/cli/uncertainty.rs) and a design from one chirp's CSV on three
#     benches, its time and its ω* on the true plant against the reference
#     limit (tests/cli/design_limit.rs), both through tests/run, which
#     installs the Python references they need;
#   - a design over the 20 FRFs of a campaign (benches/design-time.sh,
#     release build, ROUNDS rounds of `--strategy auto`).
# No figure is written when a step fails. Takes about 15 minutes once built.
# Each step's output is kept in target/performance-figures/; --splice
# writes the figures from those again without measuring (after a change to
# how they are written).
# Usage: benches/performance-figures.sh [ROUNDS | --splice]   (default 3)
set -euo pipefail
cd "$(dirname "$0")/.."
tmp=target/performance-figures
if [ "${1:-}" = --splice ]; then
  [ -f "$tmp/machine" ] || {
    echo "performance-figures.sh: --splice: no earlier run's outputs in $tmp" >&2
    exit 1
  }
else
rounds=${1:-3}
rm -rf "$tmp" && mkdir -p "$tmp"
step() { # NAME COMMAND...: its output to $tmp/NAME, shown if it fails
  local name=$1
  shift
  echo "== $name: $*" >&2
  "$@" >"$tmp/$name" 2>&1 || {
    tail -40 "$tmp/$name" >&2
    echo "performance-figures.sh: $name failed: figures not written" >&2
    exit 1
  }
}
step tests tests/run --test cli -- --nocapture --test-threads 1 \
  uncertainty::stated_uncertainties_cover_the_truth \
  uncertainty::no_update_is_off_by_more_than_5_sigma_without_a_flag \
  design_limit::a_design_from_a_csv_alone_reports_the_benchs_limit_and_holds_on_the_true_plant
venv="${BENCH_PYREF_VENV:-$HOME/.cache/bench-pyref}/bin/python"
[ -n "${BENCH_PYTHON:-}" ] || { [ -x "$venv" ] && export BENCH_PYTHON="$venv"; } || true
step chirp benches/chirp-vs-scipy.sh 5
step control cargo bench --locked --bench control -- 'fast_controller_plus_supervisor_tick|probe_validity'
step frf cargo bench --locked --bench chirp -- 'frf_h1_default_record|frf_lpm_default_record'
step design20 benches/design-time.sh target/release/bench "$rounds" auto
echo "machine: $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), $(date -u +%F)" >"$tmp/machine"
fi
python3 - "$tmp" <<'PY'
import re
import sys

sys.path.insert(0, "benches")
from figures import splice  # noqa: E402

d = sys.argv[1]
out = {k: open(f"{d}/{k}").read() for k in ["tests", "chirp", "control", "frf", "design20", "machine"]}
machine = out["machine"].strip()[len("machine: "):]
where, date = machine.rsplit(", ", 1)
UNIT = {"ps": 1e-12, "ns": 1e-9, "µs": 1e-6, "us": 1e-6, "ms": 1e-3, "s": 1.0}


def criterion(text, name):
    """The estimate (middle of criterion's interval) of a benchmark, s."""
    m = re.search(re.escape(name) + r"\s+time:\s+\[\S+ \S+ (\S+) (\S+) \S+ \S+\]", text)
    if not m:
        sys.exit(f"no criterion figure for {name}")
    return float(m.group(1)) * UNIT[m.group(2)]


def spread(xs, fmt):
    lo, hi = min(xs), max(xs)
    return fmt.format(lo) if fmt.format(lo) == fmt.format(hi) else fmt.format(lo) + "–" + fmt.format(hi)


met = lambda ok: "met" if ok else "not met"
chirp = re.search(r"median: bench (\S+) s, scipy (\S+) s, ratio (\S+)x", out["chirp"])
tick = criterion(out["control"], "control/fast_controller_plus_supervisor_tick")
on = criterion(out["control"], "control/probe_validity_on")
off = criterion(out["control"], "control/probe_validity_off")
h1 = criterion(out["frf"], "chirp/frf_h1_default_record")
lpm = criterion(out["frf"], "chirp/frf_lpm_default_record")
cover = [(m.group(1), float(m.group(2))) for m in re.finditer(r"(\S+)\s+n\s+\d+\s+within 2σ\s+(\S+) %", out["tests"])]
silent = re.search(r"(\d+) benches, (\d+) flagged, (\d+) silently off by more than 5σ", out["tests"])
designs = [
    (m.group(1), float(m.group(2)), float(m.group(3)))
    for m in re.finditer(r"(\S+): \S+ ω\* \S+ rad/s on the true plant \((\S+) of the reference limit .*, design (\S+) s$", out["tests"], re.M)
]
runs = [
    (float(m.group(1)), float(m.group(2)), float(m.group(3)))
    for m in re.finditer(r"design (\S+) s \(limit \S+ s\), .*ω\* (\S+) of the limit (\S+) rad/s", out["design20"])
]
if not (chirp and cover and silent and len(designs) == 3 and runs):
    sys.exit("an output lacks its figure:\n" + "\n".join(f"== {k}\n{v}" for k, v in out.items()))
one = [t for _, _, t in designs]
twenty = [t for t, _, _ in runs]
reach = ", ".join(f"{r:.2f} ({n})" for n, r, _ in designs)
wstar, wlim = runs[-1][1], runs[-1][2]
readme = f"""Measured by `benches/performance-figures.sh` on {date} ({where}; every run's whole output: [measured performance](docs/src/performance.md)):

| what | figure |
|---|---|
| default `bench chirp` end to end in virtual time (65.5 s of loop time: loop, MCAP, FRF, fit, plot) | {float(chirp.group(1)):.2f} s as a process (median of 5); {float(chirp.group(3)):.1f}× faster than the same job in scipy ({float(chirp.group(2)):.2f} s) |
| fast controller and supervisor, one tick (`cargo bench --bench control`) | {tick * 1e9:.0f} ns (the tick allocates nothing: a test counts it) |
| the dead-probe rules (frozen, implausible) on the tick | {(on - off) * 1e9:.1f} ns: the sample check {on * 1e9:.1f} ns with them, {off * 1e9:.1f} ns without (target ≤ 50 ns: {met(on - off <= 50e-9)}) |
| FRF: LPM against H1 on the default chirp (`cargo bench --bench chirp`) | {lpm * 1e3:.1f} ms against {h1 * 1e3:.1f} ms, {lpm / h1:.2f}× (target ≤ 2×: {met(lpm <= 2 * h1)}) |
| honest 1σ: {silent.group(1)} random hidden benches, fit and update (`tests/cli/uncertainty.rs`) | truth within the stated 2σ for {spread([c for _, c in cover], '{:.1f}')} % of every quantity ({len(cover)} quantities; asked ≥ 90 %); {silent.group(2)} flagged, {silent.group(3)} updates off by more than 5σ without a flag |
| `bench design` from one chirp's CSV, with the bench's limit (`tests/cli/design_limit.rs`, dev profile, three benches) | {spread(one, '{:.1f}')} s (target ≤ 5 s: {met(max(one) <= 5)}); the design's ω* on the true plant {reach} of the reference limit (asked ≥ 0.8) |
| `bench design` over 20 FRFs (a 20-cell campaign, `benches/design-time.sh`, release, {len(runs)} runs) | {spread(twenty, '{:.1f}')} s (target ≤ 30 s: {met(max(twenty) <= 30)}); one controller at ω* {wstar:.1f} of the workspace's limit {wlim:.1f} rad/s on the fitted models ({wstar / wlim:.2f}) |
"""
keep = lambda k, pat: "\n".join(l for l in out[k].splitlines() if re.search(pat, l))
book = f"""Measured by `benches/performance-figures.sh` on {date} ({where}). What each step printed:

```text
$ benches/chirp-vs-scipy.sh 5
{out['chirp'].strip()}
$ cargo bench --bench control -- 'fast_controller_plus_supervisor_tick|probe_validity'
{keep('control', r'time:|^control/|fast_tick_single')}
$ cargo bench --bench chirp -- 'frf_h1_default_record|frf_lpm_default_record'
{keep('frf', r'time:|^chirp/')}
$ tests/run --test cli -- --nocapture uncertainty:: design_limit::a_design_from_a_csv_alone…
{keep('tests', r'within 2σ|silently off|on the true plant')}
$ benches/design-time.sh target/release/bench {len(runs)} auto
{out['design20'].strip()}
```
"""
for path, figures in [("README.md", readme), ("docs/src/performance.md", book)]:
    splice(path, "performance", figures)
PY
echo "figures written into README.md and docs/src/performance.md"
