"""The free-spin wheel controls leave every mode the same bits: a wheel driven by a torque
(omega a state, integrated from the soil's torque) and a towed wheel with its axle's height
held, run monolithic on 1 and 2 threads, serial DDM, out-of-core, MPI on 2 ranks and a
SIGKILLed out-of-core run resumed; in 2D (the quick bed) and 3D (test_wheel3d's small bin)."""

from __future__ import annotations

import numpy as np
import pytest

from support.modes import assert_same_state, killed_and_resumed, runs_in_every_mode
from test_wheel3d import BASE as WHEEL3D_BASE

# mode-equivalence and whole-run checks: outside the fast subset (pytest -m "not slow")
pytestmark = pytest.mark.slow

# (scenario, overrides, steps, checkpoint interval): the wheel placed on the bed, one of its
# 36 lugs pointing down, settles onto it (its lug tips start level with the highest grain
# under its footprint, wherever that is: it falls until it meets the surface), then the torque
# ramps in and turns it within the run
LUGS = ["wheel.n_lugs=36", "wheel.drop_gap=0.0"]
CASES = {
    "2d-torque": (
        "quick",
        [
            "wheel.control=torque",
            "wheel.torque=3.0",
            "wheel.torque_ramp=0.001",
            "wheel.settle_time=0.025",
            *LUGS,
            "output.series_interval=0.0005",
        ],
        3000,
        500,
    ),
    "2d-towed-fixed": (
        "quick",
        [
            "wheel.control=towed",
            "wheel.speed=0.5",
            "wheel.vertical=fixed",
            "wheel.settle_time=0.025",
            *LUGS,
            "output.series_interval=0.0005",
        ],
        3000,
        500,
    ),
    "3d-torque": (
        "quick-3d",
        [
            *WHEEL3D_BASE,
            *LUGS,
            "wheel.settle_time=0.06",  # the wheel lands at 0.05 s (its lug tips start at the highest sphere)
            "wheel.travel_time=0.006",
            "wheel.control=torque",
            "wheel.torque=3.0",
            "wheel.torque_ramp=0.0005",
            "wheel.carriage=speed",
            "wheel.speed=0.2",
            "wheel.vertical=fixed",
            "output.steady_start=0.001",
            "output.steady_end=0.006",
            "output.series_interval=0.0005",
        ],
        3200,
        800,
    ),
}


@pytest.fixture(scope="module", params=sorted(CASES))
def runs(request, tmp_path_factory):
    name, overrides, steps, every = CASES[request.param]
    work = tmp_path_factory.mktemp(f"control-{request.param}")
    out = runs_in_every_mode(name, overrides, steps, every, work)
    out["_args"] = (name, overrides, steps, every, work)
    return out


def test_the_wheel_turns_by_itself(runs):
    """omega is the wheel's own: it turns (free spin) in the soil, and the summary measures it."""
    s = runs["monolithic"].summary
    assert s["vertical_force"]["whole_travel"]["value"] > 0.0
    assert s["omega"]["whole_travel"]["value"] > 0.0
    omega = runs["monolithic"].series["omega"]
    assert np.any(omega > 0.0) and len(np.unique(omega)) > 2


def test_every_mode_gives_the_same_bits_with_a_free_spin(runs):
    ref = runs["monolithic"]
    for name, res in runs.items():
        if name.startswith("_") or name == "monolithic":
            continue
        assert res.summary["state_hash"] == ref.summary["state_hash"], name
        assert_same_state(ref, res, name)
        for q in ("omega", "slip", "torque", "net_traction", "vertical_force"):
            assert res.summary[q] == ref.summary[q], (name, q)


def test_a_sigkilled_free_spin_run_resumes_to_the_same_bits(runs):
    name, overrides, steps, every, work = runs["_args"]
    resumed = killed_and_resumed(name, overrides, steps, every, work / "killed")
    assert_same_state(runs["ooc-hdf5-10"], resumed, "killed and resumed")
    for q in ("omega", "slip", "torque"):
        assert resumed.summary[q] == runs["ooc-hdf5-10"].summary[q], q
