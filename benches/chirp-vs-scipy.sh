#!/usr/bin/env bash
# Issue 16's end-to-end comparison: the default `bench chirp` (simulator,
# virtual time, release build) against benches/chirp_scipy.py (the same
# excitation, plant, record on disk and FRF CSV in numpy/scipy), both timed
# as whole processes, alternately, ROUNDS times each. Prints every run and
# the medians; the target is bench <= 0.15 s and >= 20x faster.
# Needs python3 with numpy and scipy (pip install numpy scipy), or
# BENCH_PYTHON naming one (tests/run's venv has both).
# Usage: benches/chirp-vs-scipy.sh [ROUNDS]   (default 5)
set -euo pipefail
cd "$(dirname "$0")/.."
rounds=${1:-5}
cargo build --release --locked --quiet
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
wall() { # seconds of wall time of a command, its output discarded
  local t0 t1
  t0=$(date +%s.%N)
  "$@" >/dev/null 2>&1 || { echo "chirp-vs-scipy.sh: failed: $*" >&2; return 1; }
  t1=$(date +%s.%N)
  awk -v a="$t0" -v b="$t1" 'BEGIN {print b - a}'
}
b=(); s=()
for i in $(seq "$rounds"); do
  tb=$(wall target/release/bench chirp --out "$out/chirp.mcap" --overwrite)
  ts=$(wall "${BENCH_PYTHON:-python3}" benches/chirp_scipy.py --out "$out")
  b+=("$tb"); s+=("$ts")
  printf 'round %d: bench %.3f s, scipy %.3f s\n' "$i" "${b[-1]}" "${s[-1]}"
done
median() { printf '%s\n' "$@" | sort -g | awk '{a[NR]=$1} END {print (NR%2) ? a[(NR+1)/2] : (a[NR/2]+a[NR/2+1])/2}'; }
mb=$(median "${b[@]}"); ms=$(median "${s[@]}")
printf 'median: bench %.3f s, scipy %.3f s, ratio %.1fx\n' "$mb" "$ms" "$(awk -v a="$ms" -v b="$mb" 'BEGIN {print a / b}')"
