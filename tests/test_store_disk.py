"""A full disk, for real: a small tmpfs mounted for the test (the tests run as root, in CI
too). Before an epoch is begun the store checks the room it needs (``Store.check_room``); a
sweep that cannot be stored is one line and exit code 2, never a torn epoch, and every
committed epoch stays intact and resumable."""

import json
import os
import subprocess

import numpy as np
import pytest

from support.cli import cli_in_process, one_line_error, run_cli
from ooc_dem.storage import StoreError, create_store, open_store


def _fill(mnt, leave: int):
    """A filler file taking the file system's free space down to `leave` bytes."""
    st = os.statvfs(mnt)
    free = st.f_bavail * st.f_frsize
    with open(mnt / "filler", "wb") as f:
        f.write(b"\0" * max(0, free - leave))
    return mnt / "filler"


@pytest.mark.parametrize("backend", ["hdf5", "zarr"])
def test_begin_epoch_refuses_when_the_disk_cannot_hold_it(small_fs, backend):
    mnt = small_fs("8m")
    p = str(mnt / "s")
    s = create_store(p, backend, {"run": "full"})
    x = np.arange(125_000, dtype=np.float64)  # 1 MB a group
    w = s.begin_epoch(1)
    w.write_domain(0, {"x": x})
    w.commit()
    before = sorted(os.listdir(os.path.join(p, "epochs")))
    filler = _fill(mnt, 512 << 10)  # half an epoch left
    with pytest.raises(StoreError, match="disk full or file too large") as ei:
        s.begin_epoch(2)
    msg = str(ei.value)
    assert "\n" not in msg and "epoch 2 needs about" in msg and "free" in msg, msg
    assert sorted(os.listdir(os.path.join(p, "epochs"))) == before  # nothing begun
    assert s.current() == 1 and s.verify() == []
    # the check cannot see others filling the disk during the write: ENOSPC then is the
    # same one-line error, the partial epoch is removed, the committed one untouched
    filler.unlink()
    w = s.begin_epoch(2)
    _fill(mnt, 256 << 10)
    with pytest.raises(StoreError, match="disk full or file too large"):
        w.write_domain(0, {"x": x})
        w.write_domain(1, {"x": x})
        w.commit()
    assert sorted(os.listdir(os.path.join(p, "epochs"))) == before
    s.close()
    (mnt / "filler").unlink()
    s = open_store(p)
    assert s.current() == 1 and s.verify() == []
    assert np.array_equal(s.read_epoch().read_domain(0)["x"], x)
    w = s.begin_epoch(2)  # room again: the store goes on
    w.write_domain(0, {"x": x + 1})
    w.commit()
    assert s.epochs() == [1, 2] and s.verify() == []
    s.close()


def test_out_of_core_run_on_a_full_disk_stops_cleanly_and_resumes(small_fs):
    """`ooc-dem run` whose disk fills up: exit 2, one line, the committed epochs verify, and
    `resume` finishes once there is room again."""
    mnt = small_fs("850k")  # set-up files and two epochs (~280 kB each) fit, not a third
    out = mnt / "run"
    cp = run_cli(
        "run",
        "quick",
        "--mode",
        "ooc",
        "--backend",
        "zarr",
        "--block",
        "1",
        "--steps",
        "12",
        "--out",
        out,
        "--no-progress",
        "--no-figures",
        "--set",
        "output.snapshot_interval=0",
        timeout=300,
    )
    epochs = sorted(os.listdir(out / "epochs")) if (out / "epochs").exists() else []
    if cp.returncode == 0:  # epochs grew or shrank: the size above needs a new value
        pytest.fail(f"the run fitted in 850k; epochs {epochs}")
    one_line_error(cp, "disk full or file too large")
    assert not [n for n in epochs if ".tmp-" in n], epochs  # no torn epoch left
    m = json.loads((out / "MANIFEST.json").read_text())
    assert m["current"] is not None and 0 < m["current"]["step"] < 12
    assert cli_in_process("checkpoint", "verify", out).returncode == 0
    subprocess.run(["mount", "-o", "remount,size=16m", str(mnt)], check=True)
    cp = run_cli("resume", out, "--no-progress", "--no-figures", timeout=300)
    assert cp.returncode == 0, cp.stderr
    m = json.loads((out / "MANIFEST.json").read_text())
    assert m["current"]["step"] == 12
    assert cli_in_process("checkpoint", "verify", out).returncode == 0
