"""3D scenarios: the new keys are validated like every other (one line naming
the key, exit 2), the time-step check covers both contact laws, the built-ins load."""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_hostile_input import MAX_STEPS, SCENARIO_KEYS, _hostile_values

from ooc_dem import cli
from ooc_dem.engine.stepper import Model
from ooc_dem.physics.d3 import layout as L3
from ooc_dem.model.scenario import ScenarioError, load_scenario
from ooc_dem.model.scenario_check import critical_time_step


@pytest.mark.parametrize("key,default", SCENARIO_KEYS, ids=[k for k, _ in SCENARIO_KEYS])
def test_every_key_of_a_3d_scenario_at_extreme_values(key, default, capsys):
    for value in _hostile_values(default):
        rc = cli.main(["check", "bed3d", "--set", f"{key}={value}"])
        captured = capsys.readouterr()
        where = f"{key}={value[:40]}"
        if rc == 0:
            plan = json.loads(captured.out)
            assert 0 <= plan["steps"] <= MAX_STEPS, where
            for k in ("simulated_time_s", "dt_s", "dt_critical_s", "memory_bytes"):
                assert np.isfinite(plan[k]) and plan[k] >= 0, (where, k, plan[k])
            assert plan["dt_s"] <= plan["dt_critical_s"], where
            continue
        assert rc == 2, where
        lines = [ln for ln in captured.err.splitlines() if ln.strip()]
        assert len(lines) == 1 and "Traceback" not in captured.err, (where, captured.err[-2000:])
        assert key in lines[0], (where, lines[0])


@pytest.mark.parametrize(
    "overrides,needle",
    [
        (["physics.dim=4"], "physics.dim"),
        (['contact.soil_soil.law="hertz"', "physics.dim=2", "wheel.enabled=false"], "contact.soil_soil.law"),
        (['contact.soil_wall.law="coulomb"'], "contact.soil_wall.law"),
        (["wheel.enabled=true"], "wheel.z0"),  # a 0.1 m wheel across a 0.05 m bin
        (["bin.width=0.004"], "bin.width"),
        (["contact.soil_soil.poisson_ratio=0.5"], "contact.soil_soil.poisson_ratio"),
        (["contact.soil_soil.restitution=0"], "contact.soil_soil.restitution"),
        (["contact.soil_soil.youngs_modulus=1e12"], "physics.dt"),  # Hertz step check
        (["contact.soil_wall.kn=1e9"], "contact.soil_wall"),  # linear step check
        (["bed.tiles_across=0"], "bed.tiles_across"),
    ],
)
def test_bad_3d_values_are_one_line_errors(overrides, needle):
    with pytest.raises(ScenarioError) as e:
        load_scenario("bed3d", overrides)
    msg = str(e.value)
    assert needle in msg and "\n" not in msg, msg


def test_time_step_check_covers_both_laws():
    sc = load_scenario("bed3d")
    crit = critical_time_step(sc)
    assert sc.physics.dt <= crit < 1e-4
    # stiffer Hertz soil: a smaller critical step; a faster impact: smaller still
    stiff = critical_time_step(load_scenario("bed3d", ["contact.soil_soil.youngs_modulus=1e9", "physics.dt=1e-6"]))
    fast = critical_time_step(
        load_scenario("bed3d", ["contact.soil_soil.youngs_modulus=1e9", "physics.dt=1e-6", "physics.impact_speed=10"])
    )
    assert fast < stiff < crit
    lin = load_scenario(
        "bed3d", ['contact.soil_soil.law="linear"', "contact.soil_soil.kn=1e4", "contact.soil_soil.ks=3e3"]
    )
    assert critical_time_step(lin) > 0


def test_model_of_a_3d_scenario_chooses_the_law_per_pair():
    sc = load_scenario("bed3d")
    m = Model.from_scenario(sc)
    assert m.dim == 3 and m.gravity.tolist() == [0.0, -9.8, 0.0]
    kp = m.kernel_params()
    assert kp.cp.dtype == L3.CONTACT_PARAMS and kp.walls.dtype == L3.WALLS
    assert kp.cp[L3.T_SOIL, L3.T_SOIL]["law"] == L3.LAW_HERTZ
    assert kp.cp[L3.T_WALL, L3.T_SOIL]["law"] == L3.LAW_LINEAR
    assert kp.cp[L3.T_SOIL, L3.T_WALL]["kn"] == 5.0e4
    assert kp.walls[0]["width"] == 0.05 and kp.walls[0]["length"] == 0.05


def test_builtins_and_bed3d_n():
    names = cli.main(["scenarios"])
    assert names == 0
    sc = load_scenario("bed3d-20k")
    assert sc.soil.n == 20000 and sc.dim == 3
    assert sc.bin.width == 0.1 and sc.bin.length == pytest.approx(0.05 * 5)
    for bad in ("bed3d-0", "bed3d-x", "bed3d-1.5"):
        with pytest.raises(ScenarioError, match="bed3d-N"):
            load_scenario(bad)


def test_2d_hashes_unchanged_by_the_new_keys():
    """The keys added for 3D are left out of the hashes at their defaults: 2D scenarios keep
    their hashes (stores written before resume) and bed caches."""
    assert load_scenario("quick").hash().startswith("b61a6bd91d1e")
    assert load_scenario("bed").bed_hash() == "61f75d2e791e92e7"
