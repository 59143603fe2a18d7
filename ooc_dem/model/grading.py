"""Grain sizes: radius distributions of a bed and the grading a bed reports.

A soil's grading is measured by sieving: the percent *by mass* of a sample that passes
sieves of given openings (diameters). A DEM bed is drawn by number, one radius a particle,
so a grading given by mass is turned into a number distribution first: a particle's mass
goes as d^k (k = 3 for spheres, 2 for discs of a fixed thickness), so the number density
is the mass density divided by d^k. Every distribution is truncated to [r_min, r_max]:
the time-step check and the neighbour grid rely on those bounds.

Distributions (``Grading.kind``):
- ``uniform``: radii uniform in [r_min, r_max] (one ``rng.uniform`` call: the draw the
  beds were made with before gradings existed, so their bits stay).
- ``normal``: radius ~ N(mean, std), truncated to [r_min, r_max].
- ``lognormal``: ln(radius) ~ N(ln(median), ln(geometric std)), truncated.
- ``sieve``: a sieve curve, (diameter, percent passing by mass) pairs, increasing in both,
  from 0 % to 100 %; between two sieves the mass is spread log-uniformly in diameter (the
  usual reading of a grading curve drawn on a log axis).

A truncated draw inverts the distribution's number CDF, tabulated over [r_min, r_max]: one
uniform number a particle (no rejection loop, so the random stream does not depend on the
parameters).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

KINDS = ("uniform", "normal", "lognormal", "sieve")

# points of a tabulated number CDF per decade of radius: the inverse is linear between
# them, far finer than any sieve series or than a bed's spread of sizes needs
_POINTS_PER_DECADE = 4000


@dataclass(frozen=True)
class Grading:
    """A radius distribution truncated to [r_min, r_max] (SI: metres).

    ``mean``/``std``: the normal law's radius mean and standard deviation; ``median``/
    ``gsd``: the log-normal law's median radius and geometric standard deviation (> 1);
    ``sieve``: ((diameter, percent passing by mass), ...) for the sieve curve."""

    kind: str = "uniform"
    r_min: float = 0.0
    r_max: float = 0.0
    mean: float = 0.0
    std: float = 0.0
    median: float = 0.0
    gsd: float = 0.0
    sieve: tuple[tuple[float, float], ...] = ()


def check_grading(g: Grading) -> str | None:
    """What is wrong with a grading (one line), or None."""
    if g.kind not in KINDS:
        return f"kind {g.kind!r}: must be one of {', '.join(KINDS)}"
    if g.kind == "sieve":
        return _check_sieve(g.sieve)
    if not (0 < g.r_min <= g.r_max) or not math.isfinite(g.r_max):
        return f"r_min = {g.r_min!r}, r_max = {g.r_max!r}: must be finite with 0 < r_min <= r_max"
    if g.kind == "normal":
        if not (math.isfinite(g.mean) and math.isfinite(g.std) and g.std > 0):
            return f"normal: mean = {g.mean!r}, std = {g.std!r}: std must be finite and > 0"
    if g.kind == "lognormal":
        if not (math.isfinite(g.median) and g.median > 0 and math.isfinite(g.gsd) and g.gsd > 1):
            return f"lognormal: median = {g.median!r}, gsd = {g.gsd!r}: median > 0 and gsd > 1 needed"
    return None


def _check_sieve(sieve) -> str | None:
    if len(sieve) < 2:
        return "sieve: at least two (diameter, percent passing) pairs are needed"
    d = [float(a) for a, _ in sieve]
    p = [float(b) for _, b in sieve]
    if not all(math.isfinite(x) and x > 0 for x in d):
        return f"sieve: diameters {d}: must be finite and > 0"
    if any(b <= a for a, b in zip(d, d[1:])):
        return f"sieve: diameters {d}: must increase"
    if any(b < a for a, b in zip(p, p[1:])) or p[0] != 0 or p[-1] != 100:
        return f"sieve: percent passing {p}: must not decrease and must run from 0 to 100"
    return None


def sieve_bounds(sieve) -> tuple[float, float]:
    """(r_min, r_max) of a sieve curve: half its smallest and largest diameters."""
    return 0.5 * float(sieve[0][0]), 0.5 * float(sieve[-1][0])


def draw_radii(g: Grading, n: int, rng: np.random.Generator, k: int) -> np.ndarray:
    """n radii of grading g, drawn from rng; k: the exponent of mass in size (3 spheres,
    2 discs), used only where a grading is given by mass (sieve)."""
    problem = check_grading(g)
    if problem is not None:
        raise ValueError(problem)
    if g.kind == "uniform":
        return rng.uniform(g.r_min, g.r_max, n)
    log_r, cdf = number_cdf(g, k)
    r = np.exp(np.interp(rng.random(n), cdf, log_r))
    lo, hi = radius_bounds(g)
    return np.clip(r, lo, hi)


def radius_bounds(g: Grading) -> tuple[float, float]:
    """The smallest and largest radius grading g can draw."""
    return sieve_bounds(g.sieve) if g.kind == "sieve" else (g.r_min, g.r_max)


def number_cdf(g: Grading, k: int) -> tuple[np.ndarray, np.ndarray]:
    """(ln r, the fraction of particles by number with a smaller radius) of a non-uniform
    grading on a fine grid of ln r over its bounds; draws invert it by linear interpolation."""
    lo, hi = radius_bounds(g)
    m = max(2, int(math.log10(hi / lo) * _POINTS_PER_DECADE) + 1) if hi > lo else 2
    log_r = np.linspace(math.log(lo), math.log(hi), m)
    r = np.exp(log_r)
    if g.kind == "normal":
        density = np.exp(-0.5 * ((r - g.mean) / g.std) ** 2) * r  # per unit ln r
    elif g.kind == "lognormal":
        density = np.exp(-0.5 * ((log_r - math.log(g.median)) / math.log(g.gsd)) ** 2)
    else:
        # mass per unit ln d: the slope of the log-linear passing curve between two sieves
        log_d = np.log([a for a, _ in g.sieve])
        slope = np.diff([b for _, b in g.sieve]) / np.diff(log_d)
        seg = np.clip(np.searchsorted(log_d, log_r + math.log(2.0), side="right") - 1, 0, len(slope) - 1)
        density = slope[seg] * np.exp(-k * log_r)  # number = mass / d^k
    cdf = np.concatenate([[0.0], np.cumsum(0.5 * (density[1:] + density[:-1]) * np.diff(log_r))])
    if not cdf[-1] > 0:
        raise ValueError(f"{g.kind}: no particle between r_min = {lo!r} and r_max = {hi!r}")
    return log_r, cdf / cdf[-1]


def passing(radii: np.ndarray, diameters, k: int) -> np.ndarray:
    """Percent by mass of particles of the given radii finer than each diameter (a sieve
    analysis of a bed; mass as d^k)."""
    d = 2.0 * np.sort(np.asarray(radii, np.float64))
    m = d**k
    cum = np.concatenate([[0.0], np.cumsum(m)]) / m.sum()
    idx = np.searchsorted(d, np.asarray(diameters, np.float64), side="right")
    return 100.0 * cum[idx]


def characteristic_diameters(radii: np.ndarray, k: int, percents=(10, 50, 60)) -> dict[str, float]:
    """d10, d50, d60, ... of a bed: the diameters that the given percents of its mass pass
    (linear in the cumulative mass between particles), and the uniformity coefficient
    cu = d60 / d10 when both are asked for."""
    d = 2.0 * np.sort(np.asarray(radii, np.float64))
    if d.size == 0:
        raise ValueError("no particles")
    m = d**k
    # the cumulative mass fraction at each particle's centre of mass share (a midpoint rule)
    cum = (np.cumsum(m) - 0.5 * m) / m.sum()
    out = {f"d{p:g}": float(np.interp(p / 100.0, cum, d)) for p in percents}
    if "d10" in out and "d60" in out:
        out["cu"] = out["d60"] / out["d10"]
    return out
