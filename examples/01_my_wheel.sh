#!/usr/bin/env bash
# Tutorial 1: your own 3D wheel and soil (docs/tutorial.md).
# A scenario file that starts from a built-in (base = "quick-3d") and changes a few keys,
# checked, then run briefly. Usage: examples/01_my_wheel.sh [OUT]  (default runs/my-wheel)
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
out="${1:-runs/my-wheel}"

# 1. check: validates the file exactly as `run` would, prints the resolved plan as JSON
#    (particles, steps, time step, estimated memory) and warns of set-ups that run but
#    measure the wrong thing (e.g. side walls inside the wheel's zone of influence).
ooc-dem check "$here/my_wheel.toml"

# 2. run it (the first 3D run compiles the kernels: about a minute, once)
ooc-dem run "$here/my_wheel.toml" --out "$out" --no-progress

# 3. the numbers: summary.json holds every average with its unit
python - "$out" <<'PY'
import json, sys
s = json.load(open(f"{sys.argv[1]}/summary.json"))
for key in ("slip", "net_traction", "sinkage"):
    w = s[key]["steady"]
    lo, hi = w["window_s"]
    print(f"{key:13s} {w['value']:.4g} {s[key].get('unit', '')}  (mean over {lo:.3g}-{hi:.3g} s of travel)")
PY
