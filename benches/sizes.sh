#!/usr/bin/env bash
# The sizes the README and the book quote: the release binary (with the line
# tables the release profile keeps; and stripped, for comparison), whether
# its backtraces name files and lines, and the test binaries of the workspace
# (their count and sizes). Builds what is missing. Usage: benches/sizes.sh
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release --locked -q
bin="${CARGO_TARGET_DIR:-target}/release/bench"
size_mb() { echo "$(($(stat -c %s "$1") / 1000000)) MB"; }
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
cp "$bin" "$tmp/bench" && strip "$tmp/bench"
echo "release binary: $(size_mb "$bin") (stripped: $(size_mb "$tmp/bench"))"
# Readable backtraces: the line tables (.debug_line) are in the binary,
# the rest of the debug information (.debug_info's types and variables) is
# not: a panic's backtrace names file and line.
hex=$(readelf -S -W "$bin" | awk '{for (i = 1; i <= NF; i++) if ($i == ".debug_line") print $(i + 4)}')
echo "release line tables (.debug_line, as stored): $((16#${hex:-0} / 1000)) kB"
# build.rs has the linker compress the debug sections (zlib): the flag C.
flags=$(readelf -S -W "$bin" | awk '$0 ~ /\.debug_line/ {print $(NF - 3)}')
case "$flags" in
*C*) echo "debug sections: compressed (zlib; std's backtrace reads them)" ;;
*) echo "debug sections: not compressed (flags '$flags')" ;;
esac
cargo test --workspace --locked --no-run 2>"$tmp/list" || { cat "$tmp/list"; exit 1; }
echo "test binaries:"
grep -o 'Executable [^ ]* ([^)]*)' "$tmp/list" | sed 's/Executable //' | while read -r name path; do
  path=${path#(}
  path=${path%)}
  echo "  $name $(size_mb "$path")"
done
