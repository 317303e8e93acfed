#!/usr/bin/env bash
# What `bench serve --metrics` scraped every second costs the real-time
# loop: the p99 wake-up latency of daemon jobs on a daemon without
# `--metrics`, and on one with `--metrics` and a scraper fetching
# /metrics every second for the whole job, run alternately (without,
# with, with, without, ...) so that both see the same machine. Prints
# each job's p99 and, at the end, the medians and their ratio to without
# (the bar: within 1.10). A third kind of daemon, with `--metrics` and no
# scraper, separates what the metrics cost from what the scraping does.
# A fourth, `uploading` (-U URL), is `with` and `--upload URL` besides, with
# uploads running while the job does: before the measured job it runs
# -n unpaced 150 s chirps (about 13 MB of recording each), whose uploads
# (and their read-back checksums) the daemon's upload thread is still
# doing when the measured job starts; the script reports how many files
# the store confirmed during the measured job (none: the uploads had
# already finished, and the figure says nothing about them).
#
# What is compared: `timing.wake_latency_p99_us` of each job's summary
# (`bench chirp --daemon --json`): the loop's own wake-up latency over the
# job's ticks (HDR histogram, <= 1 % above the true order statistic). The
# jobs are real-time chirps on the daemon's SCHED_FIFO loop (the shipped
# Chapter 5 bench, 5 kHz, pinned to one CPU), the same request each time.
# The scraper is one python3 process fetching /metrics once a second (a new
# connection each time), on the same machine, as a Prometheus beside the
# bench would be: its own work (the HTTP request, the loopback network
# stack) is part of what is measured. With -o it runs off the loop's CPU,
# as anything else should on a bench whose loop CPU is isolated.
#
# Usage: benches/metrics-overhead.sh [-d SECONDS] [-r ROUNDS] [-c CPU]
#            [-i INTERVAL_S] [-o] [-B BENCH]
#   -d  chirp sweep of each job, s (default 20; the job adds 5.5 s of
#       lead-in and tail)
#   -r  rounds; each runs one job on each kind of daemon, the order
#       rotating (default 6)
#   -c  CPU the loop is pinned to (default: the last one online)
#   -i  scrape interval, s (default 1)
#   -o  run the scraper off the loop's CPU (taskset)
#   -m  the kinds of daemon, comma-separated (default
#       without,unscraped,with; with -U also uploading)
#   -U  the store of the `uploading` daemon (s3://BUCKET/PREFIX with the
#       AWS_* environment, or file:///DIR)
#   -n  recordings queued for upload before each measured job (default 3)
#   -B  use this bench binary instead of building it in release (a quick
#       check of the script; figures come from a release build)
# Needs root (or the rights to SCHED_FIFO and /dev/cpu_dma_latency), curl
# and python3. Run it on a quiet machine.
set -euo pipefail

duration=20
rounds=6
cpu=$(( $(nproc) - 1 ))
interval=1
off_cpu=
modes=(without unscraped with)
modes_given=
bench=
upload_url=
backlog=3
while getopts "d:r:c:i:om:B:U:n:h" opt; do
    case $opt in
        d) duration=$OPTARG ;;
        r) rounds=$OPTARG ;;
        c) cpu=$OPTARG ;;
        i) interval=$OPTARG ;;
        o) off_cpu=1 ;;
        m) IFS=, read -r -a modes <<<"$OPTARG"; modes_given=1 ;;
        U) upload_url=$OPTARG ;;
        n) backlog=$OPTARG ;;
        B) bench=$OPTARG ;;
        *) sed -n '2,30p' "$0"; exit 2 ;;
    esac
done
shift $((OPTIND - 1))

