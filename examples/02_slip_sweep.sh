#!/usr/bin/env bash
# Tutorial 2: a drawbar pull-slip curve with error bars (docs/tutorial.md).
# `ooc-dem sweep` runs one slip-controlled run per slip from the same settled bed and writes
# the curve (drawbar_pull_slip.csv, .png); slip_errorbars.py adds each point's standard error
# from the run's own time series. Usage: examples/02_slip_sweep.sh [OUT]  (default runs/sweep)
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
out="${1:-runs/sweep}"

# the 2D quick rig, shortened: 0.1 s of settling, 0.4 s of travel, the steady window the
# last 0.3 s of it (a real curve wants the full travel and more slips)
ooc-dem sweep quick --slips 0.1,0.3,0.5 --out "$out" --no-progress \
    --set wheel.settle_time=0.1 --set wheel.travel_time=0.4 \
    --set output.steady_start=0.1 --set output.steady_end=0.4

python "$here/slip_errorbars.py" "$out"
