"""The 3D engine in every mode gives the same bits (docs/design.md section 3).

Two levels:
- kernels in the engine: a loose 3D fill falling into the box (spheres moving, contacts
  forming, walls hit) advanced by THE per-domain step monolithic, by the serial-DDM sweep
  with D in {2, 6} and K in {1, 10}, and with 1 and 2 numba threads;
- whole runs (``ooc_dem.run`` / the CLI): the tiled, settled bed ``bed3d-6000`` (the tile
  mirrored along x and across the width, streamed into the store for out-of-core)
  monolithic, DDM D in {2, 6}, out-of-core HDF5 and zarr with K in {1, 10}, and a run
  SIGKILLed mid-way and resumed.
Every comparison is ``np.array_equal`` on every state array plus the canonical hash.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import numba
import numpy as np
import pytest
from support.cli import cli_in_process, run_cli
from support.state import assert_same_state
from support.stores import committed_step

import ooc_dem
from ooc_dem.app.bed import initial_fill
from ooc_dem.model.checkpoint import hash_particles
from ooc_dem.engine import stepper as stp
from ooc_dem.engine.stepper import DomainStepper, Model
from ooc_dem.engine.sweep import sweep_run
from ooc_dem.physics.layout import AX_Y
from ooc_dem.model.scenario import load_scenario
from ooc_dem.model.state import Particles

# mode-equivalence and whole-run checks: outside the fast subset (pytest -m "not slow")
pytestmark = pytest.mark.slow

STEPS = 400
FILL = ["soil.n=1200", "bin.length=0.06", "bin.width=0.04"]


@pytest.fixture(scope="module")
def fill():
    """A loose fill 0.08 s into its fall: the lower layers are landing."""
    sc = load_scenario("bed3d", FILL)
    st = DomainStepper(initial_fill(sc), Model.from_scenario(sc))
    st.advance(0, 8000)
    return sc, st.p.sorted_by_id()


def _copy(p: Particles) -> Particles:
    return p.take(np.arange(len(p)))


def _monolithic(sc, p, threads=None, steps=STEPS):
    old = numba.get_num_threads()
    if threads is not None:
        numba.set_num_threads(threads)
    try:
        st = DomainStepper(_copy(p), Model.from_scenario(sc))
        st.advance(0, steps)
        return st.p
    finally:
        numba.set_num_threads(old)


def test_fill_moves_and_touches(fill):
    """The comparison below proves something: spheres fall, hit the floor and each other."""
    sc, p = fill
    q = _monolithic(sc, p, steps=STEPS)
    assert q.dim == 3 and q.pos.shape == (1200, 3) and q.hist_s.shape[2] == 3
    moved = np.abs(q.pos - p.sorted_by_id().pos).max(axis=1)
    assert np.abs(q.vel[:, AX_Y]).max() > 0.3 and np.median(moved) > 1e-3
    assert q.hist_n.sum() > 600 and np.abs(q.spin).max() > 1.0
    walls = q.hist_id[np.arange(q.hist_cap)[None, :] < q.hist_n[:, None]]
    assert {-5, -4, -3, -2, -1} <= set(walls[walls < 0].tolist())


@pytest.mark.parametrize("domains,block", [(2, 1), (2, 10), (6, 1), (6, 10)])
def test_ddm_sweep_equals_monolithic(fill, domains, block):
    sc, p = fill
    ref = _monolithic(sc, p)
    q, _, _, _ = sweep_run(sc, _copy(p), np.zeros(6), STEPS, domains=domains, block=block)
    assert_same_state(ref, q)
    assert hash_particles(ref, None, STEPS) == hash_particles(q, None, STEPS)


def test_one_and_two_threads(fill, monkeypatch):
    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("one core")
    sc, p = fill
    monkeypatch.setattr(stp, "SERIAL_BELOW", 0)  # the parallel path even for this bed
    assert_same_state(_monolithic(sc, p, threads=1), _monolithic(sc, p, threads=2))


# ------------------------------------------------------------------- whole runs
BED = "bed3d-6000"
RUN_STEPS = 100


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    work = tmp_path_factory.mktemp("d3runs")
    out = {}
    t0 = time.time()
    out["monolithic"] = ooc_dem.run(BED, work / "mono", steps=RUN_STEPS)
    for d in (2, 6):
        out[f"ddm-{d}"] = ooc_dem.run(BED, work / f"ddm{d}", mode="ddm", domains=d, steps=RUN_STEPS)
    for backend in ("hdf5", "zarr"):
        for k in (1, 10):
            out[f"ooc-{backend}-{k}"] = ooc_dem.run(
                BED,
                work / f"ooc-{backend}-{k}",
                mode="ooc",
                backend=backend,
                domains=3,
                block=k,
                steps=RUN_STEPS,
                checkpoint_every=50,
            )
    out["_seconds"] = time.time() - t0
    return out


def test_runs_of_every_mode_give_the_same_state(runs):
    ref = runs["monolithic"]
    h = ref.summary["state_hash"]
    s0 = ref.state()
    assert s0["pos"].shape == (6000, 3) and s0["spin"].shape == (6000, 3)
    assert s0["hist_s"].shape[1:] == (12, 3) and s0["hist_m"].shape[1:] == (12, 3)
    for name, res in runs.items():
        if name.startswith("_") or name == "monolithic":
            continue
        assert res.summary["state_hash"] == h, name
        s = res.state()
        assert s.keys() == s0.keys()
        for k in s0:
            assert np.array_equal(s0[k], s[k]), (name, k)


def test_tiled_bed_is_settled_and_seams_hold(runs):
    """The mirrored tiles meet without overlap: the bed barely moves in 100 steps."""
    s = runs["monolithic"].state()
    assert len(np.unique(s["id"])) == 6000
    speed = np.sqrt((s["vel"] ** 2).sum(axis=1))
    assert speed.mean() < 0.05


def test_sigkill_then_resume_gives_the_same_bits(runs, tmp_path):
    """ooc HDF5 K=10, checkpoint every 20 steps: killed after its first commit, resumed."""
    out = tmp_path / "killed"
    ref = runs["ooc-hdf5-10"].summary["state_hash"]
    cmd = [
        sys.executable,
        "-m",
        "ooc_dem.cli",
        "run",
        BED,
        "--mode",
        "ooc",
        "--domains",
        "3",
        "--block",
        "10",
        "--steps",
        str(RUN_STEPS),
        "--checkpoint-every",
        "20",
        "--out",
        str(out),
        "--no-progress",
        "--no-figures",
    ]
    proc = subprocess.Popen(
        cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=dict(os.environ), start_new_session=True
    )
    deadline = time.time() + 300
    killed = False
    while time.time() < deadline and proc.poll() is None:
        if committed_step(out) > 0:
            time.sleep(0.3)
            proc.send_signal(signal.SIGKILL)
            killed = True
            break
        time.sleep(0.05)
    proc.wait(timeout=60)
    if not killed:
        pytest.skip("the run finished before it could be killed")
    assert proc.returncode == -9
    cp = run_cli("resume", out, "--no-progress", "--no-figures", check=True)
    assert f"state hash: {ref}" in cp.stdout
    cli_in_process("checkpoint", "verify", out, check=True)
    a, b = ooc_dem.open_run(out).state(), runs["ooc-hdf5-10"].state()
    for k in a:
        assert np.array_equal(a[k], b[k]), k


def test_tile_share_takes_the_division_noise_away():
    """A bin n tiles across gives the tile of the base bin (0.6 m / 6 is the 0.1 m tile of
    0.2 m / 2, the same settled tile), so that a domain study compares the same soil; a
    share that is not a short decimal stays the quotient."""
    from ooc_dem.model.scenario_check import tile_scenario, tile_share
    from ooc_dem.model.scenario import load_scenario

    assert 0.6 / 6 != 0.1 and tile_share(0.6, 6) == 0.1
    assert tile_share(8.6, 86) == 0.1 and tile_share(0.2, 2) == 0.1
    assert tile_share(1.0, 3) == 1.0 / 3
    base = load_scenario("paper2008-3d")
    wide = load_scenario("paper2008-3d", ["bin.width=0.6", "bed.tiles_across=6", "soil.n=30000"])
    assert tile_scenario(wide).bed_hash() == tile_scenario(base).bed_hash()
    assert tile_scenario(wide).bin.width == 0.1
