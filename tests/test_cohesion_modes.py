"""Cohesion leaves every mode the same bits: monolithic on 1 and 2 threads, serial DDM,
out-of-core, MPI on 2 ranks and a SIGKILLed out-of-core run resumed, in 2D (the wheel
on a cohesive soil) and 3D (a cohesive bed of spheres)."""

from __future__ import annotations

import pytest

import ooc_dem
from support.modes import assert_same_state, killed_and_resumed, runs_in_every_mode

# mode-equivalence and whole-run checks: outside the fast subset (pytest -m "not slow")
pytestmark = pytest.mark.slow

CASES = {
    "2d": (
        "quick",
        [
            "contact.soil_soil.cohesion=2000.0",
            "contact.soil_wheel.cohesion=1000.0",
            "contact.soil_soil.no_tension=false",
            "wheel.control=slip",
            "wheel.slip=0.2",
            "wheel.omega=4.0",
            "wheel.settle_time=0.0",
            "wheel.drop_gap=0.0",
        ],
        400,
    ),
    "3d": ("bed3d-3000", ["contact.soil_soil.cohesion=3000.0", "contact.soil_wall.cohesion=1000.0"], 80),
}


@pytest.fixture(scope="module", params=sorted(CASES))
def runs(request, tmp_path_factory):
    name, overrides, steps = CASES[request.param]
    work = tmp_path_factory.mktemp(f"cohesion-{request.param}")
    out = runs_in_every_mode(name, overrides, steps, 20, work, timeout=600)
    out["_bare"] = ooc_dem.run(name, work / "bare", steps=steps)  # the same run without cohesion
    out["_args"] = (name, overrides, steps, work)
    return out


def test_cohesion_acts(runs):
    assert runs["monolithic"].summary["state_hash"] != runs["_bare"].summary["state_hash"]


def test_every_mode_gives_the_same_bits_with_cohesion(runs):
    ref = runs["monolithic"]
    for name, res in runs.items():
        if name.startswith("_") or name == "monolithic":
            continue
        assert res.summary["state_hash"] == ref.summary["state_hash"], name
        assert_same_state(ref, res, name)


def test_a_sigkilled_cohesive_run_resumes_to_the_same_bits(runs):
    name, overrides, steps, work = runs["_args"]
    resumed = killed_and_resumed(name, overrides, steps, 20, work / "killed")
    assert_same_state(runs["ooc-hdf5-10"], resumed, "killed and resumed")
