"""Time-step check of the 3D laws: the critical explicit (leapfrog) step of the
stiffest contact, as the 2D ``scenario.critical_time_step``.

For a mode of angular frequency w and damping ratio z the leapfrog limit is
dt_crit = (2 / w) (sqrt(1 + z^2) - z). The modes of a contact on the lightest sphere
(mass m_min, radius r_min, I = 2/5 m r^2), with ``contacts`` contacts per sphere:
- normal: w^2 = contacts kn / m_min;
- tangential, translation and rotation together: w^2 = contacts kt (1/m + r^2/I)
  = 3.5 contacts kt / m_min (this one is stiffer than the normal mode whenever
  kt > kn / 3.5; the rolling spring kr = kt r^2 on I gives 2.5 contacts kt / m_min, less).
Stiffnesses:
- linear law: kn, kt = ks; damping ratios zn, zt.
- Hertz-Mindlin: the TANGENT stiffness at the largest expected overlap,
  kn = dF/d delta = Sn = 2 E* sqrt(R* delta_max), kt = St = 8 G* sqrt(R* delta_max),
  with delta_max the Hertz maximum overlap of the lightest sphere hitting a rigid
  flat at the largest expected impact speed v_max (R* = r_min, m* = m_min: the largest
  overlap a light sphere reaches, hence the stiffest contact), and damping ratio
  z = -sqrt(5/6) beta (the Tsuji coefficient over 2 sqrt(Sn m)). This is the
  stability limit of the integrator itself; the Rayleigh time (``rayleigh_time``,
  a wave-speed estimate that does not depend on the impact speed and is usually
  quoted with a safety factor of 0.1-0.3) is given for information only.
"""

from __future__ import annotations

import math

from .layout import LAW_HERTZ


def leapfrog_limit(w2: float, z: float) -> float:
    """(2 / w) (sqrt(1 + z^2) - z); inf for w2 <= 0."""
    return 2.0 / math.sqrt(w2) * (math.sqrt(1.0 + z * z) - z) if w2 > 0 else math.inf


def hertz_max_overlap(m_eff, r_eff, estar, v):
    """delta_max = (15 m* v^2 / (16 E* sqrt(R*)))^(2/5) (validation-3d.md section 1)."""
    return (15.0 * m_eff * v * v / (16.0 * estar * math.sqrt(r_eff))) ** 0.4


def hertz_duration(m_eff, r_eff, estar, v):
    """Elastic Hertz contact duration 2.868 (m*^2 / (R* E*^2 v))^(1/5)."""
    return 2.868 * (m_eff * m_eff / (r_eff * estar * estar * v)) ** 0.2


def rayleigh_time(r, density, E, nu):
    """Rayleigh time pi r sqrt(rho / G) / (0.1631 nu + 0.8766) (information only)."""
    G = E / (2.0 * (1.0 + nu))
    return math.pi * r * math.sqrt(density / G) / (0.1631 * nu + 0.8766)


def critical_dt(cp, m_min, r_min, v_max=1.0, contacts=1.0, types=None):
    """(critical step, description of the mode that sets it) over the material pairs
    of the CONTACT_PARAMS table cp (``types``: the (a, b) pairs to check; default all
    with a nonzero stiffness). v_max: largest expected impact speed (Hertz)."""
    worst, which = math.inf, "none"
    n = cp.shape[0]
    pairs = types if types is not None else [(a, b) for a in range(n) for b in range(a, n)]
    for a, b in pairs:
        c = cp[a, b]
        if c["law"] == LAW_HERTZ:
            if c["estar"] <= 0.0:
                continue
            dmax = hertz_max_overlap(m_min, r_min, c["estar"], v_max)
            a_c = math.sqrt(r_min * dmax)
            kn = 2.0 * c["estar"] * a_c
            kt = 8.0 * c["gstar"] * a_c
            zn = zt = -math.sqrt(5.0 / 6.0) * c["beta"]
            law = "hertz"
        else:
            kn, kt, zn, zt = c["kn"], c["ks"], c["zn"], c["zt"]
            law = "linear"
            if kn <= 0.0 and kt <= 0.0:
                continue
        for mode, w2, z in (("normal", contacts * kn / m_min, zn), ("tangential", 3.5 * contacts * kt / m_min, zt)):
            lim = leapfrog_limit(w2, z)
            if lim < worst:
                worst, which = lim, f"{law} pair {a}-{b}, {mode} mode"
    return worst, which


def check_dt(dt, cp, m_min, r_min, v_max=1.0, contacts=1.0, types=None):
    """Raise ValueError when dt exceeds the critical step; returns the critical step."""
    crit, which = critical_dt(cp, m_min, r_min, v_max, contacts, types)
    if dt > crit:
        raise ValueError(
            f"dt = {dt!r} is above the stability limit {crit:.3e} s of the stiffest "
            f"contact ({which}; lightest sphere m = {m_min:.3g} kg, r = {r_min:.3g} m, "
            f"{contacts} contacts, v_max = {v_max} m/s); use dt <= {crit:.3e}"
        )
    return crit
