"""Materials folded into the contact pairs (model.materials), the restitution as an input
and the no-tension clamp as a key: the pairs' values against hand-computed ones, and the
rebound of a pair and of a wall against the stated restitution."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ooc_dem.engine.stepper import DomainStepper, Model
from ooc_dem.model.materials import restitution_of_zeta, zeta_of_restitution
from ooc_dem.model.scenario import load_scenario
from ooc_dem.model.contacts import contact_table_3d
from ooc_dem.model.schema import ScenarioError, clamps
from ooc_dem.model.state import Particles
from ooc_dem.physics.d3 import layout as L3
from ooc_dem.physics.layout import AX_X, AX_Y, T_SOIL, T_WHEEL, WC_SIZE, WG_SIZE
from support.cli import cli_in_process, one_line_error
from support.sim3d import Sim, make_spheres
from support.threads import one_numba_thread  # noqa: F401


def _estar(e1, n1, e2, n2):
    return 1.0 / ((1 - n1 * n1) / e1 + (1 - n2 * n2) / e2)


def test_a_steel_wheel_on_quartz_is_two_lines():
    """[materials.wheel] preset = "steel" on quartz soil: the soil-wheel pair's E* is the
    Hertz combination of the two, with nothing computed by hand."""
    sc = load_scenario(
        "quick-3d",
        ["materials.soil.preset='quartz'", "materials.wheel.preset='steel'", "contact.soil_soil.youngs_modulus=5e7"],
    )
    w = sc.contact.soil_wheel
    assert w.law == "hertz"
    # the pair's own youngs_modulus (5e7, the scenario's) is kept; the wheel's surface is steel
    assert (w.youngs_modulus_2, w.poisson_ratio_2) == (2.0e11, 0.30)
    cp = contact_table_3d(sc)
    expect = _estar(w.youngs_modulus, w.poisson_ratio, 2.0e11, 0.30)
    assert cp[T_WHEEL, T_SOIL]["estar"] == pytest.approx(expect, rel=1e-15)


def test_mixing_rules_and_explicit_pairs():
    """Friction, restitution, rolling friction, cohesion: the smaller of the two materials'
    values; a key the pair sets wins; a material without a value leaves the other's; a pair
    of two elastic materials is Hertz, its second surface the other body's."""
    from ooc_dem.model.scenario import scenario_from_dict

    soil = {"youngs_modulus": 1e8, "poisson_ratio": 0.25, "friction": 0.6, "restitution": 0.4, "cohesion": 500.0}
    wheel = {"youngs_modulus": 7e10, "poisson_ratio": 0.33, "friction": 0.3, "restitution": 0.7}
    sc = scenario_from_dict(
        {
            "physics": {"dim": 3, "dt": 1e-6},
            "materials": {"soil": soil, "wheel": wheel, "wall": {"friction": 0.9}},
            "contact": {"soil_wheel": {"rolling_friction": 0.05}, "soil_wall": {"friction": 0.2}},
        }
    )
    ss, sw, sl = sc.contact.soil_soil, sc.contact.soil_wheel, sc.contact.soil_wall
    assert (ss.law, ss.friction, ss.restitution, ss.cohesion) == ("hertz", 0.6, 0.4, 500.0)
    assert (sw.friction, sw.restitution, sw.cohesion, sw.rolling_friction) == (0.3, 0.4, 500.0, 0.05)
    assert (sw.law, sw.youngs_modulus, sw.youngs_modulus_2) == ("hertz", 1e8, 7e10)
    # the wall: no elastic constants, so the linear law, its damping from the soil's restitution
    assert (sl.law, sl.friction, sl.cohesion) == ("linear", 0.2, 500.0)
    assert sl.damping_n == zeta_of_restitution(0.4)


def test_restitution_and_damping_given_both_must_agree():
    """A linear pair's damping is stated once: both keys in a table must agree (a stored
    scenario writes both); a --set of one replaces the other."""
    from ooc_dem.model.scenario import scenario_from_dict

    with pytest.raises(ScenarioError, match="disagree"):
        scenario_from_dict({"contact": {"soil_soil": {"restitution": 0.3, "damping_n": 0.9}}})
    ok = scenario_from_dict({"contact": {"soil_soil": {"restitution": 0.3, "damping_n": zeta_of_restitution(0.3)}}})
    assert ok.contact.soil_soil.restitution == 0.3
    sc = load_scenario("quick", ["contact.soil_soil.damping_n=0.9"])
    assert sc.contact.soil_soil.damping_n == 0.9


def test_stiffness_soil_gives_the_wheel_the_soils_elastic_constants():
    sc = load_scenario(
        "quick-3d",
        [
            "materials.soil.youngs_modulus=5e7",
            "materials.soil.poisson_ratio=0.3",
            "materials.wheel.preset='steel'",
            "materials.wheel.stiffness='soil'",
        ],
    )
    w = sc.contact.soil_wheel
    assert (w.youngs_modulus_2, w.poisson_ratio_2) == (5e7, 0.3)


@pytest.mark.parametrize(
    "override, needle",
    [
        ("materials.wheel.preset='unobtainium'", "materials.wheel.preset"),
        ("materials.moon.friction=0.3", "materials.moon"),
        ("materials.soil.stiffness='soil'", "materials.soil.stiffness"),
        ("materials.wheel.friction='high'", "materials.wheel.friction"),
        ("contact.soil_soil.no_tension=3", "contact.soil_soil.no_tension"),
        ("contact.soil_soil.cohesion=-1.0", "contact.soil_soil.cohesion"),
    ],
)
def test_bad_materials_are_one_line_errors(override, needle):
    one_line_error(cli_in_process("check", "quick-3d", "--set", override), needle)


