"""The worker: a long-lived interpreter that runs `ooc_dem.cli.main` (or the Python API) for each
case the parent sends, output captured, RLIMIT_AS and RLIMIT_FSIZE as asked; started as
`python tools/fuzzlib/worker.py --worker` (this file imports nothing of the package: it runs
as a script, with this checkout's ooc_dem first on the path)."""

from __future__ import annotations

import json
import os
import shutil
import sys
import tempfile
import time
import traceback
from pathlib import Path


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
    os.dup2(null, 0)  # the CLI never reads the protocol
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
            main = _api_main  # the Python API, judged by the same exit rules
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
        return {
            "rc": rc if isinstance(rc, int) else 1,
            "stdout": tail(outp),
            "stderr": tail(errp),
            "exc": exc,
            "elapsed": round(elapsed, 4),
            "hwm": st.get("VmHWM", 0),
            "hwm_reset": hwm_reset,
            "rss": st.get("VmRSS", 0),
            "rss0": rss0,
        }

    # warm up: imports and the JIT caches (not counted as cases)
    import numpy  # noqa: F401
    import ooc_dem.cli  # noqa: F401
    from ooc_dem.app import run  # noqa: F401

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
    send(
        {
            "ready": True,
            "pid": os.getpid(),
            "scratch": str(scratch),
            "baseline_rss": base.get("VmRSS", 0),
            "vm_size": base.get("VmSize", 0),
            "rlimit_as": limit,
            "commands": sorted(_subcommands()),
        }
    )
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
            from ooc_dem.app.trajectory_read import Trajectory

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


if __name__ == "__main__" and "--worker" in sys.argv:
    # this checkout's ooc_dem first; not the package's modules beside this file
    sys.path[0] = str(Path(__file__).resolve().parents[2])
    sys.exit(_worker_main())
