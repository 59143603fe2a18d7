"""Memory profiling: each mode in a fresh subprocess, peak RSS against the monolithic baseline.

A child process imports the engine, warms up the JIT on a tiny problem (numba's
cache makes that a load, not a compile), sets the scenario up (bed, store), and
then resets the kernel's peak-RSS counter (``/proc/self/clear_refs`` = 5) so that
``VmHWM`` measures the run itself. It records the baseline RSS at that moment,
the peak (VmHWM and ru_maxrss), a sampled RSS time series, the resident disc
counts and the theoretical state size. Files written and read by the stores are
dropped from the page cache (``posix_fadvise(DONTNEED)``) by the storage layer.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..engine.modes import MODES, mode_names
from ..errors import OocDemError

if TYPE_CHECKING:
    import argparse

# the modes a profile runs: those of one process (the MPI modes run under mpiexec)
PROFILED_MODES = mode_names(lambda m: not m.mpi)


def _status_kb(field: str) -> int:
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(field + ":"):
                    return int(line.split()[1])
    except OSError:
        pass
    return -1


def rss_bytes() -> int:
    return _status_kb("VmRSS") * 1024


def hwm_bytes() -> int:
    return _status_kb("VmHWM") * 1024


def reset_peak() -> bool:
    """Reset VmHWM to the current RSS (Linux >= 4.0); False if not possible."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


class RssSampler(threading.Thread):
    """Samples VmRSS every `interval` seconds in a background thread."""

    def __init__(self, interval: float = 0.05) -> None:
        super().__init__(daemon=True)
        self.interval = interval
        self.t0 = time.perf_counter()
        self.samples: list[tuple[float, int]] = []
        self._halt = threading.Event()

    def run(self) -> None:
        while not self._halt.is_set():
            self.samples.append((time.perf_counter() - self.t0, rss_bytes()))
            self._halt.wait(self.interval)

    def stop(self) -> None:
        self._halt.set()
        self.join()
        self.samples.append((time.perf_counter() - self.t0, rss_bytes()))


def _warm_up(mode: str, backend: str, tmp: Path, dim: int = 2) -> None:
    """Run a tiny bed (of the measured run's dimension) through the same code path so every
    kernel is compiled or loaded."""
    from .run import RunOptions, Simulation
    from ..model.scenario import load_scenario

    if dim == 3:
        sc = load_scenario("bed3d", ["soil.n=300", "bed.tile=0", "decomposition.policy=equal"])
    else:
        sc = load_scenario("bed-300", ["decomposition.policy=equal"])
    opts = RunOptions(mode=mode, backend=backend, domains=2, block=2, steps=4, progress=False, figures=False)
    sim = Simulation(sc, tmp / "warmup", opts)
    sim.start()
    sim.run()


def child(args: argparse.Namespace) -> dict[str, Any]:
    """One mode, measured in this (fresh) process."""
    import shutil
    import tempfile
    from .run import RunOptions, Simulation
    from ..model.scenario import load_scenario
    from ..model.state import BYTES_PER_DISC, bytes_per_disc

    t_import = rss_bytes()
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    sc = load_scenario(args.scenario, args.set)
    _warm_up(args.mode, args.backend, Path(tempfile.mkdtemp(dir=work)), sc.dim)
    steps = args.steps
    opts = RunOptions(
        mode=args.mode,
        backend=args.backend,
        domains=args.domains,
        block=args.block,
        steps=steps,
        checkpoint_every=max(1, steps),
        progress=False,
        figures=False,
    )
    out = work / f"run-{args.mode}"
    shutil.rmtree(out, ignore_errors=True)
    sim = Simulation(sc, out, opts)
    # baseline: after imports and JIT warm-up, before the scenario's state exists; the peak
    # then covers setup (bed, store) and run alike, so no mode hides its state in the baseline
    import gc

    gc.collect()
    baseline = rss_bytes()
    # VmHWM, not ru_maxrss: a process spawned by vfork starts its ru_maxrss at its parent's peak
    warm_peak = hwm_bytes()
    reset_ok = reset_peak()
    sampler = RssSampler(args.interval)
    sampler.start()
    t0 = time.perf_counter()
    sim.start(streamed=True)
    t_setup = time.perf_counter() - t0
    t0 = time.perf_counter()
    summary = sim.run()
    elapsed = time.perf_counter() - t0
    sampler.stop()
    peak = hwm_bytes() if reset_ok else max(s[1] for s in sampler.samples)
    n = summary["n_discs"]
    eng = summary["engine"]
    res = {
        "mode": args.mode,
        "backend": args.backend if MODES[args.mode].out_of_core else None,
        "scenario": sc.name,
        "n_discs": n,
        "steps": steps,
        "domains": eng.get("domains"),
        "block": eng.get("block"),
        "rss_after_imports_bytes": t_import,
        "baseline_rss_bytes": baseline,
        "peak_rss_bytes": peak,
        "peak_above_baseline_bytes": peak - baseline,
        "peak_rss_lifetime_bytes": max(warm_peak, hwm_bytes()),
        "peak_reset_ok": reset_ok,
        "theoretical_state_bytes": n * (BYTES_PER_DISC if sc.dim == 2 else bytes_per_disc(3)),
        "dim": sc.dim,
        "resident_discs_max": eng.get("resident_max"),
        "setup_s": round(t_setup, 3),
        "run_s": round(elapsed, 3),
        "particle_steps_per_s": n * steps / elapsed if elapsed > 0 else None,
        "state_hash": summary["state_hash"],
        "rss_series": [[round(t, 4), b] for t, b in sampler.samples],
    }
    if not args.keep:
        shutil.rmtree(out, ignore_errors=True)
    return res


