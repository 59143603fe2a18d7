"""The in-process `ooc-dem` of tests/support keeps what a process would show (exit code, both
streams, a traceback, a warning, a write to fd 2) and fails a command that leaves the test
process changed or runs past its timeout: the refusal tests that use it can still fail."""

import os
import signal
import sys
import threading
import time
import warnings

import pytest

from ooc_dem import cli
from support.cli import cli_in_process, one_line_error, run_cli


@pytest.mark.parametrize(
    "args",
    [["check", "no-such-scenario"], ["run", "--bogus"], ["scenarios"], ["check", "quick", "--set", "physics.dt=1e-3"]],
)
def test_in_process_gives_what_a_process_gives(args):
    here, there = cli_in_process(*args), run_cli(*args)
    assert (here.returncode, here.stdout, here.stderr) == (there.returncode, there.stdout, there.stderr)


def _command(monkeypatch, body):
    monkeypatch.setitem(cli.COMMANDS, "scenarios", body)


def _refuse():
    print("ooc-dem: error: refused", file=sys.stderr)
    return 2


@pytest.mark.parametrize("what", ["traceback", "warning", "fd 2"])
def test_what_a_process_would_print_breaks_the_one_line_rule(what, monkeypatch):
    def body(args):
        if what == "traceback":
            raise ValueError("escaped")
        if what == "warning":
            warnings.warn("careful", RuntimeWarning)
        if what == "fd 2":
            os.write(2, b"from C\n")
        return _refuse()

    _command(monkeypatch, body)
    res = cli_in_process("scenarios")
    assert res.returncode == (1 if what == "traceback" else 2)
    with pytest.raises(AssertionError):
        one_line_error(res)


def test_a_refusal_passes_the_one_line_rule(monkeypatch):
    _command(monkeypatch, lambda args: _refuse())
    assert one_line_error(cli_in_process("scenarios"), "refused") == "ooc-dem: error: refused"


@pytest.mark.parametrize(
    "what", ["environment", "working directory", "signal handlers", "threads", "files left open", "still running"]
)
def test_a_command_that_changes_the_process_fails_the_test(what, monkeypatch, tmp_path):
    held = []

    def body(args):
        if what == "environment":
            os.environ["OOC_DEM_TEST_SUPPORT"] = "1"
        elif what == "working directory":
            os.chdir(tmp_path)
        elif what == "signal handlers":
            signal.signal(signal.SIGUSR1, lambda *a: None)
        elif what == "threads":
            stop = threading.Event()
            held.append(stop)
            threading.Thread(target=stop.wait).start()
        elif what == "files left open":
            held.append(open(tmp_path / "left-open", "w"))
        elif what == "still running":
            time.sleep(5)
        return _refuse()

    _command(monkeypatch, body)
    before = (os.getcwd(), dict(os.environ), signal.getsignal(signal.SIGUSR1))
    try:
        with pytest.raises(pytest.fail.Exception, match=what):
            cli_in_process("scenarios", timeout=1)
    finally:
        for h in held:
            h.set() if isinstance(h, threading.Event) else h.close()
    assert (os.getcwd(), dict(os.environ), signal.getsignal(signal.SIGUSR1)) == before  # put back


def test_the_compile_notice_follows_numbas_cache_index(tmp_path, monkeypatch):
    """kernels_cached reads numba's own cache index of the step kernel: False where it is
    absent (the first run compiles, and says so), True once it exists."""
    from ooc_dem.app.progress import kernels_cached
    from ooc_dem.physics import kernels

    cache_file = kernels(2).run_steps._cache._cache_file
    monkeypatch.setattr(cache_file, "_index_path", str(tmp_path / "run_steps.nbi"))
    assert kernels_cached(2) is False
    (tmp_path / "run_steps.nbi").write_bytes(b"")
    assert kernels_cached(2) is True