die() { echo "metrics-overhead: $*" >&2; exit 2; }
[[ $duration =~ ^[0-9]+$ ]] && [ "$duration" -ge 1 ] || die "-d: whole seconds, at least 1 (got $duration)"
[[ $rounds =~ ^[0-9]+$ ]] && [ "$rounds" -ge 1 ] || die "-r: at least 1 round (got $rounds)"
[[ $cpu =~ ^[0-9]+$ ]] && [ "$cpu" -lt "$(nproc)" ] || die "-c: a CPU from 0 to $(( $(nproc) - 1 )) (got $cpu)"
[[ $interval =~ ^[0-9.]+$ ]] || die "-i: seconds (got $interval)"
if [ -n "$upload_url" ] && [ -z "$modes_given" ]; then modes+=(uploading); fi
for m in "${modes[@]}"; do
    [[ $m =~ ^(without|unscraped|with|uploading)$ ]] || die "-m: without, unscraped, with or uploading (got $m)"
    [ "$m" != uploading ] || [ -n "$upload_url" ] || die "-m uploading needs -U URL"
done
[[ $backlog =~ ^[0-9]+$ ]] || die "-n: a number of recordings (got $backlog)"
command -v curl >/dev/null || die "curl not found"
if [ -n "$off_cpu" ]; then
    command -v taskset >/dev/null || die "-o: taskset not found (util-linux)"
    others=$(seq 0 $(( $(nproc) - 1 )) | grep -vx "$cpu" | paste -sd,)
    [ -n "$others" ] || die "-o: no CPU but the loop's"
fi
command -v python3 >/dev/null || die "python3 not found (parses the JSON summaries)"
[ "$(id -u)" -eq 0 ] || echo "metrics-overhead: not root: SCHED_FIFO or /dev/cpu_dma_latency may be refused (the daemon would warn)" >&2

root=$(cd "$(dirname "$0")/.." && pwd)
if [ -z "$bench" ]; then
    cargo build --release --quiet --manifest-path "$root/Cargo.toml" --bin bench
    target=$(cargo metadata --format-version 1 --no-deps --manifest-path "$root/Cargo.toml" |
        python3 -c 'import json, sys; print(json.load(sys.stdin)["target_directory"])')
    bench="$target/release/bench"
fi
[ -x "$bench" ] || die "-B: $bench is not an executable"
work=$(mktemp -d)
daemon=
scraper=
cleanup() {
    [ -n "$scraper" ] && kill "$scraper" 2>/dev/null
    [ -n "$daemon" ] && kill "$daemon" 2>/dev/null
    wait 2>/dev/null
    rm -rf "$work"
}
trap cleanup EXIT

# The shipped bench, its loop pinned to $cpu.
cfg="$work/bench.toml"
sed -e "s/^# cpu = .*/cpu = $cpu/" -e "s/^cpu = .*/cpu = $cpu/" \
    "$root/bench-config/sr4dof-ch5.toml" >"$cfg"
sock="$work/bench.sock"

# Starts a daemon (with extra arguments); sets $daemon and, with
# --metrics, $url.
start_daemon() {
    rm -f "$work/serve.err"
    "$bench" serve --config "$cfg" --socket "$sock" --recordings "$work/rec" "$@" \
        2>"$work/serve.err" &
    daemon=$!
    for _ in $(seq 200); do
        [ -S "$sock" ] && break
        sleep 0.05
    done
    [ -S "$sock" ] || die "the daemon did not start: $(cat "$work/serve.err")"
    url=$(sed -n 's/^bench serve: metrics on //p' "$work/serve.err")
}

stop_daemon() {
    "$bench" daemon shutdown --socket "$sock" >/dev/null
    wait "$daemon" 2>/dev/null || true
    daemon=
    rm -rf "$work/rec"
}

# One chirp job on the running daemon; prints its p99 wake-up latency, µs.
job_p99() {
    "$bench" chirp --daemon "$sock" --duration-s "$duration" --json >"$work/job.json"
    python3 -c 'import json, sys; print("%.1f" % json.load(open(sys.argv[1]))["timing"]["wake_latency_p99_us"])' "$work/job.json"
}