class OomKilled(OocDemError, RuntimeError):
    """A profiled mode was killed by its hard memory limit (message is one line)."""

    def __init__(self, message: str, result: dict[str, Any]) -> None:
        super().__init__(message)
        self.result = result


def run_child(
    scenario: str,
    mode: str,
    *,
    overrides: Sequence[str] = (),
    backend: str = "hdf5",
    domains: int | None = None,
    block: int | None = None,
    steps: int = 20,
    work: Path,
    interval: float = 0.05,
    keep: bool = False,
    threads: int | None = None,
    memory_limit: int | None = None,
) -> dict[str, Any]:
    """One mode in a fresh subprocess; with ``memory_limit`` (bytes) under a hard limit (a memory
    cgroup made for it, memlimit.py), its RSS and the cgroup's usage sampled over the whole run."""
    cmd = [
        sys.executable,
        "-m",
        "ooc_dem.app.profiling",
        "--child",
        scenario,
        "--mode",
        mode,
        "--backend",
        backend,
        "--steps",
        str(steps),
        "--work",
        str(work),
        "--interval",
        str(interval),
    ]
    for s in overrides:
        cmd += ["--set", s]
    if domains:
        cmd += ["--domains", str(domains)]
    if block:
        cmd += ["--block", str(block)]
    if keep:
        cmd.append("--keep")
    env = dict(os.environ)
    if threads:
        env["NUMBA_NUM_THREADS"] = str(threads)
    if memory_limit is None:
        cp = subprocess.run(cmd, capture_output=True, text=True, env=env)
        if cp.returncode != 0:
            last = (cp.stderr.strip().splitlines() or ["(no output)"])[-1]
            raise RuntimeError(f"profiling child for mode {mode} failed: {last}")
        measured: dict[str, Any] = json.loads(cp.stdout.strip().splitlines()[-1])
        return measured
    from ..engine.memlimit import run_limited

    lim = run_limited(cmd, memory_limit, env=env, interval=min(interval, 0.1))
    limited = {**lim.as_dict(), "limit_rss_series": lim.samples}
    if lim.oom_killed:
        raise OomKilled(lim.oom_message(f"mode {mode}"), {"mode": mode, **limited})
    if lim.returncode != 0:
        last = (lim.stderr.strip().splitlines() or ["(no output)"])[-1]
        raise RuntimeError(f"profiling child for mode {mode} failed (exit {lim.returncode}): {last}")
    res: dict[str, Any] = json.loads(lim.stdout.strip().splitlines()[-1])
    # the whole process's peak, seen from outside (imports and warm-up included)
    res["memory_limit"] = {k: v for k, v in limited.items() if k != "returncode"}
    return res


