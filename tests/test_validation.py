"""Physics validation against analytic results (docs/reference/validation.md).

Every test states its formula and its tolerance in its docstring. Units are SI.
The reference disc: r = 0.01 m, density 2000 kg/m^3, slice thickness 0.1 m
(m = rho pi r^2 b = 0.0628 kg, I = m r^2 / 2), kn = 1e5 N/m, ks = kn/3 unless a
test says otherwise. Time steps resolve a contact with several hundred steps.

Conventions of the engine that the tests rely on (ooc_dem/physics):
- the bottom wall is y = 0 with normal +y; an incline of angle theta is modelled
  by tilting gravity: gx = g sin(theta), gy = -g cos(theta); down-slope is +x;
- spin w is counter-clockwise positive, so a disc rolling in +x has w < 0 and the
  velocity of its contact point with the floor is u = vx + w r;
- leapfrog: after a step the state holds x_(n+1) and v_(n+1/2).

The kernels run on one numba thread here (module fixture): the machine has two
cores that may be busy with a long simulation, and spinning worker threads of
tiny systems are then very slow. Results do not depend on the thread count
(docs/design.md §3).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from ooc_dem.engine.stepper import DomainStepper, Model
from ooc_dem.physics.d2.contact import KN, KS, MU, MUR, N_FIELDS, NO_TENSION, ZN, ZR, ZT, contact_force
from ooc_dem.physics.layout import ID_WALL_BOTTOM, ID_WALL_LEFT, ID_WALL_RIGHT, WG_SIZE
from ooc_dem.physics.layout import WC_SIZE
from ooc_dem.model.state import Particles
from ooc_dem.physics.layout import AX_X, AX_Y, HM_R, HS_T, SP_Z
from support.threads import one_numba_thread  # noqa: F401

G = 9.81
R = 0.01
RHO = 2000.0
B = 0.1
M = RHO * math.pi * R * R * B
I_DISC = 0.5 * M * R * R
KN0 = 1.0e5
KS0 = KN0 / 3.0
TC_WALL = math.pi * math.sqrt(M / KN0)  # undamped disc-wall contact time
TC_PAIR = math.pi * math.sqrt(0.5 * M / KN0)  # undamped equal-disc contact time


# --------------------------------------------------------------------- helpers


def pair_params(kn=KN0, ks=None, zn=0.0, zt=0.0, mu=0.0, mur=0.0, zr=0.0) -> np.ndarray:
    v = np.zeros(N_FIELDS)
    v[KN] = kn
    v[KS] = kn / 3.0 if ks is None else ks
    v[ZN], v[ZT], v[MU], v[MUR], v[ZR] = zn, zt, mu, mur, zr
    v[NO_TENSION] = 1.0  # the paper's clamped law
    return v


def make_model(
    dt, disc=None, wall=None, gx=0.0, gy=0.0, bottom=False, left=False, right=False, length=1.0e3, r_max=R
) -> Model:
    cp = np.zeros((3, 3, N_FIELDS))
    if disc is not None:
        cp[0, 0] = disc
    if wall is not None:
        cp[1, 0] = wall
        cp[0, 1] = wall
    walls = np.array([length, float(left), float(right), float(bottom)])
    return Model(
        dt=dt,
        gravity=np.array([gx, gy]),
        skin=0.2 * r_max,
        cp=cp,
        walls=walls,
        wg=np.zeros(WG_SIZE),
        wc=np.zeros(WC_SIZE),
        wheel_enabled=False,
        r_max=r_max,
    )


def make_discs(x, y, r=R, vx=0.0, vy=0.0, w=0.0) -> Particles:
    x = np.atleast_1d(np.asarray(x, dtype=float))
    n = len(x)
    p = Particles.new(
        np.column_stack([x, np.broadcast_to(np.asarray(y, float), (n,))]),
        np.broadcast_to(np.asarray(r, float), (n,)),
        RHO,
        B,
    )
    p.vel[:, AX_X][:] = vx
    p.vel[:, AX_Y][:] = vy
    p.spin[:, SP_Z][:] = w
    return p


def col(p, k):
    """The 2D column named k (x, y, vx, vy, w) of p's vectors (a view)."""
    return {"x": p.pos[:, AX_X], "y": p.pos[:, AX_Y], "vx": p.vel[:, AX_X], "vy": p.vel[:, AX_Y], "w": p.spin[:, SP_Z]}[
        k
    ]


def incline(theta_deg):
    th = math.radians(theta_deg)
    return th, G * math.sin(th), -G * math.cos(th)


def trajectory(st: DomainStepper, nsteps: int, every: int = 1, forces: bool = False):
    """Advance `every` steps at a time; arrays [k, disc] of the state after k*every steps.

    Row 0 is the initial state. Positions are at t = k*every*dt, velocities at
    t - dt/2. With forces=True also the contact forces (and torques) computed in
    the last step of each chunk, i.e. at positions of row k - 1 when every == 1.
    """
    p = st.p
    keys = ("x", "y", "vx", "vy", "w")
    out = {k: [col(p, k).copy()] for k in keys}
    if forces:
        for k in ("fx", "fy", "tq"):
            out[k] = [np.zeros(len(p))]
    step = 0
    while step < nsteps:
        st.advance(step, every)
        step += every
        for k in keys:
            out[k].append(col(p, k).copy())
        if forces:
            out["fx"].append(st.force[:, AX_X].copy())
            out["fy"].append(st.force[:, AX_Y].copy())
            out["tq"].append(st.torque[:, SP_Z].copy())
    return {k: np.array(v) for k, v in out.items()}


def first_crossing(t, f):
    """Time of the first sign change of f from > 0 to <= 0, linearly interpolated."""
    k = np.flatnonzero((f[:-1] > 0) & (f[1:] <= 0))
    assert len(k), "no crossing found"
    k = k[0]
    s = f[k] / (f[k] - f[k + 1])
    return t[k] + s * (t[k + 1] - t[k]), k, s


