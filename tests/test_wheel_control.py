"""The wheel's control modes beyond a prescribed omega: a driving torque (omega free, the
wheel a rigid body about its axle), towed (omega free, no torque, the carriage at a
speed), braking (negative slip) and the axle's height held (wheel.vertical = fixed)."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

import ooc_dem
from support.cli import cli_in_process
from ooc_dem.engine.stepper import DomainStepper, Model, wheel_inertia
from ooc_dem.model.scenario import load_scenario
from ooc_dem.model.schema import ScenarioError
from ooc_dem.model.state import Particles
from ooc_dem.physics.layout import WS_SIZE, WS_THETA, WS_VX, WS_VY, WS_WZ, WS_X, WS_Y

T = 2.0  # N m, the driving torque of the free-wheel checks


def _free_wheel(overrides, steps):
    """The quick scenario's wheel alone (one disc far from it, at rest on the floor),
    driven ``steps`` steps from t = 0 (no settling): its state after each step."""
    sc = load_scenario(
        "quick",
        [
            "wheel.control=torque",
            f"wheel.torque={T!r}",
            "wheel.settle_time=0.0",
            "wheel.drawbar_load=0.0",
            *overrides,
        ],
    )
    model = Model.from_scenario(sc)
    r = sc.soil.r_max
    p = Particles.new(np.array([[sc.bin.length - 2 * r, r]]), np.array([r]), sc.soil.density, sc.physics.thickness)
    ws = np.zeros(WS_SIZE)
    ws[WS_X], ws[WS_Y] = sc.wheel.x0, 0.2
    st = DomainStepper(p, model, ws)
    states = np.empty((steps, WS_SIZE))
    for s in range(steps):
        st.advance(s, 1)
        states[s] = st.ws
    return sc, states


def test_default_inertia_is_a_uniform_disc():
    sc = load_scenario("quick", ["wheel.control=torque"])
    m = sc.wheel.load / sc.physics.gravity
    assert wheel_inertia(sc) == 0.5 * m * sc.wheel.radius**2
    assert wheel_inertia(load_scenario("quick", ["wheel.inertia=0.02"])) == 0.02


def test_a_free_wheel_accelerates_at_torque_over_inertia():
    """No contact, no ramp: omega_n = n dt T / I (clockwise: wz < 0), to rounding; the axle's
    height held to the bit, and with no drawbar load the carriage does not move."""
    n = 2000
    sc, s = _free_wheel(["wheel.torque_ramp=0.0", "wheel.vertical=fixed"], n)
    dt, inertia = sc.physics.dt, wheel_inertia(sc)
    k = np.arange(1, n + 1)
    assert np.allclose(-s[:, WS_WZ], k * dt * T / inertia, rtol=1e-12, atol=0.0)
    # theta_n = sum of the omegas (leapfrog: the new omega moves the angle), kept in [-2 pi, 2 pi]
    theta = -dt * dt * T / inertia * k * (k + 1) / 2.0
    assert np.allclose(np.cos(s[:, WS_THETA]), np.cos(theta), rtol=0.0, atol=1e-9)
    assert np.all(s[:, WS_Y] == 0.2) and np.all(s[:, WS_VY] == 0.0)
    assert np.all(s[:, WS_X] == sc.wheel.x0) and np.all(s[:, WS_VX] == 0.0)


def test_the_torque_ramps_in_and_inertia_is_read():
    """Ramped over torque_ramp, with a given inertia: step k (at t_k = k dt) adds
    T t_k / ramp / I dt, so omega_n = T dt^2 n (n - 1) / (2 I ramp) while ramping
    (T t^2 / (2 I ramp) to O(dt)), to rounding."""
    n, ramp, inertia = 1000, 0.02, 0.05
    sc, s = _free_wheel([f"wheel.torque_ramp={ramp!r}", f"wheel.inertia={inertia!r}", "wheel.vertical=fixed"], n)
    dt = sc.physics.dt
    assert -s[-1, WS_WZ] == pytest.approx(T * dt * dt * n * (n - 1) / (2.0 * inertia * ramp), rel=1e-10)


def test_a_free_wheel_falls_freely_without_the_height_held():
    n = 500
    sc, s = _free_wheel(["wheel.torque_ramp=0.0"], n)
    dt, g = sc.physics.dt, sc.physics.gravity
    assert s[-1, WS_VY] == pytest.approx(-g * n * dt, rel=1e-12)


def test_carriage_at_speed():
    n = 300
    sc, s = _free_wheel(["wheel.carriage=speed", "wheel.speed=0.05", "wheel.vertical=fixed"], n)
    assert np.all(s[:, WS_VX] == 0.05)
    assert s[-1, WS_X] == pytest.approx(sc.wheel.x0 + 0.05 * n * sc.physics.dt, rel=1e-12)


@pytest.mark.parametrize(
    "override, message",
    [
        (["wheel.control=towed"], "wheel.speed = 0.0: a towed wheel needs a carriage speed > 0"),
        (["wheel.control=spin"], "wheel.control = 'spin': must be one of 'drawbar', 'slip', 'torque', 'towed'"),
        (["wheel.vertical=held"], "wheel.vertical = 'held': must be one of 'free', 'fixed'"),
        (["wheel.carriage=free"], "wheel.carriage = 'free': must be one of 'drawbar', 'speed'"),
        (["wheel.inertia=-1.0"], "wheel.inertia = -1.0: must be a number in [0, 1e+06]"),
    ],
)
def test_bad_control_keys_are_refused(override, message):
    with pytest.raises(ScenarioError, match=re.escape(message)):
        load_scenario("quick", override)


def test_new_keys_at_their_defaults_keep_the_scenario_hash():
    sc = load_scenario("quick")
    same = load_scenario(
        "quick",
        [
            "wheel.torque=0.0",
            "wheel.torque_ramp=1.0",
            "wheel.inertia=0.0",
            "wheel.carriage=drawbar",
            "wheel.speed=0.0",
            "wheel.vertical=free",
        ],
    )
    assert same.hash() == sc.hash() and same.bed_hash() == sc.bed_hash()
    assert load_scenario("quick", ["wheel.vertical=fixed"]).hash() != sc.hash()


# ------------------------------------------------------------- runs on a bed
# the quick bed, the wheel placed on it (no settling, no drop) and driven at once
ON_BED = ["wheel.settle_time=0.0", "wheel.drop_gap=0.0", "output.steady_start=0.1", "output.steady_end=0.2"]


@pytest.fixture(scope="module")
def towed(tmp_path_factory):
    """Towed at 0.1 m/s (R omega = v at omega = 1 rad/s) for 0.6 s; steady window 0.4-0.6 s."""
    over = [
        *ON_BED,
        "wheel.control=towed",
        "wheel.speed=0.1",
        "wheel.travel_time=0.6",
        "output.steady_start=0.4",
        "output.steady_end=0.6",
    ]
    return ooc_dem.run("quick", tmp_path_factory.mktemp("towed") / "run", overrides=over, figures=False)


def test_towed_wheel_rolls_with_a_small_skid(towed):
    """The soil spins the towed wheel up from rest to omega near v / R: over the steady
    window its slip (that of the measured omega) is a skid, s in (-0.3, 0) (measured
    -0.165: the lugs roll it on a radius near the lug tips', 1.1 R, and it stutters
    lug by lug), omega in (0.7, 1.0) rad/s; with no driving torque the soil's mean
    torque is near 0 (|torque| < 0.02 N m, the wheel's inertia only), so the motion
    resistance is the towing force, -net traction > 0; the carriage moves at the
    prescribed speed."""
    s = towed.summary
    slip = s["slip"]["steady"]["value"]
    assert -0.3 < slip < 0.0, slip
    omega = s["omega"]["steady"]["value"]
    assert 0.7 < omega < 1.0, omega
    assert abs(s["torque"]["steady"]["value"]) < 0.02
    towing = -s["net_traction"]["steady"]["value"]
    assert towing > 0.0
    assert s["motion_resistance"]["steady"]["value"] == pytest.approx(towing, abs=0.2)
    assert s["travel_distance"]["whole_travel"]["value"] == pytest.approx(0.1 * 0.6, rel=1e-3)
    series = towed.series
    late = series["t_travel"] > 0.1
    assert np.all(np.isfinite(series["slip"][late]))
    assert np.all(series["drawbar"] == 0.0)


def test_braking_slip(tmp_path):
    """Negative slip, the carriage outrunning the rim (v = (1 - s) R omega): the summary's
    slip is the prescribed one to the window's one-step offset (2e-3); the soil's torque
    falls as the slip goes more negative and turns the rim forward (negative torque,
    braking) past the towed wheel's free-rolling slip (about -0.16, above): at s = -0.2
    the lugs still feel a small positive torque (measured 0.27 N m), at s = -0.5 a
    negative one (-0.23 N m), and the soil pushes the wheel back (net traction < 0)."""
    out = {}
    for slip in (-0.2, -0.5):
        over = [*ON_BED, "wheel.control=slip", f"wheel.slip={slip!r}", "wheel.travel_time=0.2"]
        res = ooc_dem.run("quick", tmp_path / f"run{slip}", overrides=over, figures=False)
        out[slip] = res.summary
        assert res.summary["slip"]["whole_travel"]["value"] == pytest.approx(slip, abs=2e-3)
        assert np.all(np.isfinite(res.series["slip"]))
        assert np.allclose(res.series["slip"], slip, rtol=0.0, atol=1e-9)
    torque = {k: v["torque"]["steady"]["value"] for k, v in out.items()}
    assert torque[-0.5] < 0.0 < torque[-0.2]
    assert out[-0.5]["net_traction"]["steady"]["value"] < 0.0


def test_fixed_height_holds_the_axle_to_the_bit(tmp_path):
    """vertical = fixed: the axle's y stays that at the end of settling, bit for bit; the
    soil's vertical force is measured (finite, pushing up once the lugs bite)."""
    over = ["wheel.settle_time=0.02", "wheel.travel_time=0.05", "wheel.vertical=fixed", "wheel.control=slip"]
    res = ooc_dem.run("quick", tmp_path / "run", overrides=over + ["wheel.slip=0.2"], figures=False)
    rec = res.series
    travel = rec["t_travel"] > 0.0
    y = rec["y"][travel]
    assert np.all(y == y[0])
    assert math.isfinite(res.summary["vertical_force"]["whole_travel"]["value"])


def test_run_prints_the_measured_omega(tmp_path):
    """A free-spinning wheel's run prints its measured omega; a prescribed one's does not."""
    sets = ["--set", "wheel.control=towed", "--set", "wheel.speed=0.1", "--set", "wheel.settle_time=0.0"]
    args = ("--steps", "300", "--no-figures", "--no-progress")
    towed = cli_in_process("run", "quick", *sets, *args, "--out", tmp_path / "towed", check=True)
    assert "wheel omega (measured, rad/s): " in towed.stdout
    plain = cli_in_process("run", "quick", *args, "--out", tmp_path / "plain", check=True)
    assert "wheel omega" not in plain.stdout


def test_a_sweep_takes_braking_slips(tmp_path):
    """sweep --slips=-0.2,0.1: both runs, the CSV in slip order, and the sweep reads back
    (report re-plots it)."""
    sets = [
        a
        for o in ("wheel.settle_time=0.0", "wheel.drop_gap=0.0", "wheel.travel_time=0.01", "output.steady_start=0.0")
        for a in ("--set", o)
    ]
    out = tmp_path / "sweep"
    cli_in_process("sweep", "quick", *sets, "--slips=-0.2,0.1", "--out", out, "--no-progress", check=True)
    data = np.genfromtxt(out / "drawbar_pull_slip.csv", delimiter=",", names=True)
    assert list(data["slip"]) == [-0.2, 0.1]
    cli_in_process("report", out, check=True)
