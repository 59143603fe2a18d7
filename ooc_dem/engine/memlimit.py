"""A child process under a hard memory limit: a memory cgroup made for it, removed after.

The honest memory proof of the out-of-core mode: whatever an RSS sample
might miss, the kernel does not - a process that needs more than the limit is killed
by the cgroup's OOM killer, and that is reported as such (``oom_killed``), never as a
mysterious failure.

The cgroup is made inside the caller's own memory cgroup (read from
``/proc/self/cgroup``), so any limit the caller already lives under still applies and
nothing outside its subtree is touched: cgroup v1
(``<memory mount>/<own path>/<name>/memory.limit_in_bytes``, also ``memory.memsw.*``
when swap accounting exists, so swap is no way around it) or cgroup v2 (``memory.max``,
``memory.swap.max``). The child joins it before it executes anything (it writes its own
pid into ``cgroup.procs`` between fork and exec), so every byte it allocates counts.

The peak RSS is the child's own: ``wait4``'s ``ru_maxrss`` and its ``VmHWM``. Linux
records, at ``exec``, the high-water RSS of the address space being replaced into the
process's ``maxrss``; a child spawned by ``subprocess`` (``vfork``) replaces *our* address
space, so its ``ru_maxrss`` starts at our lifetime peak (a test suite that grew to 300 MB
made every child "peak" at 300 MB). So the command runs as the grandchild of a small
launcher (``_LAUNCHER``: a bare interpreter that forks and execs it and reports its pid,
wait status and ``ru_maxrss``), whose few MB are all the grandchild can inherit. The cgroup's peak
(``memory.max_usage_in_bytes`` / ``memory.peak``) also counts its page cache and kernel
memory, but not shared-library pages already in the page cache, charged to whoever read
them first: RSS can exceed the limit by those (~90 MB for numba's LLVM and numpy here)
while the child's anonymous memory (RssAnon) cannot. RSS, RssAnon (``/proc/PID/status``)
and the cgroup's usage are sampled over the whole run.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import OocDemError

CGROUP_ROOT = Path("/sys/fs/cgroup")


class MemoryLimitError(OocDemError, RuntimeError):
    """No memory cgroup can be made here (message is one line)."""


def parse_size(text: str) -> int:
    """Bytes from '2GB', '512MiB', '1.5G', '300M', '1e9' (decimal units, binary with 'i')."""
    t = str(text).strip().replace("_", "")
    units = {
        "": 1,
        "b": 1,
        "k": 10**3,
        "kb": 10**3,
        "m": 10**6,
        "mb": 10**6,
        "g": 10**9,
        "gb": 10**9,
        "t": 10**12,
        "tb": 10**12,
        "kib": 2**10,
        "mib": 2**20,
        "gib": 2**30,
        "tib": 2**40,
    }
    num = t.rstrip("bBiIkKmMgGtT")
    unit = t[len(num) :].lower()
    try:
        v = float(num) * units[unit]
    except (ValueError, KeyError):
        raise ValueError(f"{text!r} is not a size (e.g. 2GB, 512MiB, 1e9)") from None
    if not v >= 1 or v != v or v == float("inf"):
        raise ValueError(f"{text!r} must be a positive size")
    return int(v)


def _own_cgroup() -> tuple[int, Path]:
    """(version, directory) of this process's memory cgroup."""
    try:
        lines = Path("/proc/self/cgroup").read_text().splitlines()
    except OSError:
        raise MemoryLimitError("no /proc/self/cgroup: memory cgroups are not available here") from None
    v2_path = None
    for line in lines:
        hid, controllers, path = line.split(":", 2)
        if "memory" in controllers.split(","):
            for mount in (CGROUP_ROOT / "memory", CGROUP_ROOT / controllers):
                if (mount / "memory.limit_in_bytes").exists():
                    return 1, mount / path.lstrip("/")
        if hid == "0" and controllers == "":
            v2_path = path
    if v2_path is not None:
        for mount in (CGROUP_ROOT, CGROUP_ROOT / "unified"):
            d = mount / v2_path.lstrip("/")
            if "memory" in _read(mount / "cgroup.controllers", "").split():
                return 2, d
    raise MemoryLimitError(
        "no memory cgroup controller is mounted (cgroup v1 memory or cgroup v2 with the memory controller)"
    )


def _read(path: Path, default=None):
    try:
        return path.read_text().strip()
    except OSError:
        return default


def _stat_value(path: Path, key: str) -> int | None:
    """A 'key value' line of a cgroup file (memory.oom_control, memory.events)."""
    text = _read(path)
    if text is None:
        return None
    for line in text.splitlines():
        parts = line.split()
        if len(parts) == 2 and parts[0] == key:
            return int(parts[1])
    return None


