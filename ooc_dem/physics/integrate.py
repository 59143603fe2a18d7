"""Leapfrog integration of the wheel, and its prescribed motion (numba, no I/O).

State at step n: positions x_n, velocities v_(n-1/2), contact history at n.
v_(n+1/2) = v_(n-1/2) + a_n dt;  x_(n+1) = x_n + v_(n+1/2) dt.
The discs are advanced in the same pass that gathers their forces
(``forces.gather_integrate``). The wheel's state, geometry and controls are the
records ``layout.WHEEL_STATE`` / ``WHEEL_GEOMETRY`` / ``WHEEL_CONTROLS`` (arrays of
shape (1,)).
"""
import math

from numba import njit

from .forces import N_CHUNKS  # noqa: F401
from .layout import (WC_DRAWBAR, WC_OMEGA, WC_RAMP, WC_SETTLE, WC_SIZE, WC_SLIP,  # noqa: F401
                     WC_SLIPMODE)


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
    else:
        s.wz = -c.omega  # clockwise drives in +x
        if c.slipmode > 0.5:
            s.vx = (1.0 - c.slip) * wg[0].radius * c.omega


@njit(cache=True)
def drawbar_force(t, wc):
    """Horizontal drawbar force on the wheel (negative: opposes travel), ramped in."""
    c = wc[0]
    if c.slipmode > 0.5 or t < c.settle:
        return 0.0
    ramp = c.ramp
    f = 1.0 if ramp <= 0.0 else min(1.0, (t - c.settle) / ramp)
    return -c.drawbar * f


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
    integrate_wheel(t, ws, wg, wc, fx_soil, fy_soil, gy, dt)


@njit(cache=True)
def integrate_wheel(t, ws, wg, wc, fx_soil, fy_soil, gy, dt):
    m = wg[0].mass
    s = ws[0]
    phase = wheel_phase(t, wc)
    if phase == 1 and wc[0].slipmode < 0.5:
        s.vx += (fx_soil + drawbar_force(t, wc)) / m * dt
    s.vy += (fy_soil / m + gy) * dt
    s.x += s.vx * dt
    s.y += s.vy * dt
    s.theta += s.wz * dt
    # keep theta bounded without changing lug positions
    if s.theta < -2.0 * math.pi:
        s.theta += 2.0 * math.pi
    elif s.theta > 2.0 * math.pi:
        s.theta -= 2.0 * math.pi
