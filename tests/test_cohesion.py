"""Cohesion (simplified JKR, physics.cohesion) against analytic answers, 2D and 3D.

The model: while two bodies overlap by delta, an attraction k_c A(delta) acts along the
normal, A the contact area of the overlap (3D: pi a^2, a the radius of the lens of two
spheres, a^2 = delta (2 R - delta) for a sphere on a wall; 2D: the chord 2 a times the
discs' thickness). The elastic laws: Hertz F = (4/3) E* sqrt(R*) delta^1.5 (3D), linear
F = kn delta (2D). Units SI; tolerances in each docstring.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import brentq, minimize_scalar

from ooc_dem.engine.stepper import DomainStepper, Model
from ooc_dem.model.state import Particles
from ooc_dem.physics.d2 import layout as L2
from ooc_dem.physics.d2.contact import contact_force
from ooc_dem.physics.d3 import layout as L3
from ooc_dem.physics.layout import AX_X, AX_Y, WC_SIZE, WG_SIZE
from support.sim3d import Sim, make_spheres
from support.threads import one_numba_thread  # noqa: F401

E, NU = 1.0e7, 0.3
RHO = 2650.0
R3 = 0.005


def lens_a2(ra, rb, d):
    """a^2 of the overlap of two spheres (discs) of radii ra, rb at distance d (the
    symmetric form, not the kernel's)."""
    return ((ra + rb) ** 2 - d * d) * (d * d - (ra - rb) ** 2) / (4.0 * d * d)


def plane_a2(r, delta):
    return delta * (2.0 * r - delta)


# ------------------------------------------------------------------ 3D
def _walls3(bottom=False):
    return L3.walls_record(1.0, 1.0, left=False, right=False, bottom=bottom, front=False, back=False)


def test_static_pair_force_3d():
    """Two spheres at rest overlapping by delta: the normal force on b is
    (4/3) E* sqrt(R*) delta^1.5 - k_c pi a^2 (relative 1e-9)."""
    ra, rb, delta, kc = 0.005, 0.004, 2.0e-5, 2.0e5
    cp = L3.contact_table({(0, 0): L3.hertz_params(E, NU, 0.5, E2=E, nu2=NU, kc=kc)})
    d = ra + rb - delta
    s = make_spheres([[0.3, 0.5, 0.5], [0.3 + d, 0.5, 0.5]], [ra, rb], density=RHO)
    sim = Sim(s, cp, _walls3(), 1e-7, gravity=(0, 0, 0), keep_forces=True)
    sim.advance(1)
    rstar = ra * rb / (ra + rb)
    estar = E / (2.0 * (1.0 - NU * NU))
    expect = 4.0 / 3.0 * estar * math.sqrt(rstar) * delta**1.5 - kc * math.pi * lens_a2(ra, rb, d)
    assert expect < 0.0  # this overlap is held by cohesion: the pair attracts
    assert sim.forces.force[1, 0] == pytest.approx(expect, rel=1e-9)
    assert sim.forces.force[0, 0] == -sim.forces.force[1, 0]


def test_equilibrium_overlap_under_zero_load_3d():
    """Two equal spheres released just touching, no gravity: they settle where the Hertz
    force equals the cohesion, (4/3) E* sqrt(R*) delta^1.5 = k_c pi a^2(delta)
    (relative 1e-3 on delta)."""
    kc = 1.0e5
    cp = L3.contact_table({(0, 0): L3.hertz_params(E, NU, 0.2, E2=E, nu2=NU, kc=kc)})
    rstar, estar = 0.5 * R3, E / (2.0 * (1.0 - NU * NU))
    d0 = 2 * R3 - 1e-7
    s = make_spheres([[0.3, 0.5, 0.5], [0.3 + d0, 0.5, 0.5]], R3, density=RHO)
    sim = Sim(s, cp, _walls3(), 2e-6, gravity=(0, 0, 0))
    sim.advance(100_000)  # 0.2 s: ~30 periods of the bond
    delta = 2 * R3 - (s.pos[1, 0] - s.pos[0, 0])

    def net(x):
        return 4.0 / 3.0 * estar * math.sqrt(rstar) * x**1.5 - kc * math.pi * lens_a2(R3, R3, 2 * R3 - x)

    expect = brentq(net, 1e-9, 1e-3)
    assert delta == pytest.approx(expect, rel=1e-3)
    assert np.abs(s.vel).max() < 1e-6


def _hanging_limit_3d(kc, estar):
    """The largest pull a sphere stuck to a wall survives: the maximum over delta of
    k_c pi delta (2R - delta) - (4/3) E* sqrt(R) delta^1.5, and its overlap."""
    f = lambda x: -(kc * math.pi * plane_a2(R3, x) - 4.0 / 3.0 * estar * math.sqrt(R3) * x**1.5)  # noqa: E731
    res = minimize_scalar(f, bounds=(1e-9, 1e-3), method="bounded", options={"xatol": 1e-13})
    return -res.fun, res.x, f


@pytest.mark.parametrize("fraction, holds", [(0.9, True), (1.1, False)])
def test_sphere_hangs_under_a_plate_up_to_the_limit_load_3d(fraction, holds):
    """A sphere stuck under a plate (the floor with gravity pointing away from it), its
    weight raised slowly to 0.9 / 1.1 of the analytic limit load
    max_delta [k_c pi delta (2R - delta) - (4/3) E* sqrt(R) delta^1.5]: at 0.9 it hangs at
    the stable overlap of that load (relative 2e-2), at 1.1 it falls."""
    kc = 1.5e5
    estar = E / (1.0 - NU * NU)
    cp = L3.contact_table({(L3.T_WALL, L3.T_SOIL): L3.hertz_params(E, NU, 0.2, kc=kc)})
    flim, dstar, f = _hanging_limit_3d(kc, estar)
    s = make_spheres([[0.5, R3 - 1e-7, 0.5]], R3, density=RHO)
    m = float(s.mass[0])
    g_end = fraction * flim / m
    sim = Sim(s, cp, _walls3(bottom=True), 2e-6, gravity=(0, 0, 0))
    sim.advance(20_000)  # stuck at the zero-load overlap
    ramp = 100
    for k in range(1, ramp + 1):
        sim.kp.gravity[AX_Y] = g_end * k / ramp
        sim.advance(1000)  # 0.2 s in all: quasi-static against the ~5 ms bond period
    sim.advance(25_000)
    y = float(s.pos[0, AX_Y])
    if holds:
        load = fraction * flim
        expect = brentq(lambda x: -f(x) - load, dstar, 1e-3)  # the stable root beyond delta*
        assert R3 - y == pytest.approx(expect, rel=2e-2)
    else:
        assert y > R3 + 1e-4, y


def test_linear_cohesion_that_outgrows_the_spring_is_refused():
    """3D linear law: k_c 2 pi R* >= kn has no equilibrium; the scenario check says so."""
    from ooc_dem.model.scenario import load_scenario
    from ooc_dem.model.schema import ScenarioError

    with pytest.raises(ScenarioError, match="cohesion outgrows the spring"):
        load_scenario("quick-3d", ["contact.soil_soil.law='linear'", "contact.soil_soil.cohesion=1e9"])


# ------------------------------------------------------------------ 2D
B = 0.1  # disc thickness
R2 = 0.01
KN = 1.0e5


def _model2(dt, cp, bottom=False, gy=0.0):
    walls = np.array([1.0e3, 0.0, 0.0, float(bottom)])
    return Model(
        dt=dt,
        gravity=np.array([0.0, gy]),
        skin=0.2 * R2,
        cp=cp,
        walls=walls,
        wg=np.zeros(WG_SIZE),
        wc=np.zeros(WC_SIZE),
        wheel_enabled=False,
        r_max=R2,
    )


def _table2(pair=None, wall=None):
    cp = np.zeros((3, 3, L2.N_FIELDS))
    if pair is not None:
        cp[0, 0] = pair
    if wall is not None:
        cp[1, 0] = cp[0, 1] = wall
    return cp


def _discs(x, y):
    x = np.atleast_1d(np.asarray(x, float))
    pos = np.column_stack([x, np.broadcast_to(np.asarray(y, float), x.shape)])
    return Particles.new(pos, np.full(len(x), R2), 2000.0, B)


def test_static_pair_force_2d():
    """The 2D law at rest: kn delta - k_c b 2 a, a^2 the half-chord of the two discs'
    overlap (relative 1e-9); with k_c = 0 the force is exactly kn delta."""
    ra, rb, delta, kc = 0.01, 0.008, 3e-5, 4e4
    d = ra + rb - delta
    out = contact_force(
        1.0,
        0.0,
        delta,
        0.0,
        0.0,
        0.0,
        0.0,
        ra,
        rb,
        0.01,
        1e-6,
        0.005,
        0.0,
        0.0,
        KN,
        KN / 3,
        0.5,
        0.5,
        0.5,
        0.0,
        0.0,
        1e-6,
        1.0,
        kc * B,
    )
    expect = KN * delta - kc * B * 2.0 * math.sqrt(lens_a2(ra, rb, d))
    assert out[0] == pytest.approx(expect, rel=1e-9)
    bare = contact_force(
        1.0,
        0.0,
        delta,
        0.0,
        0.0,
        0.0,
        0.0,
        ra,
        rb,
        0.01,
        1e-6,
        0.005,
        0.0,
        0.0,
        KN,
        KN / 3,
        0.5,
        0.5,
        0.5,
        0.0,
        0.0,
        1e-6,
    )
    assert bare[0] == KN * delta


def test_equilibrium_overlap_under_zero_load_2d():
    """Two equal discs released just touching: they settle where kn delta = k_c b 2 a(delta)
    (relative 1e-3)."""
    kc = 2.0e4
    cp = _table2(pair=L2.linear_params(KN, KN / 3, 0.3, 0.3, no_tension=False, kc=kc * B))
    p = _discs([0.5, 0.5 + 2 * R2 - 1e-7], 0.5)
    st = DomainStepper(p, _model2(2e-6, cp), reorder=False)
    st.advance(0, 100_000)
    delta = 2 * R2 - (p.pos[1, AX_X] - p.pos[0, AX_X])
    expect = brentq(lambda x: KN * x - kc * B * 2.0 * math.sqrt(lens_a2(R2, R2, 2 * R2 - x)), 1e-12, 1e-3)
    assert delta == pytest.approx(expect, rel=1e-3)


@pytest.mark.parametrize("fraction, holds", [(0.9, True), (1.1, False)])
def test_disc_hangs_under_a_wall_up_to_the_limit_load_2d(fraction, holds):
    """A disc stuck under a wall, its weight raised slowly to 0.9 / 1.1 of the analytic
    limit max_delta [k_c b 2 sqrt(delta (2R - delta)) - kn delta]: at 0.9 it hangs at the
    stable overlap (relative 2e-2), at 1.1 it falls."""
    kc = 1.8e4
    kc_b = kc * B
    cp = _table2(wall=L2.linear_params(KN, KN / 3, 0.3, 0.3, no_tension=False, kc=kc_b))
    net = lambda x: kc_b * 2.0 * math.sqrt(plane_a2(R2, x)) - KN * x  # noqa: E731
    res = minimize_scalar(lambda x: -net(x), bounds=(1e-12, 1e-3), method="bounded", options={"xatol": 1e-14})
    flim, dstar = -res.fun, res.x
    p = _discs([0.5], R2 - 1e-7)
    m = float(p.mass[0])
    st = DomainStepper(p, _model2(2e-6, cp, bottom=True), reorder=False)
    st.advance(0, 20_000)
    step = 20_000
    g_end = fraction * flim / m
    for k in range(1, 101):
        st.model.gravity[AX_Y] = g_end * k / 100
        st.advance(step, 1000)
        step += 1000
    st.advance(step, 25_000)
    y = float(p.pos[0, AX_Y])
    if holds:
        expect = brentq(lambda x: net(x) - fraction * flim, dstar, 1e-3)
        assert R2 - y == pytest.approx(expect, rel=2e-2)
    else:
        assert y > R2 + 1e-4, y
