#!/usr/bin/env bash
# Design time of `bench design` over 20 FRFs of the default chirp (issue 27:
# at most 2 s on the 2-core machine; issue 41: with the limit, at most 30 s): a 20-cell campaign of the shipped
# Chapter 5 bench over 0–9.5 % of L at +10 % mass asymmetry (the thesis'
# 6.2.2 range and a little beyond), then `bench design DIR --strategy fast`
# and `--strategy auto`, five times each; prints the design_time_s of each
# run (the fits, the search and the certificate; the process start and the
# figure excluded) and the wall time of the whole command.
#
#   benches/design-time.sh [BENCH [ROUNDS [STRATEGY...]]]
#   (defaults: target/release/bench, 5 rounds, fast and auto)
set -euo pipefail
bin=$(realpath "${1:-target/release/bench}")
rounds=${2:-5}
strategies=("${@:3}")
[ ${#strategies[@]} -gt 0 ] || strategies=(fast auto)
cfg=$(realpath bench-config/sr4dof-ch5.toml)
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
cd "$work"
cp "$cfg" sr4dof-ch5.toml
cat > ws.toml <<'TOML'
config = "sr4dof-ch5.toml"
seed = 27
[grid]
operating_point_pct = { from = 0.0, to = 9.5, step = 0.5 }
mass_asymmetry = [0.10]
TOML
"$bin" campaign run ws.toml --out ws --json > /dev/null
for strategy in "${strategies[@]}"; do
  for i in $(seq "$rounds"); do
    start=$(date +%s.%N)
    t=$("$bin" design ws --strategy "$strategy" --out "d-$strategy-$i.toml" --no-plot --json | "${BENCH_PYTHON:-python3}" -c 'import json,sys; s=json.load(sys.stdin); l=s["limit"]; print("%.2f s (limit %.2f s), ω_B %.1f rad/s, ω* %s of the limit %s rad/s, %s, inputs %d" % (s["design_time_s"], l["time_s"], s["sensitivity_bandwidth_rad_s"], s["performance_bandwidth_rad_s"], l["performance_bandwidth_rad_s"], s["strategy"], len(s["inputs"])))')
    end=$(date +%s.%N)
    echo "$strategy run $i: design $t; wall $("${BENCH_PYTHON:-python3}" -c "print(f'{$end - $start:.2f}')") s"
  done
done
