#!/usr/bin/env bash
# Wake-up latency of bench's real-time loop against cyclictest (rt-tests),
# at the same rate, priority, CPU and duration, run alternately
# (cyclictest, bench, cyclictest, bench, ...) so that both see the same
# machine. Prints each run's p99 wake-up latency and, per rate, the ratio of
# the medians bench / cyclictest.
#
# What is compared: cyclictest's latency is its timer thread's wake-up
# time minus the deadline of its absolute clock_nanosleep, bench's is the
# same quantity for its loop thread (`timing.wake_latency_p99_us` of the
# `bench chirp --realtime --json` summary). Both hold /dev/cpu_dma_latency
# at 0 (cyclictest by default, bench in every real-time run), both lock
# their memory (cyclictest -m, bench mlockall) and run SCHED_FIFO at the
# same priority pinned to the same CPU. cyclictest counts whole µs; its p99
# is taken from its histogram (-h) as the upper edge of the 1 µs bucket
# holding the 99th percentile, as bench reports the upper edge of its
# (≤ 1 % wide) bucket.
#
# Usage: benches/latency-vs-cyclictest.sh [-d SECONDS] [-r ROUNDS]
#            [-c CPU] [-p PRIORITY] [-B BENCH] [RATE_HZ ...]
#   -d  duration of each run, s (default 30; at least 1)
#   -r  rounds of (cyclictest, bench) per rate (default 3)
#   -c  CPU both are pinned to (default: the last one online)
#   -p  SCHED_FIFO priority of both (default 80)
#   -B  use this bench binary instead of building target/release/bench
#       (a quick check of the script; figures come from a release build)
#   RATE_HZ  loop rates (default 5000 10000)
# Needs root (or the rights to SCHED_FIFO and /dev/cpu_dma_latency) and
# cyclictest on PATH. Builds bench in release first. Run it on a quiet
# machine: other load shows up in both figures, but not equally.
set -euo pipefail

duration=30
rounds=3
cpu=$(( $(nproc) - 1 ))
prio=80
bench=
while getopts "d:r:c:p:B:h" opt; do
    case $opt in
        d) duration=$OPTARG ;;
        r) rounds=$OPTARG ;;
        c) cpu=$OPTARG ;;
        p) prio=$OPTARG ;;
        B) bench=$OPTARG ;;
        *) sed -n '2,30p' "$0"; exit 2 ;;
    esac
done
shift $((OPTIND - 1))
rates=("$@")
[ ${#rates[@]} -gt 0 ] || rates=(5000 10000)

die() { echo "latency-vs-cyclictest: $*" >&2; exit 2; }
[[ $duration =~ ^[0-9]+$ ]] && [ "$duration" -ge 1 ] || die "-d: whole seconds, at least 1 (got $duration)"
[[ $rounds =~ ^[0-9]+$ ]] && [ "$rounds" -ge 1 ] || die "-r: at least 1 round (got $rounds)"
[[ $cpu =~ ^[0-9]+$ ]] && [ "$cpu" -lt "$(nproc)" ] || die "-c: a CPU from 0 to $(( $(nproc) - 1 )) (got $cpu)"
[[ $prio =~ ^[0-9]+$ ]] && [ "$prio" -ge 1 ] && [ "$prio" -le 99 ] || die "-p: SCHED_FIFO priority 1-99 (got $prio)"
for r in "${rates[@]}"; do
    [[ $r =~ ^[0-9]+$ ]] && [ "$r" -ge 100 ] && [ $((1000000 % r)) -eq 0 ] ||
        die "rate $r Hz: a whole number of µs per period, at least 100 Hz (5000, 10000, 20000 ...)"
done
command -v cyclictest >/dev/null || die "cyclictest not found (install rt-tests)"
command -v python3 >/dev/null || die "python3 not found (parses the JSON results)"
[ "$(id -u)" -eq 0 ] || echo "latency-vs-cyclictest: not root: SCHED_FIFO or /dev/cpu_dma_latency may be refused (both would warn)" >&2

root=$(cd "$(dirname "$0")/.." && pwd)
if [ -z "$bench" ]; then
    cargo build --release --quiet --manifest-path "$root/Cargo.toml" --bin bench
    bench="$root/target/release/bench"
fi
[ -x "$bench" ] || die "-B: $bench is not an executable"
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

# p99 of a cyclictest --json file, µs: upper edge of the histogram's 1 µs
# bucket holding the 99th percentile (overflows count as beyond the range).
ct_p99() {
    python3 - "$1" <<'EOF'
import json, math, sys
d = json.load(open(sys.argv[1]))
t = next(iter(d["thread"].values()))
hist = sorted((int(k), v) for k, v in t["histogram"].items())
n = t["cycles"]
target = math.ceil(0.99 * n)
acc = 0
for us, c in hist:
    acc += c
    if acc >= target:
        print(us + 1)
        break
else:
    print("inf")
EOF
}

# p99 wake-up latency of a bench --json summary, µs.
bench_p99() {
    python3 -c 'import json, sys; print("%.1f" % json.load(open(sys.argv[1]))["timing"]["wake_latency_p99_us"])' "$1"
}

summary=()
for rate in "${rates[@]}"; do
    interval_us=$((1000000 / rate))
    cfg="$work/bench-$rate.toml"
    # The shipped bench at this rate, priority and CPU, without the quiet
    # lead-in, so the loop runs for the sweep's duration.
    sed -e "s/^rate_hz = .*/rate_hz = $rate.0/" \
        -e "s/^# cpu = .*/cpu = $cpu/" -e "s/^cpu = .*/cpu = $cpu/" \
        -e "s/^priority = .*/priority = $prio/" \
        -e "s/^lead_in_s = .*/lead_in_s = 0.0/" \
        "$root/bench-config/sr4dof-ch5.toml" >"$cfg"
    ct=(); be=()
    for round in $(seq 1 "$rounds"); do
        cyclictest -m -q -t 1 -p "$prio" -a "$cpu" -i "$interval_us" \
            -D "$duration" -h 100000 --json="$work/ct.json" >/dev/null
        ct+=("$(ct_p99 "$work/ct.json")")
        "$bench" chirp --realtime --config "$cfg" --duration-s "$duration" \
            --out "$work/bench.mcap" --overwrite --json >"$work/bench.json"
        be+=("$(bench_p99 "$work/bench.json")")
        printf '%6d Hz round %d: p99 wake-up latency cyclictest %s µs, bench %s µs\n' \
            "$rate" "$round" "${ct[-1]}" "${be[-1]}"
    done
    summary+=("$(python3 - "$rate" "${ct[*]}" "${be[*]}" <<'EOF'
import statistics, sys
rate = sys.argv[1]
ct = [float(x) for x in sys.argv[2].split()]
be = [float(x) for x in sys.argv[3].split()]
c, b = statistics.median(ct), statistics.median(be)
print(f"{rate:>6} Hz: median p99 cyclictest {c:.1f} µs, bench {b:.1f} µs, ratio bench/cyclictest {b / c:.2f} ({len(ct)} rounds)")
EOF
)")
done
echo
printf '%s\n' "${summary[@]}"
