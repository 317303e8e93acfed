#!/usr/bin/env bash
# Regenerates the measured figures the README and docs/src/contributing.md
# show between their `<!-- figures:begin -->` and `<!-- figures:end -->`
# markers: the CI steps' times on a clean clone (benches/ci-time.sh) and the
# sizes (benches/sizes.sh). Takes as long as CI does (tens of minutes).
# Usage: benches/readme-figures.sh [CI_TIME_OUTPUT SIZES_OUTPUT] (files of
# an earlier run of each script, to splice without measuring again).
set -euo pipefail
cd "$(dirname "$0")/.."
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
if [ $# -eq 2 ]; then
  cp "$1" "$tmp/ci" && cp "$2" "$tmp/sizes"
else
  benches/ci-time.sh >"$tmp/ci"
  benches/sizes.sh >"$tmp/sizes"
fi
{
  cat "$tmp/ci"
  echo
  echo '```text'
  cat "$tmp/sizes"
  echo '```'
} >"$tmp/figures"
for f in README.md docs/src/contributing.md; do
  python3 - "$f" "$tmp/figures" <<'PY'
import sys
path, figures = sys.argv[1], open(sys.argv[2]).read()
text = open(path).read()
a, b = "<!-- figures:begin -->\n", "<!-- figures:end -->"
i, j = text.index(a) + len(a), text.index(b)
open(path, "w").write(text[:i] + figures + text[j:])
PY
done
echo "figures written into README.md and docs/src/contributing.md"
