#!/usr/bin/env bash
# Tutorial 2: a drawbar pull-slip curve with error bars (docs/tutorial.md).
# `ooc-dem sweep` runs one slip-controlled run per slip from the same settled bed and writes
# the curve with each point's 95 % interval (drawbar_pull_slip.csv, .png); run again with
# more slips it extends the curve; `ooc-dem report` re-plots it.
# Usage: examples/02_slip_sweep.sh [OUT]  (default runs/sweep)
set -euo pipefail
out="${1:-runs/sweep}"

# the 2D quick rig, shortened: 0.1 s of settling, 1.2 s of travel, the steady window the
# last 1.05 s of it: two whole lug passages, flagged as short (a real curve wants the full
# travel and more slips)
short=(--set wheel.settle_time=0.1 --set wheel.travel_time=1.2
       --set output.steady_start=0.15 --set output.steady_end=1.2)
ooc-dem sweep quick --slips 0.1,0.5 --out "$out" --no-progress "${short[@]}"
# one more slip: the two finished runs are reused
ooc-dem sweep quick --slips 0.1,0.3,0.5 --out "$out" --no-progress "${short[@]}"
ooc-dem report "$out"
