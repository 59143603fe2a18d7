"""The rigid lugged wheel, the same in both dimensions (numba, no I/O): its lugs'
directions, the soil's reaction summed canonically, its prescribed motion (or its
driving torque, when its spin is free) and its leapfrog integration.

State at step n: positions x_n, velocities v_(n-1/2), contact history at n.
v_(n+1/2) = v_(n-1/2) + a_n dt;  x_(n+1) = x_n + v_(n+1/2) dt.
The particles are advanced in the same pass that gathers their forces
(``gather.gather_integrate``). The wheel's state, geometry and controls are the
records ``layout.WHEEL_STATE`` / ``WHEEL_GEOMETRY`` / ``WHEEL_CONTROLS`` (arrays of
shape (1,)); its axle is along z in both dimensions (3D reads the geometry's width and
z0). Each dimension's contact with the wheel's rim and lugs is its own (``d2.bodies``,
``d3.bodies``).
"""

import math

import numpy as np
from numba import njit

from .chunks import N_CHUNKS
from .detmath import det_cos, det_sin
from .layout import ID_RIM


@njit(cache=True)
def lug_directions(theta, nlugs, lugdir):
    """Unit vectors of the lugs at wheel angle theta (lug k at theta + 2 pi k / n);
    lugdir: LUG_DIRECTION records. cos and sin of the same bits on every machine (detmath),
    not libm's."""
    for k in range(nlugs):
        phi = theta + 2.0 * math.pi * k / nlugs
        lugdir[k].ux = det_cos(phi)
        lugdir[k].uy = det_sin(phi)


@njit(inline="always", cache=True)
def lug_axis_offset(dxw, dyw, ux, uy, lug_in, lug_out):
    """How far along a lug's direction (ux, uy) lies the point of its axis closest to a
    particle at (dxw, dyw) from the axle: the projection, clamped to the lug's extent
    lug_in..lug_out."""
    s = dxw * ux + dyw * uy
    if s < lug_in:
        s = lug_in
    elif s > lug_out:
        s = lug_out
    return s


@njit(cache=True)
def wheel_reaction(gid, bd):
    """Soil force and torque on the wheel: each particle's wheel rows summed in its row
    order (lugs, then rim), then the particles in ascending id (canonical). Returns
    (fx, fy, torque, number of particles touching the wheel); the lateral force of 3D
    goes to the axle."""
    body, bcount = bd.rows, bd.count
    bcap = body.shape[0] // N_CHUNKS
    total = 0
    for ch in range(N_CHUNKS):
        total += bcount[ch]
    keys = np.empty(total, np.int64)
    sx = np.empty(total)
    sy = np.empty(total)
    st = np.empty(total)
    cnt = 0
    for ch in range(N_CHUNKS):
        at = ch * bcap
        end = at + bcount[ch]
        while at < end:
            i = body[at].disc
            if body[at].pid > ID_RIM:  # a wall: no wheel rows for this particle
                at += 1
                continue
            wfx_i = 0.0
            wfy_i = 0.0
            wtq_i = 0.0
            while at < end and body[at].disc == i and body[at].pid <= ID_RIM:
                wfx_i -= body[at].bx
                wfy_i -= body[at].by
                wtq_i += body[at].wt
                at += 1
            keys[cnt] = gid[i]
            sx[cnt] = wfx_i
            sy[cnt] = wfy_i
            st[cnt] = wtq_i
            cnt += 1
    if cnt == 0:
        return 0.0, 0.0, 0.0, 0
    order = np.argsort(keys[:cnt], kind="mergesort")
    fxs = 0.0
    fys = 0.0
    tqs = 0.0
    for o in range(cnt):
        k = order[o]
        fxs += sx[k]
        fys += sy[k]
        tqs += st[k]
    return fxs, fys, tqs, cnt


@njit(cache=True)
def wheel_phase(t, wc):
    """0 while settling (omega = 0, x held), 1 while travelling."""
    return 0 if t < wc[0].settle else 1


