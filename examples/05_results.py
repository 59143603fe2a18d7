"""Tutorial 5: a run's results in pandas, and its trajectory for ParaView (docs/tutorial.md).

Runs a short 2D quick case from Python (or opens a run made by `ooc-dem run` if RUN exists),
loads the time series and the final state into pandas DataFrames, and writes the trajectory
as an XDMF time series and the final state as a VTK file that ParaView opens.
Usage: python examples/05_results.py [RUN]  (default runs/quick-short)
"""

import subprocess
import sys
from pathlib import Path

import pandas as pd

import ooc_dem

run_dir = Path(sys.argv[1] if len(sys.argv) > 1 else "runs/quick-short")

# 1. a run: made here through the Python API, or one `ooc-dem run` made before
if (run_dir / "summary.json").exists():
    res = ooc_dem.open_run(run_dir)
else:
    short = {"wheel": {"settle_time": 0.1, "travel_time": 0.3}, "output": {"steady_start": 0.1, "steady_end": 0.3}}
    sc = ooc_dem.load_scenario("quick", overrides=short)
    res = ooc_dem.run(sc, out=run_dir)  # the same run as `ooc-dem run quick --set ... --out RUN`

# 2. the time series (series.csv: one row per output.series_interval, SI units)
df = res.to_pandas()
steady = df[df["t_travel"] >= 0.1]  # s of travel; negative while the wheel settles
print(steady[["slip", "net_traction", "torque", "sinkage"]].describe().round(4))

# 3. the final state: one row per disc, sorted by id (pos is (N, 2) in 2D, (N, 3) in 3D)
state = res.state()
discs = pd.DataFrame(
    {"id": state["id"], "x": state["pos"][:, 0], "y": state["pos"][:, 1], "r": state["r"], "vx": state["vel"][:, 0]}
)
print(discs.describe().round(4))
print("discs within 5 cm of the axle along x:", int((abs(discs["x"] - df["x"].iloc[-1]) < 0.05).sum()))

# 4. for ParaView (or meshio): the trajectory frames as XDMF 3 time series (the discs in
#    trajectory.xdmf + .h5, the wheel in trajectory-wheel.xdmf + .h5), and the final state
#    as VTK (or XDMF, CSV).
#    ParaView opens both (File > Open; an XDMF reader for the .xdmf).
export = run_dir.parent / f"{run_dir.name}-export"
export.mkdir(exist_ok=True)
subprocess.run(["ooc-dem", "export-trajectory", str(run_dir), "--out", str(export / "trajectory.xdmf")], check=True)
subprocess.run(["ooc-dem", "checkpoint", "export", str(run_dir), "--out", str(export / "final.vtp")], check=True)
with res.trajectory() as frames:
    print(len(frames), "trajectory frames, t =", ", ".join(f"{t:.2f}" for t in frames.times), "s")
print("for ParaView:", *sorted(p.name for p in export.iterdir()))
