"""Radius distributions against their analytic moments, a sieve curve against a sieve
analysis of the bed drawn from it, and the characteristic diameters of a known set."""

import math

import numpy as np
import pytest

from ooc_dem.model.grading import Grading, characteristic_diameters, check_grading, draw_radii, passing

N = 200_000


def _truncated_normal_moments(mu, sigma, a, b):
    """Mean and standard deviation of N(mu, sigma) truncated to [a, b] (closed form)."""
    phi = lambda x: math.exp(-0.5 * x * x) / math.sqrt(2 * math.pi)  # noqa: E731
    Phi = lambda x: 0.5 * (1 + math.erf(x / math.sqrt(2)))  # noqa: E731
    al, be = (a - mu) / sigma, (b - mu) / sigma
    z = Phi(be) - Phi(al)
    mean = mu + sigma * (phi(al) - phi(be)) / z
    var = sigma**2 * (1 + (al * phi(al) - be * phi(be)) / z - ((phi(al) - phi(be)) / z) ** 2)
    return mean, math.sqrt(var)


def test_uniform_is_the_draw_beds_were_made_with():
    g = Grading("uniform", 1e-3, 2e-3)
    a = draw_radii(g, 1000, np.random.default_rng(7), 3)
    assert np.array_equal(a, np.random.default_rng(7).uniform(1e-3, 2e-3, 1000))


@pytest.mark.parametrize("mu,sigma,a,b", [(2e-3, 0.4e-3, 1e-3, 3e-3), (2e-3, 1e-3, 1.5e-3, 3e-3)])
def test_truncated_normal_matches_its_closed_form_moments(mu, sigma, a, b):
    r = draw_radii(Grading("normal", a, b, mean=mu, std=sigma), N, np.random.default_rng(1), 3)
    mean, std = _truncated_normal_moments(mu, sigma, a, b)
    assert r.min() >= a and r.max() <= b
    # 5 standard errors of the sample mean / std (the tabulated inverse adds < 1e-4 relative)
    assert abs(r.mean() - mean) < 5 * std / math.sqrt(N)
    assert abs(r.std() - std) < 5 * std / math.sqrt(2 * N) + 1e-4 * std


def test_lognormal_median_and_geometric_spread():
    # bounds 4 geometric standard deviations out: the truncation is negligible (6e-5 of the mass)
    med, gsd = 1.5e-3, 1.3
    g = Grading("lognormal", med / gsd**4, med * gsd**4, median=med, gsd=gsd)
    r = draw_radii(g, N, np.random.default_rng(2), 3)
    s = math.log(gsd)
    assert abs(np.log(r).mean() - math.log(med)) < 5 * s / math.sqrt(N)
    assert abs(np.log(r).std() - s) / s < 0.01


@pytest.mark.parametrize("k", [2, 3])
def test_a_bed_drawn_from_a_sieve_curve_passes_its_sieves(k):
    sieve = ((0.5e-3, 0), (1e-3, 12), (2e-3, 45), (4e-3, 90), (6e-3, 100))
    r = draw_radii(Grading("sieve", sieve=sieve), 1_000_000, np.random.default_rng(3), k)
    got = passing(r, [d for d, _ in sieve], k)
    # percent by mass is carried by the few largest grains: over 8 seeds at 2e5 grains the
    # spread was 0.54 points (k = 3) and 0.27 (k = 2), so ~0.24 and ~0.12 at 1e6; 1 point is
    # four of those and far below any bias a wrong mass-to-number conversion gives (~10 points)
    assert np.allclose(got, [p for _, p in sieve], atol=1.0), got
    assert r.min() >= 0.25e-3 and r.max() <= 3e-3


def test_characteristic_diameters_of_a_known_set():
    # equal masses at diameters 1..10 mm (k = 0: mass independent of size): d50 lies between
    # the fifth and the sixth, d10 at the first's midpoint share
    radii = 0.5e-3 * np.arange(1, 11)
    c = characteristic_diameters(radii, k=0)
    assert c["d50"] == pytest.approx(5.5e-3)
    assert c["d10"] == pytest.approx(1.5e-3)
    assert c["cu"] == pytest.approx(c["d60"] / c["d10"])
    assert np.allclose(passing(radii, [1e-3, 5e-3, 10e-3], k=0), [10, 50, 100])


@pytest.mark.parametrize(
    "g,needle",
    [
        (Grading("gravel", 1e-3, 2e-3), "kind"),
        (Grading("uniform", 2e-3, 1e-3), "r_min"),
        (Grading("normal", 1e-3, 2e-3, mean=1.5e-3, std=0.0), "std"),
        (Grading("lognormal", 1e-3, 2e-3, median=1.5e-3, gsd=1.0), "gsd"),
        (Grading("sieve", sieve=((1e-3, 0),)), "two"),
        (Grading("sieve", sieve=((2e-3, 0), (1e-3, 100))), "increase"),
        (Grading("sieve", sieve=((1e-3, 10), (2e-3, 100))), "0 to 100"),
        (Grading("sieve", sieve=((1e-3, 0), (2e-3, 60), (3e-3, 50), (4e-3, 100))), "0 to 100"),
    ],
)
def test_bad_gradings_are_named(g, needle):
    assert needle in check_grading(g)
    with pytest.raises(ValueError, match=needle):
        draw_radii(g, 10, np.random.default_rng(0), 3)
