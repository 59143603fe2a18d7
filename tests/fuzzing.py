"""Fuzz harness for the `ooc-dem` command line (shared by tests/test_fuzz.py and tools/fuzz.py).

Every generated *case* is a JSON-able dict: the strategy that made it, the base store it starts
from (``h5``: a finished monolithic HDF5 run, ``zarr``: a finished out-of-core zarr run with 3
sub-domains; ``h5_3d``/``zarr_3d``: the same of quick-3d; ``traj``: an HDF5 run with trajectory
frames; ``zarr_zstd``: compressed zarr arrays; ``ddm``: serial DDM; see BASE_RUNS), the material
it ``needs`` (``bed``: a prepared bed in w/out/bed; ``cache``: a bed cache in w/cache, given to
the command as OOC_DEM_CACHE), a list of *edits* applied to a fresh copy of the world before the
command, the ``argv`` given to ``ooc_dem.cli.main`` (or ``@api WHAT RUN``: the Python API), an
optional ``fsize`` (RLIMIT_FSIZE of the command) or ``fresh`` (a fresh interpreter instead of the
worker: what is printed at interpreter exit counts) and a few *expectations*. ``Fuzzer.run_case`` builds the
world, runs the command in a long-lived worker process and checks, for every case:

* exit code 0 (any output), or exit code 2 with exactly one non-empty line on stderr; never a
  traceback, another exit code, a crash or a timeout (reading /dev/zero forever is a bug);
* the worker's peak RSS during the case stays below a bound above its baseline (the worker also
  runs under RLIMIT_AS = its warm size + the bound, so a huge allocation is a MemoryError, i.e. a
  traceback, instead of swapping the machine);
* nothing outside the run directories (``w/run``, ``w/run2``, ``w/out``, ``w/runs``) is created, changed or
  deleted (snapshot of the whole case root: type, size, mtime, mode, sha256, link target);
* read-only commands (`checkpoint list|verify|inspect|hash|export`, `compare`, `check`) leave the
  stores byte-identical (`report` may add ``figures/``); a command that exits 2 leaves the
  committed files (MANIFEST.json and the files it names) byte-identical;
* a write command (`resume`, `checkpoint prune`, `run --out run`) that exits 0 and changed the
  manifest leaves a store that `checkpoint verify` accepts;
* the worker exits cleanly after each strategy: an abort at interpreter exit ("free(): invalid
  pointer") means some case damaged the heap (an out-of-bounds write in a kernel); the case is
  found by bisection in fresh workers and reported as ``heap_damage``;
* no temporary (``*.tmp*``) is left anywhere in the world by a command that ended (exit 0 or 2);
* under a file-size limit, exit 0 never leaves a file of exactly the limit (an output cut short);
* a refusal of a hostile declared size (trajectory rows, npz members, inflated zarr chunks,
  ``hist_cap``) peaks below SIZE_BOUND above the RSS at its call, and is never only the failure
  of an allocation sized by that number ("out of memory");
* per-case expectations, e.g. ``verify`` of an epoch whose bytes were flipped without fixing the
  checksum must not exit 0, and ``export --out`` over MANIFEST.json / an epoch file / a device
  must be refused (exit 2).

World of a case (cwd of the command is ``R/w``)::

    R/                      case root (everything below is snapshotted except w/run, w/run2,
                            w/out, w/runs)
      dev/zero -> /dev/zero (so that "../../dev/zero" from the store stays inside R)
      w/
        run/                the store under test (copy of a base run: MANIFEST.json, epochs/,
                            summary.json, series.csv, initial.npz, scenario.toml)
        run2/               an untouched copy of the other base run (for `compare`; only made when
                            the case names it)
        out/                empty directory for --out files
        runs/               (not made) where `run` without --out writes runs/<scenario name>
        victim/             a.txt, sub/b.txt
        victim_file
        victim_epochs/      copy of run/epochs, made by the "epochs/ is a symlink to it" edit
        link_victim -> victim, link_file -> victim_file, link_zero -> /dev/zero,
        dev_null -> /dev/null, dev_full -> /dev/full, scenario.toml (a valid tiny scenario)

Scenario cases use `ooc-dem check SCENARIO ...`; while the parser has no `check` command they
run as `ooc-dem profile SCENARIO --set ... --modes monolithic --out victim`, which loads and
validates the scenario the same way and then refuses the non-empty --out (counted in the
summary's ``commands_missing``).

All hostile paths resolve inside R (never more than two ".." above the store, absolute paths
only into R, devices only through symlinks), so a buggy delete or write can only hit R.
"""
from __future__ import annotations

import contextlib
import copy
import hashlib
import json
import math
import os
import re
import select
import shutil
import signal
import stat
import subprocess
import sys
import tempfile
import time
import traceback
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
GiB = 1 << 30
MEM_BOUND = 2 * GiB          # peak RSS above the worker's warm baseline
CASE_TIMEOUT = 20.0          # s per command
READ_ONLY = {"list", "verify", "inspect", "hash", "export"}
BASES = ("h5", "zarr")
SAFE_DIRS = ("run", "run2", "out", "runs", "cache")   # under R/w: where commands may write
SIZE_BOUND = 300 << 20       # peak RSS above the RSS at the call of a refusal of a hostile declared size
# a run from a prepared bed or from the bed cache (the bed cases; tiny, with a commit and frames)
BED_RUN = ["run", "quick", "--steps", "4", "--checkpoint-every", "2", "--no-progress", "--no-figures",
           "--set", "output.series_interval=0.00002", "--set", "output.snapshot_interval=0.00002"]


# =====================================================================================
# worker (a subprocess: `python tests/fuzzing.py --worker`)
# =====================================================================================

def _status() -> dict:
    out = {}
    try:
        with open("/proc/self/status") as f:
            for ln in f:
                if ln.startswith(("VmSize", "VmRSS", "VmHWM", "VmPeak")):
                    out[ln.split(":")[0]] = int(ln.split()[1]) * 1024
    except OSError:
        pass
    return out


def _worker_main() -> int:
    import resource
    proto_in = os.fdopen(os.dup(0), "r", encoding="utf-8")
    proto_out = os.fdopen(os.dup(1), "w", encoding="utf-8")
    null = os.open(os.devnull, os.O_RDONLY)
    os.dup2(null, 0)                                  # the CLI never reads the protocol
    os.environ.setdefault("MPLBACKEND", "Agg")
    scratch = Path(tempfile.mkdtemp(prefix="ooc-dem-fuzz-worker-"))
    import atexit
    atexit.register(shutil.rmtree, scratch, True)
    sys.setrecursionlimit(max(sys.getrecursionlimit(), 1000))

    def send(obj):
        proto_out.write(json.dumps(obj) + "\n")
        proto_out.flush()

    def call(argv, cwd, env=None, fsize=None):
        from ooc_dem.cli import main
        from ooc_dem.app.profiling import reset_peak
        os.chdir(cwd)
        if argv and argv[0] == API_PREFIX:
            main = _api_main                 # the Python API, judged by the same exit rules
        saved_env = {k: os.environ.get(k) for k in (env or {})}
        os.environ.update(env or {})
        saved_fsize = resource.getrlimit(resource.RLIMIT_FSIZE)
        outp, errp = scratch / "stdout", scratch / "stderr"
        sys.stdout.flush()
        sys.stderr.flush()
        saved = os.dup(1), os.dup(2)
        exc = None
        with open(outp, "wb") as fo, open(errp, "wb") as fe:
            os.dup2(fo.fileno(), 1)
            os.dup2(fe.fileno(), 2)
            hwm_reset = reset_peak()
            rss0 = _status().get("VmRSS", 0)
            t0 = time.monotonic()
            try:
                if fsize is not None:
                    # the command's own writes only (the capture files are open already)
                    resource.setrlimit(resource.RLIMIT_FSIZE, (int(fsize), saved_fsize[1]))
                rc = main(list(argv))
                rc = 0 if rc is None else rc
            except SystemExit as e:
                if e.code is None:
                    rc = 0
                elif isinstance(e.code, int):
                    rc = e.code
                else:
                    print(e.code, file=sys.stderr)
                    rc = 1
            except BaseException as e:  # noqa: BLE001 - what the interpreter would do
                exc = type(e).__name__
                traceback.print_exc()
                rc = 1
            finally:
                if fsize is not None:
                    resource.setrlimit(resource.RLIMIT_FSIZE, saved_fsize)
                for k, v in saved_env.items():
                    if v is None:
                        os.environ.pop(k, None)
                    else:
                        os.environ[k] = v
                try:
                    sys.stdout.flush()
                    sys.stderr.flush()
                except Exception:  # noqa: BLE001
                    pass
                elapsed = time.monotonic() - t0
                os.dup2(saved[0], 1)
                os.dup2(saved[1], 2)
                os.close(saved[0])
                os.close(saved[1])
        try:
            import matplotlib.pyplot as plt
            plt.close("all")
        except Exception:  # noqa: BLE001
            pass
        os.chdir(scratch)

        def tail(p):
            size = p.stat().st_size
            with open(p, "rb") as f:
                data = f.read(65536)
            return data.decode("utf-8", "replace") + (f"\n...[{size} bytes]" if size > 65536 else "")
        st = _status()
        return {"rc": rc if isinstance(rc, int) else 1, "stdout": tail(outp), "stderr": tail(errp),
                "exc": exc, "elapsed": round(elapsed, 4), "hwm": st.get("VmHWM", 0),
                "hwm_reset": hwm_reset, "rss": st.get("VmRSS", 0), "rss0": rss0}

    # warm up: imports and the JIT caches (not counted as cases)
    import numpy  # noqa: F401
    import ooc_dem.cli  # noqa: F401
    from ooc_dem.engine import run  # noqa: F401
    req = json.loads(proto_in.readline())
    for argv, cwd in req.get("warmup", []):
        call(argv, cwd)
    base = _status()
    limit = None
    if req.get("rlimit_as"):
        limit = base.get("VmSize", 0) + int(req["rlimit_as"])
        try:
            resource.setrlimit(resource.RLIMIT_AS, (limit, resource.RLIM_INFINITY))
        except (ValueError, OSError):
            limit = None
    send({"ready": True, "pid": os.getpid(), "scratch": str(scratch), "baseline_rss": base.get("VmRSS", 0),
          "vm_size": base.get("VmSize", 0), "rlimit_as": limit,
          "commands": sorted(_subcommands())})
    for line in proto_in:
        if not line.strip():
            continue
        req = json.loads(line)
        res = call(req["argv"], req["cwd"], req.get("env"), req.get("fsize"))
        res["id"] = req.get("id")
        send(res)
    return 0


API_PREFIX = "@api"


def _api_main(argv) -> int:
    """``@api WHAT RUN``: read a run through the Python API as a user would. Exit 0 when it
    reads, 2 with the exception's one line when it raises one of the package's own exception
    types (docs/api.md); anything else propagates (a traceback: a failure)."""
    from ooc_dem.api import open_run
    what, path = argv[1], argv[2]
    try:
        if what == "state":
            open_run(path).state()
        elif what == "summary":
            open_run(path).summary  # noqa: B018
        elif what == "trajectory":
            from ooc_dem.app.trajectory import Trajectory
            with Trajectory.of_run(path) as t:
                for i in range(len(t)):
                    t[i]
        else:
            raise SystemExit(f"@api: unknown {what!r}")
    except Exception as e:  # noqa: BLE001
        mod = type(e).__module__ or ""
        if not mod.startswith("ooc_dem"):
            raise
        print(" ".join(str(e).split()) or type(e).__name__, file=sys.stderr)
        return 2
    return 0


def _subcommands() -> dict:
    from ooc_dem.cli import build_parser
    return {name: sub for name, sub in _subparsers(build_parser()).items()}


def _subparsers(parser) -> dict:
    import argparse
    for a in parser._actions:
        if isinstance(a, argparse._SubParsersAction):
            return dict(a.choices)
    return {}


# =====================================================================================
# parent side: the worker handle
# =====================================================================================

def child_env() -> dict:
    """The environment of a child interpreter: this checkout's ooc_dem first, no display."""
    return dict(os.environ, MPLBACKEND="Agg", PYTHONPATH=os.pathsep.join(
        [str(ROOT)] + ([os.environ["PYTHONPATH"]] if os.environ.get("PYTHONPATH") else [])))


class WorkerDied(Exception):
    pass


class Worker:
    """A long-lived `ooc_dem.cli.main` runner with a per-call timeout and a memory watch."""

    def __init__(self, warmup=(), mem_bound=MEM_BOUND, use_rlimit=True, prepare=None, errlog=None):
        self.warmup = [list(w) for w in warmup]
        self.errlog = errlog            # the worker's own stderr (what glibc prints when it aborts)
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
            self.proc = subprocess.Popen([sys.executable, str(Path(__file__).resolve()), "--worker"],
                                         stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                         stderr=err, env=env, start_new_session=True,
                                         text=True, bufsize=1)
        finally:
            if self.errlog:
                err.close()
        self.proc.stdin.write(json.dumps({"warmup": self.warmup,
                                          "rlimit_as": self.mem_bound if self.use_rlimit else None})
                              + "\n")
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
            return {"rc": None, "error": str(e), "elapsed": time.monotonic() - t0,
                    "stderr": err, "stdout": ""}
        if res is None:
            self.kill()
            err = self._dead_stderr()
            self.kill_cleanup()
            return {"rc": None, "error": f"timeout after {timeout:.0f} s", "elapsed": timeout,
                    "stderr": err, "stdout": ""}
        res["peak_seen"] = self.peak_seen
        return res

    def kill(self):
        if self.proc is None:
            return
        if self.proc.poll() is None:
            try:
                os.killpg(self.proc.pid, signal.SIGKILL)   # its own session: the worker and children
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


# =====================================================================================
# base material and worlds
# =====================================================================================

_RUN20 = ["--steps", "20", "--checkpoint-every", "10", "--no-progress", "--no-figures"]
BASE_RUNS = {
    "h5": ["run", "quick", *_RUN20, "--set", "output.series_interval=0.00005"],
    "zarr": ["run", "quick", *_RUN20, "--mode", "ooc", "--domains", "3", "--block", "10", "--backend", "zarr",
             "--set", "output.series_interval=0.00005"],
    # 3D stores: monolithic HDF5 and out-of-core zarr (the same epoch edits as 2D)
    "h5_3d": ["run", "quick-3d", *_RUN20, "--set", "output.series_interval=0.00005"],
    "zarr_3d": ["run", "quick-3d", *_RUN20, "--mode", "ooc", "--domains", "2", "--block", "10",
                "--backend", "zarr", "--set", "output.series_interval=0.00005"],
    # a frame every 10 steps (frames 0, 10, 20) for the trajectory and film cases
    "traj": ["run", "quick", *_RUN20, "--set", "output.series_interval=0.00005",
             "--set", "output.snapshot_interval=0.0001"],
    # serial DDM (sub-domains in one process, HDF5)
    "ddm": ["run", "quick", *_RUN20, "--mode", "ddm", "--domains", "3", "--set", "output.series_interval=0.00005"],
    # a zarr store whose arrays carry a compression codec (zstd)
    "zarr_zstd": ["run", "quick", *_RUN20, "--backend", "zarr", "--compression", "zstd",
                  "--set", "output.series_interval=0.00005"],
    # a prepared bed (`--bed` cases) made with a fresh bed cache (the bed-cache cases)
    "bed": ["prepare", "quick", "--no-progress"],
}
# the second store of a world (`compare`, run2)
OTHER_BASE = {"h5": "zarr", "zarr": "h5", "ddm": "h5", "h5_3d": "zarr_3d", "zarr_3d": "h5_3d", "traj": "h5",
              "zarr_zstd": "h5"}

TINY_SCENARIO = """\
[scenario]
name = "tiny"
description = "fuzz base scenario"

[soil]
n = 300

[bin]
length = 0.1
height = 0.1

[wheel]
enabled = false

[output]
run_steps = 10
"""


def make_bases(where: Path, names=None) -> dict:
    """The finished base runs, made once with the real CLI's ``main`` in one worker process
    (imports and JIT paid once, not per base). ``where/cache`` is the bed cache the "bed" base
    was prepared with (its entry is the bed-cache cases' material)."""
    where.mkdir(parents=True, exist_ok=True)
    out, todo = {}, []
    for name in (BASE_RUNS if names is None else names):
        d = where / name
        if not (d / ("bed.npz" if name == "bed" else "summary.json")).is_file():
            shutil.rmtree(d, ignore_errors=True)
            todo.append(name)
        out[name] = d
    if todo:
        builder = Worker(use_rlimit=False).start()
        try:
            for name in todo:
                env = {"OOC_DEM_CACHE": str(where / "cache")} if name == "bed" else None
                res = builder.call([*BASE_RUNS[name], "--out", name], where, timeout=1800, env=env)
                if res.get("rc") != 0:
                    raise RuntimeError(f"base {name} failed ({res.get('rc')}): "
                                       f"{(res.get('stderr') or res.get('error') or '')[-2000:]}")
        finally:
            builder.close()
    if "bed" in out:
        out["cache"] = where / "cache"
    return out


class World:
    """The directory tree of one case."""

    def __init__(self, root: Path, base: Path, other: Path):
        self.root = root
        self.w = root / "w"
        self.run = self.w / "run"
        (root / "dev").mkdir(parents=True)
        os.symlink("/dev/zero", root / "dev" / "zero")
        self.w.mkdir()
        shutil.copytree(base, self.run, symlinks=True)
        self.base = base
        self.other = other
        (self.w / "out").mkdir()
        v = self.w / "victim"
        (v / "sub").mkdir(parents=True)
        (v / "a.txt").write_text("precious a\n")
        (v / "sub" / "b.txt").write_text("precious b\n")
        (self.w / "victim_file").write_text("precious file\n")
        for name, target in (("link_victim", "victim"), ("link_file", "victim_file"),
                             ("link_zero", "/dev/zero"), ("dev_null", "/dev/null"),
                             ("dev_full", "/dev/full")):
            os.symlink(target, self.w / name)
        (self.w / "scenario.toml").write_text(TINY_SCENARIO)

    def add_material(self, what: str, bases: dict):
        """The prepared bed (w/out/bed) or a copy of the bed cache (w/cache)."""
        if what == "bed":
            shutil.copytree(bases["bed"], self.w / "out" / "bed", symlinks=True)
        elif what == "cache":
            shutil.copytree(bases["cache"], self.w / "cache", symlinks=True)

    def add_run2(self):
        shutil.copytree(self.other, self.w / "run2", symlinks=True)

    def epoch_bytes_changed(self) -> bool:
        """Whether any file of the base store's epochs differs now (edits may cancel out: the
        same byte flipped twice is the original byte)."""
        base_m = json.loads((self.base / "MANIFEST.json").read_text())
        for e in (base_m["current"], base_m["previous"]):
            for f in e["files"]:
                now = self.run / f["path"]
                if (not now.is_file() or now.is_symlink()
                        or now.read_bytes() != (self.base / f["path"]).read_bytes()):
                    return True
        return False

    def manifest(self) -> dict:
        return json.loads((self.run / "MANIFEST.json").read_text())

    def write_manifest(self, m, raw: str | None = None):
        (self.run / "MANIFEST.json").write_text(raw if raw is not None else _dumps(m))