@njit(cache=True)
def apply_wheel_controls(t, ws, wg, wc):
    """Set the prescribed components of the wheel velocity for time t (idempotent)."""
    s = ws[0]
    c = wc[0]
    if wheel_phase(t, wc) == 0:
        s.wz = 0.0
        s.vx = 0.0
    elif c.spinmode > 0.5:
        # omega free (integrate_wheel); the carriage free under the drawbar or at a speed
        if c.speedmode > 0.5:
            s.vx = c.speed
    else:
        s.wz = -c.omega  # clockwise drives in +x
        if c.slipmode > 0.5:
            s.vx = (1.0 - c.slip) * wg[0].radius * c.omega
    if c.yfixed > 0.5 and wheel_phase(t, wc) == 1:
        s.vy = 0.0


@njit(cache=True)
def drawbar_force(t, wc):
    """Horizontal drawbar force on the wheel (negative: opposes travel), ramped in."""
    c = wc[0]
    if c.slipmode > 0.5 or c.speedmode > 0.5 or t < c.settle:
        return 0.0
    ramp = c.ramp
    f = 1.0 if ramp <= 0.0 else min(1.0, (t - c.settle) / ramp)
    return -c.drawbar * f


@njit(cache=True)
def drive_torque(t, wc):
    """Driving torque on a free-spinning wheel (clockwise positive: drives in +x), ramped
    in over torque_ramp; 0 while settling and when omega is prescribed."""
    c = wc[0]
    if c.spinmode < 0.5 or t < c.settle:
        return 0.0
    ramp = c.torque_ramp
    f = 1.0 if ramp <= 0.0 else min(1.0, (t - c.settle) / ramp)
    return c.torque * f


@njit(cache=True)
def record_and_integrate_wheel(rec, s, t, ws, wg, wc, fx_soil, fy_soil, torque_soil, contacts, gy, dt):
    """Step s's ``layout.WHEEL_RECORD`` row (the wheel's state at the step's start and the
    soil's reaction), then the wheel's integration: one writer for 2D and 3D."""
    w0 = ws[0]
    r0 = rec[s]
    r0.t = t
    r0.x = w0.x
    r0.y = w0.y
    r0.vx = w0.vx
    r0.vy = w0.vy
    r0.wz = w0.wz
    r0.theta = w0.theta
    r0.fx = fx_soil
    r0.fy = fy_soil
    r0.torque = torque_soil
    r0.drawbar = drawbar_force(t, wc)
    r0.contacts = contacts
    integrate_wheel(t, ws, wg, wc, fx_soil, fy_soil, gy, dt, torque_soil)


@njit(cache=True)
def integrate_wheel(t, ws, wg, wc, fx_soil, fy_soil, gy, dt, torque_soil):
    """The wheel's leapfrog: the free components of its velocity from the soil's reaction,
    the drawbar load, gravity and the driving torque, then its position and angle. The
    soil's torque is counter-clockwise positive, the driving torque clockwise positive."""
    m = wg[0].mass
    s = ws[0]
    c = wc[0]
    phase = wheel_phase(t, wc)
    if phase == 1 and c.slipmode < 0.5 and c.speedmode < 0.5:
        s.vx += (fx_soil + drawbar_force(t, wc)) / m * dt
    held = phase == 1 and c.yfixed > 0.5  # the axle's height held: vy = 0, y as it is
    if not held:
        s.vy += (fy_soil / m + gy) * dt
    s.x += s.vx * dt
    if not held:
        s.y += s.vy * dt
    if phase == 1 and c.spinmode > 0.5:
        s.wz += (torque_soil - drive_torque(t, wc)) / c.inertia * dt
    s.theta += s.wz * dt
    # keep theta bounded without changing lug positions
    if s.theta < -2.0 * math.pi:
        s.theta += 2.0 * math.pi
    elif s.theta > 2.0 * math.pi:
        s.theta -= 2.0 * math.pi