class MemoryCgroup:
    """A fresh memory cgroup with a hard limit; ``remove()`` deletes it (no process left)."""

    def __init__(self, limit_bytes: int, name: str | None = None):
        self.limit = int(limit_bytes)
        self.version, parent = _own_cgroup()
        self.path = parent / (name or f"ooc-dem-{os.getpid()}-{time.monotonic_ns() % 10**9}")
        try:
            if self.version == 2:
                # the parent must hand the memory controller down to its children
                ctl = parent / "cgroup.subtree_control"
                if "memory" not in _read(ctl, "").split():
                    ctl.write_text("+memory")
            self.path.mkdir()
        except OSError as e:
            raise MemoryLimitError(
                f"cannot make a memory cgroup in {parent} ({e.strerror or e}; this needs root or a delegated cgroup)"
            ) from None
        try:
            if self.version == 1:
                (self.path / "memory.limit_in_bytes").write_text(str(self.limit))
                sw = self.path / "memory.memsw.limit_in_bytes"
                if sw.exists():  # swap accounting: memory + swap under the same bound
                    sw.write_text(str(self.limit))
            else:
                (self.path / "memory.max").write_text(str(self.limit))
                sw = self.path / "memory.swap.max"
                if sw.exists():
                    sw.write_text("0")
        except OSError as e:
            self.remove()
            raise MemoryLimitError(f"cannot set the memory limit in {self.path} ({e.strerror or e})") from None

    def usage(self) -> int:
        name = "memory.usage_in_bytes" if self.version == 1 else "memory.current"
        v = _read(self.path / name)
        return int(v) if v and v.isdigit() else -1

    def peak(self) -> int | None:
        name = "memory.max_usage_in_bytes" if self.version == 1 else "memory.peak"
        v = _read(self.path / name)
        return int(v) if v and v.isdigit() else None

    def oom_kills(self) -> int | None:
        """How many processes the limit's OOM killer has killed (the kernel's count; None on
        kernels before 4.13, which do not count them)."""
        f = self.path / ("memory.oom_control" if self.version == 1 else "memory.events")
        return _stat_value(f, "oom_kill")

    def hit_limit(self) -> bool:
        if self.version == 1:
            return int(_read(self.path / "memory.failcnt", "0") or 0) > 0
        return (_stat_value(self.path / "memory.events", "max") or 0) > 0

    def remove(self) -> None:
        """Kill what is left in it (only its own processes) and delete it."""
        for attempt in range(50):
            procs = [int(p) for p in (_read(self.path / "cgroup.procs", "") or "").split()]
            for pid in procs:
                try:
                    os.kill(pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
            try:
                self.path.rmdir()
                return
            except FileNotFoundError:
                return
            except OSError:
                time.sleep(0.05)
        raise MemoryLimitError(f"cannot remove the memory cgroup {self.path}")


def own_peak_rss_bytes() -> int:
    """This process's peak RSS (VmHWM). Not ``getrusage``'s ``ru_maxrss``: a process spawned by
    ``vfork`` (``subprocess``) starts that at its parent's peak (see the module's doc)."""
    return _rss_of(os.getpid())[1]


def _rss_of(pid: int) -> tuple[int, int, int]:
    """(VmRSS, VmHWM, RssAnon) of a process in bytes (-1 when gone)."""
    got = {"VmRSS:": -1, "VmHWM:": -1, "RssAnon:": -1}
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                key = line.split(None, 1)[0] if line.strip() else ""
                if key in got:
                    got[key] = int(line.split()[1]) * 1024
    except OSError:
        pass
    return got["VmRSS:"], got["VmHWM:"], got["RssAnon:"]


@dataclass
class LimitedRun:
    """What a (possibly limited) child did."""

    cmd: list
    returncode: int
    stdout: str
    stderr: str
    wall_s: float
    peak_rss_bytes: int  # the child's own peak RSS (wait4's ru_maxrss, VmHWM samples)
    limit_bytes: int | None = None
    cgroup_version: int | None = None
    cgroup_peak_bytes: int | None = None  # RSS + page cache + kernel memory charged to the cgroup
    oom_killed: bool = False
    # [t s, child VmRSS B, cgroup usage B or -1, child RssAnon B]
    samples: list = field(default_factory=list)

    @property
    def sampled_peak_rss_bytes(self) -> int:
        return max((s[1] for s in self.samples), default=-1)

    @property
    def sampled_peak_anon_bytes(self) -> int:
        """The child's own (anonymous) memory at its sampled peak: what the limit charges in full."""
        return max((s[3] for s in self.samples), default=-1)

    def as_dict(self) -> dict:
        return {
            "returncode": self.returncode,
            "wall_s": round(self.wall_s, 3),
            "peak_rss_bytes": self.peak_rss_bytes,
            "sampled_peak_rss_bytes": self.sampled_peak_rss_bytes,
            "sampled_peak_anon_bytes": self.sampled_peak_anon_bytes,
            "memory_limit_bytes": self.limit_bytes,
            "cgroup_version": self.cgroup_version,
            "cgroup_peak_bytes": self.cgroup_peak_bytes,
            "oom_killed": self.oom_killed,
            "rss_samples": len(self.samples),
        }

    def oom_message(self, what: str) -> str:
        def mb(b):
            return f"{b / 1e6:.1f} MB"

        return (
            f"{what} was killed by the memory limit (OOM): limit {mb(self.limit_bytes)}, "
            f"peak RSS {mb(self.peak_rss_bytes)}"
            + (f", cgroup peak {mb(self.cgroup_peak_bytes)}" if self.cgroup_peak_bytes else "")
            + f" after {self.wall_s:.1f} s; raise the limit or lower the run's need (ooc: more "
            f"--domains or a smaller --memory budget)"
        )


# The launcher (run as ``python -I -S -c``, so it loads nothing but the interpreter): fork, the
# child joins the cgroup (argv[2], '' for none) and execs argv[3:]; the pid and then the wait
# status and ru_maxrss (KiB) of the child are written to the pipe fd argv[1].
_LAUNCHER = """
import os, sys
fd, procs, argv = int(sys.argv[1]), sys.argv[2], sys.argv[3:]
pid = os.fork()
if pid == 0:
    os.close(fd)
    try:
        if procs:
            with open(procs, "w") as f:
                f.write(str(os.getpid()))
        os.execvp(argv[0], argv)
    except OSError as e:
        os.write(2, f"ooc-dem: error: cannot run {argv[0]}: {e.strerror}\\n".encode())
    os._exit(127)
os.write(fd, f"{pid}\\n".encode())
while True:
    try:
        _, status, ru = os.wait4(pid, 0)
        break
    except InterruptedError:
        continue
os.write(fd, f"{status} {ru.ru_maxrss}\\n".encode())
"""


def run_limited(
    cmd, limit_bytes: int | None = None, *, env=None, cwd=None, interval: float = 0.1, stdout_path=None
) -> LimitedRun:
    """Run ``cmd`` to its end under ``limit_bytes`` (None: no limit, still measured).

    stdout and stderr go to temporary files (or ``stdout_path``), never a pipe that a
    large output could fill while we only sample."""
    cg = MemoryCgroup(limit_bytes) if limit_bytes is not None else None
    try:
        with (
            tempfile.TemporaryFile("w+") as err,
            open(stdout_path, "w+") if stdout_path else tempfile.TemporaryFile("w+") as out,
        ):
            t0 = time.perf_counter()
            argv = list(map(str, cmd))
            rfd, wfd = os.pipe()
            try:
                launcher = subprocess.Popen(
                    [
                        sys.executable,
                        "-I",
                        "-S",
                        "-c",
                        _LAUNCHER,
                        str(wfd),
                        str(cg.path / "cgroup.procs") if cg is not None else "",
                        *argv,
                    ],
                    stdout=out,
                    stderr=err,
                    env=env,
                    cwd=cwd,
                    pass_fds=(wfd,),
                )
            finally:
                os.close(wfd)
            with os.fdopen(rfd, "r") as report:
                line = report.readline()
                pid = int(line) if line.strip() else None
                samples = []
                peak_hwm = -1
                while pid is not None and launcher.poll() is None:
                    rss, hwm, anon = _rss_of(pid)
                    if rss >= 0:
                        samples.append([round(time.perf_counter() - t0, 3), rss, cg.usage() if cg else -1, anon])
                        peak_hwm = max(peak_hwm, hwm)
                    time.sleep(interval)
                launcher.wait()
                done = report.readline().split()
            wall = time.perf_counter() - t0
            if len(done) != 2:
                raise MemoryLimitError(
                    f"the launcher of {argv[0]} ended without reporting its child (exit {launcher.returncode})"
                )
            status, maxrss_kib = map(int, done)
            out.seek(0)
            err.seek(0)
            res = LimitedRun(
                cmd=argv,
                returncode=os.waitstatus_to_exitcode(status),
                stdout=out.read(),
                stderr=err.read(),
                wall_s=wall,
                peak_rss_bytes=max(maxrss_kib * 1024, peak_hwm),
                limit_bytes=limit_bytes,
                samples=samples,
            )
        if cg is not None:
            res.cgroup_version = cg.version
            res.cgroup_peak_bytes = cg.peak()
            # killed by SIGKILL while the cgroup's OOM killer counted a kill: the limit did it
            kills = cg.oom_kills()
            res.oom_killed = res.returncode == -signal.SIGKILL and (kills > 0 if kills is not None else cg.hit_limit())
        return res
    finally:
        if cg is not None:
            cg.remove()