def snapshot(root: Path, skip=()) -> dict:
    """{relative path: (type, size, mtime_ns, mode, sha256 | link target)} of a tree, no links followed."""
    out = {}
    root = Path(root)
    skip = {os.path.normpath(s) for s in skip}
    if not os.path.lexists(root):
        return {"": ("missing",)}
    for dirpath, dirnames, filenames in os.walk(root, followlinks=False):
        rel_dir = os.path.relpath(dirpath, root)
        keep = []
        for n in sorted(dirnames):
            rel = os.path.normpath(os.path.join(rel_dir, n))
            if rel in skip:
                continue
            keep.append(n)
        dirnames[:] = keep
        for n in sorted(dirnames) + sorted(filenames):
            rel = os.path.normpath(os.path.join(rel_dir, n))
            if rel in skip:
                continue
            p = os.path.join(dirpath, n)
            try:
                st = os.lstat(p)
            except OSError:
                continue
            if stat.S_ISLNK(st.st_mode):
                out[rel] = ("link", os.readlink(p))
            elif stat.S_ISDIR(st.st_mode):
                out[rel] = ("dir", st.st_mode)
            elif stat.S_ISREG(st.st_mode):
                out[rel] = ("file", st.st_size, st.st_mtime_ns, st.st_mode, _sha(p))
            else:
                out[rel] = ("other", st.st_mode)
    return out


def _sha(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _diff(a: dict, b: dict, limit=3) -> list[str]:
    out = []
    for k in sorted(set(a) | set(b)):
        if a.get(k) != b.get(k):
            what = "created" if k not in a else "deleted" if k not in b else "changed"
            out.append(f"{k or '.'} {what}")
            if len(out) >= limit:
                break
    return out


def _committed(run: Path) -> dict:
    """{relpath: sha256} of MANIFEST.json and the regular files it names inside the store."""
    out = {}
    mf = run / "MANIFEST.json"
    if not mf.is_file() or mf.is_symlink():
        return out
    out["MANIFEST.json"] = _sha(mf)
    try:
        m = json.loads(mf.read_text())
    except (ValueError, UnicodeDecodeError, RecursionError):
        return out
    if not isinstance(m, dict):
        return out
    base = os.path.realpath(run)
    for role in ("current", "previous"):
        e = m.get(role)
        files = e.get("files") if isinstance(e, dict) else None
        for f in files if isinstance(files, list) else []:
            p = f.get("path") if isinstance(f, dict) else None
            if not isinstance(p, str) or "\0" in p:
                continue
            full = os.path.realpath(os.path.join(run, p))
            if full.startswith(base + os.sep) and os.path.isfile(full) and not os.path.islink(os.path.join(run, p)):
                out[os.path.relpath(full, base)] = _sha(full)
    return out


# =====================================================================================
# edits (applied in the parent, before the command)
# =====================================================================================

RAW_HUGE_INT = "1" + "0" * 5000


def _get(tree, path):
    for k in path:
        tree = tree[k]
    return tree


def _set(tree, path, value):
    if not path:
        return value
    parent = tree
    for k in path[:-1]:
        if isinstance(parent, dict) and isinstance(k, str):
            parent = parent.get(k)
        elif isinstance(parent, list) and isinstance(k, int) and -len(parent) <= k < len(parent):
            parent = parent[k]
        else:
            return tree
    k = path[-1]
    if isinstance(parent, dict) and isinstance(k, str):
        parent[k] = value
    elif isinstance(parent, list) and isinstance(k, int) and -len(parent) <= k < len(parent):
        parent[k] = value
    return tree


def _delete(tree, path):
    try:
        parent = _get(tree, path[:-1])
        if isinstance(parent, dict):
            parent.pop(path[-1], None)
        elif isinstance(parent, list) and isinstance(path[-1], int) and path[-1] < len(parent):
            del parent[path[-1]]
    except (KeyError, IndexError, TypeError):
        pass
    return tree


def _dumps(obj) -> str:
    """json.dumps, with the deep markers written as raw text (json.dumps would recurse too deep)."""
    raws = []

    def swap(v):
        if isinstance(v, dict) and len(v) == 1 and next(iter(v)) in ("$deep_list", "$deep_dict"):
            (k, n), = v.items()
            raws.append("[" * n + "]" * n if k == "$deep_list" else '{"a": ' * n + "{}" + "}" * n)
            return f"__RAW{len(raws) - 1}__"
        if isinstance(v, dict):
            return {k: swap(x) for k, x in v.items()}
        if isinstance(v, list):
            return [swap(x) for x in v]
        return v
    text = json.dumps(swap(obj), indent=1)
    for i, r in enumerate(raws):
        text = text.replace(f'"__RAW{i}__"', r, 1)
    return text


def _decode_value(v):
    """Values travel as JSON; {"$float": "nan"} and {"$deep": n} stand for what JSON cannot carry."""
    if isinstance(v, dict) and len(v) == 1:
        (k, x), = v.items()
        if k == "$float":
            return float(x)
        if k in ("$deep_list", "$deep_dict"):
            return v                      # kept as a marker, written by _dumps
        if k == "$many_domains":
            return {str(i): {"n": 1, "arrays": {"x": [[1], "<f8"]}} for i in range(x)}
    if isinstance(v, list):
        return [_decode_value(x) for x in v]
    if isinstance(v, dict):
        return {k: _decode_value(x) for k, x in v.items()}
    return v


def _epoch_entry(m, which):
    e = m.get(which) if isinstance(m, dict) else None
    return e if isinstance(e, dict) else None


def _epoch_file_paths(world: World, which: str) -> list[Path]:
    """Regular files (relative to the store) of the named epoch."""
    m = world.manifest()
    e = _epoch_entry(m, which)
    if not e:
        return []
    return [world.run / f["path"] for f in e["files"]]


def _fix_checksums(world: World, rels: list[str]):
    m = world.manifest()
    for role in ("current", "previous"):
        e = _epoch_entry(m, role)
        for f in (e or {}).get("files", []):
            if f["path"] in rels:
                p = world.run / f["path"]
                f["size"] = p.stat().st_size
                f.pop("xxh3_128", None)          # an older store's checksum, still accepted
                f["sha256"] = _sha(p)
    world.write_manifest(m)


def apply_edit(world: World, ed: dict) -> None:
    op = ed["op"]
    run = world.run
    if op not in ("manifest_raw", "runfile", "runfile_link", "scenario_file", "epochs_symlink"):
        try:
            world.manifest()
        except (ValueError, UnicodeDecodeError, RecursionError, OSError):
            return                         # an earlier edit made the manifest unreadable
    if op == "manifest_set":
        m = world.manifest()
        value = json.loads(json.dumps(ed["value"]).replace("$ABS", str(world.w)))
        world.write_manifest(_set(m, ed["path"], _decode_value(value)))
    elif op == "manifest_delete":
        world.write_manifest(_delete(world.manifest(), ed["path"]))
    elif op == "manifest_swap":
        m = world.manifest()
        m["current"], m["previous"] = m.get("previous"), m.get("current")
        world.write_manifest(m)
    elif op == "manifest_prev_is_cur":
        m = world.manifest()
        m["previous"] = copy.deepcopy(m.get("current"))
        world.write_manifest(m)
    elif op == "manifest_raw":
        text = (run / "MANIFEST.json").read_text()
        if ed["what"] == "huge_int":
            text = re.sub(r'"step": \d+', '"step": ' + RAW_HUGE_INT, text, count=1)
        elif ed["what"] == "deep":
            text = text.replace('"meta": {', '"deep": ' + "[" * ed["n"] + "]" * ed["n"] + ', "meta": {', 1)
        elif ed["what"] == "truncate":
            text = text[: int(len(text) * ed["frac"])]
        elif ed["what"] == "nan_step":
            text = re.sub(r'"step": \d+', '"step": NaN', text, count=1)
        elif ed["what"] == "bytes":
            (run / "MANIFEST.json").write_bytes(bytes(ed["data"]))
            return
        (run / "MANIFEST.json").write_text(text)
    elif op == "epochs_symlink":
        if (run / "epochs").is_symlink() or not (run / "epochs").is_dir():
            return
        shutil.copytree(run / "epochs", world.w / "victim_epochs", symlinks=True)
        shutil.rmtree(run / "epochs")
        os.symlink("../victim_epochs", run / "epochs")
    elif op == "flip":
        files = [p for p in _epoch_file_paths(world, ed["which"]) if p.is_file()]
        if not files:
            return
        p = files[ed["file"] % len(files)]
        data = bytearray(p.read_bytes())
        if not data:
            return
        for frac, x in zip(ed["offsets"], ed["xors"]):
            i = min(int(frac * len(data)), len(data) - 1)
            data[i] ^= (x % 255) + 1
        p.write_bytes(bytes(data))
        if ed.get("recompute"):
            _fix_checksums(world, [p.relative_to(run).as_posix()])
    elif op == "truncate":
        files = [p for p in _epoch_file_paths(world, ed["which"]) if p.is_file()]
        if not files:
            return
        p = files[ed["file"] % len(files)]
        data = p.read_bytes()
        p.write_bytes(data[: int(len(data) * ed["frac"])] + bytes(ed.get("extra", [])))
        if ed.get("recompute"):
            _fix_checksums(world, [p.relative_to(run).as_posix()])
    elif op == "array":
        _edit_array(world, ed)
    elif op == "attrs":
        _edit_attrs(world, ed)
    elif op == "npz_array":
        _edit_npz_array(world, ed)
    elif op == "npz_member":
        (_edit_bomb_npz if ed["what"] == "bomb" else _edit_npz_member)(world, ed)
    elif op == "traj":
        _edit_traj(world, ed)
    elif op == "zarr_codec":
        _edit_zarr_codec(world, ed)
    elif op == "runfile":
        p = run / ed["name"]
        if not ed.get("delete") and "summary_set" not in ed:
            if p.is_symlink():
                p.unlink()
            elif p.is_dir():
                shutil.rmtree(p)
        if "text" in ed:
            p.write_text(ed["text"], encoding="utf-8", errors="surrogatepass")
        elif "json" in ed:
            p.write_text(_dumps(_decode_value(ed["json"])))
        elif "bytes" in ed:
            p.write_bytes(bytes(ed["bytes"]))
        elif "npz" in ed:
            _write_npz(p, ed["npz"])
        elif ed.get("delete"):
            if p.is_dir():
                shutil.rmtree(p)
            elif p.exists():
                p.unlink()
        elif "summary_set" in ed:
            if p.is_symlink() or not p.is_file():
                return   # an earlier edit made it a link (to /dev/zero, say): never read it here
            s = json.loads(p.read_text())
            p.write_text(_dumps(_set(s, ed["summary_set"], _decode_value(ed["value"]))))
    elif op == "runfile_link":
        p = run / ed["name"]
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p)
        elif os.path.lexists(p):
            p.unlink()
        os.symlink(ed["target"], p)
    elif op == "scenario_file":
        p = world.w / "out" / ed["name"]
        if "bytes" in ed:
            p.write_bytes(bytes(ed["bytes"]))
        else:
            p.write_text(ed["text"], encoding="utf-8", errors="surrogatepass")
    else:
        raise ValueError(f"unknown edit {op!r}")


def _write_npz(path, spec):
    import numpy as np
    arrays = {}
    for name, kind in spec.items():
        if kind == "nan":
            arrays[name] = np.full(1500, np.nan)
        elif kind == "short":
            arrays[name] = np.zeros(3)
        elif kind == "2d":
            arrays[name] = np.zeros((1500, 7))
        elif kind == "str":
            arrays[name] = np.array(["a", "b"])
        elif kind == "object":
            arrays[name] = np.array([{"a": 1}, None], dtype=object)
        elif kind == "empty":
            arrays[name] = np.zeros(0)
        elif kind == "int":
            arrays[name] = np.arange(1500)
        elif kind == "huge_shape_hdr":
            arrays[name] = np.zeros(1)
    with open(path, "wb") as f:
        np.savez(f, **arrays)


def _semantic(arr, kind, rows):
    import numpy as np
    a = np.array(arr)
    n = len(a)
    idx = [min(int(r * n), n - 1) for r in rows] if n else []
    if kind == "nan":
        if a.dtype.kind == "f":
            a[idx] = np.nan
        else:
            a[idx] = -1
    elif kind == "inf":
        if a.dtype.kind == "f":
            a[idx] = np.inf
        else:
            a[idx] = np.iinfo(a.dtype).max
    elif kind == "all_nan":
        a = np.full(a.shape, np.nan) if a.dtype.kind == "f" else np.full(a.shape, -1, a.dtype)
    elif kind == "99":
        a[idx] = 99
    elif kind == "all_99":
        a[...] = 99
    elif kind == "neg":
        a[idx] = -(10 ** 6)
    elif kind == "huge":
        a[idx] = np.iinfo(a.dtype).max if a.dtype.kind in "iu" else 1e308
    elif kind == "zero":
        a[idx] = 0
    elif kind == "dup" and n > 1:
        a[idx] = a[0]
    elif kind == "shorter":
        a = a[: max(0, n - 1)]
    elif kind == "longer":
        a = np.concatenate([a, a[:1]])
    elif kind == "empty":
        a = a[:0]
    elif kind == "2d":
        a = np.stack([a, a], axis=-1)
    elif kind == "int32":
        a = a.astype(np.int32) if a.dtype.kind == "f" else a.astype(np.float64)
    elif kind == "float32":
        a = a.astype(np.float32)
    elif kind == "bool":
        a = a.astype(bool)
    elif kind == "complex":
        a = a.astype(np.complex128)
    elif kind == "u8":
        a = a.astype(np.uint8)
    elif kind in EXTREMES:
        v = EXTREMES[kind]
        if a.dtype.kind in "iu":
            v = int(min(max(v, np.iinfo(a.dtype).min), np.iinfo(a.dtype).max))
        elif a.dtype.kind == "b":
            v = bool(v)
        if n:
            a[idx] = v
    elif kind == "drop_row" and n > 1:
        a = np.delete(a, idx[:1], axis=0)
    elif kind == "unsort" and n > 1 and a.ndim >= 2:
        a[idx] = a[idx][:, ::-1]
    return a


# finite absurd values and out-of-range indices (each written at the drawn rows)
EXTREMES = {"1e300": 1e300, "5e-324": 5e-324, "-5e-324": -5e-324, "999": 999, "i32max": 2 ** 31 - 1,
            "minus7": -7, "minus1": -1, "1e-300": 1e-300, "1e150": 1e150, "3e8": 300_000_000}


@contextlib.contextmanager
def _zarr_tree(path):
    """A zarr epoch as a directory to edit: the epoch itself (directory layout of earlier
    versions), or its zip archive unpacked into a scratch directory and packed again (stored
    entries, the edited tree's files) when the edit is done."""
    import zipfile
    path = Path(path)
    if path.is_dir():
        yield path
        return
    with tempfile.TemporaryDirectory() as tmp:
        base = Path(tmp) / "epoch"
        with zipfile.ZipFile(path) as zf:
            zf.extractall(base)
        yield base
        with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as zf:
            for f in sorted(p for p in base.rglob("*") if p.is_file()):
                zf.write(f, f.relative_to(base).as_posix())


def _edit_array(world: World, ed: dict):
    import numpy as np
    m = world.manifest()
    e = _epoch_entry(m, ed["which"])
    if not e:
        return
    group = ed["group"]
    if world.manifest().get("backend") == "hdf5":
        import h5py
        p = world.run / e["path"]
        with h5py.File(p, "r+") as f:
            gname = "globals" if group == "globals" else f"domains/{sorted(f['domains'])[ed['dom'] % len(f['domains'])]}"
            g = f[gname]
            names = sorted(g)
            name = ed["name"] if ed["name"] in g else names[ed.get("name_i", 0) % len(names)]
            if ed["kind"] == "delete":
                del g[name]
            else:
                old = g[name][()]
                new = _semantic(old, ed["kind"], ed.get("rows", [0.0]))
                ed["noop"] = _same_array(old, new)
                del g[name]
                g.create_dataset(name, data=new)
        if ed.get("update_meta"):
            _sync_meta_hdf5(world, ed["which"])
    else:
        with _zarr_tree(world.run / e["path"]) as base:
            doms = sorted((base / "domains").glob("d*"))
            gdir = base / "globals" if group == "globals" else doms[ed["dom"] % len(doms)]
            names = sorted(x.name for x in gdir.iterdir() if x.is_dir())
            name = ed["name"] if ed["name"] in names else names[ed.get("name_i", 0) % len(names)]
            adir = gdir / name
            meta = json.loads((adir / "zarr.json").read_text())
            dt = np.dtype({"float64": "<f8", "int64": "<i8", "int32": "<i4", "float32": "<f4",
                           "bool": "|b1", "uint8": "|u1"}.get(meta["data_type"], "<f8"))
            chunk = adir / "c" / "/".join(["0"] * max(1, len(meta["shape"])))
            if ed["kind"] == "delete":
                shutil.rmtree(adir)
            else:
                old = np.frombuffer(chunk.read_bytes(), dtype=dt).reshape(meta["shape"]) if chunk.exists() \
                    else np.zeros(meta["shape"], dt)
                new = _semantic(old, ed["kind"], ed.get("rows", [0.0]))
                ed["noop"] = _same_array(old, new)
                if new.ndim != old.ndim:
                    shutil.rmtree(adir / "c", ignore_errors=True)
                    chunk = adir / "c" / "/".join(["0"] * max(1, new.ndim))
                chunk.parent.mkdir(parents=True, exist_ok=True)
                chunk.write_bytes(np.ascontiguousarray(new).astype(new.dtype.newbyteorder("<")).tobytes())
                if ed.get("update_meta") or new.shape != old.shape or new.dtype != old.dtype:
                    names_ = {"<f8": "float64", "<i8": "int64", "<i4": "int32", "<f4": "float32", "|b1": "bool",
                              "|u1": "uint8", "<c16": "complex128"}
                    if ed.get("update_meta", True):
                        meta["shape"] = list(new.shape)
                        meta["chunk_grid"]["configuration"]["chunk_shape"] = list(new.shape)
                        meta["data_type"] = names_.get(new.dtype.newbyteorder("<").str, meta["data_type"])
                        (adir / "zarr.json").write_text(json.dumps(meta, indent=2))
        if ed.get("update_meta"):
            _sync_meta_zarr(world, ed["which"])
    _fix_all_checksums(world, ed["which"])


def _fix_all_checksums(world: World, which: str):
    """Re-list and re-checksum every file of the epoch (the tampering is invisible to checksums)."""
    m = world.manifest()
    e = _epoch_entry(m, which)
    if not e:
        return
    base = world.run / e["path"]
    if base.is_dir():
        files = sorted(p for p in base.rglob("*") if p.is_file())
    else:
        files = [base]
    e["files"] = [{"path": p.relative_to(world.run).as_posix(), "size": p.stat().st_size,
                   "sha256": _sha(p)} for p in files]
    world.write_manifest(m)


