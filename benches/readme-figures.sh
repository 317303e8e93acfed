#!/usr/bin/env bash
# Regenerates the measured figures the README and docs/src/contributing.md
# show between their `<!-- figures:begin -->` and `<!-- figures:end -->`
# markers: the CI steps' times on a clean clone and the contributor's inner
# loop (benches/ci-time.sh) and the sizes (benches/sizes.sh). The README
# gets three rows (CI, inner loop, release binary), the contributing page
# both outputs in full. Takes as long as CI does (tens of minutes).
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
python3 - "$tmp/ci" "$tmp/sizes" <<'PY'
import re
import sys

sys.path.insert(0, "benches")
from figures import splice  # noqa: E402

ci, sizes = open(sys.argv[1]).read(), open(sys.argv[2]).read()
rows = {}
for line in ci.splitlines():
    m = re.match(r"\| (.+?) \| (\d+)( \(FAILED\))? \|$", line.replace("**", ""))
    if m:
        rows[m.group(1)] = (int(m.group(2)), bool(m.group(3)))
if any(failed for _, failed in rows.values()):
    sys.exit("a step failed: figures not written\n" + ci)
machine = next(l for l in ci.splitlines() if l.startswith("machine:"))
date = machine.rsplit(",", 1)[1].strip()


def seconds(prefix):
    return next(s for name, (s, _) in rows.items() if name.startswith(prefix))


total = seconds("CI total")
clippy = seconds("cargo clippy")
build = seconds("test build")
tests = seconds("tests/run")
smoke = seconds("smoke: bench chirp") + seconds("smoke: bench control")
rebuild = seconds("inner loop: one-line change")
unit = seconds("inner loop: then")
binary = re.search(r"release binary: (\d+) MB \(stripped: (\d+) MB\)", sizes)
verdict = lambda ok: "met" if ok else "not met"
readme = f"""Measured by `benches/readme-figures.sh` on {date} ({machine[len('machine: '):].rsplit(',', 1)[0]}; the scripts' whole output and how it was made: [contributing](docs/src/contributing.md)):

| what | figure |
|---|---|
| CI on a clean clone (`.ci/run`: fmt, clippy, test build, every test, smoke) | {total / 60:.1f} min: clippy {clippy / 60:.1f}, test build {build / 60:.1f}, every test {tests / 60:.1f}, smoke {smoke / 60:.1f} (target ≤ 30 min: {verdict(total <= 1800)}) |
| inner loop: a one-line change in `src/`, rebuild (incremental), then the library's unit tests | {rebuild} s + {unit} s = {(rebuild + unit) / 60:.1f} min (target ≤ 3 min: {verdict(rebuild + unit <= 180)}) |
| release binary (`cargo build --release`: line tables, compressed) | {binary.group(1)} MB ({binary.group(2)} MB stripped) |
"""
book = ci.rstrip() + "\n\n```text\n" + sizes.rstrip() + "\n```\n"
for path, figures in [("README.md", readme), ("docs/src/contributing.md", book)]:
    splice(path, "figures", figures)
PY
echo "figures written into README.md and docs/src/contributing.md"
