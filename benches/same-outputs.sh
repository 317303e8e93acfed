#!/usr/bin/env bash
# Behaviour unchanged across a refactor (issue 26): runs the default chirp
# and the fast and slow steps on the simulator with one seed through two
# `bench` binaries and compares what they wrote. PNGs and the FRF CSV must
# be byte-identical; recordings are compared channel by channel through
# `bench export` without the wall-clock log time; the JSON summaries
# without the timing figures (wake-up and compute times, wall time).
#
#   benches/same-outputs.sh OLD_BENCH NEW_BENCH [SEED]
#
# Prints one line per output ("same" or "DIFF") and exits 1 on any DIFF.
set -euo pipefail
old=$1 new=$2 seed=${3:-7}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
for v in old new; do
  bin=${!v}
  mkdir -p "$work/$v"
  (
    cd "$work/$v"
    "$bin" chirp --seed "$seed" --out chirp.mcap --json >chirp.json
    "$bin" control --fast --seed "$seed" --out fast.mcap --json >fast.json
    "$bin" control --slow --seed "$seed" --out slow.mcap --json >slow.json
    for r in chirp fast slow; do
      for t in /bench/sample /bench/event /bench/envelope /sysid/frf; do
        n=$(echo "$t" | tr / _)
        "$new" export --to csv --topic "$t" --out "$r$n.csv" "$r.mcap" >/dev/null 2>&1 || true
      done
    done
  )
done
status=0
cmp_one() { # name, old digest, new digest
  if [ "$2" = "$3" ]; then echo "same $1"; else echo "DIFF $1"; status=1; fi
}
cd "$work"
for f in $(cd old && ls *.png *.frf.csv); do
  cmp_one "$f" "$(sha256sum <old/"$f" | cut -c1-64)" "$(sha256sum <new/"$f" | cut -c1-64)"
done
for f in $(cd old && ls *_bench_*.csv *_sysid_*.csv 2>/dev/null); do
  cmp_one "$f (without log_time_ns)" "$(cut -d, -f2- old/"$f" | sha256sum)" "$(cut -d, -f2- new/"$f" | sha256sum)"
done
strip='del(.timing, .recording, .frf_csv, .bode_png, .step_png, .outputs) | walk(if type == "object" then with_entries(select(.key | test("_us$|_ns$|wall|compute|wake|latency") | not)) else . end)'
if command -v jq >/dev/null; then
  for f in chirp.json fast.json slow.json; do
    cmp_one "$f (without timing)" "$(jq -S "$strip" old/$f | sha256sum)" "$(jq -S "$strip" new/$f | sha256sum)"
  done
fi
exit $status
