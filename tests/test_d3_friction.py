"""3D friction: oblique impacts (validation-3d.md section 4), a sphere on an incline
(section 5, gravity tilted instead of the wall), rolling resistance (section 5) and
the tangential history under rigid rotation (section 6)."""

import math

import numpy as np
import pytest

from ooc_dem.physics.d3 import layout as L
from support.sim3d import Sim, make_spheres
from ooc_dem.physics.d3.timestep import hertz_duration

E_AL, NU_AL, RHO_AL, R_AL = 3.8e11, 0.23, 4000.0, 0.010
BOX = L.walls_record(1.0, 1.0)
Y = np.array([0.0, 1.0, 0.0])


def oblique(cp, vn, vt, w, phi=0.7, steps=400, dt=None):
    """Sphere hitting the floor with normal speed vn, tangential speed vt along
    u = (cos phi, 0, sin phi) (a 3D direction) and spin w about u x y (so the
    contact-point slip is vc = vt + w R). Returns (e_n, vt', w', velocity, spin, u, axis)."""
    m = RHO_AL * 4 / 3 * math.pi * R_AL**3
    if dt is None:
        dt = hertz_duration(m, R_AL, E_AL / (1 - NU_AL**2), vn) / steps
    u = np.array([math.cos(phi), 0.0, math.sin(phi)])
    ax = np.cross(u, Y)
    s = make_spheres([[0.5, R_AL + 2 * vn * dt, 0.5]], R_AL, density=RHO_AL, vel=[vt * u - vn * Y], spin=[w * ax])
    sim = Sim(s, cp, BOX, dt, gravity=(0, 0, 0))
    sim.advance(steps // 4)
    while s.hist_n[0] > 0 or s.pos[0, 1] < R_AL:
        sim.advance(steps // 10)
        assert sim.step < 20 * steps, "the contact did not end"
    v, sp = s.vel[0].copy(), s.spin[0].copy()
    return v[1] / vn, v @ u, sp @ ax, v, sp, u, ax


MU, E_N = 0.3, 0.8
# the force is clamped at zero (no_tension): rigid-body impulse theory has no tensile
# normal impulse (with the damping allowed to pull, the compressive impulse that limits
# friction exceeds m (1 + e) vn by ~0.5 % at e = 0.8, and J_t with it)
HM = L.contact_table({(L.T_WALL, L.T_SOIL): L.hertz_params(E_AL, NU_AL, E_N, mu=MU, no_tension=True)})


def _gross(vn, vt, w, en, mu=MU):
    sg = math.copysign(1.0, vt + w * R_AL)
    return vt - mu * (1 + en) * vn * sg, w - 2.5 / R_AL * mu * (1 + en) * vn * sg


@pytest.mark.parametrize(
    "case", [(5.0, 1.25, 0.0), (5.0, 3.0, 0.0), (5.0, 1.5, -400.0), (3.9, 2.0, 300.0), (5.0, -2.0, 0.0)]
)
def test_oblique_gross_sliding(case):
    """Hertz-Mindlin (alumina, e = 0.8, mu = 0.3): in the gross-sliding regime
    (|vc| = psi (7/2) mu (1 + e) vn with psi >= 1.25, with and against an initial spin,
    both slip signs) vt' and w' within 1 % of rigid-body impulse theory (with the
    measured e_n); the
    motion stays in the plane of incidence (3D direction phi = 0.7)."""
    vn, psi, w = case
    vc = psi * 3.5 * MU * (1 + E_N) * vn
    vt = vc - w * R_AL
    en, vt2, w2, v, sp, u, ax = oblique(HM, vn, vt, w)
    vt_th, w_th = _gross(vn, vt, w, en)
    assert abs(en - E_N) < 0.05 * E_N  # clamped: e_n = 0.82
    assert abs(vt2 - vt_th) < 0.01 * abs(vt_th), (vt2, vt_th)
    assert abs(w2 - w_th) < 0.01 * abs(w_th), (w2, w_th)
    assert np.linalg.norm(v - (v @ u) * u - v[1] * Y) < 1e-9 * vn
    assert np.linalg.norm(sp - (sp @ ax) * ax) < 1e-9 * abs(w_th)
    print(
        f"gross sliding vn={vn} psi={psi} w={w}: vt' {vt2:.4f} vs {vt_th:.4f} "
        f"({vt2 / vt_th - 1:+.2e}), w' {w2:.2f} vs {w_th:.2f} ({w2 / w_th - 1:+.2e})"
    )


def test_oblique_gross_sliding_linear_law():
    """The same with the linear law (tangential spring ks = kn/2, zn from e = 0.8,
    mu = 0.3): vt', w' within 1 %."""
    kn = 1e7
    cp = L.contact_table({(L.T_WALL, L.T_SOIL): L.linear_params(kn, 0.5 * kn, L.zeta_of_restitution(E_N), 0.1, MU)})
    m = RHO_AL * 4 / 3 * math.pi * R_AL**3
    dt = math.pi * math.sqrt(m / kn) / 400
    vn, vt = 2.0, 6.0
    en, vt2, w2, *_ = oblique(cp, vn, vt, 0.0, dt=dt)
    vt_th, w_th = _gross(vn, vt, 0.0, en)
    assert abs(vt2 - vt_th) < 0.01 * abs(vt_th) and abs(w2 - w_th) < 0.01 * abs(w_th), (vt2, vt_th, w2, w_th)
    print(f"linear gross sliding: vt' err {vt2 / vt_th - 1:+.2e}, w' err {w2 / w_th - 1:+.2e}")


def test_oblique_sticking_trend_and_boundary():
    """Below the regime boundary psi = |vc| / ((7/2) mu (1 + e) vn) = 1 the tangential
    impulse J is less than the gross-sliding mu (1 + e) m vn and grows with psi; it
    reaches the sliding value (within 1 %) from a psi between 0.8 and 1.1 on (the
    tangential spring shifts the rigid boundary 1 slightly), and never exceeds it by
    more than 1 %. From rest the tangential rebound (vt' / vt) lies between the rigid
    sticking value 5/7 and 1 at small psi (spring recoil, Maw et al. 1976)."""
    vn = 5.0
    psis = [0.1, 0.25, 0.5, 0.75, 0.8, 0.9, 1.0, 1.1, 1.25]
    ratio = []
    for psi in psis:
        vc = psi * 3.5 * MU * (1 + E_N) * vn
        en, vt2, _w2, *_ = oblique(HM, vn, vc, 0.0)
        ratio.append((vt2 - vc) / (-MU * (1 + en) * vn))
        if psi <= 0.25:
            assert 5 / 7 < vt2 / vc < 1.0, (psi, vt2 / vc)
    ratio = np.array(ratio)
    print("psi", psis, "\nJ/J_slide", np.round(ratio, 4))
    assert (ratio <= 1.01).all()
    low = np.array(psis) <= 0.75
    assert (ratio[low] < 0.95).all() and (np.diff(ratio[low]) > 0).all()
    first = next(p for p, q in zip(psis, ratio) if abs(q - 1) < 0.01)
    assert 0.8 <= first <= 1.1, first
    assert all(abs(q - 1) < 0.01 for p, q in zip(psis, ratio) if p >= first)


def _incline(theta_deg, mu, mur=0.0, v0=0.0, steps=20000, dt=1e-5, g=9.81):
    """A sphere (r = 1 cm, 2500 kg/m^3) on the floor under gravity tilted by theta about
    z (down-slope = +x), linear law kn = 1e5, ks = 2e4, light damping, started at its
    static overlap. Returns (t, x, spin_z) sampled every 100 steps."""
    r, rho, kn = 0.01, 2500.0, 1e5
    th = math.radians(theta_deg)
    m = rho * 4 / 3 * math.pi * r**3
    cp = L.contact_table({(L.T_WALL, L.T_SOIL): L.linear_params(kn, 0.2 * kn, 0.3, 0.3, mu, mur, 0.3)})
    d0 = m * g * math.cos(th) / kn
    s = make_spheres([[0.1, r - d0, 0.5]], r, density=rho, vel=[[v0, 0, 0]], spin=[[0, 0, -v0 / r]])
    sim = Sim(s, cp, L.walls_record(100.0, 1.0), dt, gravity=(g * math.sin(th), -g * math.cos(th), 0))
    t, x, w = [], [], []
    for _ in range(steps // 100):
        sim.advance(100)
        t.append(sim.step * dt)
        x.append(s.pos[0, 0])
        w.append(s.spin[0, 2])
        assert s.hist_n[0] == 1  # stays on the floor
    return np.array(t), np.array(x), np.array(w), r


def _fit_accel(t, y, t0):
    k = t >= t0
    return 2 * np.polyfit(t[k], y[k], 2)[0]


@pytest.mark.parametrize("theta,mu", [(20.0, 0.5), (30.0, 0.2), (40.0, 0.1), (25.0, 0.1)])
def test_incline_rolling_or_sliding(theta, mu):
    """Solid sphere released at rest on an incline (section 5): rolls without slip with
    a = (5/7) g sin(theta) when tan(theta) <= (7/2) mu, slides with
    a = g (sin - mu cos) and angular acceleration (5/2) mu g cos / R above; a (fit of
    x(t) over 0.02-0.2 s) and the spin's acceleration within 1 %."""
    g = 9.81
    th = math.radians(theta)
    t, x, w, r = _incline(theta, mu, g=g)
    a = _fit_accel(t, x, 0.02)
    alpha = -_fit_accel(t, np.concatenate([[0.0], np.cumsum(w[1:] * np.diff(t))]), 0.02)
    rolls = math.tan(th) <= 3.5 * mu
    if rolls:
        ath, alth = 5 / 7 * g * math.sin(th), 5 / 7 * g * math.sin(th) / r
    else:
        ath, alth = g * (math.sin(th) - mu * math.cos(th)), 2.5 * mu * g * math.cos(th) / r
    assert abs(a / ath - 1) < 0.01, (a, ath, rolls)
    assert abs(alpha / alth - 1) < 0.01, (alpha, alth, rolls)
    print(
        f"incline {theta} deg mu={mu} ({'rolls' if rolls else 'slides'}): a err {a / ath - 1:+.2e}, "
        f"alpha err {alpha / alth - 1:+.2e}"
    )


def test_rolling_resistance_deceleration():
    """A sphere rolling without slip on the flat floor (0.5 m/s) under a saturated
    rolling moment M = mu_r R Fn decelerates at (5/7) mu_r g (section 5), within 1 %."""
    g, mur = 9.81, 0.05
    t, x, _w, _r = _incline(0.0, 0.5, mur=mur, v0=0.5, steps=40000, g=g)
    a = _fit_accel(t, x, 0.02)
    ath = -5 / 7 * mur * g
    assert abs(a / ath - 1) < 0.01, (a, ath)
    print(f"rolling resistance: a {a:.5f} vs {ath:.5f} ({a / ath - 1:+.2e})")


def _rotation(axis, phi):
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(phi) * K + (1 - math.cos(phi)) * K @ K


@pytest.mark.parametrize("axis", [(0.3, -0.5, 0.8), (0.0, 0.0, 1.0)])
def test_history_under_rigid_rotation(axis):
    """Section 6: a resting, loaded sphere pair (overlap, a tangential spring below the
    Coulomb limit, a rolling spring) rotated rigidly by 0.01 rad per step about an
    axis, 300 steps (3 rad), with the velocities held at zero: |Ft| and |M| keep their
    magnitude (rel 1e-12), stay in the tangent plane (|Ft . n| < 1e-12 |Ft|), and the
    normal force is unchanged. Without the projection step Ft would tilt out of the
    tangent plane by the accumulated angle (a test that fails without it)."""
    r = 0.01
    kn = 1e5
    cp = L.contact_table({(0, 0): L.linear_params(kn, 0.5 * kn, 0.0, 0.0, 0.5, 0.1, 0.0)})
    n0 = np.array([1.0, 2.0, 2.0]) / 3.0
    delta = 1e-4
    c = np.array([0.5, 0.5, 0.5])
    p0 = [c - (r - delta / 2) * n0, c + (r - delta / 2) * n0]
    s = make_spheres(p0, r, density=2500.0)
    t0 = np.cross(n0, [0.0, 0.0, 1.0])
    t0 /= np.linalg.norm(t0)
    fs, ms = 0.3 * 0.5 * kn * delta, 0.3 * 0.1 * r / 2 * kn * delta
    for i in range(2):  # both partners hold identical copies (canonical: a's frame)
        s.hist_n[i] = 1
        s.hist_id[i, 0] = 1 - i
        s.hist_s[i, 0] = fs * t0
        s.hist_m[i, 0] = ms * np.cross(n0, t0)
    sim = Sim(
        s, cp, L.walls_record(1.0, 1.0, False, False, False, False, False), 1e-14, gravity=(0, 0, 0), keep_forces=True
    )
    step = _rotation(axis, 0.01)
    rot = np.eye(3)
    for k in range(300):
        rot = step @ rot
        s.pos[:] = c + (np.array(p0) - c) @ rot.T
        s.vel[:] = 0.0
        s.spin[:] = 0.0
        sim.advance(1)
        n = rot @ n0
        fb = sim.forces.force[1]
        fn = fb @ n
        ft = fn * n - fb
        st = s.hist_s[1, 0]
        assert abs(fn / (kn * delta) - 1) < 1e-9
        assert abs(np.linalg.norm(ft) / fs - 1) < 1e-12, (k, np.linalg.norm(ft), fs)
        assert abs(ft @ n) < 1e-12 * fs and abs(st @ n) < 1e-12 * fs
        assert abs(np.linalg.norm(s.hist_m[1, 0]) / ms - 1) < 1e-12
        assert abs(s.hist_m[1, 0] @ n) < 1e-12 * ms
        assert np.array_equal(s.hist_s[0, 0], s.hist_s[1, 0])
    # the projection transports the spring parallel along the path of n (LAMMPS): it
    # keeps |Ft| but not the pair frame's twist, so its direction differs from R t0
    # by the path's holonomy (information only)
    print(
        f"rigid rotation about {axis}: |Ft|/Fs - 1 = {np.linalg.norm(ft) / fs - 1:+.1e}, "
        f"spring vs R t0: {np.degrees(math.acos(min(1, st @ (rot @ t0) / fs))):.1f} deg"
    )