def rel_err(measured, expected):
    return abs(measured - expected) / abs(expected)


def _hist_value(p, i, pid, which="ft"):
    arr = p.hist_s[:, :, HS_T] if which == "ft" else p.hist_m[:, :, HM_R]
    for s in range(p.hist_n[i]):
        if p.hist_id[i, s] == pid:
            return arr[i, s]
    return 0.0


# ------------------------------------------------------------- 1. restitution

CLAMPED_E = {0.1: 0.744, 0.2: 0.572, 0.3: 0.451, 0.5: 0.298, 1.0: 0.135}


def _restitution_wall(zeta, v0=0.5):
    dt = TC_WALL / 1000
    p = make_discs(0.5, R + 0.01 * R, vy=-v0)
    st = DomainStepper(p, make_model(dt, wall=pair_params(zn=zeta), bottom=True), reorder=False)
    st.advance(0, int((0.01 * R / v0 + 2.0 * TC_WALL) / dt))
    assert p.pos[:, AX_Y][0] > R, "disc still in contact"
    return p.vel[:, AX_Y][0] / v0


def _restitution_pair(zeta, v0=0.5):
    dt = TC_PAIR / 1000
    gap = 0.01 * R
    p = make_discs([-(R + gap / 2), R + gap / 2], 0.0, vx=np.array([0.5 * v0, -0.5 * v0]))
    st = DomainStepper(p, make_model(dt, disc=pair_params(zn=zeta)), reorder=False)
    st.advance(0, int((gap / v0 + 2.0 * TC_PAIR) / dt))
    assert p.pos[:, AX_X][1] - p.pos[:, AX_X][0] > 2 * R, "discs still in contact"
    return (p.vel[:, AX_X][1] - p.vel[:, AX_X][0]) / v0


@pytest.mark.parametrize("zeta", sorted(CLAMPED_E))
def test_restitution_clamped_engine(zeta):
    """Clamped convention (the engine's law: Fn = max(0, kn d - cn vn)), full engine.

    A disc dropped on the bottom wall (m* = m) and two equal discs head-on
    (m* = m/2), no gravity, dt = t_c/1000. e = |v_out / v_in| must match the
    tabulated clamped values 0.744, 0.572, 0.451, 0.298, 0.135 (zeta = 0.1, 0.2,
    0.3, 0.5, 1.0; the last is e^-2) to 1 % relative.
    """
    e_tab = CLAMPED_E[zeta]
    e_wall = _restitution_wall(zeta)
    e_pair = _restitution_pair(zeta)
    assert rel_err(e_wall, e_tab) < 0.01, (e_wall, e_tab)
    assert rel_err(e_pair, e_tab) < 0.01, (e_pair, e_tab)


def _voigt_unclamped(delta, vn, kn, zeta, meff):
    """The engine's normal force with its no-tension clamp undone.

    contact_force returns max(0, kn d - cn vn); that expression is odd in
    (d, vn), so f(d, vn) - f(-d, -vn) = kn d - cn vn exactly (one term is 0).
    """
    a = contact_force(
        0.0, 1.0, delta, 0.0, vn, 0.0, 0.0, 0.0, R, meff, 1.0, R, 0.0, 0.0, kn, kn / 3, zeta, 0.0, 0.0, 0.0, 0.0, 1e-6
    )[0]
    b = contact_force(
        0.0, 1.0, -delta, 0.0, -vn, 0.0, 0.0, 0.0, R, meff, 1.0, R, 0.0, 0.0, kn, kn / 3, zeta, 0.0, 0.0, 0.0, 0.0, 1e-6
    )[0]
    return a - b


def _unclamped_collision(zeta, meff=0.5 * M, kn=KN0, v0=0.5, nper=2000):
    """RK4 of the relative normal motion m* dvn/dt = F, d(delta)/dt = -vn.

    Starts at first touch (delta = 0, vn = -v0); returns (e, t_c, peak overlap)
    at the return of the overlap to zero.
    """
    h = math.pi * math.sqrt(meff / kn) / nper

    def rhs(d, v):
        return -v, _voigt_unclamped(d, v, kn, zeta, meff) / meff

    d, v, t, dmax = 0.0, -v0, 0.0, 0.0
    for _ in range(20 * nper):
        k1 = rhs(d, v)
        k2 = rhs(d + 0.5 * h * k1[0], v + 0.5 * h * k1[1])
        k3 = rhs(d + 0.5 * h * k2[0], v + 0.5 * h * k2[1])
        k4 = rhs(d + h * k3[0], v + h * k3[1])
        dn = d + h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        vn = v + h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        if dn <= 0.0 and t > 0.0:
            s = d / (d - dn)
            return (v + s * (vn - v)) / v0, t + s * h, dmax
        d, v, t = dn, vn, t + h
        dmax = max(dmax, d)
    raise AssertionError("overlap never returned to zero")


@pytest.mark.parametrize("zeta", [0.0, 0.1, 0.2, 0.3, 0.5, 0.8])
def test_restitution_and_duration_unclamped(zeta):
    """Unclamped (pure Voigt) convention, from the engine's contact_force.

    The clamp is undone algebraically (see _voigt_unclamped) and the relative
    normal motion of an equal-disc pair (m* = m/2) is integrated with RK4 (2000
    steps per contact). Checks, each to 1 % relative:
    e = exp(-pi z / sqrt(1 - z^2)) (e = 1 at z = 0, absolute 1 %) and
    t_c = pi / (w0 sqrt(1 - z^2)), w0 = sqrt(kn/m*).
    This checks the engine's kn and its damping coefficient 2 z sqrt(m* kn).
    """
    meff = 0.5 * M
    e, tc, _ = _unclamped_collision(zeta, meff)
    e_th = math.exp(-math.pi * zeta / math.sqrt(1 - zeta * zeta))
    tc_th = math.pi / (math.sqrt(KN0 / meff) * math.sqrt(1 - zeta * zeta))
    assert abs(e - e_th) < 0.01 * e_th, (e, e_th)
    assert rel_err(tc, tc_th) < 0.01, (tc, tc_th)


