"""A wheel loaded from a triangle mesh leaves every mode the same bits: monolithic on 1 and
2 threads, serial DDM, out-of-core, MPI on 2 ranks and a SIGKILLed out-of-core run resumed
(test_wheel3d's small bin, its wheel written as a mesh by tools/make_wheel_meshes.py)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from support.modes import assert_same_state, killed_and_resumed, runs_in_every_mode
from test_wheel3d import BASE as WHEEL3D_BASE

from ooc_dem.model.scenario import load_scenario

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))
from make_wheel_meshes import chevron_wheel  # noqa: E402

pytestmark = pytest.mark.slow

OVERRIDES = [
    *WHEEL3D_BASE,
    "wheel.drop_gap=0.0",
    "wheel.settle_time=0.06",
    "wheel.travel_time=0.006",
    "output.steady_start=0.001",
    "output.steady_end=0.006",
    "output.series_interval=0.0005",
]
STEPS, EVERY = 3200, 800


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    work = tmp_path_factory.mktemp("mesh-modes")
    w = load_scenario("quick-3d", OVERRIDES).wheel
    path = work / "chevron.stl"
    chevron_wheel(w.radius, w.width, w.n_lugs, w.lug_tip_radius, w.lug_thickness).export(path)
    overrides = [*OVERRIDES, f"wheel.mesh={path}"]
    out = runs_in_every_mode("quick-3d", overrides, STEPS, EVERY, work)
    out["_args"] = ("quick-3d", overrides, STEPS, EVERY, work)
    return out


def test_every_mode_gives_the_same_bits_with_a_mesh_wheel(runs):
    ref = runs["monolithic"]
    assert ref.summary["vertical_force"]["whole_travel"]["value"] > 0.0  # the mesh carries the wheel
    for name, res in runs.items():
        if name.startswith("_") or name == "monolithic":
            continue
        assert res.summary["state_hash"] == ref.summary["state_hash"], name
        assert_same_state(ref, res, name)
        for q in ("slip", "torque", "net_traction", "vertical_force"):
            assert res.summary[q] == ref.summary[q], (name, q)


def test_a_sigkilled_mesh_wheel_run_resumes_to_the_same_bits(runs):
    name, overrides, steps, every, work = runs["_args"]
    resumed = killed_and_resumed(name, overrides, steps, every, work / "killed")
    assert_same_state(runs["ooc-hdf5-10"], resumed, "killed and resumed")