def _sync_meta_hdf5(world, which):
    import h5py
    m = world.manifest()
    e = _epoch_entry(m, which)
    with h5py.File(world.run / e["path"], "r") as f:
        for i, dname in enumerate(sorted(f["domains"])):
            g = f["domains"][dname]
            key = str(int(dname[1:]))
            arrays = {n: [list(g[n].shape), g[n].dtype.str] for n in g}
            first = next(iter(arrays.values()), None)
            e["domains"][key] = {"n": first[0][0] if first and first[0] else 0, "arrays": arrays}
        g = f["globals"]
        e["globals"] = {"arrays": {n: [list(g[n].shape), g[n].dtype.str] for n in g}}
    world.write_manifest(m)


def _sync_meta_zarr(world, which):
    m = world.manifest()
    e = _epoch_entry(m, which)
    with _zarr_tree(world.run / e["path"]) as base:
        strs = {"float64": "<f8", "int64": "<i8", "int32": "<i4", "float32": "<f4", "bool": "|b1",
                "uint8": "|u1", "complex128": "<c16"}

        def arrays(gdir):
            out = {}
            for a in sorted(x for x in gdir.iterdir() if x.is_dir()):
                meta = json.loads((a / "zarr.json").read_text())
                out[a.name] = [meta["shape"], strs.get(meta["data_type"], meta["data_type"])]
            return out
        for dname in sorted((base / "domains").glob("d*")):
            arr = arrays(dname)
            first = next(iter(arr.values()), None)
            e["domains"][str(int(dname.name[1:]))] = {"n": first[0][0] if first and first[0] else 0, "arrays": arr}
        e["globals"] = {"arrays": arrays(base / "globals")}
    world.write_manifest(m)


def _edit_attrs(world: World, ed: dict):
    m = world.manifest()
    e = _epoch_entry(m, ed["which"])
    if not e:
        return
    value = ed["value"]          # None: delete the attribute, else the new JSON string
    if m.get("backend") == "hdf5":
        import h5py
        with h5py.File(world.run / e["path"], "r+") as f:
            g = f["globals"] if ed["group"] == "globals" else f["domains"][sorted(f["domains"])[ed["dom"] % len(f["domains"])]]
            if value is None:
                if "ooc_dem_attrs" in g.attrs:
                    del g.attrs["ooc_dem_attrs"]
            else:
                g.attrs["ooc_dem_attrs"] = value
    else:
        with _zarr_tree(world.run / e["path"]) as base:
            doms = sorted((base / "domains").glob("d*"))
            gdir = base / "globals" if ed["group"] == "globals" else doms[ed["dom"] % len(doms)]
            meta = json.loads((gdir / "zarr.json").read_text())
            if value is None:
                meta.get("attributes", {}).pop("ooc_dem_attrs", None)
            else:
                meta.setdefault("attributes", {})["ooc_dem_attrs"] = value
            (gdir / "zarr.json").write_text(json.dumps(meta, indent=2))
    _fix_all_checksums(world, ed["which"])


def _bombs_dir(world: World) -> Path:
    """Where built bombs are kept between cases (beside the session's case directories)."""
    d = world.root.parent.parent / "bombs"
    d.mkdir(exist_ok=True)
    return d


def _gzip_zeros(world: World, size: int) -> Path:
    """A gzip stream of ``size`` zero bytes (about size / 1000 bytes), built once a session."""
    import zlib
    p = _bombs_dir(world) / f"zeros-{size}.gz"
    if not p.is_file():
        c = zlib.compressobj(1, zlib.DEFLATED, 31)
        block = bytes(min(size, 16 << 20))
        with open(p.with_suffix(".part"), "wb") as f:
            left = size
            while left:
                k = min(left, len(block))
                f.write(c.compress(block[:k]))
                left -= k
            f.write(c.flush())
        os.replace(p.with_suffix(".part"), p)
    return p


def _npz_path(world: World, where: str) -> Path | None:
    if where == "bed":
        return world.w / "out" / "bed" / "bed.npz"
    if where == "cache":
        found = sorted((world.w / "cache" / "beds").glob("*.npz"))
        return found[0] if found else None
    return world.run / "initial.npz"