# ---------------------------------------------------------- 2. contact duration


@pytest.mark.parametrize("kind", ["pair", "wall"])
def test_contact_duration_and_peak_overlap_undamped(kind):
    """Undamped head-on contact in the full engine (no clamp acts when zeta = 0).

    t_c = pi sqrt(m*/kn), peak overlap d = v0 sqrt(m*/kn), peak force kn d;
    m* = m/2 for two equal discs, m* = m for a disc on the wall. Contact start
    and end are interpolated linearly between steps (positions move linearly
    within a step). Tolerance 1 % relative each; dt = t_c/1000.
    """
    v0 = 0.5
    if kind == "pair":
        meff, tc_th = 0.5 * M, TC_PAIR
        dt = tc_th / 1000
        gap = 0.01 * R
        p = make_discs([-(R + gap / 2), R + gap / 2], 0.0, vx=np.array([0.5 * v0, -0.5 * v0]))
        model = make_model(dt, disc=pair_params())
    else:
        meff, tc_th = M, TC_WALL
        dt = tc_th / 1000
        gap = 0.01 * R
        p = make_discs(0.5, R + gap, vy=-v0)
        model = make_model(dt, wall=pair_params(), bottom=True)
    st = DomainStepper(p, model, reorder=False, keep_forces=True)
    tr = trajectory(st, int((gap / v0 + 1.3 * tc_th) / dt), forces=True)
    t = np.arange(len(tr["x"])) * dt
    if kind == "pair":
        overlap = 2 * R - (tr["x"][:, 1] - tr["x"][:, 0])
        force = np.abs(tr["fx"][:, 1])
    else:
        overlap = R - tr["y"][:, 0]
        force = np.abs(tr["fy"][:, 0])
    t_on, _, _ = first_crossing(t, -overlap)
    k_on = np.flatnonzero(overlap > 0)[0]
    t_off, _, _ = first_crossing(t[k_on:], overlap[k_on:])
    tc = t_off - t_on
    d_th = v0 * math.sqrt(meff / KN0)
    assert rel_err(tc, tc_th) < 0.01, (tc, tc_th)
    assert rel_err(overlap.max(), d_th) < 0.01, (overlap.max(), d_th)
    assert rel_err(force.max(), KN0 * d_th) < 0.01, (force.max(), KN0 * d_th)


# ---------------------------------------------------------- 3. block on incline


def _on_incline(theta_deg, wall, t_end, block=False, ramp=0.0, dt=5e-6, every=100):
    """One disc (or rotation-locked block) on the bottom wall under tilted gravity.

    Starts at the static normal overlap m g cos(theta)/kn, at rest. With ramp > 0
    the tilt grows linearly from 0 to theta over `ramp` seconds (quasi-static
    loading: a sudden tilt makes the friction overshoot its static value while
    the body is brought to rest, which can slip a body that would rest).
    Returns (theta, particles, trajectory, velocity times).
    """
    th = math.radians(theta_deg)
    p = make_discs(0.0, R - M * G * math.cos(0.0 if ramp > 0 else th) / KN0)
    if block:
        p.inertia[:] = np.inf  # rotation locked: a block
    model = make_model(dt, wall=wall, bottom=True)
    st = DomainStepper(p, model, reorder=False)
    keys = ("x", "y", "vx", "vy", "w")
    tr = {k: [col(p, k).copy()] for k in keys}
    nsteps = int(round(t_end / dt))
    for step in range(0, nsteps, every):
        t = step * dt
        a = th if ramp <= 0 else th * min(1.0, t / ramp)
        model.gravity[:] = (G * math.sin(a), -G * math.cos(a))
        st.advance(step, every)
        for k in keys:
            tr[k].append(col(p, k).copy())
    tr = {k: np.array(v) for k, v in tr.items()}
    t = np.arange(len(tr["x"])) * every * dt - 0.5 * dt  # velocity times
    return th, p, tr, t


def _slope(t, v, t1, t2):
    k1, k2 = np.searchsorted(t, [t1, t2])
    k2 = min(k2, len(t) - 1)
    return (v[k2] - v[k1]) / (t[k2] - t[k1])


def test_block_rests_on_incline_below_friction_angle():
    """Rotation-locked block (inertia = inf), mu = 0.5, tilted quasi-statically
    (over 0.03 s) to tan(theta) = 0.95 mu, then held 0.03 s: it rests.

    With no slip the friction equals m g sin(theta) (< mu m g cos(theta)) and is
    carried by the tangential spring: stored spring = m g sin(theta) and the
    block's displacement = its elastic stretch m g sin(theta)/ks, both to 1 %
    (any slip would add to the displacement); final speed < 1e-6 m/s.
    """
    mu = 0.5
    theta = math.degrees(math.atan(0.95 * mu))
    wall = pair_params(zn=0.5, zt=0.5, mu=mu)
    th, p, tr, _ = _on_incline(theta, wall, 0.06, block=True, ramp=0.03)
    f = M * G * math.sin(th)
    assert rel_err(tr["x"][-1, 0], f / KS0) < 0.01, (tr["x"][-1, 0], f / KS0)
    assert abs(tr["vx"][-1, 0]) < 1e-6
    assert p.spin[:, SP_Z][0] == 0.0
    s = _hist_value(p, 0, ID_WALL_BOTTOM)
    assert rel_err(abs(s), f) < 0.01, (s, f)


