"""The parent side of the worker: start it, send a case, read the answer within a timeout while
watching its memory, kill and restart it."""

from __future__ import annotations

import json
import os
import select
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

from .common import CASE_TIMEOUT, GiB, MEM_BOUND, ROOT


def child_env() -> dict:
    """The environment of a child interpreter: this checkout's ooc_dem first, no display."""
    return dict(
        os.environ,
        MPLBACKEND="Agg",
        PYTHONPATH=os.pathsep.join([str(ROOT)] + ([os.environ["PYTHONPATH"]] if os.environ.get("PYTHONPATH") else [])),
    )


# the worker's own file, run as a script
WORKER_SCRIPT = Path(__file__).resolve().with_name("worker.py")


class WorkerDied(Exception):
    pass


class Worker:
    """A long-lived `ooc_dem.cli.main` runner with a per-call timeout and a memory watch."""

    def __init__(
        self, warmup=(), mem_bound=MEM_BOUND, use_rlimit=True, prepare=None, errlog=None, script=WORKER_SCRIPT
    ):
        self.warmup = [list(w) for w in warmup]
        self.script = script  # run as `python SCRIPT --worker` (a tool may wrap the worker)
        self.errlog = errlog  # the worker's own stderr (what glibc prints when it aborts)
        self.prepare = prepare
        self.mem_bound = mem_bound
        self.use_rlimit = use_rlimit
        self.proc = None
        self.restarts = 0
        self.info = {}
        self._n = 0

    def start(self):
        if self.prepare is not None:
            self.prepare()
        env = child_env()
        env.pop("PYTHONHASHSEED", None)
        err = open(self.errlog, "wb") if self.errlog else subprocess.DEVNULL
        try:
            self.proc = subprocess.Popen(
                [sys.executable, str(self.script), "--worker"],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=err,
                env=env,
                start_new_session=True,
                text=True,
                bufsize=1,
            )
        finally:
            if self.errlog:
                err.close()
        self.proc.stdin.write(
            json.dumps({"warmup": self.warmup, "rlimit_as": self.mem_bound if self.use_rlimit else None}) + "\n"
        )
        self.proc.stdin.flush()
        msg = self._read(timeout=300)
        if msg is None or not msg.get("ready"):
            self.kill()
            raise RuntimeError("fuzz worker did not start")
        self.info = msg
        return self

    def _read(self, timeout):
        import psutil

        deadline = time.monotonic() + timeout
        fd = self.proc.stdout
        try:
            ps = psutil.Process(self.proc.pid)
        except psutil.Error:
            ps = None
        self.peak_seen = 0
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            r, _, _ = select.select([fd], [], [], min(left, 0.1))
            if r:
                line = fd.readline()
                if not line:
                    raise WorkerDied(self._death())
                return json.loads(line)
            if self.proc.poll() is not None:
                raise WorkerDied(self._death())
            if ps is not None and self.info:
                try:
                    rss = ps.memory_info().rss
                except psutil.Error:
                    continue
                self.peak_seen = max(self.peak_seen, rss)
                if rss > self.info.get("baseline_rss", 0) + self.mem_bound + GiB // 2:
                    self.kill()
                    raise WorkerDied(f"killed: RSS {rss / GiB:.2f} GiB above the bound")

    def _death(self):
        rc = self.proc.wait()
        return f"worker died ({'signal ' + signal.Signals(-rc).name if rc < 0 else f'exit {rc}'})"

    def _dead_stderr(self) -> str:
        """What the dead worker's command had written to its (captured) stderr."""
        try:
            with open(Path(self.info["scratch"]) / "stderr", "rb") as f:
                return f.read()[-20000:].decode("utf-8", "replace")
        except (KeyError, OSError):
            return ""

    def call(self, argv, cwd, timeout=CASE_TIMEOUT, env=None, fsize=None) -> dict:
        """{"rc", "stdout", "stderr", "exc", "elapsed", "hwm", ...} or {"rc": None, "error": ...}."""
        if self.proc is None or self.proc.poll() is not None:
            self.restarts += self.proc is not None
            self.start()
        self._n += 1
        t0 = time.monotonic()
        try:
            req = {"id": self._n, "argv": list(argv), "cwd": str(cwd)}
            if env:
                req["env"] = dict(env)
            if fsize is not None:
                req["fsize"] = int(fsize)
            self.proc.stdin.write(json.dumps(req) + "\n")
            self.proc.stdin.flush()
            res = self._read(timeout)
        except (WorkerDied, BrokenPipeError) as e:
            err = self._dead_stderr()
            self.kill()
            self.kill_cleanup()
            return {"rc": None, "error": str(e), "elapsed": time.monotonic() - t0, "stderr": err, "stdout": ""}
        if res is None:
            self.kill()
            err = self._dead_stderr()
            self.kill_cleanup()
            return {
                "rc": None,
                "error": f"timeout after {timeout:.0f} s",
                "elapsed": timeout,
                "stderr": err,
                "stdout": "",
            }
        res["peak_seen"] = self.peak_seen
        return res

    def kill(self):
        if self.proc is None:
            return
        if self.proc.poll() is None:
            try:
                os.killpg(self.proc.pid, signal.SIGKILL)  # its own session: the worker and children
            except (ProcessLookupError, PermissionError):
                self.proc.kill()
            self.proc.wait()
        for f in (self.proc.stdin, self.proc.stdout):
            try:
                f.close()
            except Exception:  # noqa: BLE001
                pass

    def kill_cleanup(self):
        if self.info.get("scratch"):
            shutil.rmtree(self.info["scratch"], ignore_errors=True)

    def close(self) -> int | None:
        """End the worker normally; its exit status (a damaged heap aborts at interpreter exit)."""
        rc = None
        if self.proc is not None and self.proc.poll() is None:
            try:
                self.proc.stdin.close()
                rc = self.proc.wait(timeout=30)
            except Exception:  # noqa: BLE001
                self.kill()
        elif self.proc is not None:
            rc = self.proc.returncode
        for f in (self.proc.stdout,) if self.proc is not None else ():
            try:
                f.close()
            except Exception:  # noqa: BLE001
                pass
        self.proc = None
        if self.info.get("scratch"):
            shutil.rmtree(self.info["scratch"], ignore_errors=True)
        return rc

    def errlog_tail(self) -> str:
        try:
            with open(self.errlog, "rb") as f:
                return f.read()[-2000:].decode("utf-8", "replace")
        except (TypeError, OSError):
            return ""
