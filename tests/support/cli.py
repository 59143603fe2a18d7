"""`ooc-dem` for the tests: in a fresh interpreter (``run_cli``) or in this one
(``cli_in_process``), and the bad-input rule both must keep (``one_line_error``).

A fresh interpreter costs about 1.5 s before the command does anything, which is all a refusal
costs; ``cli_in_process`` runs the same ``ooc_dem.cli.main`` here. Keep ``run_cli`` where the
process is the point: signals and exit codes under a signal, memory limits and peak RSS,
environment variables, MPI, the console script, a command that runs a simulation (its threads
and compiled kernels), or anything that would leave this process changed. ``cli_in_process``
checks the last: a command that leaves the working directory, environment, umask, resource
limits, signal handlers, numba's thread count, ``sys.path``, an open file or a thread behind
fails the test that ran it; so does one still running after its ``timeout``.
"""

from __future__ import annotations

import contextlib
from collections import Counter
import dataclasses
import os
import resource
import signal
import subprocess
import sys
import tempfile
import threading
import traceback
import warnings

import pytest


def run_cli(*args, check=False, timeout=900, env=None):
    """Run `ooc-dem ...` in a fresh interpreter; returns CompletedProcess."""
    e = dict(os.environ)
    if env:
        e.update(env)
    cp = subprocess.run(
        [sys.executable, "-m", "ooc_dem.cli", *map(str, args)], capture_output=True, text=True, timeout=timeout, env=e
    )
    if check and cp.returncode != 0:
        raise AssertionError(f"ooc-dem {' '.join(map(str, args))} failed ({cp.returncode}):\n{cp.stderr}")
    return cp


@dataclasses.dataclass
class CliResult:
    """A finished in-process `ooc-dem`: what the tests read of a CompletedProcess."""

    args: list
    returncode: int
    stdout: str
    stderr: str


class CliTimeout(BaseException):
    """The in-process command ran past its timeout (a BaseException: the command's own
    ``except Exception`` and ``except OSError`` must not turn it into a refusal)."""


def cli_in_process(*args, check=False, timeout=900) -> CliResult:
    """Run `ooc-dem ...` in this interpreter: ``ooc_dem.cli.main`` with stdout and stderr captured
    (Python's streams and file descriptors 1 and 2), SystemExit turned into the exit code a
    process would give and an escaping exception into a traceback on stderr and exit code 1,
    every warning a fresh interpreter would print written to stderr. A command still running
    after ``timeout`` seconds fails the test (at its next Python bytecode: SIGALRM)."""
    from ooc_dem import cli

    argv = [str(a) for a in args]
    before = _process_state()
    try:
        with (
            _alarm(timeout, argv),
            _captured() as out,
            warnings.catch_warnings(record=True) as caught,
            _argv([cli.__file__, *argv]),
        ):
            # a fresh interpreter's filters, whatever an earlier test left in this process's: it
            # hides these by default and prints everything else
            warnings.resetwarnings()
            warnings.simplefilter("default")
            for category in (DeprecationWarning, PendingDeprecationWarning, ImportWarning, ResourceWarning):
                warnings.filterwarnings("ignore", category=category)
            try:
                code = cli.main(argv)
            except SystemExit as e:
                code = e.code
            except (KeyboardInterrupt, CliTimeout):
                raise
            except BaseException:  # what the interpreter would print before exiting 1
                traceback.print_exc()
                code = 1
            if code is not None and not isinstance(code, int):
                print(code, file=sys.stderr)
                code = 1
            for w in caught:
                sys.stderr.write(warnings.formatwarning(w.message, w.category, w.filename, w.lineno, w.line))
    except CliTimeout as e:
        pytest.fail(str(e))
    changed = _changes(before, _process_state())
    if changed:
        _restore(before)
        pytest.fail(
            f"in-process `ooc-dem {' '.join(argv)}` left this process changed ({'; '.join(changed)}): "
            f"run it in a fresh interpreter (run_cli)"
        )
    res = CliResult(argv, 0 if code is None else code, out["stdout"], out["stderr"])
    if check and res.returncode != 0:
        raise AssertionError(f"ooc-dem {' '.join(argv)} failed ({res.returncode}):\n{res.stderr}")
    return res


def error_lines(stderr: str) -> list[str]:
    """The non-empty lines of a command's stderr but its warnings (`check` and `run` warn of
    a scenario before they start: ``ooc-dem: warning: ...``)."""
    return [ln for ln in stderr.splitlines() if ln.strip() and not ln.startswith("ooc-dem: warning: ")]


