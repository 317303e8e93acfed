#!/usr/bin/env bash
# Time of `bench fit` as a process on the default chirp's and the default
# multisine's FRFs over many benches (issue 45, item 3: every default fit
# at most 1 s on this 2-core machine): two campaigns of the shipped
# Chapter 5 bench, one with `[excitation] kind = "exponential"` (the default)
# and one with `kind = "multisine"`, over 0–9 % of L in steps of 1.5 % and
# mass asymmetry −12, −6, +6 and +12 % (both residue-sign patterns: 28
# cells each, each cell its own noise seed), then `bench fit CELL/frf.csv
# --json` on every cell, timed as a process. Prints each fit's time, mode
# count and flags, and per campaign the median, the largest and how many
# took more than 1 s.
#
#   benches/fit-time.sh [BENCH]   (default: target/release/bench)
set -euo pipefail
bin=$(realpath "${1:-target/release/bench}")
py=${BENCH_PYTHON:-python3}
cfg=$(realpath bench-config/sr4dof-ch5.toml)
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
cd "$work"
for kind in exponential multisine; do
  if [ "$kind" = multisine ]; then
    # A multisine takes no sweep duration or taper.
    sed -e 's/^kind = "exponential"/kind = "multisine"/' -e '/^duration_s = /d' -e '/^taper_s = /d' "$cfg" > "$kind.toml"
  else
    cp "$cfg" "$kind.toml"
  fi
  cat > "$kind-campaign.toml" <<TOML
config = "$kind.toml"
seed = 45
[grid]
operating_point_pct = { from = 0.0, to = 9.0, step = 1.5 }
mass_asymmetry = [-0.12, -0.06, 0.06, 0.12]
TOML
  "$bin" campaign run "$kind-campaign.toml" --out "$kind" --json > /dev/null
  : > "$kind.times"
  for csv in "$kind"/cells/*/frf.csv; do
    start=$(date +%s.%N)
    out=$("$bin" fit "$csv" --json 2>/dev/null || true)
    end=$(date +%s.%N)
    echo "$out" | "$py" -c "
import json, sys
t = $end - $start
try:
    s = json.load(sys.stdin)
    f = s['fit']
    n = len(f.get('modes', []))
    flags = f['quality']['flags']
except Exception as e:
    n, flags = -1, ['no fit: %s' % e]
print('%.3f %d %s %s' % (t, n, '$csv', ';'.join(map(str, flags)) or '-'))
" >> "$kind.times"
  done
  "$py" - "$kind" "$kind.times" <<'PY'
import statistics, sys
kind, path = sys.argv[1], sys.argv[2]
rows = [l.rstrip("\n").split(maxsplit=3) for l in open(path) if l.strip()]
t = sorted(float(r[0]) for r in rows)
slow = [r for r in rows if float(r[0]) > 1.0]
print(f"{kind}: {len(t)} fits, median {statistics.median(t):.2f} s, largest {t[-1]:.2f} s, over 1 s: {len(slow)}")
for r in slow:
    print("  over 1 s:", " ".join(r))
flagged = [r for r in rows if len(r) > 3 and r[3].strip() != "-"]
print(f"{kind}: {len(flagged)} flagged")
for r in flagged:
    print("  flagged:", " ".join(r))
PY
done