def test_elastic_constants_in_2d_are_refused():
    with pytest.raises(ScenarioError, match="physics.dim = 3"):
        load_scenario("quick", ["materials.soil.preset='quartz'"])


def test_defaults_keep_todays_clamp_and_hashes():
    """The clamp defaults as before (linear on, Hertz off); an explicit key is written and
    read back; the built-ins' hashes do not see the new keys."""
    sc = load_scenario("quick-3d")
    assert clamps(sc.contact.soil_wall) and not clamps(sc.contact.soil_soil)
    assert sc.contact.soil_soil.no_tension is None
    sc2 = load_scenario("quick-3d", ["contact.soil_soil.no_tension=true"])
    assert clamps(sc2.contact.soil_soil) and sc2.hash() != sc.hash()
    from ooc_dem.model.scenario import scenario_from_toml

    assert scenario_from_toml(sc2.to_toml()) == sc2
    assert scenario_from_toml(sc.to_toml()) == sc
    assert load_scenario("quick-3d", ["contact.soil_soil.no_tension=false"]).hash() == sc.hash()


# ------------------------------------------------------------ restitution
def test_restitution_and_damping_ratio_are_inverse():
    for e in (0.05, 0.3, 0.5, 0.9, 1.0):
        assert restitution_of_zeta(zeta_of_restitution(e)) == pytest.approx(e, rel=1e-12)


E_TARGET = 0.3


def _rebound_2d(model_cp, pair: bool):
    """e of a disc on the floor (pair False) or of two equal discs head-on, no gravity."""
    r, b = 0.01, 0.1
    if pair:
        pos = np.array([[0.5 - r - 1e-5, 0.5], [0.5 + r + 1e-5, 0.5]])
        vel = [[0.25, 0.0], [-0.25, 0.0]]
    else:
        pos = np.array([[0.5, r + 1e-5]])
        vel = [[0.0, -0.5]]
    p = Particles.new(pos, np.full(len(pos), r), 2000.0, b)
    p.vel[:] = vel
    walls = np.array([1.0e3, 0.0, 0.0, 1.0])
    m = float(p.mass[0])
    kn = model_cp[0, 0, 0] if pair else model_cp[1, 0, 0]
    tc = math.pi * math.sqrt((0.5 * m if pair else m) / kn)
    dt = tc / 1000
    model = Model(dt, np.zeros(2), 0.2 * r, model_cp, walls, np.zeros(WG_SIZE), np.zeros(WC_SIZE), False, r)
    DomainStepper(p, model, reorder=False).advance(0, int(3 * tc / dt))
    if pair:
        return (p.vel[1, AX_X] - p.vel[0, AX_X]) / 0.5
    return p.vel[0, AX_Y] / 0.5


@pytest.mark.parametrize("pair", [True, False], ids=["pair", "wall"])
def test_restitution_as_input_2d(pair):
    """2D linear law, restitution = 0.3 given instead of damping_n, the clamp off: the
    rebound's e within 2 % of 0.3 (a disc on the floor and two discs head-on)."""
    key = "soil_soil" if pair else "soil_wall"
    sc = load_scenario("quick", [f"contact.{key}.restitution={E_TARGET}", f"contact.{key}.no_tension=false"])
    assert getattr(sc.contact, key).damping_n == pytest.approx(zeta_of_restitution(E_TARGET))
    e = _rebound_2d(Model.from_scenario(sc).cp, pair)
    assert e == pytest.approx(E_TARGET, rel=0.02)


@pytest.mark.parametrize("law", ["linear", "hertz"])
@pytest.mark.parametrize("pair", [True, False], ids=["pair", "wall"])
def test_restitution_as_input_3d(law, pair):
    """3D, restitution = 0.3 stated on the pair, the clamp off: e within 2 %."""
    key = "soil_soil" if pair else "soil_wall"
    sets = [f"contact.{key}.law='{law}'", f"contact.{key}.restitution={E_TARGET}", f"contact.{key}.no_tension=false"]
    if law == "linear":
        sets += [f"contact.{key}.kn=5e4", f"contact.{key}.ks=2e4"]
    sc = load_scenario("quick-3d", sets)
    cp = contact_table_3d(sc)
    r, v = 0.005, 0.5
    walls = L3.walls_record(1.0, 1.0, left=False, right=False, bottom=not pair, front=False, back=False)
    if pair:
        s = make_spheres([[0.5 - r - 1e-5, 0.5, 0.5], [0.5 + r + 1e-5, 0.5, 0.5]], r, density=2650.0)
        s.vel[:, 0] = [0.5 * v, -0.5 * v]
    else:
        s = make_spheres([[0.5, r + 1e-5, 0.5]], r, density=2650.0, vel=[[0.0, -v, 0.0]])
    sim = Sim(s, cp, walls, 2e-7, gravity=(0, 0, 0))
    sim.advance(20_000)
    e = (s.vel[1, 0] - s.vel[0, 0]) / v if pair else s.vel[0, 1] / v
    assert e == pytest.approx(E_TARGET, rel=0.02)
