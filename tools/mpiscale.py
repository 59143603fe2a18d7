#!/usr/bin/env python
"""Strong scaling of ``--mode mpi`` on this machine, and the inputs of the scaling model.

For each scenario: the same run (same D, K, steps) with 1 and with 2 MPI ranks of one
numba thread each (``mpiexec -n R``, ``NUMBA_NUM_THREADS=1``), beside the monolithic
run in one process with 2 threads; configurations alternate within each repeat, and the
best of the repeats is kept (this machine varies by 15-25 % from run to run). A run's
time is the ``wall_time_s`` of its ``summary.json`` (the steps and their epochs, without
interpreter start and bed set-up). The hashes must agree (bit-identical modes).

Each scenario is given as NAME[:D[:K[:STEPS]]] (the flags --domains, --block, --steps
fill what an entry leaves out). ``--wheel-x0`` runs each wheel scenario again with the
wheel set down at those x (the load balance changes as the wheel travels: the paper's
wheel slab is half of paper2008's bin), so one report covers the run's start and end.

Then a ping-pong of ``Sendrecv`` between two ranks through the MPI's shared memory gives
the latency and bandwidth, and the model (docs/benchmarks.md, "Scaling model") predicts the
efficiency of R ranks on a larger bed from: the time per particle-step of one rank, the
halo rows and messages per block measured here, and those two MPI numbers.

    python tools/mpiscale.py                    # bed-1000000 (D 8, K 20) and paper2008 (D 3, K 4)
    python tools/mpiscale.py --scenarios paper2008:3:4:4000 --wheel-x0 0.15,0.32
    python tools/mpiscale.py --scenarios bed-100000 --steps 200 --repeat 1
    python tools/mpiscale.py --pingpong-only

Prints one JSON object per run, then the report (one JSON object).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# a ping-pong child (run under mpiexec -n 2): round trips of Sendrecv-paired messages
_PINGPONG = r"""
import json, sys, time
import numpy as np
from mpi4py import MPI
comm = MPI.COMM_WORLD
rank = comm.Get_rank()
other = 1 - rank
out = {}
for nbytes in (8, 1 << 10, 1 << 16, 1 << 20, 1 << 24):
    send = np.ones(nbytes, np.uint8)
    recv = np.empty(nbytes, np.uint8)
    reps = max(5, min(2000, (64 << 20) // nbytes))
    for _ in range(3):
        comm.Sendrecv(send, dest=other, recvbuf=recv, source=other)
    comm.Barrier()
    t = time.perf_counter()
    for _ in range(reps):
        comm.Sendrecv(send, dest=other, recvbuf=recv, source=other)
    el = (time.perf_counter() - t) / reps
    out[str(nbytes)] = el
if rank == 0:
    print(json.dumps(out))
"""


def pingpong(mpiexec: str) -> dict:
    """Seconds per exchange of n bytes each way, latency (8 B) and bandwidth (16 MiB)."""
    cp = subprocess.run(
        [mpiexec, "-n", "2", sys.executable, "-c", _PINGPONG],
        capture_output=True,
        text=True,
        env=dict(os.environ),
        timeout=600,
    )
    if cp.returncode != 0:
        raise SystemExit(f"mpiscale: the ping-pong failed: {cp.stderr.strip().splitlines()[-1:]}")
    times = {int(k): v for k, v in json.loads(cp.stdout.strip().splitlines()[-1]).items()}
    big = max(times)
    return {
        "seconds_per_exchange": {str(k): round(v, 9) for k, v in sorted(times.items())},
        "latency_s": times[8],
        "bandwidth_bytes_per_s": big / (times[big] - times[8]),
    }


def run_once(
    scenario: str,
    mode: str,
    ranks: int,
    threads: int,
    steps: int,
    domains: int,
    block: int,
    overrides: list[str],
    work: Path,
    mpiexec: str | None = None,
    extra=(),
) -> dict:
    """One `ooc-dem run` (under ``mpiexec -n ranks`` for the MPI modes), measured by its
    summary.json; ``extra``: more command-line flags."""
    out = work / f"{scenario}-{mode}-{ranks}r-{threads}t"
    shutil.rmtree(out, ignore_errors=True)
    cmd = [
        sys.executable,
        "-m",
        "ooc_dem.cli",
        "run",
        scenario,
        "--mode",
        mode,
        "--steps",
        str(steps),
        "--checkpoint-every",
        str(steps),
        "--out",
        str(out),
        "--no-progress",
        "--no-figures",
    ]
    if mode != "monolithic":
        cmd += ["--domains", str(domains)] + (["--block", str(block)] if block else [])  # 0: the mode's own K
    for s in overrides:
        cmd += ["--set", s]
    cmd += list(extra)
    if mode in ("mpi", "mpi-ooc"):
        cmd = [mpiexec, "-n", str(ranks), *cmd]
    env = {**os.environ, "NUMBA_NUM_THREADS": str(threads), "PYTHONPATH": str(ROOT)}
    t = time.perf_counter()
    cp = subprocess.run(cmd, capture_output=True, text=True, env=env)
    total = time.perf_counter() - t
    if cp.returncode != 0:
        raise SystemExit(f"mpiscale: {' '.join(cmd)} failed: {cp.stderr.strip().splitlines()[-1:]}")
    s = json.loads((out / "summary.json").read_text())
    eng = s.get("engine") or {}
    shutil.rmtree(out, ignore_errors=True)
    return {
        "scenario": scenario,
        "mode": mode,
        "flags": list(extra),
        "ranks": ranks,
        "threads_per_rank": threads,
        "steps": steps,
        "domains": eng.get("domains"),
        "block": eng.get("block"),
        "n": s["n_discs"],
        "wall_time_s": s["wall_time_s"],
        "process_s": round(total, 3),
        "particle_steps_per_s": s["n_discs"] * steps / s["wall_time_s"],
        "state_hash": s["state_hash"],
        "engine": eng,
    }


def model(one: dict, two: dict, pp: dict, dtype_bytes: int, n_target: float, ranks_list) -> dict:
    """Efficiency of R ranks on an n_target-disc bed of the same depth, K and halo.

    Per block of K steps a rank computes its N/R discs (t_ps seconds per particle-step on
    one core, measured with one rank) and then pays a cost per block that does not shrink
    with N/R: the exchange of a halo strip of fixed width with each of its two neighbours
    (a bed of the same depth with more discs is longer, with the same discs per metre) and
    the Python work around it (packing rows, the refresh, the ownership update, the
    rebuild decision's allreduce). That cost is measured, not assumed: the 2-rank run's
    time minus half the 1-rank run's, per block, is what one neighbour exchange costs
    (rank 0 of 2 has one neighbour; with more ranks each has two, so twice that; the larger
    rank's share of the discs is taken off first, so imbalance is not counted), plus
    2 log2(R) latencies for the collectives. The wire part alone (the ping-pong's latency
    and bandwidth for the rows and messages actually sent) is given beside it."""
    import math

    K = one["block"]
    blocks = one["steps"] / K
    t_ps = one["wall_time_s"] / (one["n"] * one["steps"])  # one rank, one core
    eng2 = two["engine"]
    rows_strip = eng2["rank0_halo_rows_sent"] / blocks
    msgs_neighbour = eng2["rank0_messages"] / blocks
    lat, bw = pp["latency_s"], pp["bandwidth_bytes_per_s"]
    wire = msgs_neighbour * lat + rows_strip * dtype_bytes / bw
    # the 2-rank run's slower rank holds this share of the discs (its compute: that share of
    # the 1-rank run's); the rest of its time is the per-block cost
    share = max(eng2.get("rank_discs") or [one["n"] / 2]) / one["n"]
    per_neighbour = max((two["wall_time_s"] - one["wall_time_s"] * share) / blocks, wire)
    out = {
        "t_particle_step_s": t_ps,
        "largest_rank_share_of_2": share,
        "halo_rows_per_neighbour_per_block": rows_strip,
        "messages_per_neighbour_per_block": msgs_neighbour,
        "row_bytes": dtype_bytes,
        "wire_s_per_neighbour_per_block": wire,
        "measured_s_per_neighbour_per_block": per_neighbour,
        "n_target": n_target,
        "block": K,
        "predicted": [],
    }

    def cost(R):
        return 2 * per_neighbour + 2 * math.log2(max(R, 2)) * lat

    for R in ranks_list:
        comp = n_target / R * K * t_ps
        c = cost(R)
        out["predicted"].append(
            {
                "ranks": R,
                "discs_per_rank": n_target / R,
                "compute_per_block_s": comp,
                "exchange_per_block_s": c,
                "efficiency": comp / (comp + c),
            }
        )
    # below this many discs per rank (1024 ranks' collectives) the efficiency is under 80 %
    n_min = 4.0 * cost(1024) / (K * t_ps)
    out["discs_per_rank_at_80_percent"] = n_min
    out["slab_width_at_80_percent_m"] = n_min / one["discs_per_m"] if one.get("discs_per_m") else None
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--scenarios", default="bed-1000000:8:20:200,paper2008:3:4:4000", help="NAME[:D[:K[:STEPS]]], comma-separated"
    )
    ap.add_argument("--steps", type=int, default=400)
    ap.add_argument("--domains", type=int, default=8)
    ap.add_argument("--block", type=int, default=20)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--set", action="append", default=[], help="scenario override for every run")
    ap.add_argument("--wheel-x0", default="", help="also run each wheel scenario with wheel.x0 at these x (m)")
    ap.add_argument("--target", type=float, default=1e8, help="discs of the modelled bed")
    ap.add_argument("--pingpong-only", action="store_true")
    a = ap.parse_args(argv)
    mpiexec = shutil.which("mpiexec")
    if mpiexec is None:
        print("mpiscale: no mpiexec on PATH (pip install 'ooc-dem[mpi]')", file=sys.stderr)
        return 2
    load0 = os.getloadavg()
    pp = pingpong(mpiexec)
    print(json.dumps({"pingpong": pp}), flush=True)
    if a.pingpong_only:
        return 0
    from ooc_dem.engine.mpi import row_words
    from ooc_dem.engine.stepper import Model
    from ooc_dem.model.scenario import load_scenario

    report = {"tool": "tools/mpiscale.py", "pingpong": pp, "scenarios": []}
    cases = []
    for item in a.scenarios.split(","):
        name, *rest = item.split(":")
        try:
            D, K, steps = [int(v) for v in rest] + [a.domains, a.block, a.steps][len(rest) :]
        except ValueError:
            ap.error(f"--scenarios entry {item!r}: NAME[:D[:K[:STEPS]]] with integers")
        cases.append((name, D, K, steps, list(a.set)))
        if a.wheel_x0 and load_scenario(name, a.set).wheel.enabled:
            cases += [(name, D, K, steps, [*a.set, f"wheel.x0={x}"]) for x in a.wheel_x0.split(",")]
    with tempfile.TemporaryDirectory(prefix="mpiscale-") as tmp:
        work = Path(tmp)
        for scen, D, K, steps, sets in cases:
            # a first run of each configuration warms numba's cache and the bed cache
            configs = [("monolithic", 1, 2), ("mpi", 1, 1), ("mpi", 2, 1)]
            for mode, R, T in configs:
                run_once(scen, mode, R, T, K, D, K, sets, work, mpiexec)
            best = {}
            for _ in range(a.repeat):
                for mode, R, T in configs:
                    r = run_once(scen, mode, R, T, steps, D, K, sets, work, mpiexec)
                    print(json.dumps({k: v for k, v in r.items() if k != "engine"}), flush=True)
                    key = (mode, R, T)
                    if key not in best or r["wall_time_s"] < best[key]["wall_time_s"]:
                        best[key] = r
            mono, one, two = best[configs[0]], best[configs[1]], best[configs[2]]
            hashes = {r["state_hash"] for r in best.values()}
            sc = load_scenario(scen, sets)
            m = Model.from_scenario(sc)
            one = {**one, "discs_per_m": one["n"] / sc.bin.length}
            entry = {
                "scenario": scen,
                "set": sets,
                "n": one["n"],
                "steps": steps,
                "domains": D,
                "block": K,
                "runs": list(best.values()),
                "hashes_equal": len(hashes) == 1,
                "speedup_2_ranks_over_1": one["wall_time_s"] / two["wall_time_s"],
                "speedup_2_ranks_over_monolithic_2_threads": mono["wall_time_s"] / two["wall_time_s"],
                "model": model(one, two, pp, 8 * row_words(m.dim, m.hist_cap), a.target, (8, 64, 1024)),
            }
            report["scenarios"].append(entry)
    report["machine"] = {
        "cpus": os.cpu_count(),
        "loadavg_before": [round(x, 2) for x in load0],
        "loadavg_after": [round(x, 2) for x in os.getloadavg()],
    }
    print(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