def _edit_npz_array(world: World, ed: dict):
    """One array of a bed file (a prepared bed.npz or a bed-cache entry) edited, or the file removed."""
    import numpy as np
    p = _npz_path(world, ed["file"])
    if p is None or not p.is_file():
        return
    if ed["kind"] == "remove_file":
        p.unlink()
        return
    with np.load(p, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    name = ed["name"] if ed["name"] in arrays else sorted(arrays)[0]
    if ed["kind"] == "delete":
        del arrays[name]
    elif ed["kind"] == "drop_disc":           # one disc removed from every array (a consistent tamper)
        i = min(int(ed.get("rows", [0.0])[0] * len(arrays["id"])), len(arrays["id"]) - 1)
        arrays = {k: np.delete(v, i, axis=0) for k, v in arrays.items()}
    else:
        arrays[name] = _semantic(arrays[name], ed["kind"], ed.get("rows", [0.0]))
    with open(p, "wb") as f:
        np.savez(f, **arrays)


def _npy_header(shape, descr="<f8", fortran=False) -> bytes:
    """A .npy version-1 header declaring ``shape`` (whatever data follows)."""
    d = "{'descr': %r, 'fortran_order': %s, 'shape': %s, }" % (descr, fortran, repr(tuple(shape)))
    pad = 64 - (10 + len(d) + 1) % 64
    d = (d + " " * pad + "\n").encode("latin1")
    return b"\x93NUMPY\x01\x00" + len(d).to_bytes(2, "little") + d


def _edit_npz_member(world: World, ed: dict):
    """``initial.npz`` rebuilt with one hostile member (the others kept as written):
    ``declared`` -- a header declaring ``shape`` over a few bytes of data; ``bomb`` -- ``size``
    bytes of deflated zeros under a header declaring all of them (a few MB on disk);
    ``object`` -- a pickled object array; ``shape``/``dtype``/``fortran`` -- wrong layouts."""
    import zipfile
    p = world.run / "initial.npz"
    member = ed["member"] + ".npy"
    kept = {}
    if p.is_file() and not p.is_symlink():
        try:
            with zipfile.ZipFile(p) as zf:
                kept = {n: zf.read(n) for n in zf.namelist() if n != member}
        except (zipfile.BadZipFile, OSError):
            kept = {}
    what = ed["what"]
    tmp = p.with_name("initial.npz.part")
    with zipfile.ZipFile(tmp, "w", zipfile.ZIP_STORED, allowZip64=True) as zf:
        for n, data in kept.items():
            zf.writestr(n, data)
        if what == "bomb":
            size = int(ed["size"])
            zi = zipfile.ZipInfo(member)
            zi.compress_type = zipfile.ZIP_DEFLATED
            block = bytes(16 << 20)
            with zf.open(zi, "w", force_zip64=True) as f:
                f.write(_npy_header((size // 8,)))
                left = size // 8 * 8
                while left:
                    k = min(left, len(block))
                    f.write(block[:k])
                    left -= k
        elif what == "declared":
            zf.writestr(member, _npy_header(tuple(ed["shape"]), ed.get("descr", "<f8")) + bytes(64))
        elif what == "object":
            import io
            import numpy as np
            b = io.BytesIO()
            np.save(b, np.array([{"a": 1}, None], dtype=object), allow_pickle=True)
            zf.writestr(member, b.getvalue())
        elif what == "fortran":
            zf.writestr(member, _npy_header((750, 2), "<f8", True) + bytes(750 * 2 * 8))
        elif what == "shape":
            zf.writestr(member, _npy_header(tuple(ed["shape"]), "<f8") + bytes(8 * math.prod(ed["shape"])))
        elif what == "dtype":
            zf.writestr(member, _npy_header((1500,), ed["descr"]) + bytes(1500 * 16))
    os.replace(tmp, p)


def _edit_bomb_npz(world: World, ed: dict):
    """The bomb member is built once per (member, size) and copied (it takes seconds to deflate)."""
    key = f"initial-{ed['member']}-{ed['size']}-{_sha(world.run / 'initial.npz')[:12]}.npz"
    built = _bombs_dir(world) / key
    if not built.is_file():
        _edit_npz_member(world, ed)
        shutil.copyfile(world.run / "initial.npz", built.with_suffix(".part"))
        os.replace(built.with_suffix(".part"), built)
    else:
        shutil.copyfile(built, world.run / "initial.npz")


def _frames(world: World) -> list[Path]:
    return sorted((world.run / "trajectory").glob("frame-*.h5"))


def _edit_traj(world: World, ed: dict):
    """One trajectory frame file edited: an attribute, one dataset (_semantic kinds), every row
    dataset re-declared at ``rows`` rows with no data written (a few KB on disk), or removed."""
    import h5py
    import numpy as np
    frames = _frames(world)
    if not frames:
        return
    p = frames[ed["frame"] % len(frames)]
    what = ed["what"]
    if what == "remove":
        p.unlink()
        return
    with h5py.File(p, "r+") as f:
        if what == "attr":
            v = _decode_value(ed["value"])
            if v is None:
                if ed["key"] in f.attrs:
                    del f.attrs[ed["key"]]
            else:
                f.attrs[ed["key"]] = np.array(v) if isinstance(v, list) else v
        elif what == "dataset":
            name = ed["name"] if ed["name"] in f else sorted(f)[0]
            new = _semantic(f[name][()], ed["kind"], ed.get("rows", [0.0]))
            del f[name]
            if ed["kind"] != "delete":
                f.create_dataset(name, data=new)
        elif what == "declare_rows":
            rows = int(ed["rows"])
            for name in sorted(f):
                ds = f[name]
                tail, dt = ds.shape[1:], ds.dtype
                del f[name]
                f.create_dataset(name, shape=(rows, *tail), dtype=dt, chunks=(min(rows, 1 << 16), *tail),
                                 fillvalue=0)
            if ed.get("n_discs"):
                f.attrs["n_discs"] = rows


ZARR_CODECS = {
    "gzip": {"name": "gzip", "configuration": {"level": 5}},
    "zstd": {"name": "zstd", "configuration": {"level": 0, "checksum": False}},
    "blosc": {"name": "blosc", "configuration": {"cname": "lz4", "clevel": 5, "shuffle": "shuffle",
                                                  "typesize": 8, "blocksize": 0}},
    "crc32c": {"name": "crc32c"},
    "unknown": {"name": "frobnicate", "configuration": {}},
}


def _edit_zarr_codec(world: World, ed: dict):
    """One array document of a zarr epoch names another codec chain: a compressor over the
    chunk encoded with it (``encode``) or left as it was, a gzip chunk of ``size`` zero bytes
    (far beyond the declared shape), the sharding codec, an unknown codec."""
    m = world.manifest()
    e = _epoch_entry(m, ed["which"])
    if not e or m.get("backend") != "zarr":
        return
    import gzip
    with _zarr_tree(world.run / e["path"]) as base:
        doms = sorted((base / "domains").glob("d*"))
        gdir = base / "globals" if ed["group"] == "globals" else doms[ed["dom"] % len(doms)]
        names = sorted(x.name for x in gdir.iterdir() if x.is_dir())
        adir = gdir / (ed["name"] if ed["name"] in names else names[ed.get("name_i", 0) % len(names)])
        meta = json.loads((adir / "zarr.json").read_text())
        chunks = sorted(p for p in (adir / "c").rglob("*") if p.is_file()) if (adir / "c").is_dir() else []
        raw = chunks[0].read_bytes() if chunks else b""
        codec = ed["codec"]
        bytes_codec = {"name": "bytes", "configuration": {"endian": "little"}}
        data = raw
        if codec == "gzip_bomb":
            meta["codecs"] = [bytes_codec, ZARR_CODECS["gzip"]]
            data = None
        elif codec == "sharding":
            meta["codecs"] = [{"name": "sharding_indexed", "configuration": {
                "chunk_shape": meta["chunk_grid"]["configuration"]["chunk_shape"],
                "codecs": [bytes_codec], "index_codecs": [bytes_codec, {"name": "crc32c"}],
                "index_location": "end"}}]
        elif codec == "sharding_many":
            # inner chunks of one row, an index without checksum: the chunk's bytes read as
            # offsets, one read task per inner chunk
            meta["codecs"] = [{"name": "sharding_indexed", "configuration": {
                "chunk_shape": [1] * len(meta["shape"]), "codecs": [bytes_codec], "index_codecs": [bytes_codec],
                "index_location": ed.get("index_location", "end")}}]
        elif codec == "transpose":
            meta["codecs"] = [{"name": "transpose", "configuration": {"order": list(range(len(meta["shape"])))[::-1]}},
                              bytes_codec]
        else:
            meta["codecs"] = [bytes_codec, ZARR_CODECS[codec]]
            if ed.get("encode") and codec == "gzip":
                data = gzip.compress(raw)
            elif ed.get("encode") and codec in ("zstd", "blosc"):
                import numcodecs
                data = bytes((numcodecs.Zstd(level=0) if codec == "zstd" else
                              numcodecs.Blosc(cname="lz4", clevel=5, shuffle=1, typesize=8)).encode(raw))
        (adir / "zarr.json").write_text(json.dumps(meta, indent=2))
        target = chunks[0] if chunks else adir / "c" / "/".join(["0"] * max(1, len(meta["shape"])))
        target.parent.mkdir(parents=True, exist_ok=True)
        if data is None:
            shutil.copyfile(_gzip_zeros(world, int(ed["size"])), target)
        else:
            target.write_bytes(data)
    _fix_all_checksums(world, ed["which"])


# =====================================================================================
# running and checking one case
# =====================================================================================

def _command_of(argv) -> tuple[str, str | None]:
    cmd = argv[0] if argv else ""
    sub = argv[1] if cmd == "checkpoint" and len(argv) > 1 else None
    return cmd, sub


def _stderr_lines(text: str) -> list[str]:
    return [ln for ln in text.splitlines() if ln.strip()]


def failure_class(rec: dict, err: str | None = None) -> str:
    """A short key that groups failures with the same cause."""
    prop = rec["property"]
    cmd = " ".join(x for x in _command_of(rec["argv"]) if x)
    err = (rec.get("stderr") or "") if err is None else err
    where = ""
    if "Traceback" in err:
        frames = re.findall(r'File "([^"]+)", line \d+, in (\S+)', err)
        own = [f"{Path(f).parent.name}/{Path(f).name}:{fn}" for f, fn in frames
               if "ooc_dem" in f and "fuzzing.py" not in f]
        last = [ln for ln in err.strip().splitlines() if ln and not ln.startswith(" ")][-1:]
        exc = rec.get("exc") or (last[0].split(":")[0] if last else "?")
        where = f"{exc} at {own[-1] if own else (frames[-1][1] if frames else '?')}"
    elif rec.get("exc"):
        where = rec["exc"]
    elif rec.get("error"):
        where = re.sub(r"\d+(\.\d+)?", "N", rec["error"])
    return f"{prop} | {cmd} | {where}".strip(" |")


def fast_tmp() -> str | None:
    """/dev/shm when usable (a case creates and deletes a few hundred files; tmpfs is ~50x faster)."""
    d = "/dev/shm"
    try:
        st = os.statvfs(d)
        if os.access(d, os.W_OK) and st.f_bavail * st.f_frsize > 2 * GiB:
            return d
    except OSError:
        pass
    return None


class Fuzzer:
    """Owns the session directory, the base runs and the worker; runs and checks cases."""

    def __init__(self, workdir: Path | None = None, bases_dir: Path | None = None,
                 timeout=CASE_TIMEOUT, mem_bound=MEM_BOUND, keep_failed: int = 0, log=None,
                 bisect_budget_s: float = 150.0, bases=None):
        self.bisect_budget_s = bisect_budget_s
        self._tmp = None
        if workdir is None:
            self._tmp = tempfile.TemporaryDirectory(prefix="ooc-dem-fuzz-", dir=fast_tmp())
            workdir = Path(self._tmp.name)
        self.work = Path(workdir)
        self.cases_dir = self.work / "cases"
        self.cases_dir.mkdir(parents=True, exist_ok=True)
        self.bases = make_bases(Path(bases_dir) if bases_dir else self.work / "bases", bases)
        self.timeout = timeout
        self.mem_bound = mem_bound
        self.keep_failed = keep_failed
        self.log = log or (lambda msg: None)
        warm = self.work / "warm"
        stores = [b for b in ("h5", "zarr", "h5_3d", "zarr_3d") if b in self.bases]

        def prepare():                   # fresh copies before every (re)start of the worker
            shutil.rmtree(warm, ignore_errors=True)
            warm.mkdir()
            for b in stores:
                shutil.copytree(self.bases[b], warm / b)
        tail = ["--no-progress", "--no-figures"]
        self.worker = Worker(prepare=prepare, errlog=self.work / "worker-stderr.log",
                             warmup=[(["resume", b, "--steps", "21", *tail], str(warm)) for b in stores] +
                             [(["report", "h5"], str(warm))],
                             mem_bound=mem_bound).start()
        self.commands = set(self.worker.info.get("commands", []))
        # the state hash after `resume --steps 30` of each intact base (made when first needed):
        # a resume that falls back from a damaged current epoch to the previous one must end
        # with these bits
        self.ref_hash = {}
        self.n = 0
        self.slowest: list = []           # (seconds, case) of the slowest cases
        self._current = ""
        self.counts: dict[str, int] = {}
        self.missing: dict[str, int] = {}
        self.inapplicable: dict[str, int] = {}   # cases whose edits the harness could not apply
        self.failures: list[dict] = []
        self.elapsed = 0.0
        self.max_peak = 0
        self.history: list[dict] = []     # the last cases run in the current worker
        self.worker_cases: list[dict] = []  # every case run in the current worker

    def reference(self, base: str, what: str):
        """The state hash (as a one-item list) an intact world ends with: ``resume`` -- the
        base resumed to step 30; ``bed_run`` -- BED_RUN from the intact bed cache."""
        key = (base, what)
        if key not in self.ref_hash:
            ref = self.work / "ref"
            shutil.rmtree(ref, ignore_errors=True)
            ref.mkdir()
            env = None
            if what == "resume":
                shutil.copytree(self.bases[base], ref / "run")
                self.worker.call(["resume", "run", "--steps", "30", "--no-progress", "--no-figures"], ref)
            elif what == "export_previous":
                shutil.copytree(self.bases[base], ref / "run")
                self.worker.call(["checkpoint", "export", "run", "--epoch", "10", "--out", "e.csv"], ref)
                self.ref_hash[key] = _csv_body(ref / "e.csv")
                shutil.rmtree(ref, ignore_errors=True)
                return self.ref_hash[key]
            elif what == "previous":
                shutil.copytree(self.bases[base], ref / "run")
                h = self.worker.call(["checkpoint", "hash", "run", "--epoch", "10"], ref)
                self.ref_hash[key] = (h.get("stdout") or "").strip().splitlines()[-1:] or None
                shutil.rmtree(ref, ignore_errors=True)
                return self.ref_hash[key]
            else:
                shutil.copytree(self.bases["cache"], ref / "cache")
                env = {"OOC_DEM_CACHE": str(ref / "cache")}
                self.worker.call([*BED_RUN, "--out", "run"], ref, timeout=max(self.timeout, 60), env=env)
            h = self.worker.call(["checkpoint", "hash", "run"], ref)
            self.ref_hash[key] = (h.get("stdout") or "").strip().splitlines()[-1:] or None
            shutil.rmtree(ref, ignore_errors=True)
        return self.ref_hash[key]

    def restart_worker(self):
        """A fresh worker (a strategy's cases cannot be hit by an earlier one's heap damage)."""
        self.worker.kill()
        self.worker.kill_cleanup()
        self.worker.restarts += 1
        self.worker.start()
        self.history = []
        self.worker_cases = []

    def end_worker(self, bisect_budget_s: float | None = None) -> None:
        """Stop the worker normally; if it aborts at exit, some case damaged its heap (an
        out-of-bounds write in a kernel): find that case by bisection in fresh workers."""
        cases = self.worker_cases
        self.worker_cases, self.history = [], []
        rc = self.worker.close()
        if rc in (0, None) or not cases:
            return
        why = f"worker exited with {signal.Signals(-rc).name if rc < 0 else rc} at interpreter exit: " \
              + " ".join(self.worker.errlog_tail().split())[-300:]
        budget = self.bisect_budget_s if bisect_budget_s is None else bisect_budget_s
        culprit, note = self._bisect(cases, time.monotonic() + budget)
        rec = self._fail(culprit or cases[-1], "heap_damage",
                         why + (f"; bisected to this case ({note})" if culprit else
                                f"; not bisected ({note}); {len(cases)} cases ran in that worker"),
                         {"rc": rc, "stderr": self.worker.errlog_tail()})
        if not culprit:
            rec["preceded_by"] = [{"base": c.get("base"), "argv": short(c["argv"]),
                                   "edits": short(c.get("edits", []))} for c in cases[-5:]]
        self.failures.append(rec)

    def _aborts(self, cases) -> bool:
        saved = (self.n, dict(self.counts), list(self.failures), dict(self.missing), dict(self.inapplicable),
                 self.elapsed, self.max_peak)
        try:
            self.worker.start()
            for c in cases:
                self.run_case(c)
            self.worker_cases = []
            return self.worker.close() not in (0, None) or len(self.failures) > len(saved[2]) and any(
                f["property"] == "crash_or_timeout" for f in self.failures[len(saved[2]):])
        finally:
            self.n, self.counts, self.failures, self.missing, self.inapplicable, self.elapsed, self.max_peak = saved
            self.history = []

    def _bisect(self, cases, deadline):
        """The single case that makes a fresh worker abort, or (None, why)."""
        engine = [c for c in cases if _command_of(c["argv"])[0] in ("resume", "run", "sweep", "prepare")]
        if engine and time.monotonic() < deadline and self._aborts(engine):
            cases = engine
        elif time.monotonic() >= deadline or not self._aborts(cases):
            return None, "the abort did not recur"
        while len(cases) > 1:
            if time.monotonic() > deadline:
                return None, f"bisection ran out of time with {len(cases)} candidates"
            half = cases[: len(cases) // 2]
            if self._aborts(half):
                cases = half
            elif self._aborts(cases[len(cases) // 2:]):
                cases = cases[len(cases) // 2:]
            else:
                return None, f"needs several of {len(cases)} cases together"
        return cases[0], "it alone makes a fresh worker abort at exit"

    def close(self):
        self.worker.close()
        if self._tmp is not None:
            self._tmp.cleanup()

    # ---- one case
    def run_case(self, case: dict) -> list[dict]:
        t0 = time.monotonic()
        self.n += 1
        self._current = f"{case.get('strategy')} {case.get('base', 'h5')} {' '.join(map(str, case['argv']))[:80]}"
        strategy = case.get("strategy", "?")
        self.counts[strategy] = self.counts.get(strategy, 0) + 1
        root = self.cases_dir / f"c{self.n:06d}"
        shutil.rmtree(root, ignore_errors=True)
        other = OTHER_BASE.get(case.get("base", "h5"), "h5")
        world = World(root, self.bases[case.get("base", "h5")], self.bases[other])
        fails = []
        try:
            if "run2" in json.dumps(case):
                world.add_run2()
            for what in case.get("needs", []):
                world.add_material(what, self.bases)
            for i, ed in enumerate(case.get("edits", [])):
                try:
                    apply_edit(world, ed)
                except (ValueError, UnicodeDecodeError, KeyError, IndexError, TypeError, OSError):
                    if i == 0:
                        raise
                    # an earlier edit damaged what this one edits (e.g. flipped bytes in zarr.json)
        except Exception as e:  # noqa: BLE001 - the harness could not make this case (e.g. h5py
            # refuses a value, or an earlier flip left an HDF5 file h5py cannot edit): nothing of
            # ooc-dem ran, so it is counted as not applicable, never as a pass or a failure
            key = f"{type(e).__name__}: {' '.join(str(e).split())[:80]}"
            self.inapplicable[key] = self.inapplicable.get(key, 0) + 1
            self._finish(root, fails, t0)
            return fails
        if any(ed.get("noop") for ed in case.get("edits", ())):
            case = _without_noop_expectations(case)
        argv = [str(a) for a in case["argv"]]
        cmd, sub = _command_of(argv)
        if cmd == "check" and cmd not in self.commands:
            self.missing[cmd] = self.missing.get(cmd, 0) + 1
            if cmd == "check":
                # `check` not merged yet: `profile SCENARIO --set ... --out victim` validates the
                # scenario and its overrides the same way, then refuses the non-empty --out
                argv = ["profile", argv[1], *_only_sets(argv[2:]), "--modes", "monolithic", "--out", "victim"]
                case = dict(case, argv=argv, via="profile (no `check` command yet)")
                cmd, sub = _command_of(argv)
        skip = [os.path.join("w", d) for d in SAFE_DIRS]
        outside0 = snapshot(root, skip)
        session0 = sorted(os.listdir(self.cases_dir))
        stores0 = {d: snapshot(world.w / d) for d in ("run", "run2")}
        committed0 = _committed(world.run)
        restarts = self.worker.restarts
        env = {"OOC_DEM_CACHE": str(world.w / "cache")} if "cache" in case.get("needs", []) else None
        timeout = max(self.timeout, case.get("timeout", 0))
        if case.get("fresh"):
            res = _fresh_call(argv, world.w, timeout, env, case.get("fsize"))
        else:
            res = self.worker.call(argv, world.w, timeout=timeout, env=env, fsize=case.get("fsize"))
        died = self.worker.proc is None or self.worker.proc.poll() is not None or self.worker.restarts != restarts
        if case.get("fresh"):
            pass                         # its own interpreter: nothing to do with the worker's history
        elif res.get("rc") is None and self.history:
            res["preceded_by"] = list(self.history)
        if case.get("fresh"):
            pass
        elif died or res.get("rc") is None:
            self.history, self.worker_cases = [], []
        else:
            self.history = (self.history + [{"base": case.get("base", "h5"), "edits": short(case.get("edits", [])),
                                             "argv": short(argv)}])[-3:]
            self.worker_cases.append(case)
        fails += self.check(case, argv, world, res, outside0, session0, stores0, committed0)
        self._finish(root, fails, t0)
        return fails

    def _finish(self, root, fails, t0):
        dt = time.monotonic() - t0
        self.elapsed += dt
        self.slowest = sorted(self.slowest + [(round(dt, 2), self._current)], key=lambda x: -x[0])[:10]
        self.failures += fails
        if fails and self.keep_failed > 0:
            self.keep_failed -= 1
            for f in fails:
                f["kept_dir"] = str(root)
        else:
            shutil.rmtree(root, ignore_errors=True)

    def _fail(self, case, prop, detail, res) -> dict:
        rec = {"strategy": case.get("strategy"), "base": case.get("base", "h5"),
               "edits": case.get("edits", []), "argv": [str(a) for a in case["argv"]],
               "property": prop, "detail": detail, "exit_code": res.get("rc"),
               "exc": res.get("exc"), "error": res.get("error")}
        if res.get("preceded_by"):
            # a crash may be heap damage done by an earlier case in the same worker
            rec["preceded_by"] = res["preceded_by"]
        err = res.get("stderr") or ""
        rec["stderr"] = err if len(err) <= 3000 else err[:1000] + "\n...\n" + err[-2000:]
        rec["class"] = failure_class(rec, err)
        self.log(f"FAIL [{rec['class']}] {' '.join(rec['argv'])}: {detail}")
        return rec

    def check(self, case, argv, world, res, outside0, session0, stores0, committed0) -> list[dict]:
        fails = []
        cmd, sub = _command_of(argv)
        rc = res.get("rc")
        err = res.get("stderr") or ""
        lines = _stderr_lines(err)
        peak = max(res.get("hwm", 0), res.get("peak_seen", 0))
        self.max_peak = max(self.max_peak, peak)
        if rc is None:
            fails.append(self._fail(case, "crash_or_timeout", res.get("error"), res))
        elif rc not in (0, 2):
            fails.append(self._fail(case, "exit_code", f"exit code {rc}"
                                    + (f" ({res.get('exc')})" if res.get("exc") else ""), res))
        elif rc == 2 and len(lines) != 1:
            fails.append(self._fail(case, "stderr_lines", f"exit 2 with {len(lines)} stderr lines", res))
        elif "Traceback (most recent call last)" in err:
            fails.append(self._fail(case, "traceback", "traceback on stderr", res))
        base_rss = self.worker.info.get("baseline_rss", 0)
        if rc is not None and res.get("hwm_reset") and peak - base_rss > self.mem_bound:
            fails.append(self._fail(case, "memory", f"peak RSS {peak / GiB:.2f} GiB", res))
        elif (rc is not None and res.get("hwm_reset") and case.get("expect", {}).get("size_bound")
              and res.get("hwm", 0) - res.get("rss0", 0) > SIZE_BOUND):
            fails.append(self._fail(case, "memory", f"peak RSS {(res['hwm'] - res['rss0']) / 2**20:.0f} MB "
                                    f"above the RSS at the call (bound {SIZE_BOUND >> 20} MB) for a hostile "
                                    f"declared size", res))
        if (rc == 2 and case.get("expect", {}).get("size_bound") and not any(f["property"] == "memory" for f in fails)
                and re.search(r"out of memory|unable to allocate|memoryerror", err, re.I)):
            # refused only because the allocation failed: it was sized by the hostile number
            # (the worker's RLIMIT_AS stops it; a user's machine would swap or be OOM-killed)
            fails.append(self._fail(case, "memory", "a hostile declared size was refused only by running out "
                                    "of memory (allocated before any check)", res))
        if rc in (0, 2):
            left = _temporaries(world.w)
            if left:
                fails.append(self._fail(case, "temporary_left", ", ".join(left[:3]), res))
        if rc == 0 and case.get("fsize"):
            cut = _cut_files(world.w, case["fsize"])
            if cut:
                fails.append(self._fail(case, "truncated_output", f"exit 0 under RLIMIT_FSIZE = {case['fsize']} "
                                        f"with files of exactly that size (cut at the limit): "
                                        f"{', '.join(cut[:3])}", res))
        # nothing outside the run directories changes
        outside1 = snapshot(world.root, [os.path.join("w", d) for d in SAFE_DIRS])
        if cmd == "animate" and _opt(argv, "--out") is None and rc == 0:
            # `animate RUN` writes RUN.mp4 beside the run directory by design (never inside
            # the store): that one new file is its output, not a stray write
            outside1 = {k: v for k, v in outside1.items()
                        if k in outside0 or not (os.path.dirname(k) == "w" and k.endswith(".mp4"))}
        if outside1 != outside0:
            fails.append(self._fail(case, "outside_changed", ", ".join(_diff(outside0, outside1)), res))
        session1 = sorted(os.listdir(self.cases_dir))
        if session1 != session0:
            fails.append(self._fail(case, "outside_changed",
                                    f"session dir: {sorted(set(session0) ^ set(session1))[:3]}", res))
        # read-only commands leave the stores alone
        out_opt = _opt(argv, "--out") or ""
        read_only = (cmd == "checkpoint" and sub in READ_ONLY and not (sub == "export" and out_opt.startswith("run"))) \
            or cmd in ("compare", "check", "report", API_PREFIX) or (cmd == "profile" and out_opt == "victim") \
            or (cmd in ("animate", "export-trajectory") and out_opt.startswith("out/"))
        if read_only and rc is not None:
            for d in ("run", "run2"):
                after = snapshot(world.w / d)
                before = stores0[d]
                if cmd == "report":
                    after = {k: v for k, v in after.items() if not k.startswith("figures")}
                    before = {k: v for k, v in before.items() if not k.startswith("figures")}
                if after != before:
                    fails.append(self._fail(case, "read_only_changed_store",
                                            f"{d}: " + ", ".join(_diff(before, after)), res))
        # exit 2: nothing committed is touched
        if rc == 2:
            committed1 = {k: v for k, v in _committed(world.run).items()}
            lost = [k for k, v in committed0.items() if committed1.get(k) != v
                    and _sha_or_none(world.run / k) != v]
            if lost:
                fails.append(self._fail(case, "committed_changed_on_error", ", ".join(lost[:3]), res))
        # a successful write leaves a verifiable store
        writes = cmd == "resume" or (cmd == "checkpoint" and sub == "prune") or (
            cmd == "run" and _opt(argv, "--out") in ("run", "./run"))
        if writes and rc == 0 and _committed(world.run).get("MANIFEST.json") != committed0.get("MANIFEST.json"):
            v = self.worker.call(["checkpoint", "verify", "run"], world.w, timeout=self.timeout)
            if v.get("rc") != 0:
                r2 = dict(res, stderr=(v.get("stderr") or "") + (v.get("stdout") or "")[-500:])
                fails.append(self._fail(case, "store_invalid_after_write",
                                        f"`checkpoint verify run` after it: exit {v.get('rc')}", r2))
        # strategy expectations
        exp = dict(case.get("expect", {}))
        if cmd == "checkpoint" and sub == "export" and out_opt in EXPORT_OUTS_BAD:
            exp["refuse"] = f"export --out {out_opt} ({EXPORT_OUTS_BAD[out_opt]}) accepted"
        if exp.get("same_bits_as_intact") and rc == 0:
            h = self.worker.call(["checkpoint", "hash", "run"], world.w, timeout=self.timeout)
            got = (h.get("stdout") or "").strip().splitlines()[-1:]
            want = self.reference(case.get("base", "h5"), "resume")
            if want and got != want:
                fails.append(self._fail(case, "resumed_from_wrong_data",
                                        f"resume of a detectably invalid current epoch exited 0 and ended "
                                        f"with state hash {got[0][:16] if got else None}... instead of the "
                                        f"intact run's {want[0][:16]}... (neither refused nor fell back)", res))
        if exp.get("hash_fallback") and rc == 0:
            got = (res.get("stdout") or "").strip().splitlines()[-1:]
            want = self.reference(case.get("base", "h5"), "previous")
            if want and got != want:
                fails.append(self._fail(case, "accepted_invalid_epoch",
                                        f"`checkpoint hash` of a detectably invalid current epoch printed "
                                        f"{got[0][:24] if got else None}... (neither refused nor the previous "
                                        f"epoch's {want[0][:24]}...)", res))
        if exp.get("export_fallback") and rc == 0:
            got = _csv_body(world.w / out_opt)
            want = self.reference(case.get("base", "h5"), "export_previous")
            if got != want:
                fails.append(self._fail(case, "accepted_invalid_epoch",
                                        "`checkpoint export` of a detectably invalid current epoch wrote it "
                                        "(neither refused nor the previous epoch)", res))
        made = world.w / (_opt(argv, "--out") or "-")
        # before the resume below, which moves the store on to a later epoch
        if exp.get("same_as_intact_cache") and rc == 0 and (made / "MANIFEST.json").is_file():
            h = self.worker.call(["checkpoint", "hash", str(made.relative_to(world.w))], world.w, timeout=self.timeout)
            got = (h.get("stdout") or "").strip().splitlines()[-1:]
            want = self.reference(case.get("base", "h5"), "bed_run")
            if want and got != want:
                fails.append(self._fail(case, "ran_on_damaged_cache",
                                        f"exit 0 with state hash {got[0][:16] if got else None}... instead of "
                                        f"{want[0][:16]}... (a damaged bed-cache entry neither rebuilt nor refused)",
                                        res))
        if exp.get("resumable") and rc == 0 and (made / "MANIFEST.json").is_file():
            v = self.worker.call(["resume", str(made.relative_to(world.w)), "--steps", str(exp["resumable"]),
                                  "--no-progress", "--no-figures"], world.w, timeout=max(self.timeout, 30))
            if v.get("rc") != 0:
                r2 = dict(res, stderr=(v.get("stderr") or "") + (v.get("stdout") or "")[-500:])
                fails.append(self._fail(case, "store_refused_by_own_resume",
                                        f"exit 0, then `resume` of the store it wrote: exit {v.get('rc')}", r2))
        if exp.get("refuse") and rc == 0 and (argv[:2] != ["checkpoint", "verify"]
                                              or world.epoch_bytes_changed()):
            fails.append(self._fail(case, "accepted_bad_input", exp["refuse"], res))
        return fails

    # ---- summary
    def summary(self) -> dict:
        classes: dict[str, dict] = {}
        for f in self.failures:
            c = classes.setdefault(f["class"], {"count": 0, "example": f})
            c["count"] += 1
        return {"cases": self.n, "cases_per_strategy": dict(self.counts),
                "elapsed_s": round(self.elapsed, 1),
                "cases_per_s": round(self.n / self.elapsed, 2) if self.elapsed else None,
                "worker_restarts": self.worker.restarts,
                "worker_baseline_rss_mb": round(self.worker.info.get("baseline_rss", 0) / 2**20, 1),
                "max_peak_rss_mb": round(self.max_peak / 2**20, 1),
                "slowest_cases": [f"{t} s {c}" for t, c in self.slowest],
                "commands_missing": dict(self.missing),
                "inapplicable_cases": dict(self.inapplicable),
                "failures": len(self.failures),
                "failure_classes": [{"class": k, "count": v["count"], "argv": short(v["example"]["argv"]),
                                     "base": v["example"]["base"], "edits": short(v["example"]["edits"]),
                                     "exit_code": v["example"]["exit_code"],
                                     **({"preceded_by": v["example"]["preceded_by"]}
                                        if v["example"].get("preceded_by") else {}),
                                     "detail": v["example"]["detail"],
                                     "stderr": v["example"]["stderr"][-1500:]}
                                    for k, v in sorted(classes.items())]}


def _csv_body(path: Path):
    """An exported CSV without its first line (which names the store), or None."""
    try:
        return path.read_text(errors="replace").split("\n", 1)[1]
    except (OSError, IndexError):
        return None


TEMP_NAME = re.compile(r"\.tmp")


def _temporaries(root: Path) -> list[str]:
    """Names of temporaries (``*.tmp*``) left anywhere below root after a command ended."""
    out = []
    for dirpath, dirnames, filenames in os.walk(root, followlinks=False):
        for n in dirnames + filenames:
            if TEMP_NAME.search(n):
                out.append(os.path.relpath(os.path.join(dirpath, n), root))
    return sorted(out)


def _cut_files(root: Path, limit: int) -> list[str]:
    """Regular files below root of exactly ``limit`` bytes (what a write cut by RLIMIT_FSIZE leaves)."""
    out = []
    for dirpath, _, filenames in os.walk(root, followlinks=False):
        for n in filenames:
            p = os.path.join(dirpath, n)
            try:
                st = os.lstat(p)
            except OSError:
                continue
            if stat.S_ISREG(st.st_mode) and st.st_size == limit:
                out.append(os.path.relpath(p, root))
    return sorted(out)


def _fresh_call(argv, cwd, timeout, env=None, fsize=None) -> dict:
    """The command in a fresh interpreter (`python -m ooc_dem.cli`), as a user runs it: what
    it prints at interpreter exit counts too (pipes: RLIMIT_FSIZE does not cut them)."""
    import resource
    e = child_env()
    e.update(env or {})

    def limits():
        if fsize is not None:
            resource.setrlimit(resource.RLIMIT_FSIZE, (int(fsize), resource.getrlimit(resource.RLIMIT_FSIZE)[1]))
    t0 = time.monotonic()
    p = subprocess.Popen([sys.executable, "-m", "ooc_dem.cli", *argv], cwd=cwd, env=e, text=True,
                         stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         start_new_session=True, preexec_fn=limits, errors="replace")
    try:
        out, err = p.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        out, err = p.communicate()
        return {"rc": None, "error": f"timeout after {timeout:.0f} s", "elapsed": timeout,
                "stderr": err[-20000:], "stdout": out[-2000:]}
    rc = p.returncode
    if rc < 0:
        err += f"\n[killed by signal {signal.Signals(-rc).name}]"
    return {"rc": rc, "stdout": out[-65536:], "stderr": err[-65536:], "elapsed": time.monotonic() - t0,
            "exc": None, "hwm_reset": False}


def _only_sets(args):
    out = []
    for i, a in enumerate(args):
        if a == "--set" and i + 1 < len(args):
            out += ["--set", args[i + 1]]
    return out


def short(x, n=120):
    """A long argument or value shown as its head and length (reports stay readable)."""
    if isinstance(x, str):
        return x if len(x) <= n else f"{x[:40]}...({len(x)} chars)"
    if isinstance(x, list):
        return [short(v, n) for v in x]
    if isinstance(x, dict):
        return {k: short(v, n) for k, v in x.items()}
    return x


def _sha_or_none(p: Path):
    try:
        return _sha(p) if p.is_file() else None
    except OSError:
        return None


def _opt(argv, name):
    for i, a in enumerate(argv):
        if a == name and i + 1 < len(argv):
            return argv[i + 1]
        if a.startswith(name + "="):
            return a.split("=", 1)[1]
    return None



# =====================================================================================
# strategies (hypothesis)
# =====================================================================================

HUGE_DIGITS = "9" * 5000
# values as TOML text (for --set and scenario files)
TOML_FLOATS = ["1e308", "-1e308", "5e-324", "-5e-324", "-0.0", "0.0", "nan", "-nan", "inf", "-inf",
               "1e-200", "1e400", "1.7976931348623157e308", "2.2250738585072014e-308", "1e-5", "0.5"]
TOML_INTS = ["0", "-1", "1", "2", "2147483647", "2147483648", "4294967296", "9223372036854775807",
             "9223372036854775808", "-9223372036854775809", "100000", "2000000000", "2000000001",
             "99999999999", "0x7fffffffffffffff", HUGE_DIGITS, "-" + HUGE_DIGITS]
TOML_STRINGS = ['"é🦀"', '"\\u0000"', '"../../x"', '"a\\nb"', '"\\u001b[31mred"', '""',
                "bare", "'x'", '"' + "x" * 100000 + '"', '"."', '".."', '"runs/../../x"', '"\\t"',
                '"con"', '"x/y"', '"drawbar"', '"slip"', '"wheel"', '"equal"']
TOML_OTHER = ["true", "false", "[1, 2]", "[]", "[[[[1]]]]", "{a = 1}", "{}", "[" * 5000 + "]" * 5000,
              "{a = " * 300 + "1" + "}" * 300, "1979-05-27T07:32:00Z", "[1.0, nan]", "= 1", "",
              "{dt = 1e-5}", "1_000", "+1", "0o777", "0b1", "1e", "[1,", "\"unterminated"]
TOML_VALUES = TOML_FLOATS + TOML_INTS + TOML_STRINGS + TOML_OTHER

NAME_VALUES = ['"é🦀"', '"\\u0000"', '"../../x"', '"../../victim/x"',
               '"a\\nb"', '"\\u001b[31m"', '""', '"."', '".."', '"runs"', '"x" ', '"' + "n" * 5000 + '"',
               '"../run2"', '"a/b/c"', '"\\r"', '"🦀/../../.."']

BED_NAMES = ["bed-inf", "bed-nan", "bed-1e400", "bed-2000000000", "bed-0", "bed--1", "bed-1.5",
             "bed-1e9", "bed-9999999999999", "bed-", "bed-1k", "bed-1m", "bed-100000m", "bed-1_000",
             "bed-\u0661\u0662\u0663", "bed-1e-5", "bed-" + HUGE_DIGITS, "bed-0x10", "bed-1e308",
             "bed-2000000001", "bed-1000", "bed-1200", "bed-Infinity", "bed- 12", "bed-12\n",
             "bed-100k", "bed-2e9", "bed-3e9", "bed-1.0000000001"]

STEPS_VALUES = ["0", "1", "5", "10", "100000000000", "1e11", "99999999999999999999", "-1", "abc",
                HUGE_DIGITS, "", "2147483648", "9223372036854775808", " 3", "0x10", "1_0"]
DURATION_VALUES = ["1e308", "5e-324", "1e-300", "nan", "inf", "-1", "0", "1e-5", "0.00002",
                   "1e400", "abc", "", "-0.0", "1e20"]
UNTIL_VALUES = ["0.0002", "0.0003", "0.00025", "1e308", "inf", "nan", "5e-324", "1e-300", "0",
                "-1", "1e20", "abc"]
DOMAIN_VALUES = ["1", "2", "3", "4096", "4097", "100000", "2147483648", "0", "-1", "1e11",
                 HUGE_DIGITS, "abc"]
BLOCK_VALUES = ["1", "2", "10", "10000", "10001", "1000000000", "0", "-1", "abc", HUGE_DIGITS]
EPOCH_VALUES = ["10", "20", "0", "30", "-1", "1e11", "99999999999999999999", "abc", HUGE_DIGITS, "15"]
KEEP_VALUES = ["1", "2", "3", "0", "-1", "100000", "1e308", HUGE_DIGITS, "abc"]
STORE_ARGS = ["run", "run", "run", "run/", "run2", "victim", "victim_file", "link_victim", "link_zero",
              "nonexistent", "", ".", "run/epochs", "run/MANIFEST.json", "out", "dev_null",
              "run/../run", "./run", "run//"]
SAFE_SECTIONS = ("scenario", "wheel", "output", "decomposition")

# hostile paths for manifest entries (relative to the store R/w/run; all stay inside R)
PATHS = ["../victim", "../victim_file", "../victim/a.txt", "../victim/sub", "../link_victim",
         "../link_file", "../link_zero", "../../dev/zero", "../dev_null", ".", "", "epochs",
         "epochs/", "MANIFEST.json", "./MANIFEST.json", "epochs/../MANIFEST.json", "summary.json",
         "initial.npz", "epochs/e000000000010.h5", "epochs/e000000000020.h5",
         "epochs/e000000000010.zarr", "epochs/e000000000020.zarr", "epochs/e000000000020.h5/x",
         "epochs/nonexistent.h5", "epochs\\..\\..\\victim", "epochs/\u0000", "..", "../..",
         "../run2/epochs/e000000000020.h5", "../run2", "epochs/e000000000020.zarr/zarr.json",
         "é🦀", "epochs/" + "x" * 5000, "../victim_epochs", "$ABS/victim", "$ABS/victim_file",
         "$ABS/link_zero", "$ABS/run/epochs/e000000000020.h5", "~/x", "epochs/*", "epochs/.."]

SCENARIO_TOMLS = ["", "[[[", "x = 1", "[physics]\ndt = 1e308\n", "[soil]\nn = " + HUGE_DIGITS + "\n",
                  "[physics]\ndt = nan\n", "a = " + "[" * 5000 + "]" * 5000, "\u0000", TINY_SCENARIO,
                  "[soil]\nn = 2000000000\n", "[scenario]\nname = \"../../x\"\n", "[decomposition]\n"
                  "domains = 4096\n", "[wheel]\nenabled = 3\n", "[bin]\nlength = 1e308\n"]


def _j(v):
    """JSON-able form of a value (NaN/inf and deep structures as markers)."""
    if isinstance(v, float) and not math.isfinite(v):
        return {"$float": repr(v)}
    return v


JSON_VALUES = [None, True, False, 0, -1, 1, 2, 10, 20, 2 ** 31, 2 ** 63, 2 ** 64, -2 ** 63 - 1, 10 ** 100,
               1e308, -1e308, 5e-324, -0.0, 0.5, 20.0, _j(float("nan")), _j(float("inf")), _j(float("-inf")),
               "", "x", "0", "20", "é🦀", "\u0000\u001b[31m\n", "../victim", [], [1], [[]], {}, {"0": {}},
               {"$deep_list": 100000}, {"$deep_dict": 100000}, {"$deep_list": 50},
               "x" * 100000, "hdf5", "zarr", "memory", "ooc-dem-store", 1, "1"]
DOMAIN_MAPS = [{"x": {"n": 1, "arrays": {}}}, {"-1": {"n": 1, "arrays": {}}},
               {"99999999999999999999": {"n": 0, "arrays": {}}}, {"0.0": {}}, {"1e3": {"n": 1}},
               {"0": {"n": 10 ** 12, "arrays": {"x": [[10 ** 12], "<f8"]}}},
               {"0": {"n": 1500, "arrays": {"x": [[1500], "|O"]}}},
               {"0": {"n": 1500, "arrays": {"x": [[-1], "<f8"]}}},
               {"0": {"n": 1500, "arrays": {"../../x": [[1500], "<f8"]}}},
               {" 0": {}}, {"٠": {}}, {"0": None}, {"0": []}, {"0": {"n": "many", "arrays": []}}]


def _manifest_paths():
    top = [["format"], ["format_version"], ["backend"], ["meta"], ["meta", "run"],
           ["meta", "run", "mode"], ["meta", "run", "backend"], ["meta", "run", "domains"],
           ["meta", "run", "block"], ["meta", "run", "steps"], ["meta", "run", "checkpoint_every"],
           ["meta", "scenario_toml"], ["meta", "scenario_hash"], ["meta", "scenario_name"],
           ["meta", "format_version"], ["meta", "engine_version"], ["created_at"], ["current"],
           ["previous"]]
    ent = [["step"], ["path"], ["files"], ["files", 0], ["files", 0, "path"], ["files", 0, "size"],
           ["files", 0, "sha256"], ["files", -1, "path"], ["domains"], ["domains", "0"],
           ["domains", "0", "n"], ["domains", "0", "arrays"], ["domains", "0", "arrays", "x"],
           ["domains", "0", "arrays", "x", 0], ["domains", "0", "arrays", "x", 1],
           ["domains", "0", "arrays", "hist_n"], ["globals"], ["globals", "arrays"],
           ["globals", "arrays", "wheel_state"], ["committed_at"]]
    return top + [[e] + p for e in ("current", "previous") for p in ent]


MANIFEST_PATHS = _manifest_paths()
READ_CMDS = [["checkpoint", "list", "run"], ["checkpoint", "verify", "run"],
             ["checkpoint", "inspect", "run"], ["checkpoint", "hash", "run"],
             ["checkpoint", "verify", "run", "--epoch", "10"], ["checkpoint", "hash", "run", "--epoch", "10"],
             ["checkpoint", "export", "run", "--out", "out/s.csv"],
             ["checkpoint", "export", "run", "--out", "out/s.xdmf"]]
WRITE_CMDS = [["checkpoint", "prune", "run", "--keep", "1"],
              ["resume", "run", "--steps", "30", "--no-progress", "--no-figures"]]
OTHER_CMDS = [["report", "run"], ["compare", "run", "run2"]]
STORE_CMDS = READ_CMDS + WRITE_CMDS + WRITE_CMDS + OTHER_CMDS


def scenario_values(sc) -> list[tuple[str, object]]:
    """(section.key, value) of every value of a scenario, from ooc_dem.model.scenario's dataclasses."""
    import dataclasses
    out = []

    def walk(obj, prefix):
        for f in dataclasses.fields(obj):
            v = getattr(obj, f.name)
            if dataclasses.is_dataclass(v):
                walk(v, f"{prefix}{f.name}.")
            else:
                out.append((f"{prefix}{f.name}", v))
    walk(sc, "")
    return out


def scenario_keys() -> list[str]:
    """section.key of every scenario value."""
    from ooc_dem.model.scenario import Scenario
    return [k for k, _ in scenario_values(Scenario())]


def build_strategies():
    """{name: hypothesis strategy producing cases}."""
    from hypothesis import strategies as st
    keys = scenario_keys()
    safe_keys = [k for k in keys if k.split(".")[0] in SAFE_SECTIONS]
    hostile_keys = ["physics", "physics.dt.x", "a.b", "scenario.name.x", "contact.soil_soil",
                    "x" * 1000 + ".y", ".", "physics..dt", ".".join(["a"] * 500), "contact.x.kn",
                    "wheel.radius.", " physics.dt", "physics.dt ", "🦀.🦀", "physics.DT"]
    random_float = st.floats(allow_nan=True, allow_infinity=True).map(repr)
    random_int = st.integers(min_value=-(2 ** 70), max_value=2 ** 70).map(str)
    value = st.one_of(st.sampled_from(TOML_VALUES), random_float, random_int,
                      st.text(max_size=12).map(json.dumps), st.text(max_size=8))

    def set_item(key_st):
        return st.builds(lambda k, v: f"{k}={v}", key_st, value)

    any_key = st.one_of(st.sampled_from(keys), st.sampled_from(keys), st.sampled_from(hostile_keys))
    scen_name = st.sampled_from(["quick", "quick", "bed-1000", "scenario.toml", "paper2008"])

    @st.composite
    def scenario_case(draw):
        base = draw(st.one_of(scen_name, st.sampled_from(BED_NAMES)))
        argv = ["check", base]
        for item in draw(st.lists(st.one_of(set_item(any_key),
                                            st.builds(lambda v: f"scenario.name={v}", st.sampled_from(NAME_VALUES))),
                                  min_size=0 if base.startswith("bed-") else 1, max_size=3)):
            argv += ["--set", item]
        for opt, pool in (("--mode", ["monolithic", "ddm", "ooc", "gpu"]), ("--domains", DOMAIN_VALUES),
                          ("--block", BLOCK_VALUES), ("--backend", ["hdf5", "zarr", "memory", "x"])):
            if draw(st.integers(0, 3)) == 0:
                argv += [opt, draw(st.sampled_from(pool))]
        k = draw(st.integers(0, 3))
        if k == 1:
            argv += ["--steps", draw(st.sampled_from(STEPS_VALUES))]
        elif k == 2:
            argv += ["--duration", draw(st.sampled_from(DURATION_VALUES))]
        return {"strategy": "scenario", "base": "h5", "edits": [], "argv": argv}

    toml_line = st.one_of(
        st.builds(lambda k, v: f"{k.rpartition('.')[2]} = {v}", st.sampled_from(keys), value),
        st.builds(lambda k: f"[{k.rpartition('.')[0] or k}]", st.sampled_from(keys)),
        st.sampled_from(["[physics", "[[soil]]", "[soil]\n[soil]", "a.b.c = 1", "x = \"\\u", "\ufeff",
                         "[contact.soil_soil.extra]", "soil = 3", "[" * 1000, "a = " + "[" * 3000,
                         "n = " + HUGE_DIGITS, "\u0000", "\r\n", "# comment", "physics = {dt = 1e308}"]),
        st.text(max_size=30))

    @st.composite
    def scenario_file_case(draw):
        if draw(st.integers(0, 4)) == 0:
            ed = {"op": "scenario_file", "name": "s.toml", "bytes": list(draw(st.binary(max_size=200)))}
        else:
            head = draw(st.sampled_from(["", TINY_SCENARIO]))
            lines = draw(st.lists(toml_line, min_size=1, max_size=8))
            ed = {"op": "scenario_file", "name": "s.toml", "text": head + "\n".join(lines) + "\n"}
        argv = ["check", "out/s.toml"]
        if draw(st.booleans()):
            argv += ["--set", draw(set_item(any_key))]
        return {"strategy": "scenario_file", "base": "h5", "edits": [ed], "argv": argv}

    # ---- CLI flags, from the real parser
    @st.composite
    def cli_case(draw):
        from ooc_dem.cli import build_parser
        subs = _subparsers(build_parser())
        names = [n for n in subs if n not in ("profile", "check")] + ["profile"]
        weights = {"checkpoint": 6, "resume": 3, "run": 3, "report": 1, "compare": 1, "sweep": 1,
                   "prepare": 1, "scenarios": 1, "profile": 1}
        pool = [n for n in names for _ in range(weights.get(n, 1))]
        cmd = draw(st.sampled_from(pool))
        parser = subs[cmd]
        argv = [cmd]
        if cmd == "checkpoint":
            csubs = _subparsers(parser)
            c = draw(st.sampled_from(sorted(csubs)))
            argv.append(c)
            parser = csubs[c]
        # (scenario.name only from NAME_VALUES: a random absolute name would make `run` write outside R)
        set_st = st.one_of(set_item(st.sampled_from([k for k in safe_keys if k != "scenario.name"] + hostile_keys)),
                           st.builds(lambda v: f"scenario.name={v}", st.sampled_from(NAME_VALUES)))
        argv += _draw_args(draw, st, parser, cmd, argv[-1], set_st)
        if draw(st.integers(0, 15)) == 0:
            argv.insert(draw(st.integers(0, len(argv))),
                        draw(st.sampled_from(["--frobnicate", "-x", "--", "--help", "-", "--steps",
                                              "--set", "é🦀", "--out=", "--epoch=-1", "\u0000"])))
        return {"strategy": "cli", "base": draw(st.sampled_from(BASES)), "edits": [], "argv": argv}

    # ---- manifest edits
    path_value = st.one_of(st.sampled_from(PATHS), st.sampled_from(JSON_VALUES))

    @st.composite
    def manifest_edit(draw):
        k = draw(st.integers(0, 12))
        if k <= 6:
            path = draw(st.sampled_from(MANIFEST_PATHS))
            last = path[-1]
            if last == "path":
                v = draw(path_value)
            elif last == "domains":
                v = draw(st.one_of(st.sampled_from(DOMAIN_MAPS), st.sampled_from(JSON_VALUES),
                                   st.just({"$many_domains": 100000})))
            elif last == "scenario_toml":
                v = draw(st.one_of(st.sampled_from(SCENARIO_TOMLS), st.sampled_from(JSON_VALUES)))
            else:
                v = draw(st.one_of(st.sampled_from(JSON_VALUES),
                                   st.integers(min_value=-(2 ** 70), max_value=2 ** 70),
                                   st.floats().map(_j), st.text(max_size=10)))
            return {"op": "manifest_set", "path": path, "value": v}
        if k <= 8:
            return {"op": "manifest_delete", "path": draw(st.sampled_from(MANIFEST_PATHS))}
        if k == 9:
            return draw(st.sampled_from([{"op": "manifest_swap"}, {"op": "manifest_prev_is_cur"},
                                         {"op": "epochs_symlink"}]))
        if k == 10:
            return {"op": "manifest_set", "path": [draw(st.sampled_from(["current", "previous"])), "files"],
                    "value": []}
        return draw(st.one_of(
            st.sampled_from([{"op": "manifest_raw", "what": "huge_int"},
                             {"op": "manifest_raw", "what": "nan_step"},
                             {"op": "manifest_raw", "what": "deep", "n": 100000},
                             {"op": "manifest_raw", "what": "deep", "n": 900}]),
            st.builds(lambda f: {"op": "manifest_raw", "what": "truncate", "frac": f},
                      st.floats(0, 0.999)),
            st.builds(lambda b: {"op": "manifest_raw", "what": "bytes", "data": list(b)},
                      st.binary(max_size=64))))

    @st.composite
    def manifest_case(draw):
        edits = draw(st.lists(manifest_edit(), min_size=1, max_size=3))
        return {"strategy": "manifest", "base": draw(st.sampled_from(BASES)), "edits": edits,
                "argv": draw(st.sampled_from(STORE_CMDS))}

    # ---- epoch edits
    which = st.sampled_from(["current", "current", "previous"])
    arr_kinds = ["nan", "inf", "all_nan", "99", "all_99", "neg", "huge", "zero", "dup", "shorter",
                 "longer", "empty", "2d", "int32", "float32", "bool", "complex", "u8", "delete"]
    dom_names = ["id", "pos", "vel", "spin", "r", "mass", "inertia", "mat", "hist_n", "hist_id",
                 "hist_s", "hist_m"]   # a domain record of store format 2
    glob_names = ["wheel_state", "metrics_iacc", "metrics_wacc", "metrics_rows"]
    attr_values = [None, "garbage", "{}", "[]", "null", '{"step": "x"}', '{"step": 1e308}',
                   '{"time": NaN}', '{"step": -1, "time": -1}', "[" * 100000, '"\u0000"',
                   '{"step": 20, "time": 0.0002, "mode": "gpu"}', '{"engine": {"domains": 100000}}',
                   '{"redecompositions": [{"step": 0, "bounds": [1e308]}]}',
                   '{"xmin": NaN, "xmax": -1}', '{"n": 99999999}']
    fracs = st.floats(0, 0.9999)

    @st.composite
    def epoch_edit(draw, kinds=arr_kinds):
        k = draw(st.integers(0, 9))
        if k <= 2:
            n = draw(st.integers(1, 4))
            return {"op": "flip", "which": draw(which), "file": draw(st.integers(0, 1000)),
                    "offsets": draw(st.lists(fracs, min_size=n, max_size=n)),
                    "xors": draw(st.lists(st.integers(0, 254), min_size=n, max_size=n)),
                    "recompute": draw(st.booleans())}
        if k == 3:
            return {"op": "truncate", "which": draw(which), "file": draw(st.integers(0, 1000)),
                    "frac": draw(fracs), "extra": list(draw(st.binary(max_size=8))),
                    "recompute": draw(st.booleans())}
        if k <= 7:
            g = draw(st.sampled_from(["domain", "domain", "domain", "globals"]))
            return {"op": "array", "which": draw(which), "group": g, "dom": draw(st.integers(0, 5)),
                    "name": draw(st.sampled_from(dom_names if g == "domain" else glob_names)),
                    "kind": draw(st.sampled_from(kinds)), "rows": draw(st.lists(fracs, min_size=1, max_size=3)),
                    "update_meta": draw(st.booleans())}
        return {"op": "attrs", "which": draw(which), "group": draw(st.sampled_from(["domain", "globals"])),
                "dom": draw(st.integers(0, 5)), "value": draw(st.sampled_from(attr_values))}

    epoch_cmds = READ_CMDS[:6] + WRITE_CMDS * 2 + [["checkpoint", "export", "run", "--out", "out/s.csv"]]

    @st.composite
    def epoch_case(draw):
        edits = draw(st.lists(epoch_edit(), min_size=1, max_size=2))
        if draw(st.integers(0, 5)) == 0:
            edits.append({"op": "manifest_set", "path": [edits[0]["which"], "files"], "value": []})
        argv = draw(st.sampled_from(epoch_cmds))
        return _epoch_expect({"strategy": "epoch", "base": draw(st.sampled_from(BASES)),
                              "edits": edits, "argv": argv})

    # ---- run-directory files for report / compare
    series_texts = ["", "t [s]\n", "garbage\n\x00\x01", "nan,nan,nan\n", "1e308," * 13 + "\n",
                    "t [s],x\n" + "1,2\n" * 3, HUGE_DIGITS + "\n", "a" * 200000, "\ufeff\u0000",
                    "t [s],t_travel [s],x [m]\n1,2\n", "1,2,3,4,5,6,7,8,9,10,11,12,13\n" * 1000,
                    "inf,-inf,nan,0,0,0,0,0,0,0,0,0,0\n"]
    summary_paths = [["slip"], ["slip", "whole_travel", "value"], ["slip", "steady"], ["steps"],
                     ["n_discs"], ["wall_time_s"], ["state_hash"], ["scenario"], ["mode"],
                     ["simulated_time_s"], ["net_traction", "unit"], ["sinkage", "static"],
                     ["engine"], ["sinkage"], ["net_traction", "steady", "window_s"]]
    npz_specs = [{"x": "nan", "y": "nan"}, {"x": "short"}, {}, {"x": "object"}, {"x": "str", "y": "str"},
                 {"x": "2d", "y": "2d", "id": "int"}, {"x": "empty", "y": "empty"}]

    @st.composite
    def runfile_edit(draw):
        name = draw(st.sampled_from(["summary.json", "summary.json", "series.csv", "initial.npz",
                                     "scenario.toml", "figures"]))
        k = draw(st.integers(0, 4))
        if name == "figures":
            return draw(st.sampled_from([{"op": "runfile", "name": "figures", "text": "not a dir"},
                                         {"op": "runfile_link", "name": "figures", "target": "../victim"}]))
        if k == 0:
            return {"op": "runfile", "name": name, "delete": True}
        if k == 1:
            return {"op": "runfile", "name": name, "bytes": list(draw(st.binary(max_size=100)))}
        if k == 2 and name != "initial.npz":
            return {"op": "runfile_link", "name": name,
                    "target": draw(st.sampled_from(["../link_zero", "../victim", "/dev/zero", "../dev_null"]))}
        if name == "summary.json":
            if draw(st.booleans()):
                return {"op": "runfile", "name": name, "json": draw(st.sampled_from(JSON_VALUES))}
            return {"op": "runfile", "name": name, "summary_set": draw(st.sampled_from(summary_paths)),
                    "value": draw(st.one_of(st.sampled_from(JSON_VALUES), st.floats().map(_j)))}
        if name == "series.csv":
            return {"op": "runfile", "name": name, "text": draw(st.sampled_from(series_texts))}
        if name == "initial.npz":
            return {"op": "runfile", "name": name, "npz": draw(st.sampled_from(npz_specs))}
        return {"op": "runfile", "name": name, "text": draw(st.sampled_from(SCENARIO_TOMLS))}

    @st.composite
    def runfiles_case(draw):
        edits = draw(st.lists(runfile_edit(), min_size=1, max_size=3))
        argv = draw(st.sampled_from([["report", "run"], ["report", "run"], ["compare", "run", "run2"],
                                     ["compare", "run2", "run"], ["compare", "run", "run"]]))
        return {"strategy": "runfiles", "base": draw(st.sampled_from(BASES)), "edits": edits, "argv": argv}

    # ---- 3D stores: the epoch edits (and finite absurd values) on quick-3d, HDF5 and zarr
    kinds3 = arr_kinds + list(EXTREMES) + ["drop_row", "unsort"]

    @st.composite
    def epoch3d_case(draw):
        edits = draw(st.lists(epoch_edit(kinds3), min_size=1, max_size=2))
        argv = draw(st.sampled_from(EPOCH3D_CMDS))
        return _epoch_expect({"strategy": "epoch3d", "base": draw(st.sampled_from(["h5_3d", "zarr_3d"])),
                              "edits": edits, "argv": argv})

    # ---- beds: `run --bed` of an edited prepared bed, and an edited bed-cache entry
    bed_kinds = arr_kinds + list(EXTREMES) + ["drop_disc", "delete"]

    @st.composite
    def bed_case(draw):
        where = draw(st.sampled_from(["bed", "bed", "cache"]))
        kinds = bed_kinds + (["remove_file"] if where == "cache" else [])
        edits = [{"op": "npz_array", "file": where, "name": draw(st.sampled_from(dom_names)),
                  "kind": draw(st.sampled_from(kinds)), "rows": draw(st.lists(fracs, min_size=1, max_size=3))}
                 for _ in range(draw(st.integers(1, 2)))]
        extra = draw(st.sampled_from([[], [], ["--mode", "ooc", "--domains", "2", "--backend", "zarr"],
                                      ["--mode", "ddm", "--domains", "2"]]))
        return _bed_case(where, edits, extra)

    # ---- trajectory frames: declared row counts, shapes, dtypes, attributes
    traj_attr_values = [None, -1, 0, 1, 3, 2 ** 25, 2 ** 40, 2 ** 62, 1.5, "x", _j(float("nan")),
                        [0.0] * 6, [_j(float("nan"))] * 6, [1.0, 2.0], 1e308, 5e-324]

    @st.composite
    def traj_edit(draw):
        k = draw(st.integers(0, 9))
        frame = draw(st.integers(0, 5))
        if k <= 2:
            return {"op": "traj", "frame": frame, "what": "attr",
                    "key": draw(st.sampled_from(["n_discs", "step", "dim", "frame_every_steps", "dt", "time",
                                                 "wheel_state", "format_version", "format", "scenario_hash"])),
                    "value": draw(st.sampled_from(traj_attr_values))}
        if k <= 6:
            return {"op": "traj", "frame": frame, "what": "dataset", "name": draw(st.sampled_from(TRAJ_FIELDS)),
                    "kind": draw(st.sampled_from(kinds3)), "rows": draw(st.lists(fracs, min_size=1, max_size=3))}
        if k <= 8:
            return {"op": "traj", "frame": frame, "what": "declare_rows",
                    "rows": draw(st.sampled_from(DECLARED_ROWS)), "n_discs": draw(st.booleans())}
        return {"op": "traj", "frame": frame, "what": "remove"}

    @st.composite
    def trajectory_case(draw):
        edits = draw(st.lists(traj_edit(), min_size=1, max_size=2))
        return _size_expect({"strategy": "trajectory", "base": "traj", "edits": edits,
                             "argv": draw(st.sampled_from(TRAJ_CMDS))})

    # ---- npz members of initial.npz
    @st.composite
    def npz_edit(draw):
        member = draw(st.sampled_from(["x", "y", "r", "id", "surface"]))
        what = draw(st.sampled_from(["bomb", "declared", "declared", "object", "fortran", "shape", "dtype"]))
        ed = {"op": "npz_member", "member": member, "what": what}
        if what == "bomb":
            ed["size"] = draw(st.sampled_from(BOMB_SIZES))
        elif what == "declared":
            ed["shape"] = draw(st.sampled_from(DECLARED_SHAPES))
            ed["descr"] = draw(st.sampled_from(["<f8", "<i8", "|u1", "<c16"]))
        elif what == "shape":
            ed["shape"] = draw(st.sampled_from([[1500, 2], [3], [0], [1500, 1, 1], [1], [2, 750]]))
        elif what == "dtype":
            ed["descr"] = draw(st.sampled_from(["<c16", "|b1", "<U4", "|V16", ">f8", "<m8[s]"]))
        return ed

    @st.composite
    def npz_case(draw):
        edits = draw(st.lists(npz_edit(), min_size=1, max_size=2))
        argv = draw(st.sampled_from(NPZ_CMDS))
        base = "traj" if argv[0] == "animate" else draw(st.sampled_from(["h5", "zarr"]))
        return _size_expect({"strategy": "npz", "base": base, "edits": edits, "argv": argv})

    # ---- zarr archives with codecs
    @st.composite
    def zarr_codec_case(draw):
        base = draw(st.sampled_from(["zarr", "zarr", "zarr_3d", "zarr_zstd"]))
        g = draw(st.sampled_from(["domain", "domain", "domain", "globals"]))
        codec = draw(st.sampled_from(["gzip", "zstd", "blosc", "crc32c", "unknown", "sharding", "sharding_many",
                                      "transpose", "gzip_bomb", "gzip_bomb"]))
        ed = {"op": "zarr_codec", "which": draw(which), "group": g, "dom": draw(st.integers(0, 5)),
              "name": draw(st.sampled_from(dom_names if g == "domain" else glob_names)), "codec": codec,
              "encode": draw(st.booleans())}
        if codec == "gzip_bomb":
            ed["size"] = draw(st.sampled_from(BOMB_SIZES))
        case = _size_expect({"strategy": "zarr_codec", "base": base, "edits": [ed],
                             "argv": draw(st.sampled_from(ZARR_CMDS))})
        if codec.startswith("sharding") and case["argv"][0] == "checkpoint":
            case["fresh"] = True        # what zarr prints at interpreter exit counts
        return case

    # ---- file-size limits on every writer
    @st.composite
    def fsize_case(draw):
        argv, base, needs = draw(st.sampled_from(FSIZE_CMDS))
        # log-uniform from 1 KB to 8 MB: every writer's output is cut somewhere, or fits
        limit = draw(st.one_of(st.sampled_from(FSIZE_LIMITS), st.floats(10, 23).map(lambda e: int(2 ** e))))
        return {"strategy": "fsize", "base": base, "edits": [], "argv": list(argv), "needs": list(needs),
                "fsize": limit, "timeout": 30}

    return {"scenario": scenario_case(), "scenario_file": scenario_file_case(), "cli": cli_case(),
            "manifest": manifest_case(), "epoch": epoch_case(), "runfiles": runfiles_case(),
            "epoch3d": epoch3d_case(), "bed": bed_case(), "trajectory": trajectory_case(), "npz": npz_case(),
            "zarr_codec": zarr_codec_case(), "fsize": fsize_case()}


MiB = 1 << 20
TRAJ_FIELDS = ["id", "pos", "vel", "spin", "r", "mat"]
DECLARED_ROWS = [2 ** 20, 2 ** 22, 2 ** 25, 2 ** 28, 2 ** 31, 2 ** 40 + 1]
BOMB_SIZES = [384 * MiB, 1024 * MiB]          # inflated sizes (each a few hundred KB on disk), > SIZE_BOUND
DECLARED_SHAPES = [[2 ** 40], [2 ** 31], [2 ** 28], [2 ** 62, 2 ** 62], [1500, 2 ** 30], [2 ** 25]]
RESUME30 = ["resume", "run", "--steps", "30", "--no-progress", "--no-figures"]
EPOCH3D_CMDS = [["checkpoint", "hash", "run"], ["checkpoint", "hash", "run"], ["checkpoint", "verify", "run"],
                ["checkpoint", "inspect", "run"], ["checkpoint", "export", "run", "--out", "out/s.csv"],
                ["checkpoint", "export", "run", "--out", "out/s.xdmf"], RESUME30, RESUME30,
                ["@api", "state", "run"]]
TRAJ_CMDS = [["animate", "run", "--out", "out/f.gif", "--no-progress"],
             ["animate", "run", "--out", "out/f.mp4", "--no-progress"], ["report", "run"],
             ["@api", "trajectory", "run"], ["@api", "trajectory", "run"],
             ["export-trajectory", "run", "--out", "out/t.xdmf"], RESUME30]
NPZ_CMDS = [["report", "run"], ["report", "run"], ["compare", "run", "run2"], ["compare", "run2", "run"],
            ["animate", "run", "--out", "out/f.gif", "--no-progress"]]
ZARR_CMDS = [RESUME30, RESUME30, ["checkpoint", "hash", "run"], ["checkpoint", "hash", "run"],
             ["checkpoint", "export", "run", "--out", "out/s.csv"], ["checkpoint", "export", "run", "--out", "out/s.vtp"],
             ["checkpoint", "verify", "run"], ["@api", "state", "run"]]
FSIZE_LIMITS = [1024, 4096, 16384, 102400, 262144, 1 << 20, 4 << 20]
FSIZE_CMDS = ([(["checkpoint", "export", "run", "--out", f"out/e.{x}"], b, ()) for x in ("csv", "xdmf", "vtk", "vtp")
               for b in ("h5", "zarr")]
              + [(["checkpoint", "export", "run", "--out", "out/e.xdmf"], "h5_3d", ())]
              + [(RESUME30, b, ()) for b in ("h5", "zarr", "traj", "h5_3d")]
              + [([*BED_RUN, "--out", "out/r"], "h5", ("cache",)),
                 ([*BED_RUN, "--backend", "zarr", "--out", "out/r"], "h5", ("cache",))]
              + [(["animate", "run", "--out", f"out/f.{x}", "--no-progress"], "traj", ()) for x in ("mp4", "gif")]
              + [(["export-trajectory", "run", "--out", "out/t.xdmf"], "traj", ())])


def invalid_bed(edits) -> bool:
    """Whether the edits make a bed file detectably invalid (the store's own invariants)."""
    for ed in edits:
        n, k = ed.get("name"), ed.get("kind")
        if k in ("delete", "drop_disc", "remove_file", "shorter", "longer", "empty", "2d"):
            return True
        if (n in FINITE and k in ("nan", "inf", "all_nan")) or (n == "id" and k in ("dup", "neg", "minus7", "minus1")) \
                or (n == "hist_n" and k in ("99", "all_99", "neg", "999", "i32max", "minus7", "minus1")) \
                or (n == "mat" and k in ("99", "all_99", "neg", "999", "i32max", "minus7", "minus1", "huge")) \
                or (n in ("r", "mass", "inertia") and k in ("zero", "neg", "minus7", "minus1", "5e-324", "-5e-324")) \
                or (n in ("vel", "spin") and k in ("1e300", "huge")):
            return True
    return False


def _bed_case(where, edits, extra=()) -> dict:
    """A run from an edited prepared bed (``where`` = "bed") or bed-cache entry ("cache"): a
    detectably invalid bed is refused; a cache entry that fails is rebuilt (the intact run's
    bits) or refused; whatever exits 0 leaves a store its own `resume` accepts."""
    bad = invalid_bed(edits)
    if where == "bed":
        argv = [*BED_RUN, *extra, "--bed", "out/bed", "--out", "out/r"]
        expect = {"resumable": 6, **({"refuse": "a run from a detectably invalid bed exited 0"} if bad else {})}
        return {"strategy": "bed", "base": "h5", "edits": edits, "argv": argv, "needs": ["bed"], "expect": expect}
    argv = [*BED_RUN, *extra, "--out", "out/r"]
    expect = {"resumable": 6, **({"same_as_intact_cache": True} if bad and not extra else {})}
    return {"strategy": "bed", "base": "h5", "edits": edits, "argv": argv, "needs": ["cache"], "expect": expect,
            "timeout": 60}


def _size_expect(case: dict) -> dict:
    """A hostile declared size (rows, members, inflated chunks) is refused under SIZE_BOUND."""
    for ed in case["edits"]:
        if ed.get("what") in ("declare_rows", "bomb", "declared") or ed.get("codec") == "gzip_bomb":
            case.setdefault("expect", {})["size_bound"] = True
    return case


PER_DISC = ("id", "pos", "vel", "spin", "r", "mass", "inertia", "mat", "hist_n")
FINITE = ("pos", "vel", "spin", "r", "mass", "inertia", "hist_s", "hist_m")


def invalid_current(edits) -> bool:
    """Whether the edits make the current epoch's state detectably invalid (not finite, duplicate
    ids, history counts beyond capacity, arrays of the wrong length, bad wheel state, missing
    step/time attributes), whatever the checksums say."""
    for ed in edits:
        if ed.get("which") != "current":
            continue
        if ed["op"] == "array":
            n, k = ed["name"], ed["kind"]
            if k == "delete":
                return True
            if ed["group"] == "domain":
                if (n in FINITE and k in ("nan", "inf", "all_nan")) or (n == "id" and k == "dup") \
                        or (n == "hist_n" and k in ("99", "all_99", "neg")) \
                        or (n in PER_DISC and k in ("shorter", "longer", "empty", "2d")):
                    return True
                # finite absurd values and indices out of range (the step's arithmetic and
                # the material table); 2D and 3D
                if (n == "mat" and k in ("999", "i32max", "minus1", "minus7")) \
                        or (n == "id" and k in ("minus1", "minus7")) \
                        or (n == "hist_n" and k in ("999", "i32max", "minus1", "minus7")) \
                        or (n in ("r", "mass", "inertia") and k in ("5e-324", "-5e-324", "minus1", "minus7")) \
                        or (n in ("vel", "spin") and k == "1e300") \
                        or (n in ("r", "mass", "inertia") and k == "zero") \
                        or (n in FINITE and k in ("float32", "int32", "complex", "u8", "bool")):
                    return True
            elif n == "wheel_state" and k in ("nan", "inf", "all_nan", "shorter", "longer", "empty", "2d"):
                return True
        elif ed["op"] == "attrs" and ed["group"] == "globals" and ed["value"] in (
                None, "garbage", "[]", "null", '"\u0000"', "[" * 100000, '{"step": "x"}'):
            return True
    return False


def _same_array(old, new) -> bool:
    """Whether an array edit changed nothing (e.g. "longer" or "nan" on a domain holding no
    disc): the epoch then holds the intact state, whatever the edit's kind says."""
    return old.dtype == new.dtype and old.shape == new.shape and old.tobytes() == new.tobytes()


def _without_noop_expectations(case: dict) -> dict:
    """The case's expectations as if its edits that changed nothing had not been made."""
    real = [ed for ed in case["edits"] if not ed.get("noop")]
    if invalid_current(real):
        return case
    expect = {k: v for k, v in case.get("expect", {}).items()
              if k not in ("same_bits_as_intact", "hash_fallback", "export_fallback")}
    return dict(case, expect=expect)


def _epoch_expect(case: dict) -> dict:
    """`checkpoint verify` must not accept an epoch whose bytes changed without a checksum fix;
    `resume` of a detectably invalid current epoch must refuse or fall back (same final bits)."""
    argv = case["argv"]
    # the intact bits only when the epoch a fallback resumes is intact: a previous epoch edited
    # with its checksums recomputed holds another state that no reader can tell from the real one
    previous_edited = any(ed.get("which") == "previous" and (ed["op"] in ("array", "attrs") or ed.get("recompute"))
                          for ed in case["edits"])
    if argv[0] == "resume" and invalid_current(case["edits"]) and not previous_edited:
        case.setdefault("expect", {})["same_bits_as_intact"] = True
    # the readers of an epoch validate it as resume does: `hash` of a detectably invalid
    # current epoch refuses or falls back to the previous one (its hash)
    only_current = invalid_current(case["edits"]) and all(
        ed.get("which") == "current" and ed["op"] in ("array", "attrs") for ed in case["edits"])
    if argv[:2] == ["checkpoint", "hash"] and _opt(argv, "--epoch") is None and only_current:
        case.setdefault("expect", {})["hash_fallback"] = True
    # ... and `export` of it refuses or writes the previous epoch
    if (argv[:2] == ["checkpoint", "export"] and _opt(argv, "--epoch") is None and only_current
            and (_opt(argv, "--out") or "").endswith(".csv")):
        case.setdefault("expect", {})["export_fallback"] = True
    damaged = set()
    for ed in case["edits"]:
        if ed["op"] == "flip" and not ed.get("recompute"):
            damaged.add(ed["which"])
        if ed["op"] == "truncate" and not ed.get("recompute") and (ed["frac"] < 1 or ed.get("extra")):
            damaged.add(ed["which"])
        if ed["op"] in ("array", "attrs"):   # these recompute every checksum of their epoch, so
            damaged.discard(ed["which"])      # earlier damage there is covered by new checksums
    if argv[:2] == ["checkpoint", "verify"] and damaged:
        epoch = _opt(argv, "--epoch")
        if epoch is None or (epoch == "10" and "previous" in damaged) or (epoch == "20" and "current" in damaged):
            case.setdefault("expect", {})["refuse"] = (
                f"verify exit 0 although the {'/'.join(sorted(damaged))} epoch's bytes changed "
                f"(checksums not recomputed)")
    return case


def _draw_args(draw, st, parser, cmd, sub, set_st) -> list[str]:
    """Positionals and options of one (sub)parser, from the hostile pools; long runs are kept short."""
    import argparse
    argv: list[str] = []
    opts: list[str] = []
    for a in parser._actions:
        if isinstance(a, (argparse._HelpAction, argparse._SubParsersAction)):
            continue
        if not a.option_strings:                         # positional
            if a.dest == "scenario":
                names = ["quick", "quick", "quick", "bed-1200", "run/scenario.toml", "victim_file",
                         "link_zero", "nonexistent.toml", "", "run", "dev_null"] + BED_NAMES[:12]
                if cmd != "check":
                    # a valid million-disc bed is a real run, not a tiny one (check only plans it);
                    # substituted in place, so the draws of every other case stay the same
                    names = [n if n != "bed-1m" else "bed-100000m" for n in names]
                v = draw(st.sampled_from(names))
            else:
                v = draw(st.sampled_from(STORE_ARGS))
            argv.append(v)
            continue
        name = a.option_strings[-1]
        if a.dest in ("no_progress", "no_figures"):
            continue                                     # added below
        if draw(st.integers(0, 2)) != 0 and not (a.required and draw(st.integers(0, 20)) != 0):
            continue
        if a.nargs == 0:
            opts.append(name)
            continue
        if a.choices:
            v = draw(st.sampled_from(list(a.choices) + ["", "x", "HDF5"]))
        else:
            v = draw(st.sampled_from(_pool(a.dest, cmd, sub)))
        if a.dest == "set":
            for _ in range(draw(st.integers(1, 3))):
                opts += [name, draw(set_st)]
            continue
        opts += [name, v]
    # keep simulations tiny: `run` always gets a small step count or a hostile duration
    if cmd == "run":
        opts = _strip(opts, ("--steps", "--duration"))
        if draw(st.integers(0, 3)) == 0:
            opts += ["--duration", draw(st.sampled_from([d for d in DURATION_VALUES if d not in ("1e-5", "0.00002")] + ["0.00002"]))]
        else:
            opts += ["--steps", draw(st.sampled_from(["0", "1", "3", "5", "100000000000", "1e11", "-1"]))]
    if cmd == "resume":
        opts = _strip(opts, ("--steps", "--until"))
        k = draw(st.integers(0, 2))
        if k == 0:
            opts += ["--steps", draw(st.sampled_from(["20", "21", "25", "30", "0", "10"] + STEPS_VALUES[4:]))]
        elif k == 1:
            opts += ["--until", draw(st.sampled_from(UNTIL_VALUES))]
    if cmd == "sweep":
        opts += ["--set", "wheel.settle_time=0", "--set", "wheel.travel_time=0.0001",
                 "--set", "output.steady_start=0", "--set", "output.steady_end=0.0001"]
    if cmd == "profile":                                 # never spawn: the --out check refuses first
        opts = _strip(opts, ("--out",)) + ["--out", "victim"]
    if cmd in ("run", "resume", "prepare", "sweep") and draw(st.integers(0, 5)) != 0:
        opts.append("--no-progress")
    if cmd in ("run", "resume") and draw(st.integers(0, 5)) != 0:
        opts.append("--no-figures")
    return argv + opts


def _strip(opts, names):
    out, skip = [], False
    for o in opts:
        if skip:
            skip = False
            continue
        if o in names:
            skip = True
            continue
        out.append(o)
    return out


EXPORT_OUTS_OK = ["out/s.csv", "out/s.xdmf", "out/s.vtk", "out/s.vtp", "out/noext", "out/sub/deep/s.csv",
                  "out/s.CSV", "out/.csv", "out/s.h5"]
EXPORT_OUTS_BAD = {"run/MANIFEST.json": "over the store's MANIFEST.json",
                   "run/epochs/e000000000020.h5": "over an epoch file",
                   "run/epochs/e000000000010.h5": "over an epoch file",
                   "run/epochs/e000000000020.zarr/zarr.json": "over an epoch file",
                   "run/epochs/e000000000020.zarr/domains/d0000/x/c/0": "over an epoch file",
                   "run/epochs/../MANIFEST.json": "over the store's MANIFEST.json",
                   "dev_null": "to a device node", "dev_full": "to a device node",
                   "link_zero": "to a device node", "run": "over the store directory",
                   "out": "over a directory", "run/epochs/x.csv": "inside epochs/"}

# hostile values per option destination of the real parser (anything else: GENERIC_VALUES)
OPTION_POOLS = {
    "steps": STEPS_VALUES, "duration": DURATION_VALUES, "until": UNTIL_VALUES,
    "domains": DOMAIN_VALUES, "block": BLOCK_VALUES, "epoch": EPOCH_VALUES, "keep": KEEP_VALUES,
    "checkpoint_every": ["1", "2", "10", "0", "-1", "100000000000", HUGE_DIGITS, "abc"],
    "slips": ["0.1", "0.1,0.2", "abc", "", ",", "nan", "inf", "1", "-0.0", "0.99999999999", "1e-300",
              "0.1,abc", "-1", "0.5,0.5", HUGE_DIGITS],
    "modes": ["monolithic", "gpu", "", ",", "monolithic,ddm,ooc", "ooc,ooc", "é🦀"],
    "bed": ["run", "out", "victim", "link_zero", "nonexistent", "victim_file", "", "dev_null", "run2"],
    "out": ["out/x", "out/x", "run", "run2", "victim", "victim_file", "link_victim", "link_file",
            "dev_null", "", "out", "runs/y", "out/é🦀", "out/" + "x" * 300, "run/epochs"],
    "format": ["xdmf", "vtk", "csv"],
}
EXPORT_OUT_POOL = EXPORT_OUTS_OK + list(EXPORT_OUTS_BAD)   # `checkpoint export --out`
GENERIC_VALUES = ["", "x", "0", "-1", "1e308", "nan", HUGE_DIGITS, "é🦀"]


def _pool(dest, cmd, sub) -> list[str]:
    if dest == "out" and cmd == "checkpoint":
        return EXPORT_OUT_POOL
    return OPTION_POOLS.get(dest, GENERIC_VALUES)



# =====================================================================================
# the bugs found by hand: always run (hypothesis @example)
# =====================================================================================

RUN_TAIL = ["--no-progress", "--no-figures"]


def _c(strategy, argv, edits=(), base="h5", expect=None):
    case = {"strategy": strategy, "base": base, "edits": list(edits), "argv": list(argv)}
    if expect:
        case["expect"] = expect
    return case


def _known_cases() -> dict:
    ck = lambda *a: _c("scenario", ["check", "quick", *a])  # noqa: E731
    sets = lambda *kv: [x for k in kv for x in ("--set", k)]  # noqa: E731
    scen = [ck(*sets("soil.r_min=1e-200")), ck(*sets("soil.r_min=1e-200", "soil.r_max=1e-200")),
            ck(*sets("physics.dt=5e-324")), ck(*sets("wheel.settle_time=1e308")),
            ck(*sets("wheel.travel_time=1e308")), ck(*sets("output.series_interval=5e-324")),
            ck(*sets("contact.soil_soil.kn=1e308")), ck(*sets("soil.density=5e-324")),
            ck(*sets("physics.thickness=1e308")), ck(*sets("bin.length=1e308")),
            ck(*sets("physics.gravity=-0.0")), ck(*sets("wheel.omega=nan")), ck(*sets("wheel.radius=inf")),
            ck("--steps", "100000000000"), ck("--duration", "1e308"), ck("--mode", "ooc", "--domains", "100000"),
            ck("--mode", "ddm", "--domains", "100000"), ck("--block", "1000000000"),
            ck(*sets("physics.dt=" + "[" * 5000 + "]" * 5000)), ck(*sets("soil.n=" + HUGE_DIGITS)),
            ck(*sets("soil.seed=" + HUGE_DIGITS)), ck(*sets('scenario.name="é🦀"')),
            ck(*sets('scenario.name="\\u0000\\u001b[31m"')), ck(*sets('scenario.name="../../x"')),
            ck(*sets("physics.dt={a = " + "{a = " * 300 + "1" + "}" * 301)),
            ck(*sets(".".join(["a"] * 500) + "=1"))]
    scen += [_c("scenario", ["check", n]) for n in
             ("bed-inf", "bed-nan", "bed-1e400", "bed-2000000000", "bed-" + HUGE_DIGITS, "bed-1e308")]
    scen_file = [_c("scenario_file", ["check", "out/s.toml"],
                    [{"op": "scenario_file", "name": "s.toml", "text": t}]) for t in
                 ("a = " + "[" * 5000 + "]" * 5000 + "\n", "[soil]\nn = " + HUGE_DIGITS + "\n",
                  "[" * 1000 + "\n", "[scenario]\nname = \"../../x\"\n")]
    scen_file.append(_c("scenario_file", ["check", "out/s.toml"],
                        [{"op": "scenario_file", "name": "s.toml", "bytes": list(b"\xff\xfe\x00[\x80")}]))
    cli = [_c("cli", ["run", "quick", "--steps", "100000000000", "--out", "out/r", *RUN_TAIL]),
           _c("cli", ["run", "quick", "--duration", "1e308", "--out", "out/r", *RUN_TAIL]),
           _c("cli", ["resume", "run", "--until", "1e308", *RUN_TAIL]),
           _c("cli", ["resume", "run", "--steps", "100000000000", *RUN_TAIL]),
           _c("cli", ["run", "quick", "--mode", "ooc", "--domains", "100000", "--steps", "1", "--out", "out/r",
                      *RUN_TAIL]),
           _c("cli", ["run", "quick", "--set", 'scenario.name="../../x"', "--steps", "1", *RUN_TAIL]),
           _c("cli", ["run", "quick", "--set", 'scenario.name="../victim"', "--steps", "1", *RUN_TAIL]),
           _c("cli", ["run", "bed-inf", "--steps", "1", *RUN_TAIL]),
           _c("cli", ["run", "bed-2000000000", "--steps", "1", "--out", "out/r", *RUN_TAIL]),
           _c("cli", ["prepare", "bed-nan", "--out", "out/p", "--no-progress"]),
           _c("cli", ["run", "quick", "--out", "victim", "--steps", "1", *RUN_TAIL]),
           _c("cli", ["checkpoint", "export", "run", "--out", "run/MANIFEST.json", "--format", "csv"]),
           _c("cli", ["checkpoint", "export", "run", "--out", "run/epochs/e000000000020.h5", "--format", "csv"]),
           _c("cli", ["checkpoint", "export", "run", "--out", "run/epochs/e000000000020.h5", "--format", "xdmf"]),
           _c("cli", ["checkpoint", "export", "run", "--out", "dev_null", "--format", "csv"]),
           _c("cli", ["checkpoint", "export", "run", "--out", "dev_full", "--format", "vtk"]),
           _c("cli", ["checkpoint", "export", "run", "--out", "run/epochs/e000000000020.zarr/zarr.json",
                      "--format", "csv"], base="zarr"),
           _c("cli", ["checkpoint", "hash", "run", "--epoch", HUGE_DIGITS])]
    M = lambda path, value: {"op": "manifest_set", "path": path, "value": value}  # noqa: E731
    prune = ["checkpoint", "prune", "run", "--keep", "1"]
    resume = ["resume", "run", "--steps", "30", *RUN_TAIL]
    verify = ["checkpoint", "verify", "run"]
    man = []
    for pth in ("../victim", "../victim_file", "$ABS/victim", "$ABS/victim_file", ".", "epochs",
                "MANIFEST.json", "../link_victim", ".."):
        man.append(_c("manifest", prune, [M(["previous", "path"], pth)]))
        man.append(_c("manifest", prune, [M(["previous", "path"], pth)], base="zarr"))
    man += [_c("manifest", prune, [{"op": "manifest_prev_is_cur"}]),
            _c("manifest", prune, [{"op": "manifest_prev_is_cur"}], base="zarr"),
            _c("manifest", resume, [{"op": "manifest_prev_is_cur"}]),
            _c("manifest", resume, [{"op": "epochs_symlink"}]),
            _c("manifest", resume, [{"op": "epochs_symlink"}], base="zarr"),
            _c("manifest", prune, [{"op": "epochs_symlink"}]),
            _c("manifest", verify, [M(["current", "files", 0, "path"], "../../dev/zero")]),
            _c("manifest", verify, [M(["current", "files", 0, "path"], "../../dev/zero"),
                                    M(["current", "files", 0, "size"], 0)]),
            _c("manifest", ["checkpoint", "hash", "run"], [M(["current", "files", 0, "path"], "../../dev/zero")]),
            _c("manifest", ["checkpoint", "list", "run"], [M(["current", "files", 0, "path"], "../link_zero")]),
            _c("manifest", verify, [M(["current", "files", 0, "path"], "$ABS/victim_file")]),
            _c("manifest", verify, [M(["current", "path"], "../run2/epochs/e000000000020.h5"),
                                    M(["current", "files", 0, "path"], "../run2/epochs/e000000000020.h5")]),
            _c("manifest", ["checkpoint", "hash", "run"], [{"op": "manifest_delete", "path": ["current", "globals"]}]),
            _c("manifest", resume, [{"op": "manifest_delete", "path": ["current", "globals"]}]),
            _c("manifest", ["checkpoint", "inspect", "run"], [M(["current", "domains"], {"x": {"n": 1, "arrays": {}}})]),
            _c("manifest", resume, [M(["current", "domains"], {"x": {"n": 1, "arrays": {}}})]),
            _c("manifest", resume, [M(["meta", "run", "domains"], "many")]),
            _c("manifest", resume, [M(["meta", "run", "mode"], ["ooc"])]),
            _c("manifest", resume, [M(["meta", "run", "steps"], "30")]),
            _c("manifest", resume, [M(["meta", "run", "checkpoint_every"], 0)]),
            _c("manifest", resume, [M(["meta", "run"], None)]),
            _c("manifest", resume, [M(["meta", "scenario_toml"], "[[[")]),
            _c("manifest", resume, [M(["meta", "scenario_toml"], 12)]),
            _c("manifest", resume, [M(["meta", "scenario_toml"], "[soil]\nn = " + HUGE_DIGITS + "\n")]),
            _c("manifest", verify, [{"op": "manifest_raw", "what": "deep", "n": 100000}]),
            _c("manifest", resume, [{"op": "manifest_raw", "what": "huge_int"}]),
            _c("manifest", ["checkpoint", "list", "run"], [M(["current", "step"], "20")]),
            _c("manifest", ["checkpoint", "list", "run"], [M(["current", "files", 0, "size"], "big")]),
            _c("manifest", ["checkpoint", "list", "run"], [M(["current", "domains"], [])])]
    A = lambda name, kind, which="current", **kw: {"op": "array", "which": which, "group": kw.get("group", "domain"),  # noqa: E731
                                                  "dom": 0, "name": name, "kind": kind, "rows": [0.0, 0.5],
                                                  "update_meta": kw.get("update_meta", False)}
    ep = []
    for base in BASES:
        ep += [_c("epoch", resume, [A("hist_n", "99")], base), _c("epoch", resume, [A("hist_n", "all_99")], base),
               _c("epoch", resume, [A("pos", "nan")], base), _c("epoch", resume, [A("vel", "all_nan")], base),
               _c("epoch", resume, [A("id", "dup")], base), _c("epoch", verify, [A("id", "dup")], base),
               _c("epoch", ["checkpoint", "hash", "run"], [A("hist_n", "all_99")], base),
               _c("epoch", resume, [A("pos", "shorter", update_meta=True)], base),
               _c("epoch", resume, [A("pos", "int32", update_meta=True)], base),
               _c("epoch", resume, [A("wheel_state", "shorter", group="globals", update_meta=True)], base),
               _c("epoch", resume, [{"op": "attrs", "which": "current", "group": "globals", "dom": 0, "value": None}], base),
               _c("epoch", ["checkpoint", "hash", "run"],
                  [{"op": "attrs", "which": "current", "group": "globals", "dom": 0, "value": None}], base),
               _c("epoch", ["checkpoint", "inspect", "run"],
                  [{"op": "attrs", "which": "current", "group": "globals", "dom": 0, "value": "garbage"}], base),
               _epoch_expect(_c("epoch", verify, [
                   {"op": "flip", "which": "current", "file": 0, "offsets": [0.5], "xors": [7], "recompute": False},
                   M(["current", "files"], [])], base)),
               _epoch_expect(_c("epoch", verify, [
                   {"op": "flip", "which": "previous", "file": 0, "offsets": [0.3], "xors": [1], "recompute": False},
                   M(["previous", "files"], [])], base))]
    rf = [_c("runfiles", ["report", "run"], [{"op": "runfile", "name": "summary.json", "json": []}]),
          _c("runfiles", ["report", "run"], [{"op": "runfile", "name": "summary.json", "summary_set": ["slip"], "value": 3}]),
          _c("runfiles", ["report", "run"], [{"op": "runfile", "name": "summary.json", "json": {"$deep_list": 100000}}]),
          _c("runfiles", ["report", "run"], [{"op": "runfile", "name": "series.csv", "text": "garbage\n\x00\x01"}]),
          _c("runfiles", ["report", "run"], [{"op": "runfile", "name": "initial.npz", "bytes": list(b"PK\x03\x04junk")}]),
          _c("runfiles", ["report", "run"], [{"op": "runfile_link", "name": "summary.json", "target": "../link_zero"}]),
          _c("runfiles", ["report", "run"], [{"op": "runfile_link", "name": "figures", "target": "../victim"}]),
          _c("runfiles", ["compare", "run", "run2"], [{"op": "runfile", "name": "summary.json", "json": "x"}]),
          _c("runfiles", ["compare", "run", "run2"], [{"op": "runfile", "name": "summary.json", "summary_set": ["slip", "steady"], "value": None}]),
          _c("runfiles", ["compare", "run", "run2"], [{"op": "runfile", "name": "initial.npz", "npz": {"x": "object"}}]),
          _c("runfiles", ["compare", "run", "run2"], [{"op": "runfile", "name": "series.csv", "text": "1e308," * 13 + "\n"}]),
          _c("runfiles", ["compare", "run", "run2"], [{"op": "runfile_link", "name": "summary.json", "target": "/dev/zero"}])]
    # the readers that skipped the epoch validation (hash, export) and finite absurd values
    hash_ = ["checkpoint", "hash", "run"]
    csv = ["checkpoint", "export", "run", "--out", "out/s.csv"]
    for base in BASES:
        ep += [_c("epoch", hash_, [A("pos", "nan")], base), _c("epoch", csv, [A("pos", "nan")], base),
               _c("epoch", hash_, [A("r", "zero")], base), _c("epoch", hash_, [A("id", "minus7")], base),
               _c("epoch", hash_, [A("hist_n", "99")], base), _c("epoch", hash_, [A("pos", "float32", update_meta=True)], base),
               _c("epoch", resume, [A("vel", "1e300")], base), _c("epoch", resume, [A("mass", "5e-324")], base),
               _c("epoch", resume, [A("mat", "999")], base)]
    # a damaged current epoch whose recorded size is absurd: resume falls back, never "disk full"
    for base in BASES:
        ep.append(_c("epoch", resume, [{"op": "flip", "which": "current", "file": 0, "offsets": [0.5], "xors": [7],
                                        "recompute": False},
                                       M(["current", "files", 0, "size"], 10 ** 18)], base,
                     expect={"same_bits_as_intact": True}))
    # a domain's attributes replaced (no n, xmin, xmax): an out-of-core resume read the group
    # as empty and committed an epoch short of its discs; an array edit that changes nothing
    # (a domain holding no disc) leaves the intact state
    DA = lambda which, dom, value: {"op": "attrs", "which": which, "group": "domain", "dom": dom,  # noqa: E731
                                    "value": value}
    ep += [_c("epoch", resume, [DA("current", 5, '{"step": 1e308}')], "zarr"),
           _c("epoch", resume, [{"op": "flip", "which": "current", "file": 187, "offsets": [0.0, 0.6],
                                 "xors": [88, 188], "recompute": False},
                                DA("previous", 3, '{"engine": {"domains": 100000}}')], "zarr")]
    # an absurd finite value that `check` accepts crashes `run`
    cli += [_c("cli", ["run", "quick-3d", "--set", "wheel.width=1e-300", "--steps", "1", "--out", "out/r", *RUN_TAIL]),
            _c("cli", ["check", "quick-3d", "--set", "wheel.width=1e-300"])]
    # untyped exceptions from the API on a hostile manifest; hist_cap sizing an allocation
    api = ["@api", "state", "run"]
    man += [_c("manifest", api, [M(["meta", "dim"], 3.0)]), _c("manifest", api, [M(["meta", "dim"], 3.0)], base="zarr"),
            _c("manifest", api, [M(["meta", "hist_cap"], 100000)], expect={"size_bound": True}),
            _c("manifest", ["checkpoint", "hash", "run"], [M(["meta", "hist_cap"], 100000)], expect={"size_bound": True})]
    ep = [_epoch_expect(c) for c in ep]
    # 3D stores: a material index past the table, the same readers
    ep3 = []
    for base in ("h5_3d", "zarr_3d"):
        ep3 += [_c("epoch3d", resume, [A("mat", "i32max")], base), _c("epoch3d", hash_, [A("pos", "nan")], base),
                _c("epoch3d", csv, [A("pos", "nan")], base), _c("epoch3d", resume, [A("vel", "1e300")], base),
                _c("epoch3d", hash_, [A("hist_n", "all_99")], base), _c("epoch3d", api, [A("r", "zero")], base)]
    big_id = dict(A("id", "3e8"), rows=[0.0])          # one disc, so that the ids stay distinct
    ep3.append(_c("epoch3d", resume, [big_id], "zarr_3d", expect={"size_bound": True}))
    ep += [_c("epoch", resume, [big_id], "zarr", expect={"size_bound": True}),
           dict(_c("epoch", resume, [big_id], "ddm", expect={"size_bound": True}), heavy=True)]
    ep3.append(_c("epoch3d", hash_, [A("spin", "longer") | {"dom": 5}], "zarr_3d"))
    ep3 = [_epoch_expect(c) for c in ep3]
    # beds: `run --bed` and the bed cache load beds without the store's validation
    B = lambda name, kind, where="bed": {"op": "npz_array", "file": where, "name": name, "kind": kind, "rows": [0.0]}  # noqa: E731
    beds = [_bed_case("bed", [B("mat", "999")]), _bed_case("bed", [B("r", "zero")]),
            _bed_case("bed", [B("hist_n", "99")]), _bed_case("bed", [B("id", "minus7")]),
            _bed_case("bed", [B("mat", "minus1")]), _bed_case("bed", [B("pos", "nan")]),
            _bed_case("bed", [B("mat", "i32max")], ["--mode", "ooc", "--domains", "2", "--backend", "zarr"]),
            _bed_case("cache", [B("id", "drop_disc", "cache")]), _bed_case("cache", [B("r", "zero", "cache")]),
            _bed_case("cache", [B("pos", "nan", "cache")]), _bed_case("cache", [B("mat", "999", "cache")]),
            # a ratio of the state bounds overflowing: numpy's warning made the one-line error three
            _bed_case("bed", [B("hist_m", "5e-324"), B("inertia", "huge")],
                      ["--mode", "ooc", "--domains", "2", "--backend", "zarr"])]
    # allocations sized by a declared size: a frame declaring 2^25 rows, an npz member of 4 GB
    # deflated zeros, a gzip zarr chunk inflating to 4 GB
    T = lambda *e, argv=("animate", "run", "--out", "out/f.gif", "--no-progress"): _size_expect(  # noqa: E731
        _c("trajectory", list(argv), list(e), base="traj"))
    traj = [T({"op": "traj", "frame": 1, "what": "declare_rows", "rows": 2 ** 25, "n_discs": True}),
            T({"op": "traj", "frame": 1, "what": "declare_rows", "rows": 2 ** 25, "n_discs": False}),
            T({"op": "traj", "frame": 0, "what": "declare_rows", "rows": 2 ** 25, "n_discs": True},
              argv=("@api", "trajectory", "run")),
            T({"op": "traj", "frame": 2, "what": "dataset", "name": "pos", "kind": "nan", "rows": [0.0]}),
            T({"op": "traj", "frame": 2, "what": "dataset", "name": "mat", "kind": "i32max", "rows": [0.0]}),
            T({"op": "traj", "frame": 1, "what": "attr", "key": "n_discs", "value": 2 ** 40}),
            # an array attribute where a string belongs compares element-wise (a traceback)
            T({"op": "traj", "frame": 2, "what": "attr", "key": "format", "value": [1.0, 2.0]},
              argv=("animate", "run", "--out", "out/f.mp4", "--no-progress"))]
    Z = lambda *e, argv=("report", "run"), base="h5": _size_expect(_c("npz", list(argv), list(e), base=base))  # noqa: E731
    npz = [Z({"op": "npz_member", "member": "x", "what": "bomb", "size": 4 << 30}),
           Z({"op": "npz_member", "member": "x", "what": "bomb", "size": 384 * MiB}),
           Z({"op": "npz_member", "member": "x", "what": "bomb", "size": 384 * MiB}, argv=("compare", "run", "run2")),
           Z({"op": "npz_member", "member": "x", "what": "declared", "shape": [2 ** 40], "descr": "<f8"}),
           Z({"op": "npz_member", "member": "x", "what": "object"}),
           Z({"op": "npz_member", "member": "x", "what": "dtype", "descr": "<c16"}),
           Z({"op": "npz_member", "member": "surface", "what": "shape", "shape": [0]}),
           Z({"op": "npz_member", "member": "x", "what": "shape", "shape": [1500, 2]}),
           Z({"op": "npz_member", "member": "y", "what": "shape", "shape": [1]})]
    zc = lambda codec, argv, base="zarr", **kw: _size_expect(_c(  # noqa: E731
        "zarr_codec", list(argv), [{"op": "zarr_codec", "which": "current", "group": "domain", "dom": 0,
                                    "name": "pos", "codec": codec, "encode": kw.get("encode", False),
                                    **({"size": kw["size"]} if "size" in kw else {})}], base=base))
    zarr = [zc("gzip_bomb", resume, size=4 << 30), zc("gzip_bomb", hash_, size=384 * MiB),
            zc("gzip_bomb", resume, size=384 * MiB), zc("gzip_bomb", csv, base="zarr_3d", size=384 * MiB), zc("sharding", hash_), zc("unknown", hash_),
            zc("gzip", resume, encode=True), zc("blosc", verify), zc("zstd", ["@api", "state", "run"], base="zarr_zstd")]
    zarr += [zc("sharding_many", hash_), zc("sharding_many", csv, base="zarr_zstd")]
    for c in zarr:
        if c["edits"][0]["codec"].startswith("sharding"):
            c["fresh"] = True     # zarr's messages at interpreter exit count
    # the 4 GB reproductions take seconds to build: campaigns only (the CI slice has the 512 MB ones)
    for c in npz + zarr:
        if c["edits"][0].get("size", 0) >= 4 << 30:
            c["heavy"] = True
    # a cache rebuild settles a bed (seconds): one in the CI slice, the others in campaigns
    for c in beds:
        if "cache" in c["needs"] and c["edits"][0]["kind"] != "drop_disc":
            c["heavy"] = True
    # writers under a file-size limit (`ulimit -f 100`: 102400 bytes)
    F = lambda argv, base="h5", limit=102400, needs=(): {  # noqa: E731
        "strategy": "fsize", "base": base, "edits": [], "argv": list(argv), "fsize": limit, "needs": list(needs),
        "timeout": 30}
    fs = [F(["checkpoint", "export", "run", "--out", "out/e.xdmf"]),
          F(["checkpoint", "export", "run", "--out", "out/e.xdmf"], base="zarr"),
          F(RESUME30, base="traj", limit=4096), F(RESUME30, base="h5", limit=102400),
          F(["animate", "run", "--out", "out/f.mp4", "--no-progress"], base="traj", limit=16384),
          F([*BED_RUN, "--out", "out/r"], needs=("cache",), limit=102400)]
    return {"scenario": scen, "scenario_file": scen_file, "cli": cli, "manifest": man, "epoch": ep,
            "runfiles": rf, "epoch3d": ep3, "bed": beds, "trajectory": traj, "npz": npz, "zarr_codec": zarr,
            "fsize": fs}


KNOWN = _known_cases()
STRATEGY_NAMES = ("scenario", "scenario_file", "cli", "manifest", "epoch", "runfiles",
                  "epoch3d", "bed", "trajectory", "npz", "zarr_codec", "fsize")
# the base material each strategy's worlds start from
STRATEGY_BASES = {"scenario": ("h5", "zarr"), "scenario_file": ("h5", "zarr"), "cli": ("h5", "zarr"),
                  "manifest": ("h5", "zarr"), "epoch": ("h5", "zarr", "ddm"), "runfiles": ("h5", "zarr"),
                  "epoch3d": ("h5_3d", "zarr_3d"), "bed": ("h5", "zarr", "bed"),
                  "trajectory": ("traj", "h5"), "npz": ("h5", "zarr", "traj"),
                  "zarr_codec": ("zarr", "h5", "zarr_3d", "h5_3d", "zarr_zstd"),
                  "fsize": ("h5", "zarr", "traj", "h5_3d", "bed")}


def bases_for(names, heavy: bool = True) -> list[str]:
    """The base material the named strategies need (h5 and zarr always: the worker warms on
    them); with heavy, also what their heavy known cases start from."""
    out = ["h5", "zarr"]
    for n in names:
        out += [b for b in STRATEGY_BASES[n] if b not in out]
        if heavy:
            out += [c["base"] for c in KNOWN.get(n, []) if c.get("heavy") and c["base"] not in out]
    return out


def run_strategy(fuzzer: Fuzzer, name: str, n: int, seed: int | None = None, known: bool = True,
                 strategies: dict | None = None, heavy: bool = True, end: bool = True) -> int:
    """Run the known cases of a strategy plus n generated ones; returns the number of cases run.
    heavy=False leaves out the known cases marked heavy (seconds to build their input);
    end=False keeps the worker for the next strategy (its exit is checked at the last one)."""
    from hypothesis import HealthCheck, Phase, example, given, settings
    from hypothesis import seed as hseed
    strategies = strategies or build_strategies()
    before = fuzzer.counts.get(name, 0)

    @settings(max_examples=max(n, 1), deadline=None, derandomize=seed is None, database=None,
              phases=[Phase.explicit, Phase.generate], suppress_health_check=list(HealthCheck),
              report_multiple_bugs=False)
    @given(case=strategies[name])
    def body(case):
        fuzzer.run_case(case)

    if known:
        for ex in KNOWN.get(name, []):
            if heavy or not ex.get("heavy"):
                body = example(case=ex)(body)
    if seed is not None:
        body = hseed(seed)(body)
    if n > 0 or known:
        body()
    if end:
        fuzzer.end_worker()      # the next strategy gets a fresh worker
    return fuzzer.counts.get(name, 0) - before


if __name__ == "__main__" and "--worker" in sys.argv:
    sys.path.insert(0, str(ROOT))
    sys.exit(_worker_main())
