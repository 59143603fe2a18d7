#!/usr/bin/env python
"""Peak RSS of `ooc-dem export-trajectory` and `ooc-dem animate` on a synthetic N-disc trajectory.

    python tools/trajectory_memory.py --discs 1000000 --frames 3 --work DIR

Writes DIR/run/trajectory/ (frames of N discs on a jittered grid, written in 8 parts each
as an out-of-core run would) and DIR/run/scenario.toml (quick's wheel), then runs each
command in a fresh interpreter and prints its peak RSS (VmHWM) next to one frame's size.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def peak_rss(cmd) -> tuple[int, float, int]:
    """(VmHWM bytes, wall s, exit code) of cmd, read from /proc before it is reaped."""
    t0 = time.time()
    p = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, cwd=ROOT)
    hwm = 0
    while p.poll() is None:
        try:
            for line in open(f"/proc/{p.pid}/status"):
                if line.startswith("VmHWM"):
                    hwm = max(hwm, int(line.split()[1]) * 1024)
        except OSError:
            pass
        time.sleep(0.05)
    return hwm, time.time() - t0, p.returncode


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--discs", type=int, default=1_000_000)
    ap.add_argument("--frames", type=int, default=3)
    ap.add_argument("--work", required=True)
    a = ap.parse_args()
    from ooc_dem.model.scenario import load_scenario
    from ooc_dem.app.trajectory import TrajectoryWriter

    work = Path(a.work)
    run = work / "run"
    run.mkdir(parents=True, exist_ok=True)
    sc = load_scenario("quick")
    n = a.discs
    side = int(np.ceil(np.sqrt(n * 8)))  # a bin 8x wider than high
    r = 0.5 * sc.bin.length / side
    length = sc.bin.length
    sc = dataclasses.replace(sc, soil=dataclasses.replace(sc.soil, n=n))
    (run / "scenario.toml").write_text(sc.to_toml())
    w = TrajectoryWriter.create(run, sc, 2, n)
    rng = np.random.default_rng(0)
    ids = np.arange(n)
    gx = (ids % side + 0.5) * 2 * r
    gy = (ids // side + 0.5) * 2 * r
    for k in range(a.frames):
        step = k * w.every
        for part in np.array_split(rng.permutation(n), 8):
            w.write_part(
                step,
                {
                    "id": part,
                    "pos": np.column_stack([gx[part], gy[part]]) + k * 1e-4,
                    "vel": np.zeros((len(part), 2)),
                    "spin": np.zeros((len(part), 1)),
                    "r": np.full(len(part), r),
                    "mat": np.zeros(len(part), np.int32),
                },
            )
        w.end(step, step * sc.physics.dt, [0.5 * length, side / 8 * 2 * r + 0.12, 0.01, 0, 0.1 * k, -1.0])
    w.close()
    frame_bytes = n * (8 + 16 + 16 + 8 + 8 + 4)
    cli = [sys.executable, "-m", "ooc_dem.cli"]
    rows = {"discs": n, "frames": a.frames, "frame_bytes": frame_bytes}
    base, _, _ = peak_rss([sys.executable, "-c", "import numpy, h5py, matplotlib.pyplot"])
    rows["baseline_rss"] = base
    for name, cmd in (
        ("export-trajectory", cli + ["export-trajectory", run, "--out", work / "t.xdmf"]),
        ("animate", cli + ["animate", run, "--out", work / "t.mp4", "--no-progress"]),
    ):
        hwm, wall, rc = peak_rss(list(map(str, cmd)))
        rows[name] = {"peak_rss": hwm, "above_baseline": hwm - base, "wall_s": round(wall, 1), "exit": rc}
    print(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
