"""Small runs the tests share: the short wheel run's overrides and the base run's length."""

# a short wheel run on the quick rig: 0.1 s of settling, 0.4 s of travel
WHEEL_TEST = [
    "wheel.settle_time=0.1",
    "wheel.travel_time=0.4",
    "wheel.drawbar_ramp=0.1",
    "output.steady_start=0.1",
    "output.steady_end=0.4",
]

# the base_run fixture's length and checkpoint interval: its current epoch is at BASE_RUN_STEPS
BASE_RUN_STEPS = 40
BASE_RUN_CKPT = 20


def kill_after_first_commit(cmd: list[str], out, timeout: float = 600.0) -> bool:
    """Start `cmd` (a run writing the store `out`) in its own session and SIGKILL it once its
    first epoch is committed; True if it was killed (False: it finished first)."""
    import signal
    import subprocess
    import time

    from .stores import committed_step

    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True)
    deadline = time.time() + timeout
    killed = False
    while time.time() < deadline and proc.poll() is None:
        if committed_step(out) > 0:
            proc.send_signal(signal.SIGKILL)
            killed = True
            break
        time.sleep(0.05)
    proc.wait(timeout=60)
    assert not killed or proc.returncode == -9, proc.returncode
    return killed