@pytest.mark.parametrize("theta_deg, mu", [(30.0, 0.3), (math.degrees(math.atan(0.55)), 0.5)])
def test_block_slides_on_incline_above_friction_angle(theta_deg, mu):
    """Rotation-locked block with tan(theta) > mu slides: a = g (sin - mu cos).

    Cases: theta = 30 deg, mu = 0.3 (a = 2.36 m/s^2) and tan(theta) = 1.1 mu,
    mu = 0.5 (a = 0.43 m/s^2). Sudden tilt; a is the slope of vx over
    0.02 s..0.06 s. Tolerance 1 % relative.
    """
    wall = pair_params(zn=0.5, zt=0.5, mu=mu)
    th, p, tr, t = _on_incline(theta_deg, wall, 0.06, block=True)
    a_th = G * (math.sin(th) - mu * math.cos(th))
    a = _slope(t, tr["vx"][:, 0], 0.02, 0.06)
    assert rel_err(a, a_th) < 0.01, (a, a_th)
    assert p.spin[:, SP_Z][0] == 0.0


# ---------------------------------------------------------- 4. disc on incline


def test_disc_rolls_without_slip_on_incline():
    """Disc on an incline, theta = 20 deg, mu = 0.5 >= tan(theta)/3 = 0.12: rolls.

    a = (2/3) g sin(theta) and angular acceleration -a/r (rolling in +x is
    clockwise); slopes of vx and w over 0.02 s..0.08 s. Tolerance 1 % relative;
    the contact-point slip speed |vx + w r| stays below 1e-3 |vx|.
    """
    th, p, tr, t = _on_incline(20.0, pair_params(zn=0.5, zt=0.5, mu=0.5), 0.08)
    a_th = 2.0 / 3.0 * G * math.sin(th)
    a = _slope(t, tr["vx"][:, 0], 0.02, 0.08)
    alpha = _slope(t, tr["w"][:, 0], 0.02, 0.08)
    assert rel_err(a, a_th) < 0.01, (a, a_th)
    assert rel_err(alpha, -a_th / R) < 0.01, (alpha, -a_th / R)
    slip = tr["vx"][-1, 0] + tr["w"][-1, 0] * R
    assert abs(slip) < 1e-3 * abs(tr["vx"][-1, 0]), slip


def test_disc_slides_and_spins_up_on_steep_incline():
    """theta = 30 deg, mu = 0.1 < tan(theta)/3 = 0.19: the disc slips throughout.

    a = g (sin(theta) - mu cos(theta)) = 4.06 m/s^2 and angular acceleration
    -2 mu g cos(theta)/r = -170 rad/s^2 (clockwise). Slopes over 0.02..0.06 s;
    tolerance 1 % relative each.
    """
    mu = 0.1
    th, p, tr, t = _on_incline(30.0, pair_params(zn=0.5, zt=0.5, mu=mu), 0.06)
    a_th = G * (math.sin(th) - mu * math.cos(th))
    alpha_th = -2.0 * mu * G * math.cos(th) / R
    a = _slope(t, tr["vx"][:, 0], 0.02, 0.06)
    alpha = _slope(t, tr["w"][:, 0], 0.02, 0.06)
    assert rel_err(a, a_th) < 0.01, (a, a_th)
    assert rel_err(alpha, alpha_th) < 0.01, (alpha, alpha_th)
    assert tr["vx"][-1, 0] + tr["w"][-1, 0] * R > 0.1  # still slipping


# ------------------------------------------------------- 5. rolling resistance


def test_rolling_resistance_holds_disc_below_eta():
    """Disc-wall rolling resistance eta_r = 0.2 (limit eta_r r Fn), mu = 0.8,
    tilted quasi-statically (0.03 s) to tan(theta) = 0.95 eta_r, held 0.07 s:
    the disc rests.

    At rest the friction is f = m g sin(theta) and the rolling moment f r
    (< eta_r r m g cos): the stored rolling spring must equal f r to 1 %. With
    no slip and no plastic rolling the centre moves by the two elastic
    stretches, 2 f/ks (tangential spring f/ks plus rotation f/(ks r) times r,
    since kr = ks r^2), to 1 %; final speed < 1e-6 m/s.
    """
    eta = 0.2
    theta = math.degrees(math.atan(0.95 * eta))
    wall = pair_params(zn=0.5, zt=0.5, mu=0.8, mur=eta, zr=0.5)
    th, p, tr, t = _on_incline(theta, wall, 0.10, ramp=0.03)
    f = M * G * math.sin(th)
    assert abs(tr["vx"][-1, 0]) < 1e-6 and abs(tr["w"][-1, 0]) < 1e-6 / R
    assert rel_err(tr["x"][-1, 0], 2 * f / KS0) < 0.01, (tr["x"][-1, 0], 2 * f / KS0)
    mr = _hist_value(p, 0, ID_WALL_BOTTOM, "mr")
    assert rel_err(abs(mr), f * R) < 0.01, (mr, f * R)


@pytest.mark.parametrize("theta_deg", [25.0, math.degrees(math.atan(1.1 * 0.2))])
def test_rolling_resistance_disc_rolls_above_eta(theta_deg):
    """eta_r = 0.2, tan(theta) > eta_r (theta = 25 deg, and tan(theta) = 1.1
    eta_r), mu = 0.8: the disc rolls.

    With the rolling moment at its limit eta_r r m g cos(theta) and no slip,
    m a = m g sin - F and I a/r = F r - eta_r r m g cos give
    a = (2/3) g (sin(theta) - eta_r cos(theta)) (1.58 and 0.13 m/s^2; needs
    mu >= (tan + 2 eta_r)/3). Slope of vx over 0.02..0.08 s; 1 % relative.
    """
    eta = 0.2
    wall = pair_params(zn=0.5, zt=0.5, mu=0.8, mur=eta, zr=0.5)
    th, p, tr, t = _on_incline(theta_deg, wall, 0.08)
    a_th = 2.0 / 3.0 * G * (math.sin(th) - eta * math.cos(th))
    a = _slope(t, tr["vx"][:, 0], 0.02, 0.08)
    assert rel_err(a, a_th) < 0.01, (a, a_th)


# ------------------------------------------------------- 6. sliding to rolling


