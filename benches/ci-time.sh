#!/usr/bin/env bash
# Times CI on a clean clone of this repository's HEAD, step by step as
# .ci/run runs them, then the contributor's inner loop: a one-line change
# in src/ and `cargo test` rebuilding and running. Prints one Markdown
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
step "test build (cargo test --no-run)" cargo test --workspace --locked --no-run
step "tests/run (every test)" tests/run
mkdir -p recordings
step "smoke: bench chirp (the tests' build)" target/debug/bench chirp
step "smoke: bench control --fast" target/debug/bench control --fast
total1=$(date +%s.%N)
rows+=("| **CI total (.ci/run's steps)** | **$(printf '%.0f' "$(echo "$total1 - $total0" | bc)")** |")
# The inner loop: a one-line change in src/ (a comment at the end of the
# library's root, so the library and every test binary build again); the
# run that follows is the "tests/run" row above.
echo "// ci-time: a one-line change" >>src/lib.rs
step "one-line change in src/: rebuild (cargo test --no-run)" cargo test --workspace --locked --no-run
git checkout -q src/lib.rs
echo "| step | seconds |"
echo "|---|---|"
printf '%s\n' "${rows[@]}"
echo
echo "machine: $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs), $(date -u +%F)"
echo "target directory after the run: $(du -sh target | cut -f1); test binaries: $(find target/debug/deps -maxdepth 1 -type f -executable -name '*-*' ! -name '*.so' ! -name 'build-script*' | xargs -r -n1 basename | sed 's/-[0-9a-f]*$//' | sort -u | tr '\n' ' ')"