def report(results: list[dict[str, Any]], out: Path) -> dict[str, Any]:
    """Write memory.json, memory.md and memory.png; returns the JSON document."""
    out.mkdir(parents=True, exist_ok=True)
    mono = next((r for r in results if r["mode"] == "monolithic"), None)
    doc: dict[str, Any] = {"runs": results}
    if mono:
        for r in results:
            r["peak_ratio_to_monolithic"] = r["peak_rss_bytes"] / mono["peak_rss_bytes"]
            base = mono["peak_above_baseline_bytes"]
            r["above_baseline_ratio_to_monolithic"] = (r["peak_above_baseline_bytes"] / base) if base > 0 else None
    (out / "memory.json").write_text(json.dumps(doc, indent=2))
    mib = 1 / 2**20
    lines = [
        "| mode | discs | D | K | baseline RSS (MiB) | peak RSS (MiB) | peak − baseline (MiB) | "
        "÷ monolithic (peak − baseline) | resident discs (max) | state (MiB) | particle-steps/s |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        ratio = r.get("above_baseline_ratio_to_monolithic")
        lines.append(
            f"| {r['mode']}{'/' + r['backend'] if r.get('backend') else ''} | {r['n_discs']} | "
            f"{r.get('domains') or 1} | {r.get('block') or 1} | {r['baseline_rss_bytes'] * mib:.1f} | "
            f"{r['peak_rss_bytes'] * mib:.1f} | {r['peak_above_baseline_bytes'] * mib:.1f} | "
            f"{'' if ratio is None else f'{ratio:.3f}'} | {r.get('resident_discs_max')} | "
            f"{r['theoretical_state_bytes'] * mib:.1f} | {r['particle_steps_per_s']:.3g} |"
        )
    md = "\n".join(lines) + "\n"
    (out / "memory.md").write_text(md)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.5))
    for r in results:
        s = np.array(r["rss_series"], dtype=float)
        if len(s):
            ax.plot(s[:, 0], s[:, 1] * mib, label=f"{r['mode']} (peak {r['peak_rss_bytes'] * mib:.0f} MiB)")
    ax.set_xlabel("time since the run started [s]")
    ax.set_ylabel("RSS [MiB]")
    ax.set_title(f"RSS over time — {results[0]['scenario']}, {results[0]['n_discs']} discs")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "memory.png", dpi=110)
    plt.close(fig)
    return doc


def profile(
    scenario: str,
    modes: Iterable[str],
    out: Path,
    overrides: Sequence[str] = (),
    backend: str = "hdf5",
    domains: int | None = None,
    block: int | None = None,
    steps: int = 20,
    memory_limit: int | None = None,
) -> dict[str, Any]:
    """Each mode in a fresh subprocess (under ``memory_limit`` bytes, a hard cgroup limit, if
    given). A mode killed by the limit raises OomKilled after memory.json records it."""
    results: list[dict[str, Any]] = []
    for m in modes:
        try:
            results.append(
                run_child(
                    scenario,
                    m,
                    overrides=overrides,
                    backend=backend,
                    domains=domains,
                    block=block,
                    steps=steps,
                    work=out / "work",
                    memory_limit=memory_limit,
                )
            )
        except OomKilled as e:
            import shutil

            shutil.rmtree(out / "work", ignore_errors=True)
            out.mkdir(parents=True, exist_ok=True)
            (out / "memory.json").write_text(json.dumps({"runs": results, "oom_killed": e.result}, indent=2))
            raise
        r = results[-1]
        lim = r.get("memory_limit")
        print(
            f"{m}: peak {r['peak_rss_bytes'] / 2**20:.1f} MiB, above baseline "
            f"{r['peak_above_baseline_bytes'] / 2**20:.1f} MiB, resident max {r['resident_discs_max']}"
            + (
                f"; under a {lim['memory_limit_bytes'] / 2**20:.0f} MiB limit: whole-process peak RSS "
                f"{lim['peak_rss_bytes'] / 2**20:.1f} MiB, cgroup peak {lim['cgroup_peak_bytes'] / 2**20:.1f} MiB"
                if lim
                else ""
            ),
            file=sys.stderr,
            flush=True,
        )
    import shutil

    shutil.rmtree(out / "work", ignore_errors=True)
    return report(results, out)


def _main() -> None:
    import argparse

    ap = argparse.ArgumentParser()
    ap.add_argument("--child", action="store_true")
    ap.add_argument("scenario")
    ap.add_argument("--mode", choices=PROFILED_MODES)
    ap.add_argument("--backend", default="hdf5")
    ap.add_argument("--domains", type=int)
    ap.add_argument("--block", type=int)
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--work", required=True)
    ap.add_argument("--interval", type=float, default=0.05)
    ap.add_argument("--set", action="append", default=[])
    ap.add_argument("--keep", action="store_true")
    args = ap.parse_args()
    print(json.dumps(child(args)))


if __name__ == "__main__":
    _main()
