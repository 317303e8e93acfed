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
#   -T  with an s3:// -U: uploads paced to this many MB/s by a proxy the
#       script runs in front of AWS_ENDPOINT (off the loop's CPU with -o),
#       so that they last through the measured job as a store across a
#       lab network would make them (a store on loopback takes 13 MB in
#       0.15 s)
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
throttle=
while getopts "d:r:c:i:om:B:U:n:T:h" opt; do
    case $opt in
        d) duration=$OPTARG ;;
        r) rounds=$OPTARG ;;
        c) cpu=$OPTARG ;;
        i) interval=$OPTARG ;;
        o) off_cpu=1 ;;
        m) IFS=, read -r -a modes <<<"$OPTARG"; modes_given=1 ;;
        U) upload_url=$OPTARG ;;
        n) backlog=$OPTARG ;;
        T) throttle=$OPTARG ;;
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
if [ -n "$throttle" ]; then
    [[ $throttle =~ ^[0-9.]+$ ]] || die "-T: MB/s (got $throttle)"
    [[ $upload_url == s3://* ]] || die "-T needs an s3:// store (-U)"
    [[ ${AWS_ENDPOINT:-} =~ ^http://([^:/]+):([0-9]+)/?$ ]] || die "-T needs AWS_ENDPOINT=http://HOST:PORT (got ${AWS_ENDPOINT:-nothing})"
fi
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
proxy=
cleanup() {
    [ -n "$scraper" ] && kill "$scraper" 2>/dev/null
    [ -n "$daemon" ] && kill "$daemon" 2>/dev/null
    [ -n "$proxy" ] && kill "$proxy" 2>/dev/null
    wait 2>/dev/null
    rm -rf "$work"
}
trap cleanup EXIT

# The pacing proxy of -T: every connection to the store forwarded, what
# goes to the store paced to $throttle MB/s per connection (a multipart
# upload has up to two parts in flight).
proxy=
if [ -n "$throttle" ]; then
    pace=(python3 -u -c '
import asyncio, sys
host, port, rate = sys.argv[1], int(sys.argv[2]), float(sys.argv[3]) * 1e6
async def pump(r, w, paced):
    try:
        while data := await r.read(65536):
            if paced:
                await asyncio.sleep(len(data) / rate)
            w.write(data)
            await w.drain()
    except OSError:
        pass
    finally:
        w.close()
async def serve(cr, cw):
    sr, sw = await asyncio.open_connection(host, port)
    await asyncio.gather(pump(cr, sw, True), pump(sr, cw, False))
async def main():
    srv = await asyncio.start_server(serve, "127.0.0.1", 0)
    print(srv.sockets[0].getsockname()[1], flush=True)
    await srv.serve_forever()
asyncio.run(main())
' "${BASH_REMATCH[1]}" "${BASH_REMATCH[2]}" "$throttle")
    if [ -n "$off_cpu" ]; then pace=(taskset -c "$others" "${pace[@]}"); fi
    "${pace[@]}" >"$work/proxy.port" &
    proxy=$!
    for _ in $(seq 100); do [ -s "$work/proxy.port" ] && break; sleep 0.05; done
    [ -s "$work/proxy.port" ] || die "-T: the pacing proxy did not start"
    export AWS_ENDPOINT="http://127.0.0.1:$(cat "$work/proxy.port")"
fi

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

# The backlog's uploads against the measured job (its files are
# `-job<backlog+1>.`), from the journal: how many of the backlog's files
# the store confirmed between the UTC times $1 and $2, and when the last
# of them was confirmed, s after $1.
backlog_during() {
    python3 - "$work/rec/upload-journal.jsonl" "$1" "$2" "-job$((backlog + 1))." <<'PY'
import datetime, json, sys
path, a, b, mine = sys.argv[1:5]
t = lambda s: datetime.datetime.fromisoformat(s.replace("Z", "+00:00")).timestamp()
ta, tb = t(a + "Z"), t(b + "Z")
times = [t(l["time_utc"]) for l in map(json.loads, open(path))
         if l["op"] == "confirmed" and mine not in l["key"]]
during = [x for x in times if ta <= x <= tb + 1]
last = max(times) - ta if times else float("nan")
print(f"{len(during)} of {len(times)} backlog files confirmed during the {tb - ta:.0f} s job, the last at {last:+.1f} s")
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
        echo "  (uploading: $(backlog_during "$t0" "$t1"))" >&2
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