def one_line_error(cp, *needles) -> str:
    """Assert the bad-input rule on a finished `ooc-dem` (a process or ``cli_in_process``): exit
    code 2 (not a signal), exactly one non-empty line on stderr (but warnings), no traceback,
    every needle in that line; return it."""
    if cp.returncode < 0:
        pytest.fail(
            f"killed by {signal.Signals(-cp.returncode).name} instead of exit 2; stderr ends: "
            f"{cp.stderr.strip()[-600:]}"
        )
    assert cp.returncode == 2, (cp.returncode, cp.stdout[-2000:], cp.stderr[-3000:])
    assert "Traceback" not in cp.stderr, cp.stderr[-3000:]
    lines = error_lines(cp.stderr)
    assert len(lines) == 1, cp.stderr[-3000:]
    for n in needles:
        assert n in lines[0], (n, lines[0])
    return lines[0]


@contextlib.contextmanager
def _alarm(timeout, argv):
    def expired(signum, frame):
        raise CliTimeout(f"in-process `ooc-dem {' '.join(argv)}` still running after {timeout} s")

    previous = signal.signal(signal.SIGALRM, expired)
    signal.setitimer(signal.ITIMER_REAL, timeout)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


@contextlib.contextmanager
def _argv(argv):
    saved = sys.argv
    sys.argv = argv
    try:
        yield
    finally:
        sys.argv = saved


@contextlib.contextmanager
def _captured():
    """Capture stdout and stderr at the file descriptors, so a library writing to fd 2 is seen
    as in a process; yields a dict filled with both texts on exit."""
    out = {}
    saved = []
    try:
        for fd, name in ((1, "stdout"), (2, "stderr")):
            getattr(sys, name).flush()
            tmp = tempfile.TemporaryFile()
            saved.append((fd, name, os.dup(fd), getattr(sys, name), tmp))
            os.dup2(tmp.fileno(), fd)
            setattr(sys, name, open(fd, "w", encoding="utf-8", errors="backslashreplace", closefd=False))
        yield out
    finally:
        for fd, name, fd_before, stream_before, tmp in reversed(saved):
            getattr(sys, name).close()  # flushes; the descriptor stays (closefd=False)
            os.dup2(fd_before, fd)
            os.close(fd_before)
            setattr(sys, name, stream_before)
            tmp.seek(0)
            out[name] = tmp.read().decode("utf-8", "replace")
            tmp.close()


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _open_files() -> list[str]:
    """The regular files this process holds open (a store's lock or epoch left open); not those
    of the Python installation (a library's cache: matplotlib keeps its fonts open)."""
    installed = tuple({os.path.join(p, "") for p in (sys.prefix, sys.base_prefix, sys.exec_prefix)})
    files = []
    for fd in os.listdir("/proc/self/fd"):
        try:
            target = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            continue
        if target.startswith("/") and not target.startswith(("/dev/", "/proc/", *installed)):
            files.append(target)
    return sorted(files)


def _process_state() -> dict:
    state = {
        "working directory": os.getcwd(),
        "environment": dict(os.environ),
        "umask": _umask(),
        "resource limits": {
            n: resource.getrlimit(getattr(resource, n)) for n in dir(resource) if n.startswith("RLIMIT_")
        },
        "signal handlers": {
            s.name: signal.getsignal(s) for s in signal.valid_signals() if isinstance(s, signal.Signals)
        },
        "sys.path": list(sys.path),
        "open files": _open_files(),
        # a library's daemon thread (zarr's event loop) lives as long as the process anyway
        "threads": {t.ident: t.name for t in threading.enumerate() if not t.daemon},
    }
    if "numba" in sys.modules:
        state["numba threads"] = sys.modules["numba"].get_num_threads()
    return state


def _changes(before: dict, after: dict) -> list[str]:
    changed = []
    for what, was in before.items():
        now = after.get(what)
        if what == "threads":  # a thread that ended is no change; one still running is
            now = {k: v for k, v in now.items() if k not in was}
            if now:
                changed.append(f"threads still running: {sorted(now.values())}")
        elif what == "open files":
            # files opened and not closed; files closed meanwhile (an earlier test's leaked
            # handles collected by the garbage collector during the command) are no change
            extra = sorted((Counter(now) - Counter(was)).elements())
            if extra:
                changed.append(f"files left open: {extra}"[:400])
        elif isinstance(was, dict) and now != was:
            keys = sorted(k for k in set(was) | set(now) if was.get(k) != now.get(k))
            changed.append(f"{what}: {', '.join(map(str, keys))[:300]}")
        elif now != was:
            changed.append(f"{what}: {was!r} -> {now!r}")
    return changed


def _restore(state: dict) -> None:
    """Put back what can be put back, so one failing test does not spoil the next."""
    os.chdir(state["working directory"])
    os.environ.clear()
    os.environ.update(state["environment"])
    os.umask(state["umask"])
    sys.path[:] = state["sys.path"]
    for name, handler in state["signal handlers"].items():
        if handler is not None and signal.getsignal(signal.Signals[name]) != handler:
            signal.signal(signal.Signals[name], handler)
    if "numba threads" in state:
        sys.modules["numba"].set_num_threads(state["numba threads"])
