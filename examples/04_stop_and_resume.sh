#!/usr/bin/env bash
# Tutorial 4: stopping and resuming a run (docs/tutorial.md).
# (a) a planned stop: run the first steps, resume to the end later;
# (b) an unplanned one: a run killed with SIGKILL (a crash, a job's time limit), resumed.
# Both end with the same bits as the run left alone. Usage: examples/04_stop_and_resume.sh [OUT]
set -euo pipefail
out="${1:-runs/resume}"
# the 2D quick rig, shortened to 0.1 s of settling and 0.6 s of travel: 70 000 steps of 1e-5 s
short=(--set wheel.settle_time=0.1 --set wheel.travel_time=0.6
       --set output.steady_start=0.2 --set output.steady_end=0.6 --no-progress)

# the reference: left alone from start to end
ooc-dem run quick "${short[@]}" --out "$out/whole"

# (a) planned: stop after 30 000 steps (an epoch is committed there), continue to 70 000
ooc-dem run quick "${short[@]}" --steps 30000 --out "$out/planned"
ooc-dem checkpoint list "$out/planned"
ooc-dem resume "$out/planned" --steps 70000 --no-progress

# (b) unplanned: commit an epoch every 10 000 steps, kill the run once one is committed
ooc-dem run quick "${short[@]}" --checkpoint-every 10000 --out "$out/killed" &
run=$!
until python -c "import json, sys; sys.exit(json.load(open('$out/killed/MANIFEST.json'))['current']['step'] < 10000)" 2>/dev/null; do
    sleep 0.2
done
kill -KILL "$run" || true   # (the run may just have finished: then there is nothing to redo)
wait "$run" || echo "run killed (exit $?)"
ooc-dem checkpoint list "$out/killed"
ooc-dem resume "$out/killed" --no-progress   # from the last committed epoch to the end

# all three end with the same state, bit for bit
ooc-dem compare "$out/whole" "$out/planned"
ooc-dem compare "$out/whole" "$out/killed"
