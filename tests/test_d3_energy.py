"""Energy of an undamped, frictionless box of spheres (validation-3d.md section 7)."""

import math

import numpy as np
import pytest

from ooc_dem.physics.d3 import layout as L
from support.sim3d import Sim, make_spheres
from ooc_dem.physics.d3.timestep import hertz_duration

E, NU, RHO, R = 1e7, 0.3, 1000.0, 0.01
BOXL = 0.1


def _potential(pos, r, law, k):
    """Elastic energy of every overlap at positions pos: Hertz (8/15) E* sqrt(R*) d^(5/2)
    (k = (E*_pair, E*_wall)), linear kn d^2 / 2 (k = (kn, kn))."""

    def en(d, estar, rstar):
        if law == "hertz":
            return 8 / 15 * estar * np.sqrt(rstar) * d**2.5
        return 0.5 * estar * d * d

    u = 0.0
    diff = pos[:, None, :] - pos[None, :, :]
    dist = np.sqrt((diff**2).sum(-1))
    iu = np.triu_indices(len(pos), 1)
    d = (r[:, None] + r[None, :])[iu] - dist[iu]
    rs = (r[:, None] * r[None, :] / (r[:, None] + r[None, :]))[iu]
    on = d > 0
    u += en(d[on], k[0], rs[on]).sum()
    # walls: floor y = 0, x = 0 / BOXL, z = 0 / BOXL (the box has no lid)
    for dw in (r - pos[:, 1], r - pos[:, 0], r - (BOXL - pos[:, 0]), r - pos[:, 2], r - (BOXL - pos[:, 2])):
        u += en(dw[dw > 0], k[1], r[dw > 0]).sum()
    return u


def _run(law, gravity, nsteps=100_000, every=100, seed=3):
    rng = np.random.default_rng(seed)
    g = np.linspace(0.2, 0.8, 3) * BOXL
    pos = np.array([[x, y, z] for x in g for y in g for z in g])
    pos += rng.uniform(-0.003, 0.003, pos.shape)
    r = R * rng.uniform(0.8, 1.0, len(pos))
    vel = rng.normal(0.0, 0.6, pos.shape)
    s = make_spheres(pos, r, density=RHO, vel=vel)
    m_min = s.mass.min()
    vmax = 2 * np.abs(vel).max() * math.sqrt(3)
    if law == "hertz":
        cp = L.contact_table({(0, 0): L.hertz_params(E, NU, 1.0, E2=E, nu2=NU), (1, 0): L.hertz_params(E, NU, 1.0)})
        k = (cp[0, 0]["estar"], cp[1, 0]["estar"])
        tc = hertz_duration(m_min / 2, r.min() / 2, k[0], vmax)
        dt = tc / 50
    else:
        kn = 2e3
        cp = L.contact_table({(0, 0): L.linear_params(kn, 0.0), (1, 0): L.linear_params(kn, 0.0)})
        k = (kn, kn)
        tc = math.pi * math.sqrt(m_min / 2 / kn)
        # the linear force has a kink at contact onset: each collision leaves an O(dt^2)
        # energy error of random sign (a random walk: 3-4e-4 after 1e5 steps at tc/50,
        # 5-6e-5 at tc/100), so this law runs at tc/100
        dt = tc / 100
    gvec = np.array([0.0, -gravity, 0.0])
    sim = Sim(s, cp, L.walls_record(BOXL, BOXL), dt, gravity=gvec)
    energy = []
    for _ in range(nsteps // every):
        sim.advance(every - 1)
        v0 = s.vel.copy()
        x = s.pos.copy()  # x_n
        sim.advance(1)
        v = 0.5 * (v0 + s.vel)  # v_n
        ke = 0.5 * (s.mass[:, None] * v * v).sum() + 0.5 * (s.inertia[:, None] * s.spin**2).sum()
        energy.append(ke + _potential(x, s.r, law, k) - (s.mass[:, None] * x * gvec).sum())
    return np.array(energy), sim


@pytest.mark.parametrize("law,gravity", [("hertz", 9.81), ("linear", 9.81)])
def test_energy_bounded_no_drift(law, gravity):
    """27 spheres in the open-topped box under gravity, 1e5 steps at dt = tc/50 (Hertz)
    or tc/100 (linear; tc of the shortest contact): the total energy (kinetic at integer
    steps + elastic + gravitational) stays within 1e-4 of its start, and a linear fit
    over the run drifts by less than 5e-5 of it (no secular drift)."""
    e, sim = _run(law, gravity)
    rel = np.abs(e / e[0] - 1)
    t = np.arange(len(e))
    drift = np.polyfit(t, e / e[0], 1)[0] * len(e)
    collisions = sim.rebuilds
    print(
        f"energy {law} g={gravity}: max rel err {rel.max():.2e}, drift over run {drift:+.2e}, "
        f"{collisions} list rebuilds"
    )
    assert collisions > 50  # the spheres really moved about
    assert rel.max() < 1e-4
    assert abs(drift) < 5e-5
