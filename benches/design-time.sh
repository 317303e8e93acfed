#!/usr/bin/env bash
# Design time of `bench design` over 20 FRFs of the default chirp (issue 27:
# at most 2 s on the 2-core machine; issue 41: with the limit, at most 30 s): a 20-cell campaign of the shipped
# Chapter 5 bench over 0–9.5 % of L at +10 % mass asymmetry (the thesis'
# 6.2.2 range and a little beyond), then `bench design DIR --strategy fast`
# and `--strategy auto`, five times each; prints the design_time_s of each
# run (the fits, the search and the certificate; the process start and the
# figure excluded) and the wall time of the whole command.
#
#   benches/design-time.sh [BENCH]      (default: target/release/bench)
set -euo pipefail
bin=$(realpath "${1:-target/release/bench}")
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
for strategy in fast auto; do
  for i in 1 2 3 4 5; do
    start=$(date +%s.%N)
    t=$("$bin" design ws --strategy "$strategy" --out "d-$strategy-$i.toml" --no-plot --json | python3 -c 'import json,sys; s=json.load(sys.stdin); l=s["limit"]; print("%.2f s (limit %.2f s), ω_B %.1f rad/s, ω* %s of the limit %s rad/s, %s, inputs %d" % (s["design_time_s"], l["time_s"], s["sensitivity_bandwidth_rad_s"], s["performance_bandwidth_rad_s"], l["performance_bandwidth_rad_s"], s["strategy"], len(s["inputs"])))')
    end=$(date +%s.%N)
    echo "$strategy run $i: design $t; wall $(python3 -c "print(f'{$end - $start:.2f}')") s"
  done
done
