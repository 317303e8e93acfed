#!/usr/bin/env bash
# Times CI on a clean clone of this repository's HEAD, step by step as
# .ci/run runs them, then the contributor's inner loop: a one-line change
# in src/, `cargo test` rebuilding (incremental, as cargo's default) and
# the library's unit tests running. Prints one Markdown
# table (step, seconds) and the disk the build took; the README and
# docs/src/contributing.md quote it. Usage: benches/ci-time.sh [WORKDIR]
# (default: a fresh temporary directory, removed afterwards).
# Needs what tests/run installs (run that once first, so that the apt and
# pip installs are not timed; they are cached on a CI machine too).
set -euo pipefail
src="$(cd "$(dirname "$0")/.." && pwd)"
work="${1:-$(mktemp -d)}"
keep="${1:+yes}"
trap '[ -n "$keep" ] || rm -rf "$work"' EXIT
# mktemp -d makes it 0700: the tests that run `bench` as another user
# (uid 65534: the daemon's socket refuses it) must reach the binary, as in
# any checkout others can read.
chmod a+rx "$work"
git clone -q "$src" "$work/bench"
cd "$work/bench"
export CARGO_TERM_COLOR=never CARGO_TARGET_DIR="$work/bench/target" CARGO_INCREMENTAL="${CARGO_INCREMENTAL:-0}"
declare -a rows
step() { # NAME COMMAND...
  local name=$1
  shift
  local t0 t1
  t0=$(date +%s.%N)
  local status=ok log
  log="$work/$(echo "$name" | tr -c 'A-Za-z0-9\n' '_').log"
  "$@" >"$log" 2>&1 || { status=FAILED; echo "step '$name' failed: $log" >&2; tail -n 30 "$log" >&2 || true; }
  t1=$(date +%s.%N)
  rows+=("| $name | $(printf '%.0f' "$(echo "$t1 - $t0" | bc)")$([ $status = ok ] || echo " ($status)") |")
}
total0=$(date +%s.%N)
step "cargo fmt --check" cargo fmt --all -- --check
step "cargo clippy (all targets)" cargo clippy --workspace --all-targets --locked -- -D warnings
step "test build (cargo test --no-run)" cargo test --workspace --locked --no-run --timings
# Where the build's time went, crate by crate (cargo's --timings report),
# kept beside the checkout's own target directory.
mkdir -p "$src/target" && cp target/cargo-timings/cargo-timing.html "$src/target/ci-time-build-timings.html" 2>/dev/null || true
step "tests/run (every test)" tests/run
mkdir -p recordings
step "smoke: bench chirp (the tests' build)" target/debug/bench chirp
step "smoke: bench control --fast" target/debug/bench control --fast
total1=$(date +%s.%N)
rows+=("| **CI total (.ci/run's steps)** | **$(printf '%.0f' "$(echo "$total1 - $total0" | bc)")** |")
# The inner loop, as a contributor has it: incremental compilation on
# (cargo's default for the dev profile; CI turns it off), its caches made
# by one build first (not timed), then a one-line change in src/ (an item
# added to the library's root: its metadata changes, so the library and
# every test binary build again), the rebuild, and the library's unit tests (the hal's and the
# application's, `cargo test --lib`).
# (touched: after CI's non-incremental build cargo finds them fresh, and
# would make no caches).
touch src/lib.rs hal/*/src/lib.rs
CARGO_INCREMENTAL=1 cargo test --workspace --locked --no-run >"$work/incremental-warm.log" 2>&1
echo "#[doc(hidden)] pub const CI_TIME_ONE_LINE: u32 = 1; // ci-time: a one-line change" >>src/lib.rs
export CARGO_INCREMENTAL=1
step "inner loop: one-line change in src/, rebuild (cargo test --no-run, incremental)" cargo test --workspace --locked --no-run
step "inner loop: then the library's unit tests (cargo test --workspace --lib)" cargo test --workspace --locked --lib
git checkout -q src/lib.rs
echo "| step | seconds |"
echo "|---|---|"
printf '%s\n' "${rows[@]}"
echo
echo "machine: $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), $(date -u +%F)"
echo "target directory after the run: $(du -sh target | cut -f1); test binaries: $(find target/debug/deps -maxdepth 1 -type f -executable -name '*-*' ! -name '*.so' ! -name 'build-script*' | xargs -r -n1 basename | sed 's/-[0-9a-f]*$//' | sort -u | tr '\n' ' ')"
