#!/usr/bin/env python
"""A large out-of-core run, measured: a 2D bare bed streamed straight into the store, S sweeps
of K steps, then `checkpoint hash` and `checkpoint verify`, each optionally under a hard
memory limit (a memory cgroup, ooc_dem.engine.memlimit). Prints one JSON object.

    python tools/bigrun.py --discs 2000000 --sweeps 3 --block 20 --memory 1.5GB \\
        --memory-limit 2GB --out /work/big/run

The run itself is `ooc-dem run bed-N --mode ooc` (the same Simulation, plan and streamed
set-up: tiles written into the store as they are made) in a child process; the child
times each sweep's parts - reading the slab and its halo (``read_strip``), computing
(``DomainStepper`` construction and ``advance``), writing the owned discs and committing
(the epoch writer's ``write_domain``, ``commit``), and the rest (``other_s``: assembling
the slab in RAM) - by wrapping those functions, so the engine carries no timing code. Reported: the plan (D, K, expected peak), set-up time, per-sweep read /
compute / write seconds, bytes on disk per disc (the committed epoch's files, and the
whole store while two epochs coexist), each child's peak RSS and cgroup peak, the state
hash and the verify result. Disk is checked first: an epoch is written before the
previous one is dropped, so a run needs about two epochs of free space.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EPOCH_BYTES_PER_DISC = 160  # a committed 2D epoch on disk, hdf5 (156.3 measured at 2e5 discs)
sys.path.insert(0, str(ROOT))


def _timed(owner, name, bucket, key):
    """Wrap owner.name so that its wall time is added to bucket[key]."""
    fn = getattr(owner, name)

    def wrapper(*a, **k):
        t = time.perf_counter()
        try:
            return fn(*a, **k)
        finally:
            bucket[key] += time.perf_counter() - t

    setattr(owner, name, wrapper)


def child(a) -> dict:
    """The run, in this process (under the parent's memory limit)."""
    from ooc_dem.engine import ooc, stepper
    from ooc_dem.app.run import RunOptions, Simulation
    from ooc_dem.model.scenario import load_scenario
    from ooc_dem import storage

    sc = load_scenario(f"bed-{a.discs}", ["decomposition.policy=equal"])
    opts = RunOptions(
        mode="ooc",
        backend=a.backend,
        domains=a.domains,
        block=a.block,
        steps=a.sweeps * a.block,
        memory=a.memory,
        progress=False,
        figures=False,
    )
    sim = Simulation(sc, a.out, opts)
    now = {"read": 0.0, "compute": 0.0, "write": 0.0}
    _timed(ooc, "read_strip", now, "read")
    _timed(stepper.DomainStepper, "__init__", now, "compute")  # its neighbour lists
    _timed(stepper.DomainStepper, "advance", now, "compute")
    sweeps = []
    begin = ooc.OocEngine.sweep

    def timed_sweep(self, step0, k, frame=None):
        for key in now:
            now[key] = 0.0
        t = time.perf_counter()
        rec = begin(self, step0, k, frame)
        wall = time.perf_counter() - t
        sweeps.append(
            {
                "step": step0 + k,
                "wall_s": round(wall, 3),
                **{f"{key}_s": round(v, 3) for key, v in now.items()},
                # assembling slabs in RAM: filling a slab from its strips' records,
                # ordering the owned discs by cell and gathering them into a record
                "other_s": round(wall - sum(now.values()), 3),
            }
        )
        return rec

    ooc.OocEngine.sweep = timed_sweep
    # the epoch writer (storage's public one, in front of every backend): writing the
    # groups and the commit
    for name in ("write_domain", "commit"):
        _timed(storage.EpochWriter, name, now, "write")
    if a.keep_epochs == 1:
        # disk economy: once an epoch is committed the previous one goes (a kill can then
        # only resume from the current epoch; it never leaves less than one whole epoch)
        commit = sim.commit

        def commit_and_prune():
            commit()
            sim.store.prune(1)

        sim.commit = commit_and_prune
    t = time.perf_counter()
    sim.start(streamed=True)
    setup = time.perf_counter() - t
    t = time.perf_counter()
    summary = sim.run()
    return {
        "plan": sim.plan.as_dict(),
        "setup_s": round(setup, 3),
        "run_s": round(time.perf_counter() - t, 3),
        "sweeps": sweeps,
        "state_hash_in_run": summary["state_hash"],
        "engine": {k: summary["engine"].get(k) for k in ("domains", "block", "resident_max")},
    }


def _limited(cmd, limit, env):
    from ooc_dem.engine.memlimit import run_limited

    res = run_limited(cmd, limit, env=env, interval=0.2)
    d = res.as_dict()
    if res.oom_killed:
        d["error"] = res.oom_message(" ".join(cmd[2:5]))
    elif res.returncode != 0:
        d["error"] = (res.stderr.strip().splitlines() or ["(no output)"])[-1]
    return res, d


class _DiskSampler(threading.Thread):
    """The store directory's size, sampled every second (its peak: epochs coexisting)."""

    def __init__(self, out: Path):
        super().__init__(daemon=True)
        self.out, self.peak, self._halt = out, 0, threading.Event()

    def run(self):
        while not self._halt.is_set():
            try:
                size = sum(p.stat().st_size for p in self.out.rglob("*") if p.is_file())
            except OSError:  # a file renamed or deleted while we looked
                size = 0
            self.peak = max(self.peak, size)
            self._halt.wait(1.0)

    def stop(self):
        self._halt.set()
        self.join()


def _epoch_bytes(out: Path) -> tuple[int, int]:
    """(bytes of the current epoch's files, bytes of the whole store directory)."""
    man = json.loads((out / "MANIFEST.json").read_text())
    cur = sum(int(f["size"]) for f in man["current"]["files"])
    total = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
    return cur, total


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--discs", type=int, default=2_000_000)
    ap.add_argument("--sweeps", type=int, default=3)
    ap.add_argument("--block", type=int, default=20, help="K steps per sweep")
    ap.add_argument("--domains", type=int, help="D (default: chosen by --memory, else the scenario's)")
    ap.add_argument("--memory", help="the run's memory budget (ooc-dem run --memory), e.g. 1.5GB")
    ap.add_argument("--memory-limit", help="hard limit for every child (a memory cgroup), e.g. 2GB")
    ap.add_argument("--backend", default="hdf5", choices=["hdf5", "zarr"])
    ap.add_argument(
        "--keep-epochs",
        type=int,
        choices=[1, 2],
        default=2,
        help="committed epochs kept on disk (2: the store's default, current and previous; "
        "1: the previous is deleted after each commit, so a sweep needs 2 epochs of "
        "disk instead of 3)",
    )
    ap.add_argument("--out", required=True, help="the run directory (must not exist)")
    ap.add_argument("--keep", action="store_true", help="keep the store afterwards")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args()
    from ooc_dem.engine.memlimit import parse_size

    if a.child:
        a.memory = parse_size(a.memory) if a.memory else None
        print(json.dumps(child(a)))
        return 0
    out = Path(a.out)
    if out.exists():
        print(f"bigrun: error: --out {out} exists", file=sys.stderr)
        return 2
    limit = parse_size(a.memory_limit) if a.memory_limit else None
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    # the plan first (no files): D, K and the expected peak, and the disk the run needs
    plan_cmd = [
        sys.executable,
        "-m",
        "ooc_dem.cli",
        "check",
        f"bed-{a.discs}",
        "--mode",
        "ooc",
        "--set",
        "decomposition.policy=equal",
        "--block",
        str(a.block),
        "--steps",
        str(a.sweeps * a.block),
        "--backend",
        a.backend,
    ]
    plan_cmd += ["--domains", str(a.domains)] if a.domains else []
    plan_cmd += ["--memory", a.memory] if a.memory else []
    cp = subprocess.run(plan_cmd, capture_output=True, text=True, env=env)
    if cp.returncode != 0:
        print(cp.stderr.strip(), file=sys.stderr)
        return 2
    out.parent.mkdir(parents=True, exist_ok=True)
    free = shutil.disk_usage(out.parent).free
    # an epoch is ~160 B/disc on disk (hdf5, 2D, measured); during a sweep the kept epochs
    # and the one being written coexist
    need_disk = int((a.keep_epochs + 1) * a.discs * EPOCH_BYTES_PER_DISC * 1.05)
    if need_disk > free:
        print(
            f"bigrun: error: about {need_disk / 1e9:.1f} GB of disk needed ({a.keep_epochs + 1} epochs), "
            f"{free / 1e9:.1f} GB free under {out.parent}",
            file=sys.stderr,
        )
        return 2
    doc = {
        "discs": a.discs,
        "sweeps": a.sweeps,
        "block": a.block,
        "backend": a.backend,
        "memory": a.memory,
        "memory_limit_bytes": limit,
        "keep_epochs": a.keep_epochs,
        "disk_free_before_bytes": free,
        "disk_needed_estimate_bytes": need_disk,
        "plan": json.loads(cp.stdout),
    }
    cmd = [
        sys.executable,
        __file__,
        "--child",
        "--discs",
        str(a.discs),
        "--sweeps",
        str(a.sweeps),
        "--block",
        str(a.block),
        "--backend",
        a.backend,
        "--out",
        str(out),
        "--keep-epochs",
        str(a.keep_epochs),
    ]
    cmd += ["--domains", str(a.domains)] if a.domains else []
    cmd += ["--memory", a.memory] if a.memory else []
    t = time.perf_counter()
    disk = _DiskSampler(out)
    disk.start()
    try:
        res, doc["run"] = _limited(cmd, limit, env)
    finally:
        disk.stop()
    doc["run"]["wall_s"] = round(time.perf_counter() - t, 3)
    doc["run"]["store_peak_bytes_sampled"] = disk.peak
    if res.returncode == 0:
        doc["run"].update(json.loads(res.stdout.strip().splitlines()[-1]))
        cur, total = _epoch_bytes(out)
        doc["disk"] = {
            "epoch_bytes": cur,
            "epoch_bytes_per_disc": round(cur / a.discs, 2),
            "store_bytes": total,
            "store_bytes_per_disc": round(total / a.discs, 2),
        }
        sw = doc["run"]["sweeps"]
        if sw:
            io = cur * 2  # a sweep reads the previous epoch and writes the next
            doc["run"]["mean_sweep_s"] = round(sum(s["wall_s"] for s in sw) / len(sw), 3)
            doc["run"]["io_bytes_per_s"] = round(io / doc["run"]["mean_sweep_s"])
            doc["run"]["particle_steps_per_s"] = round(a.discs * a.block / doc["run"]["mean_sweep_s"])
        for what in ("hash", "verify"):
            r, d = _limited([sys.executable, "-m", "ooc_dem.cli", "checkpoint", what, str(out)], limit, env)
            d["output"] = r.stdout.strip().splitlines()[-1] if r.stdout.strip() else ""
            doc[what] = d
        doc["state_hash"] = doc["hash"]["output"]
        doc["hash_matches_run"] = doc["state_hash"] == doc["run"]["state_hash_in_run"]
        doc["verify_ok"] = doc["verify"]["returncode"] == 0
    if not a.keep:
        shutil.rmtree(out, ignore_errors=True)
    print(json.dumps(doc, indent=2))
    return 0 if res.returncode == 0 and doc.get("verify_ok") and doc.get("hash_matches_run") else 1


if __name__ == "__main__":
    sys.exit(main())