# Files the store confirmed between the UTC times $1 and $2 (the journal).
confirmed_between() {
    python3 - "$work/rec/upload-journal.jsonl" "$1" "$2" <<'PY'
import json, sys
a, b = sys.argv[2], sys.argv[3]
n = 0
for line in open(sys.argv[1]):
    l = json.loads(line)
    if l["op"] == "confirmed" and a <= l["time_utc"][:19] <= b:
        n += 1
print(n)
PY
}

run() { # $1: without | unscraped | with | uploading
    if [ "$1" = without ]; then
        start_daemon
    elif [ "$1" = uploading ]; then
        start_daemon --metrics 127.0.0.1:0 --upload "$upload_url"
        [ -n "$url" ] || die "no metrics address in: $(cat "$work/serve.err")"
        for _ in $(seq "$backlog"); do
            "$bench" chirp --daemon "$sock" --duration-s 150 --pace off --json >/dev/null
        done
    else
        start_daemon --metrics 127.0.0.1:0
        [ -n "$url" ] || die "no metrics address in: $(cat "$work/serve.err")"
    fi
    if [ "$1" = with ] || [ "$1" = uploading ]; then
        scrape=(python3 -c '
import sys, time, urllib.request
url, every = sys.argv[1], float(sys.argv[2])
next_t = time.monotonic()
while True:
    try:
        urllib.request.urlopen(url, timeout=5).read()
    except OSError:
        pass
    next_t += every
    time.sleep(max(0.0, next_t - time.monotonic()))
' "$url" "$interval")
        if [ -n "$off_cpu" ]; then scrape=(taskset -c "$others" "${scrape[@]}"); fi
        "${scrape[@]}" &
        scraper=$!
    fi
    t0=$(date -u +%Y-%m-%dT%H:%M:%S)
    p99=$(job_p99)
    t1=$(date -u +%Y-%m-%dT%H:%M:%S)
    if [ "$1" = uploading ]; then
        echo "  (uploading: $(confirmed_between "$t0" "$t1") file(s) confirmed by the store during the measured job)" >&2
    fi
    if [ -n "$scraper" ]; then
        kill "$scraper" 2>/dev/null; wait "$scraper" 2>/dev/null || true
        scraper=
    fi
    if [ "$1" != without ]; then
        # The metrics saw the job. (Read whole first: grep -q would close
        # the pipe on curl.)
        text=$(curl -s "$url")
        grep -q '^bench_jobs_total{kind="chirp",outcome="ok"} [1-9]' <<<"$text" ||
            die "the metrics did not count the job"
    fi
    stop_daemon
}

# The kinds of daemon, in a rotating order (a Latin square over the
# rounds): without --metrics; with --metrics, nobody scraping (the tap and
# the server alone); with --metrics scraped every second (the bar).
declare -A results
for round in $(seq 1 "$rounds"); do
    k=$(( (round - 1) % ${#modes[@]} ))
    order=("${modes[@]:$k}" "${modes[@]:0:$k}")
    for mode in "${order[@]}"; do
        run "$mode"
        results[$mode]+="$p99 "
        printf 'round %d %-9s p99 wake-up latency %s µs\n' "$round" "$mode" "$p99"
    done
done

python3 - "${results[without]:-}" "${results[unscraped]:-}" "${results[with]:-}" "${results[uploading]:-}" <<'EOF'
import statistics, sys
names = ["without --metrics", "--metrics, unscraped", "--metrics, scraped every second", "scraped, and uploads running"]
runs = [[float(x) for x in a.split()] for a in sys.argv[1:]]
base = statistics.median(runs[0]) if runs[0] else None
for name, r in zip(names, runs):
    if not r:
        continue
    m = statistics.median(r)
    if base is None:
        base = m
    print(f"{name:32s} median p99 {m:6.1f} µs  ratio {m / base:.3f}  ({' '.join(f'{x:.1f}' for x in sorted(r))})")
print("bar: scraped every second (and uploading) within 1.10 of without")
EOF
