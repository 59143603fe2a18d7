"""Grain sizes: radius distributions of a bed and the grading a bed reports.

A soil's grading is measured by sieving: the percent *by mass* of a sample that passes
sieves of given openings (diameters). A DEM bed is drawn by number, one radius a particle,
so a grading given by mass is turned into a number distribution first: a particle's mass
goes as d^k (k = 3 for spheres, 2 for discs of a fixed thickness), so the number density
is the mass density divided by d^k. Every distribution is truncated to [r_min, r_max]:
the time-step check and the neighbour grid rely on those bounds.

Distributions (``Grading.kind``; the scenario's ``[soil.grading]``, docs/reference/grading.md):
- ``uniform``: radii uniform in [r_min, r_max] (one ``rng.uniform`` call: the draw the
  beds were made with before gradings existed, so their bits stay).
- ``normal``: radius ~ N(r_mean, r_std), truncated to [r_min, r_max].
- ``lognormal``: ln(radius) ~ N(ln(r_median), ln(gsd)), truncated.
- ``sieve``: a sieve curve, openings ``sizes`` (diameters, increasing) and the percent by
  mass ``passing`` each (not decreasing, in [0, 100]); between two sieves the mass is spread
  log-uniformly in diameter (the usual reading of a grading curve drawn on a log axis).
  Truncated like the others: only the curve's mass between diameters 2 r_min and 2 r_max
  is drawn (none below its first sieve or above its last), so a measured curve is entered
  as measured and its fines or its largest stones are cut off by the bounds.

A truncated draw inverts the distribution's number CDF, tabulated over [r_min, r_max]: one
uniform number a particle (no rejection loop, so the random stream does not depend on the
parameters).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..physics import exactmath

if TYPE_CHECKING:
    from .schema import Soil

KINDS = ("uniform", "normal", "lognormal", "sieve")
# the parameters each kind reads (the others must stay at their defaults)
PARAMETERS = {
    "uniform": (),
    "normal": ("r_mean", "r_std"),
    "lognormal": ("r_median", "gsd"),
    "sieve": ("sizes", "passing"),
}
MAX_SIEVES = 1000  # pairs of a sieve curve (a sieve series has a few dozen at most)

# points of a tabulated number CDF per decade of radius: the inverse is linear between
# them, far finer than any sieve series or than a bed's spread of sizes needs (a spread
# below their spacing, 0.06 % of the radius, is drawn as that spacing)
_POINTS_PER_DECADE = 4000


@dataclass(frozen=True)
class Grading:
    """A radius distribution truncated to [r_min, r_max] (SI: metres).

    ``r_mean``/``r_std``: the normal law's radius mean and standard deviation; ``r_median``/
    ``gsd``: the log-normal law's median radius and geometric standard deviation (> 1);
    ``sizes``/``passing``: the sieve curve, openings (diameters) and percent passing by mass."""

    kind: str = "uniform"
    r_min: float = 0.0
    r_max: float = 0.0
    r_mean: float = 0.0
    r_std: float = 0.0
    r_median: float = 0.0
    gsd: float = 0.0
    sizes: tuple[float, ...] = ()
    passing: tuple[float, ...] = ()


def check_grading(g: Grading, key: Callable[[str], str] = str) -> str | None:
    """What is wrong with a grading (one line), or None. ``key`` names a field in the
    message (the scenario's soil.r_min, soil.grading.r_std, ...)."""
    if g.kind not in KINDS:
        return f"{key('kind')} = {g.kind!r}: must be one of {', '.join(map(repr, KINDS))}"
    lo, hi = g.r_min, g.r_max
    if not (0 < lo <= hi < math.inf):
        return f"{key('r_min')} = {lo!r}, {key('r_max')} = {hi!r}: must be finite with 0 < r_min <= r_max"
    if g.kind == "uniform":
        return None
    if not lo < hi:
        return f"{key('kind')} = {g.kind!r}: a distribution needs {key('r_min')} < {key('r_max')} (both {lo!r})"
    if g.kind == "normal":
        if not lo <= g.r_mean <= hi:
            return f"{key('r_mean')} = {g.r_mean!r}: must lie in [{key('r_min')}, {key('r_max')}] = [{lo!r}, {hi!r}]"
        if not (0 < g.r_std < math.inf):
            return f"{key('r_std')} = {g.r_std!r}: must be finite and > 0"
    elif g.kind == "lognormal":
        if not lo <= g.r_median <= hi:
            return (
                f"{key('r_median')} = {g.r_median!r}: must lie in [{key('r_min')}, {key('r_max')}] = [{lo!r}, {hi!r}]"
            )
        if not (1 < g.gsd < math.inf):
            return f"{key('gsd')} = {g.gsd!r}: the geometric standard deviation must be finite and > 1"
    else:
        return _check_sieve(g, key)
    if not _tabulated(g, 3)[1][-1] > 0:  # a spread far below the grid's spacing, all of it between two points
        spread = key("r_std") if g.kind == "normal" else key("gsd")
        return (
            f"{spread} = {g.r_std if g.kind == 'normal' else g.gsd!r}: too narrow to draw from "
            f"(no mass on a grid of {_POINTS_PER_DECADE} radii a decade); for grains of one size use "
            f"{key('kind')} = 'uniform' with close {key('r_min')} and {key('r_max')}"
        )
    return None


def _check_sieve(g: Grading, key: Callable[[str], str]) -> str | None:
    d, p = g.sizes, g.passing
    if len(d) < 2 or len(d) > MAX_SIEVES:
        return f"{key('sizes')}: {len(d)} sieves; a sieve curve has 2 to {MAX_SIEVES}"
    if len(p) != len(d):
        return f"{key('passing')}: {len(p)} values for {len(d)} {key('sizes')}: one percent a sieve"
    if not all(0 < x < math.inf for x in d):
        return f"{key('sizes')} = {_short(d)}: openings must be finite and > 0 (m)"
    if any(b <= a for a, b in zip(d, d[1:])):
        return f"{key('sizes')} = {_short(d)}: openings must increase"
    if not all(0 <= x <= 100 for x in p):
        return f"{key('passing')} = {_short(p)}: percents must lie in [0, 100]"
    if any(b < a for a, b in zip(p, p[1:])):
        return f"{key('passing')} = {_short(p)}: percents passing must not decrease with the opening"
    lo, hi = curve_passing(g, [2 * g.r_min, 2 * g.r_max])
    if not hi > lo:
        return (
            f"{key('sizes')}, {key('passing')}: no mass between the diameters 2 {key('r_min')} = "
            f"{2 * g.r_min!r} and 2 {key('r_max')} = {2 * g.r_max!r} (the curve passes {lo:g} % and {hi:g} %)"
        )
    return None


def _short(values: Sequence[float], limit: int = 8) -> str:
    """An array as a one-line message shows it (the first ``limit`` values)."""
    shown = ", ".join(repr(v) for v in values[:limit])
    return f"[{shown}{', ...' if len(values) > limit else ''}]"


def curve_passing(g: Grading, diameters: ArrayLike) -> NDArray[np.float64]:
    """Percent passing of sieve grading g's curve at the given diameters: log-linear between
    its sieves, flat outside them (untruncated: the curve as entered)."""
    log_d = np.log(np.asarray(g.sizes, np.float64))
    return np.interp(np.log(np.asarray(diameters, np.float64)), log_d, np.asarray(g.passing, np.float64))


def draw_radii(g: Grading, n: int, rng: np.random.Generator, k: int) -> NDArray[np.float64]:
    """n radii of grading g, drawn from rng; k: the exponent of mass in size (3 spheres,
    2 discs), used only where a grading is given by mass (sieve)."""
    problem = check_grading(g)
    if problem is not None:
        raise ValueError(problem)
    if g.kind == "uniform":
        return rng.uniform(g.r_min, g.r_max, n)
    log_r, cdf = number_cdf(g, k)
    # exp correctly rounded (exactmath), not numpy's: a drawn radius is the same on every machine
    r = exactmath.exp_array(np.interp(rng.random(n), cdf, log_r))
    return np.clip(r, g.r_min, g.r_max)


def number_cdf(g: Grading, k: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(ln r, the fraction of particles by number with a smaller radius) of a non-uniform
    grading on a fine grid of ln r over [r_min, r_max]; draws invert it by linear interpolation."""
    log_r, cdf = _tabulated(g, k)
    if not cdf[-1] > 0:
        raise ValueError(f"{g.kind}: no particle between r_min = {g.r_min!r} and r_max = {g.r_max!r}")
    return log_r, cdf / cdf[-1]


def _tabulated(g: Grading, k: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(ln r, the number CDF not yet normalised) on number_cdf's grid."""
    lo, hi = g.r_min, g.r_max
    # every ln and exp of the grid correctly rounded (exactmath): the same CDF on every machine
    m = max(2, int(exactmath.log10(hi / lo) * _POINTS_PER_DECADE) + 1)
    log_r = np.linspace(exactmath.ln(lo), exactmath.ln(hi), m)
    r = exactmath.exp_array(log_r)
    if g.kind == "normal":
        with np.errstate(over="ignore", under="ignore"):  # far tails of a narrow law: 0
            density = exactmath.exp_array(-0.5 * ((r - g.r_mean) / g.r_std) ** 2) * r  # per unit ln r
    elif g.kind == "lognormal":
        with np.errstate(over="ignore", under="ignore"):
            density = exactmath.exp_array(-0.5 * ((log_r - exactmath.ln(g.r_median)) / exactmath.ln(g.gsd)) ** 2)
    else:
        # mass per unit ln d: the slope of the log-linear passing curve between two sieves,
        # none below the first sieve or above the last (the curve says nothing there)
        log_d = exactmath.ln_array(g.sizes)
        slope = np.diff(np.asarray(g.passing, np.float64)) / np.diff(log_d)
        x = log_r + exactmath.ln(2.0)
        seg = np.clip(np.searchsorted(log_d, x, side="right") - 1, 0, len(slope) - 1)
        inside = (x >= log_d[0]) & (x <= log_d[-1])
        density = np.where(inside, slope[seg], 0.0) * exactmath.exp_array(-k * log_r)  # number = mass / d^k
    cdf = np.concatenate([[0.0], np.cumsum(0.5 * (density[1:] + density[:-1]) * np.diff(log_r))])
    return log_r, cdf


def passing(radii: ArrayLike, diameters: ArrayLike, k: int) -> NDArray[np.float64]:
    """Percent by mass of particles of the given radii finer than each diameter (a sieve
    analysis of a bed; mass as d^k)."""
    d = 2.0 * np.sort(np.asarray(radii, np.float64))
    m = d**k
    cum = np.concatenate([[0.0], np.cumsum(m)]) / m.sum()
    idx = np.searchsorted(d, np.asarray(diameters, np.float64), side="right")
    return 100.0 * cum[idx]


def characteristic_diameters(
    radii: ArrayLike, k: int, percents: Sequence[float] = (10, 50, 60), counts: ArrayLike | None = None
) -> dict[str, float]:
    """d10, d50, d60, ... of a bed: the diameters that the given percents of its mass pass
    (linear in the cumulative mass between sizes), and the uniformity coefficient
    cu = d60 / d10 when both are asked for. ``counts``: how many particles have each of the
    (distinct, increasing) ``radii``; without it every radius is one particle."""
    if counts is None:
        r, c = np.unique(np.asarray(radii, np.float64), return_counts=True)
    else:
        r, c = np.asarray(radii, np.float64), np.asarray(counts, np.float64)
    d = 2.0 * r
    if d.size == 0:
        raise ValueError("no particles")
    m = c * d**k
    # the cumulative mass fraction at the middle of each size's share (a midpoint rule)
    cum = (np.cumsum(m) - 0.5 * m) / m.sum()
    out = {f"d{p:g}": float(np.interp(p / 100.0, cum, d)) for p in percents}
    if "d10" in out and "d60" in out:
        out["cu"] = out["d60"] / out["d10"]
    return out


def grading_of_soil(soil: Soil) -> Grading:
    """The Grading of a scenario's [soil] section: its [soil.grading] between soil.r_min and
    soil.r_max."""
    g = soil.grading
    return Grading(
        kind=g.kind,
        r_min=soil.r_min,
        r_max=soil.r_max,
        r_mean=g.r_mean,
        r_std=g.r_std,
        r_median=g.r_median,
        gsd=g.gsd,
        sizes=tuple(g.sizes),
        passing=tuple(g.passing),
    )


def mean_power(g: Grading, p: int, k: int) -> float:
    """The mean of r^p over the grains of grading g (by number); k: the exponent of mass in
    size (3 spheres, 2 discs) that a sieve curve is read with."""
    lo, hi = g.r_min, g.r_max
    if g.kind == "uniform":
        if hi <= lo:
            return float(lo**p)
        return float((hi ** (p + 1) - lo ** (p + 1)) / ((p + 1) * (hi - lo)))
    log_r, cdf = number_cdf(g, k)
    mid = np.exp(0.5 * (log_r[1:] + log_r[:-1]))
    return float(np.sum(mid**p * np.diff(cdf)))
