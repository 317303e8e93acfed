#!/usr/bin/env bash
# Time of `bench chirp` on the densest FRF grid the config allows (issue 25:
# 10 000 points per decade at a relative resolution of 0.2 %, a 5 s chirp
# of the shipped Chapter 5 bench, in virtual time): the whole process
# (the simulated run, the FRF on 37 000 lines, the modal fit that thins
# it to 1 000 per decade, the CSV, the figures), beside the same chirp on
# the default grid (400 points per decade). Before the fit thinned the
# grid its post-processing took 104 s. The test
# `cli::the_densest_grid_post_processes_every_point_and_an_interrupt_there_finishes_it`
# checks what the run writes; the seconds are measured here, not there.
#
#   benches/dense-grid-time.sh [BENCH [ROUNDS]]
#   (defaults: target/release/bench, 3 rounds)
set -euo pipefail
bin=$(realpath "${1:-target/release/bench}")
rounds=${2:-3}
cfg=$(realpath bench-config/sr4dof-ch5.toml)
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
cd "$work"
sed -e 's/^points_per_decade = 400 /points_per_decade = 10000 /' \
    -e 's/^relative_resolution = 0.004 /relative_resolution = 0.002 /' "$cfg" > dense.toml
grep -q '^points_per_decade = 10000 ' dense.toml
grep -q '^relative_resolution = 0.002 ' dense.toml
now() { date +%s.%N; }
for i in $(seq "$rounds"); do
  for grid in dense default; do
    c=dense.toml; [ $grid = dense ] || c="$cfg"
    rm -f run.*
    start=$(now)
    "$bin" chirp --duration-s 5 --json --config "$c" --out run.mcap > summary.json 2> log.txt
    end=$(now)
    rows=$(($(wc -l < run.frf.csv) - 1))
    python3 -c "print(f'run $i, $grid grid: {$end - $start:.2f} s as a process, {$rows} CSV rows')"
  done
done
