"""Leapfrog integration of discs and the wheel (numba, no I/O).

State at step n: positions x_n, velocities v_(n-1/2), contact history at n.
v_(n+1/2) = v_(n-1/2) + a_n dt;  x_(n+1) = x_n + v_(n+1/2) dt.
"""
import math

from numba import njit, prange

from .forces import WG_MASS, WG_R, WS_THETA, WS_VX, WS_VY, WS_WZ, WS_X, WS_Y

# wheel controls wc[...]
WC_SETTLE, WC_OMEGA, WC_SLIPMODE, WC_DRAWBAR, WC_RAMP, WC_SLIP = range(6)
WC_SIZE = 6


N_CHUNKS = 64


@njit(parallel=True, cache=True)
def integrate_discs(n, x, y, vx, vy, w, mass, inertia, fx, fy, tq, gx, gy, dt, xref, yref, part):
    """Advance discs 0..n-1 one step; returns the largest squared displacement since
    the last neighbour build (a max is order-free, so the chunking never changes it).
    part is scratch of N_CHUNKS entries."""
    size = (n + N_CHUNKS - 1) // N_CHUNKS
    for c in prange(N_CHUNKS):
        m = 0.0
        for i in range(c * size, min(n, (c + 1) * size)):
            vx[i] += (fx[i] / mass[i] + gx) * dt
            vy[i] += (fy[i] / mass[i] + gy) * dt
            w[i] += tq[i] / inertia[i] * dt
            x[i] += vx[i] * dt
            y[i] += vy[i] * dt
            ddx = x[i] - xref[i]
            ddy = y[i] - yref[i]
            d = ddx * ddx + ddy * ddy
            if d > m:
                m = d
        part[c] = m
    return part.max()


@njit(cache=True)
def wheel_phase(t, wc):
    """0 while settling (omega = 0, x held), 1 while travelling."""
    return 0 if t < wc[WC_SETTLE] else 1


@njit(cache=True)
def apply_wheel_controls(t, ws, wg, wc):
    """Set the prescribed components of the wheel velocity for time t."""
    if wheel_phase(t, wc) == 0:
        ws[WS_WZ] = 0.0
        ws[WS_VX] = 0.0
    else:
        ws[WS_WZ] = -wc[WC_OMEGA]  # clockwise drives in +x
        if wc[WC_SLIPMODE] > 0.5:
            ws[WS_VX] = (1.0 - wc[WC_SLIP]) * wg[WG_R] * wc[WC_OMEGA]


@njit(cache=True)
def drawbar_force(t, wc):
    """Horizontal drawbar force on the wheel (negative: opposes travel), ramped in."""
    if wc[WC_SLIPMODE] > 0.5 or t < wc[WC_SETTLE]:
        return 0.0
    ramp = wc[WC_RAMP]
    f = 1.0 if ramp <= 0.0 else min(1.0, (t - wc[WC_SETTLE]) / ramp)
    return -wc[WC_DRAWBAR] * f


@njit(cache=True)
def integrate_wheel(t, ws, wg, wc, fx_soil, fy_soil, gy, dt):
    m = wg[WG_MASS]
    phase = wheel_phase(t, wc)
    if phase == 1 and wc[WC_SLIPMODE] < 0.5:
        ws[WS_VX] += (fx_soil + drawbar_force(t, wc)) / m * dt
    ws[WS_VY] += (fy_soil / m + gy) * dt
    ws[WS_X] += ws[WS_VX] * dt
    ws[WS_Y] += ws[WS_VY] * dt
    ws[WS_THETA] += ws[WS_WZ] * dt
    # keep theta bounded without changing lug positions
    if ws[WS_THETA] < -2.0 * math.pi:
        ws[WS_THETA] += 2.0 * math.pi
    elif ws[WS_THETA] > 2.0 * math.pi:
        ws[WS_THETA] -= 2.0 * math.pi
