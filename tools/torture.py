#!/usr/bin/env python
"""kill -9 + resume torture for ooc-dem checkpoint/restart.

    python tools/torture.py --trials N [--modes monolithic,ooc-hdf5,ooc-zarr] [--seed S]

For every mode (MODE or MODE-BACKEND: monolithic, ddm, ooc; hdf5, zarr) an uninterrupted
reference run gives the final `checkpoint hash` and the run's wall time T. Each of the N trials
per mode starts the same run and SIGKILLs it after a random delay drawn uniformly from [0, T]
(so the kill can land anywhere: interpreter start-up, bed setup, stepping, writing an epoch,
committing it); with --kills K the first K-1 resumes are killed the same way too. Then the run
is resumed until it finishes. A kill before the first commit leaves nothing to resume: the
trial starts the run afresh ("restarted" rather than "resumed"), but a missing manifest next to
committed-looking epoch files is a failure. A trial passes when the final hash equals the
reference and `checkpoint verify` passes. All references must agree too (the modes are
bit-identical).

Prints one JSON object on stdout (progress goes to stderr); exit status 1 on any failure.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EPOCH_FILE = re.compile(r"^e\d{12,}(\.r\d+)?\.(h5|zarr)$")
NOTHING_COMMITTED = ("no such store", "not an ooc-dem store", "MANIFEST.json missing", "no committed epoch")


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def parse_mode(name: str) -> tuple[str, str]:
    mode, _, backend = name.partition("-")
    if mode not in ("monolithic", "ddm", "ooc") or backend not in ("", "hdf5", "zarr"):
        raise SystemExit(
            f"torture.py: error: mode {name!r}: expected MODE[-BACKEND] with MODE in "
            f"monolithic, ddm, ooc and BACKEND in hdf5, zarr"
        )
    return mode, backend or "hdf5"


class Torture:
    def __init__(self, args, workdir: Path):
        self.a = args
        self.work = workdir
        self.env = dict(
            os.environ,
            PYTHONPATH=os.pathsep.join(
                [str(ROOT)] + ([os.environ["PYTHONPATH"]] if os.environ.get("PYTHONPATH") else [])
            ),
        )

    # ------------------------------------------------------------ commands
    def cli(self, *args) -> list[str]:
        return [sys.executable, "-m", "ooc_dem.cli", *map(str, args)]

    def run_cmd(self, out: Path, mode_name: str) -> list[str]:
        mode, backend = parse_mode(mode_name)
        a = self.a
        return self.cli(
            "run",
            a.scenario,
            "--out",
            out,
            "--steps",
            a.steps,
            "--checkpoint-every",
            a.checkpoint_every,
            "--mode",
            mode,
            "--backend",
            backend,
            "--domains",
            a.domains,
            "--block",
            a.block,
            "--no-progress",
            "--no-figures",
        )

    def resume_cmd(self, out: Path) -> list[str]:
        return self.cli("resume", out, "--no-progress", "--no-figures")

    def call(self, cmd) -> subprocess.CompletedProcess:
        return subprocess.run(cmd, capture_output=True, text=True, timeout=self.a.timeout, env=self.env)

    def killed(self, cmd, delay: float) -> int:
        """Start cmd, SIGKILL it after `delay` s; its exit status (-9 if the kill landed)."""
        with open(os.devnull, "wb") as null:
            proc = subprocess.Popen(cmd, stdout=null, stderr=null, env=self.env)
            try:
                proc.wait(timeout=delay)
            except subprocess.TimeoutExpired:
                proc.kill()
            return proc.wait()

    def hash(self, out: Path) -> str | None:
        cp = self.call(self.cli("checkpoint", "hash", out))
        return cp.stdout.strip() if cp.returncode == 0 else None

    # ------------------------------------------------------------ reference
    def reference(self, mode_name: str) -> dict:
        out = self.work / "ref" / mode_name
        t0 = time.monotonic()
        cp = self.call(self.run_cmd(out, mode_name))
        wall = time.monotonic() - t0
        if cp.returncode != 0:
            raise SystemExit(
                f"torture.py: reference run {mode_name} failed ({cp.returncode}): {cp.stderr.strip().splitlines()[-1:]}"
            )
        h = self.hash(out)
        log(f"reference {mode_name}: {wall:.1f} s, hash {h}")
        return {"hash": h, "wall_s": round(wall, 3)}

    # ------------------------------------------------------------ one trial
    @staticmethod
    def committed(out: Path) -> bool | None:
        """Whether the store names a committed epoch (None: no readable manifest)."""
        try:
            m = json.loads((out / "MANIFEST.json").read_text())
        except (OSError, ValueError):
            return None
        return isinstance(m, dict) and m.get("current") is not None

    @staticmethod
    def lost_commit(out: Path) -> bool:
        """No manifest next to committed-looking epoch files: a commit was lost."""
        edir = out / "epochs"
        return (
            not (out / "MANIFEST.json").exists()
            and edir.is_dir()
            and any(EPOCH_FILE.match(n) for n in os.listdir(edir))
        )

    def trial(self, mode_name: str, idx: int, rng: random.Random, wall: float) -> dict:
        out = self.work / mode_name / f"trial-{idx:03d}"
        shutil.rmtree(out, ignore_errors=True)
        out.parent.mkdir(parents=True, exist_ok=True)
        rec = {"trial": idx, "delays": [], "exit_at_kill": [], "restarted": False, "resumes": 0}
        fresh = True  # the next process is `run` (no store yet / restarted)
        for _ in range(self.a.kills):
            delay = round(rng.uniform(0.0, wall), 3)
            rec["delays"].append(delay)
            if not fresh:
                rec["resumes"] += 1
            rec["exit_at_kill"].append(
                self.killed(self.run_cmd(out, mode_name) if fresh else self.resume_cmd(out), delay)
            )
            if self.lost_commit(out):
                return self.fail(rec, "MANIFEST.json lost although epoch files exist")
            fresh = False
            if self.committed(out) is False or not (out / "MANIFEST.json").exists():
                # killed before the first commit: nothing to resume, start afresh
                shutil.rmtree(out, ignore_errors=True)
                rec["restarted"] = True
                fresh = True
        for _ in range(5):  # now let it finish
            if fresh:
                cp = self.call(self.run_cmd(out, mode_name))
                if cp.returncode != 0:
                    return self.fail(rec, f"fresh run failed: {cp.stderr.strip()[-300:]}")
                break
            cp = self.call(self.resume_cmd(out))
            rec["resumes"] += 1
            if "Traceback" in cp.stderr:
                return self.fail(rec, f"resume printed a traceback: {cp.stderr.strip()[-300:]}")
            if cp.returncode == 0:
                break
            if not any(s in cp.stderr for s in NOTHING_COMMITTED) or self.lost_commit(out):
                return self.fail(rec, f"resume failed ({cp.returncode}): {cp.stderr.strip()[-300:]}")
            rec["restarted"] = True
            rec["restart_reason"] = cp.stderr.strip().splitlines()[-1]
            shutil.rmtree(out, ignore_errors=True)
            fresh = True
        else:
            return self.fail(rec, "did not finish after 5 attempts")
        rec["hash"] = self.hash(out)
        v = self.call(self.cli("checkpoint", "verify", out))
        if v.returncode != 0:
            return self.fail(rec, f"checkpoint verify failed: {v.stdout.strip()[-300:]} {v.stderr.strip()}")
        if rec["hash"] != self.reference_hash:
            return self.fail(rec, f"final hash {rec['hash']} != reference {self.reference_hash}")
        rec["ok"] = True
        if not self.a.keep:
            shutil.rmtree(out, ignore_errors=True)
        return rec

    @staticmethod
    def fail(rec: dict, reason: str) -> dict:
        rec["ok"] = False
        rec["reason"] = reason
        return rec

    # ------------------------------------------------------------ all
    def main(self) -> dict:
        a = self.a
        modes = [m.strip() for m in a.modes.split(",") if m.strip()]
        for m in modes:
            parse_mode(m)
        rng = random.Random(a.seed)
        refs = {m: self.reference(m) for m in modes}
        hashes = {r["hash"] for r in refs.values()}
        result = {
            "trials": a.trials,
            "seed": a.seed,
            "scenario": a.scenario,
            "steps": a.steps,
            "checkpoint_every": a.checkpoint_every,
            "domains": a.domains,
            "block": a.block,
            "kills_per_trial": a.kills,
            "references": refs,
            "references_agree": len(hashes) == 1 and None not in hashes,
            "modes": {},
        }
        for m in modes:
            self.reference_hash = refs[m]["hash"]
            stats = {
                "passed": 0,
                "failed": 0,
                "resumed": 0,
                "restarted": 0,
                "kill_delays": [],
                "finished_before_kill": 0,
                "failures": [],
            }
            for i in range(a.trials):
                rec = self.trial(m, i, rng, refs[m]["wall_s"])
                stats["kill_delays"].append(rec["delays"][0] if len(rec["delays"]) == 1 else rec["delays"])
                stats["finished_before_kill"] += sum(1 for c in rec["exit_at_kill"] if c == 0)
                stats["restarted" if rec["restarted"] else "resumed"] += 1
                if rec["ok"]:
                    stats["passed"] += 1
                else:
                    stats["failed"] += 1
                    stats["failures"].append({k: rec.get(k) for k in ("trial", "delays", "exit_at_kill", "reason")})
                log(
                    f"{m} trial {i}: kill after {rec['delays']} s -> "
                    f"{'restarted' if rec['restarted'] else 'resumed'}, "
                    f"{'ok' if rec['ok'] else 'FAILED: ' + rec.get('reason', '')}"
                )
            result["modes"][m] = stats
        result["ok"] = result["references_agree"] and all(s["failed"] == 0 for s in result["modes"].values())
        return result


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--trials", type=int, required=True, help="trials per mode")
    p.add_argument(
        "--modes", default="monolithic,ooc-hdf5,ooc-zarr", help="comma-separated MODE[-BACKEND] (default: %(default)s)"
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--kills", type=int, default=1, help="SIGKILLs per trial (the run, then resumes)")
    p.add_argument("--scenario", default="bed-1200")
    p.add_argument("--steps", type=int, default=1200)
    p.add_argument("--checkpoint-every", type=int, default=60)
    p.add_argument("--domains", type=int, default=3)
    p.add_argument("--block", type=int, default=10)
    p.add_argument("--timeout", type=float, default=900, help="per process, s")
    p.add_argument("--workdir", help="keep runs here (default: a temporary directory, removed)")
    p.add_argument("--keep", action="store_true", help="keep the trial directories of passed trials")
    a = p.parse_args(argv)
    if a.trials < 1 or a.kills < 1:
        p.error("--trials and --kills must be >= 1")
    if a.workdir:
        work = Path(a.workdir)
        work.mkdir(parents=True, exist_ok=True)
        result = Torture(a, work).main()
    else:
        with tempfile.TemporaryDirectory(prefix="ooc-dem-torture-") as d:
            result = Torture(a, Path(d)).main()
    print(json.dumps(result, indent=2))
    return 0 if result["ok"] else 1


if __name__ == "__main__":
    sys.exit(main())