def test_sliding_to_rolling_on_flat_ground():
    """Disc launched with v0 = 0.5 m/s and no spin on flat ground, mu = 0.3.

    Rolling (contact-point speed vx + w r = 0) begins at t = v0/(3 mu g) with
    speed (2/3) v0 after sliding 5 v0^2/(18 mu g). The first zero of the slip
    speed is interpolated between steps. Tolerance 1 % relative each.
    """
    v0, mu = 0.5, 0.3
    dt = 5e-6
    wall = pair_params(zn=0.5, zt=0.5, mu=mu)
    p = make_discs(0.0, R - M * G / KN0, vx=v0)
    st = DomainStepper(p, make_model(dt, wall=wall, gy=-G, bottom=True), reorder=False)
    t_th = v0 / (3 * mu * G)
    every = 4
    tr = trajectory(st, int(1.2 * t_th / dt), every=every)
    tv = np.arange(len(tr["x"])) * every * dt - 0.5 * dt  # velocity times
    slip = tr["vx"][:, 0] + tr["w"][:, 0] * R
    t_roll, k, s = first_crossing(tv, slip)
    v_roll = tr["vx"][k, 0] + s * (tr["vx"][k + 1, 0] - tr["vx"][k, 0])
    tx = tv + 0.5 * dt
    x_roll = np.interp(t_roll, tx, tr["x"][:, 0])
    assert rel_err(t_roll, t_th) < 0.01, (t_roll, t_th)
    assert rel_err(v_roll, 2.0 / 3.0 * v0) < 0.01, (v_roll, 2 * v0 / 3)
    d_th = 5 * v0 * v0 / (18 * mu * G)
    assert rel_err(x_roll, d_th) < 0.01, (x_roll, d_th)


# --------------------------------------------------------- 7. oblique impact


def _oblique(theta_deg, mu, v=0.5):
    th = math.radians(theta_deg)
    dt = TC_WALL / 1000
    gap = 0.01 * R
    p = make_discs(0.5, R + gap, vx=v * math.sin(th), vy=-v * math.cos(th))
    st = DomainStepper(p, make_model(dt, wall=pair_params(ks=KN0 / 3, mu=mu), bottom=True), reorder=False)
    st.advance(0, int((gap / (v * math.cos(th)) + 1.5 * TC_WALL) / dt))
    assert p.pos[:, AX_Y][0] > R, "still in contact"
    return th, v, p.vel[:, AX_X][0], p.vel[:, AX_Y][0], p.spin[:, SP_Z][0]


def test_oblique_impact_sticking():
    """Disc-wall impact, ks = kn/3, no damping, theta = 30 deg from the normal,
    mu = 0.5 (tan(theta) = 0.58 <= 3 mu): tangential and normal periods are equal
    and the contact sticks. The contact-point tangential velocity reverses
    (u' = -u, u = vx + w r), centre e_t = vx'/vx = 1/3, spin
    w' = -(4/3) v sin(theta)/r (moving in +x: clockwise), e_n = 1.
    Tolerance 1 % relative each (u' relative to u).
    """
    th, v, vx, vy, w = _oblique(30.0, 0.5)
    u_in = v * math.sin(th)
    assert rel_err(vx + w * R, -u_in) < 0.01, (vx + w * R, -u_in)
    assert rel_err(vx / u_in, 1.0 / 3.0) < 0.01, vx / u_in
    assert rel_err(w, -4.0 / 3.0 * v * math.sin(th) / R) < 0.01
    assert rel_err(vy / (v * math.cos(th)), 1.0) < 0.01


def test_oblique_impact_sliding():
    """Disc-wall impact, ks = kn/3, no damping, theta = 45 deg, mu = 0.1
    (tan(theta) = 1 > 3 mu): slides throughout. e_t = 1 - 2 mu/tan(theta) = 0.8,
    e_n = 1, w' = -4 mu v cos(theta)/r. Tolerance 1 % relative each.
    """
    mu = 0.1
    th, v, vx, vy, w = _oblique(45.0, mu)
    assert rel_err(vx / (v * math.sin(th)), 1 - 2 * mu / math.tan(th)) < 0.01
    assert rel_err(vy / (v * math.cos(th)), 1.0) < 0.01
    assert rel_err(w, -4 * mu * v * math.cos(th) / R) < 0.01, (w, -4 * mu * v * math.cos(th) / R)


# --------------------------------------------------- 8. opposite spins, head-on


def test_equal_opposite_spins_head_on_exact():
    """Two equal discs, spins +w and -w, head-on with friction mu = 0.5,
    damping 0.3: the contact points move together, so the tangential force is
    exactly zero: torques == 0 at every step, spins, vy and y unchanged bit for
    bit (exact, tolerance 0), while the normal collision does happen.
    """
    v0, w0 = 0.5, 40.0
    dt = TC_PAIR / 500
    gap = 0.01 * R
    p = make_discs([-(R + gap / 2), R + gap / 2], 0.0, vx=np.array([0.5 * v0, -0.5 * v0]), w=np.array([w0, -w0]))
    st = DomainStepper(p, make_model(dt, disc=pair_params(zn=0.3, zt=0.3, mu=0.5)), reorder=False, keep_forces=True)
    tr = trajectory(st, int((gap / v0 + 1.5 * TC_PAIR) / dt), forces=True)
    assert np.abs(tr["fx"]).max() > 0  # they did collide
    assert p.vel[:, AX_X][0] < 0 < p.vel[:, AX_X][1]  # and rebounded
    assert np.all(tr["tq"] == 0.0)
    assert np.all(tr["fy"] == 0.0)
    assert np.all(tr["w"][:, 0] == w0) and np.all(tr["w"][:, 1] == -w0)
    assert np.all(tr["vy"] == 0.0) and np.all(tr["y"] == 0.0)


# ------------------------------------------------------------- 9. energy


def _energy(p, x, y, vx, vy, w, L, kn):
    """Kinetic + potential + spring energy; velocities at the integer time."""
    e = 0.5 * p.mass * (vx * vx + vy * vy) + 0.5 * p.inertia * w * w + p.mass * G * y
    es = 0.0
    r = p.r
    for i in range(len(x)):
        for d in (r[i] - x[i], r[i] - (L - x[i]), r[i] - y[i]):
            if d > 0:
                es += 0.5 * kn * d * d
        for j in range(i + 1, len(x)):
            d = r[i] + r[j] - math.hypot(x[j] - x[i], y[j] - y[i])
            if d > 0:
                es += 0.5 * kn * d * d
    return float(e.sum() + es)


def test_energy_conserved_without_damping_and_friction():
    """8 discs (r in [0.7, 1] x 0.01 m) bouncing in a box 0.1 m wide (left,
    right and bottom walls) under gravity, no damping, no friction, dt = 1e-5
    (w dt <= 0.04 for the stiffest pair). Energy E = sum(m v^2/2 + I w^2/2 +
    m g y) + sum(kn d^2/2) evaluated at integer steps with v_n = (v_(n-1/2) +
    v_(n+1/2))/2, sampled every 1000 steps over 1 s (> 100 collisions).
    Bound: max |E - E0| / E0 < 0.1 % (measured ~1e-4).
    """
    rng = np.random.default_rng(3)
    n, L, dt = 8, 0.1, 1e-5
    r = rng.uniform(0.7 * R, R, n)
    x = 0.012 + (L - 0.024) * np.arange(n) / (n - 1)
    y = 0.02 + 0.03 * rng.random(n) + (np.arange(n) % 2) * 0.025
    p = Particles.new(np.column_stack([x, y]), r, RHO, B)
    p.vel[:, AX_X][:] = rng.normal(0, 0.8, n)
    p.vel[:, AX_Y][:] = rng.normal(0, 0.8, n)
    p.spin[:, SP_Z][:] = rng.normal(0, 10.0, n)
    prm = pair_params(mu=0.0)
    model = make_model(dt, disc=prm, wall=prm, gy=-G, bottom=True, left=True, right=True, length=L, r_max=R)
    st = DomainStepper(p, model, reorder=False)
    w_start = p.spin[:, SP_Z].copy()
    energies, contacts_seen, step = [], 0, 0
    prev = set()
    total = int(1.0 / dt)
    while step < total:
        x0, y0, vx0, vy0 = p.pos[:, AX_X].copy(), p.pos[:, AX_Y].copy(), p.vel[:, AX_X].copy(), p.vel[:, AX_Y].copy()
        st.advance(step, 1)
        step += 1
        if step % 1000 == 1:
            energies.append(
                _energy(p, x0, y0, 0.5 * (vx0 + p.vel[:, AX_X]), 0.5 * (vy0 + p.vel[:, AX_Y]), p.spin[:, SP_Z], L, KN0)
            )
        # count contact starts (a contact lasts > 20 steps; sample every 10)
        st.advance(step, 9)
        step += 9
        now = {(i, int(p.hist_id[i, s])) for i in range(n) for s in range(p.hist_n[i])}
        contacts_seen += len(now - prev)
        prev = now
    energies = np.array(energies)
    drift = np.abs(energies - energies[0]).max() / energies[0]
    assert contacts_seen > 100, contacts_seen
    assert drift < 0.001, drift
    assert np.array_equal(p.spin[:, SP_Z], w_start)  # no friction: spins never change


# ------------------------------------------------------------ 10. momentum


def _pair_collision(mu, mur=0.0, steps_per_tc=500):
    """Two unequal discs, oblique off-centre impact (20 deg), spins, damping."""
    ra, rb = R, 0.8 * R
    phi = math.radians(20.0)
    gap = 0.02 * R
    d0 = ra + rb + gap
    x = np.array([0.003, 0.003 + d0 * math.cos(phi)])
    y = np.array([-0.002, -0.002 + d0 * math.sin(phi)])
    p = Particles.new(np.column_stack([x, y]), np.array([ra, rb]), RHO, B)
    p.vel[:, AX_X][:] = [0.35, -0.25]
    p.vel[:, AX_Y][:] = [0.05, -0.02]
    p.spin[:, SP_Z][:] = [20.0, -35.0]
    meff = p.mass[0] * p.mass[1] / p.mass.sum()
    tc = math.pi * math.sqrt(meff / KN0)
    dt = tc / steps_per_tc
    prm = pair_params(zn=0.3, zt=0.3, mu=mu, mur=mur, zr=0.3)
    st = DomainStepper(p, make_model(dt, disc=prm), reorder=False, keep_forces=True)
    tr = trajectory(st, int(3 * tc / dt), forces=True)
    return p, tr, dt


def _angular_momentum(p, tr):
    """L about the origin from the stored state (x_(n+1), v_(n+1/2), w_(n+1/2)).

    For leapfrog x_(n+1) x v_(n+1/2) = x_n x v_(n+1/2), so L changes over a step
    by exactly dt times the torque of the forces at time n.
    """
    m, inertia = p.mass[None, :], p.inertia[None, :]
    orb = m * (tr["x"] * tr["vy"] - tr["y"] * tr["vx"])
    scale = (
        (m * np.hypot(tr["x"], tr["y"]) * np.hypot(tr["vx"], tr["vy"]) + inertia * np.abs(tr["w"])).sum(axis=1).max()
    )
    return (orb + inertia * tr["w"]).sum(axis=1), scale


def test_momentum_of_isolated_pair_exact():
    """Isolated unequal pair (m_b = 0.64 m_a), oblique impact with friction
    mu = 0.5, rolling resistance 0.1, damping 0.3 and spins: the total momentum
    sum(m v) changes by rounding only: max |P_n - P_0| < 1e-12 sum(m |v|) at
    every step. The pair does interact (velocities change by > 10 %).
    """
    p, tr, _ = _pair_collision(mu=0.5, mur=0.1)
    m = p.mass[None, :]
    px = (m * tr["vx"]).sum(axis=1)
    py = (m * tr["vy"]).sum(axis=1)
    scale = (m * np.hypot(tr["vx"], tr["vy"])).sum(axis=1)[0]
    assert np.abs(tr["vx"][-1] - tr["vx"][0]).max() > 0.03
    assert np.abs(tr["tq"]).max() > 0  # friction acted
    assert np.abs(px - px[0]).max() < 1e-12 * scale, np.abs(px - px[0]).max() / scale
    assert np.abs(py - py[0]).max() < 1e-12 * scale, np.abs(py - py[0]).max() / scale


def test_angular_momentum_of_isolated_pair():
    """Angular momentum L = sum(m x × v + I w) about the origin.

    Frictionless pair (mu = 0): central forces only, L conserved to rounding,
    max |L_n - L_0| < 1e-12 L_scale. With friction (mu = 0.5) the engine applies
    the tangential force with lever arms r_a, r_b (the radii) while the centres
    are r_a + r_b - delta apart, so each contact adds a torque delta ft: the
    pair's L must change by exactly dt sum_n delta_n ft_n (checked to 1e-9
    L_scale; ft_n recovered from the recorded torques, tq_a + tq_b =
    (r_a + r_b) ft), and |Delta L| <= delta_max sum |ft| dt. The size of this
    convention-dependent change, |Delta L|/L_scale, is ~1e-3 here (delta/r ~ 1 %).
    """
    p, tr, _ = _pair_collision(mu=0.0)
    L, scale = _angular_momentum(p, tr)
    assert np.abs(L - L[0]).max() < 1e-12 * scale, np.abs(L - L[0]).max() / scale

    p, tr, dt = _pair_collision(mu=0.5)
    L, scale = _angular_momentum(p, tr)
    ra, rb = p.r
    # forces in row k were computed from the positions of row k - 1
    delta = ra + rb - np.hypot(tr["x"][:-1, 1] - tr["x"][:-1, 0], tr["y"][:-1, 1] - tr["y"][:-1, 0])
    ft = (tr["tq"][1:, 0] + tr["tq"][1:, 1]) / (ra + rb)
    assert np.abs(ft).max() > 0
    leak = np.concatenate([[0.0], np.cumsum(dt * np.where(delta > 0, delta, 0.0) * ft)])
    assert np.abs((L - L[0]) - leak).max() < 1e-9 * scale
    assert abs(L[-1] - L[0]) <= delta.max() * np.abs(ft).sum() * dt * (1 + 1e-9)


def test_newton_third_law_random_cluster():
    """Random overlapping cluster of 30 discs (no walls, no gravity) with
    friction, rolling resistance, damping, random velocities and spins: at each
    of 40 steps the sum of all contact forces is zero to rounding,
    |sum fx|, |sum fy| < 1e-13 sum |f|.
    """
    rng = np.random.default_rng(11)
    n = 30
    k = np.arange(n)
    x = (k % 6) * 1.85 * R + rng.uniform(-0.05, 0.05, n) * R
    y = (k // 6) * 1.85 * R + rng.uniform(-0.05, 0.05, n) * R
    p = Particles.new(np.column_stack([x, y]), rng.uniform(0.9 * R, R, n), RHO, B)
    p.id[:] = rng.permutation(1000)[:n]  # ids unrelated to the order
    p.vel[:, AX_X][:] = rng.normal(0, 0.2, n)
    p.vel[:, AX_Y][:] = rng.normal(0, 0.2, n)
    p.spin[:, SP_Z][:] = rng.normal(0, 20.0, n)
    prm = pair_params(zn=0.2, zt=0.2, mu=0.4, mur=0.1, zr=0.2)
    st = DomainStepper(p, make_model(1e-5, disc=prm), reorder=False, keep_forces=True)
    for s in range(40):
        st.advance(s, 1)
        scale = np.abs(st.force[:, AX_X]).sum() + np.abs(st.force[:, AX_Y]).sum()
        assert scale > 0
        assert abs(st.force[:, AX_X].sum()) < 1e-13 * scale, (s, st.force[:, AX_X].sum() / scale)
        assert abs(st.force[:, AX_Y].sum()) < 1e-13 * scale, (s, st.force[:, AX_Y].sum() / scale)


# ------------------------------------------------------ 11. settled bed statics


def all_contacts(p: Particles, model: Model):
    """Every contact force of a state, evaluated with the engine's contact_force
    exactly as the engine's producers do (canonical orientation, stored history).

    Returns a list of (disc index, partner global id (walls < 0), fx, fy) with the
    force on that disc; a disc pair appears twice, once per side.
    """
    cp, walls, dt = model.cp, model.walls, model.dt
    tw = cp.shape[0] - 2
    length = walls[0]
    out = []

    def hist(i, pid):
        for s in range(p.hist_n[i]):
            if p.hist_id[i, s] == pid:
                return p.hist_s[:, :, HS_T][i, s], p.hist_m[:, :, HM_R][i, s]
        return 0.0, 0.0

    for i in range(len(p)):
        c = cp[tw, p.mat[i]]
        for pid, delta, nx, ny, on in (
            (ID_WALL_RIGHT, p.r[i] - (length - p.pos[:, AX_X][i]), -1.0, 0.0, walls[2]),
            (ID_WALL_LEFT, p.r[i] - p.pos[:, AX_X][i], 1.0, 0.0, walls[1]),
            (ID_WALL_BOTTOM, p.r[i] - p.pos[:, AX_Y][i], 0.0, 1.0, walls[3]),
        ):
            if on > 0.5 and delta > 0:
                s, mr = hist(i, pid)
                fn, ft, _, _, _ = contact_force(
                    nx,
                    ny,
                    delta,
                    p.vel[:, AX_X][i],
                    p.vel[:, AX_Y][i],
                    0.0,
                    p.spin[:, SP_Z][i],
                    0.0,
                    p.r[i],
                    p.mass[i],
                    p.inertia[i],
                    p.r[i],
                    s,
                    mr,
                    c[KN],
                    c[KS],
                    c[ZN],
                    c[ZT],
                    c[MU],
                    c[MUR],
                    c[ZR],
                    dt,
                )
                out.append((i, pid, fn * nx + ft * ny, fn * ny - ft * nx))
    dx = p.pos[:, AX_X][None, :] - p.pos[:, AX_X][:, None]
    dy = p.pos[:, AX_Y][None, :] - p.pos[:, AX_Y][:, None]
    rs = p.r[None, :] + p.r[:, None]
    for i, j in zip(*np.nonzero(np.triu(dx * dx + dy * dy < rs * rs, 1))):
        a, b = (i, j) if p.id[i] < p.id[j] else (j, i)
        ddx, ddy = p.pos[:, AX_X][b] - p.pos[:, AX_X][a], p.pos[:, AX_Y][b] - p.pos[:, AX_Y][a]
        d = math.sqrt(ddx * ddx + ddy * ddy)
        nx, ny = ddx / d, ddy / d
        s, mr = hist(a, p.id[b])
        c = cp[p.mat[a], p.mat[b]]
        ma, mb, ia, ib, ra, rb = p.mass[a], p.mass[b], p.inertia[a], p.inertia[b], p.r[a], p.r[b]
        fn, ft, _, _, _ = contact_force(
            nx,
            ny,
            ra + rb - d,
            p.vel[:, AX_X][b] - p.vel[:, AX_X][a],
            p.vel[:, AX_Y][b] - p.vel[:, AX_Y][a],
            p.spin[:, SP_Z][a],
            p.spin[:, SP_Z][b],
            ra,
            rb,
            ma * mb / (ma + mb),
            ia * ib / (ia + ib),
            ra * rb / (ra + rb),
            s,
            mr,
            c[KN],
            c[KS],
            c[ZN],
            c[ZT],
            c[MU],
            c[MUR],
            c[ZR],
            dt,
        )
        bx, by = fn * nx + ft * ny, fn * ny - ft * nx
        out.append((b, int(p.id[a]), bx, by))
        out.append((a, int(p.id[b]), -bx, -by))
    return out


@pytest.fixture(scope="module", params=[0.0, 0.5], ids=["frictionless-walls", "walls-mu0.5"])
def settled(request):
    from ooc_dem.app.bed import settled_bed
    from ooc_dem.model.scenario import load_scenario

    sc = load_scenario(
        "quick", ["soil.n=300", "bin.length=0.12", "wheel.enabled=false", f"contact.soil_wall.friction={request.param}"]
    )
    p = settled_bed(sc)
    model = Model.from_scenario(sc).without_wheel()
    return request.param, p, model, all_contacts(p, model)


def test_settled_bed_wall_reaction_equals_weight(settled):
    """Settled bed of 300 discs in a 0.12 m bin (quick scenario physics).

    Contact forces are evaluated from the settled state with the engine's
    contact_force (all_contacts), first checked against the engine's own per-disc
    sums after one step (relative 1e-12) and against Newton's third law in the
    closed box: sum of all contact forces on discs = sum of wall forces (1e-12 W).
    Then statics: bottom reaction + vertical side-wall friction = weight W =
    sum m g to 1 %; with frictionless walls the side walls carry nothing and the
    bottom reaction alone equals W to 1 %.
    """
    wall_mu, p, model, cts = settled
    n = len(p)
    fx, fy = np.zeros(n), np.zeros(n)
    for i, _, a, b in cts:
        fx[i] += a
        fy[i] += b
    q = p.take(np.arange(n))
    st = DomainStepper(q, model, reorder=False, keep_forces=True)
    st.advance(0, 1)
    scale = np.abs(st.force[:, AX_Y]).max()
    assert np.allclose(fx, st.force[:, AX_X], rtol=0, atol=1e-12 * scale)
    assert np.allclose(fy, st.force[:, AX_Y], rtol=0, atol=1e-12 * scale)
    W = float((p.mass * -model.gravity[AX_Y]).sum())
    bottom = sum(c[3] for c in cts if c[1] == ID_WALL_BOTTOM)
    side = sum(c[3] for c in cts if c[1] in (ID_WALL_LEFT, ID_WALL_RIGHT))
    assert abs(st.force[:, AX_Y].sum() - (bottom + side)) < 1e-12 * W
    assert rel_err(bottom + side, W) < 0.01, (bottom + side) / W
    if wall_mu == 0.0:
        assert side == 0.0
        assert rel_err(bottom, W) < 0.01, bottom / W


def test_settled_bed_pressure_grows_with_depth(settled):
    """Vertical force transmitted across horizontal cuts of the settled bed.

    F_cut(h) = vertical force on the discs with centres above h from the discs
    below. Statics of the discs above: F_cut(h) + S(h) = W_above(h) (S: side-wall
    friction on them), to 1 % of the bed weight, at 6 cut heights; the mean
    vertical pressure F_cut(h)/length grows strictly with depth.
    """
    _, p, model, cts = settled
    g = -model.gravity[AX_Y]
    W = float((p.mass * g).sum())
    length = model.walls[0]
    index_of = {int(gid): k for k, gid in enumerate(p.id)}
    top = float((p.pos[:, AX_Y] + p.r).max())
    pressures = []
    for frac in (0.85, 0.7, 0.55, 0.4, 0.25, 0.1):
        h = frac * top
        up = p.pos[:, AX_Y] >= h
        f_cut = sum(c[3] for c in cts if c[1] >= 0 and up[c[0]] and not up[index_of[c[1]]])
        s_up = sum(c[3] for c in cts if c[1] in (ID_WALL_LEFT, ID_WALL_RIGHT) and up[c[0]])
        w_up = float((p.mass[up] * g).sum())
        assert abs(f_cut + s_up - w_up) < 0.01 * W, (h, f_cut, s_up, w_up)
        pressures.append(f_cut / length)
    assert all(b > a for a, b in zip(pressures, pressures[1:])), pressures
