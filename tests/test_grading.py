"""Radius distributions against their analytic moments, a sieve curve against a sieve
analysis of the bed drawn from it, the characteristic diameters of a known set, and the
scenario's [soil.grading] through `ooc-dem check`."""

import math
import re

import numpy as np
import pytest

from ooc_dem.model.grading import Grading, characteristic_diameters, check_grading, draw_radii, passing
from ooc_dem.model.scenario import load_scenario
from support.cli import cli_in_process, one_line_error

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
    r = draw_radii(Grading("normal", a, b, r_mean=mu, r_std=sigma), N, np.random.default_rng(1), 3)
    mean, std = _truncated_normal_moments(mu, sigma, a, b)
    assert r.min() >= a and r.max() <= b
    # 5 standard errors of the sample mean / std (the tabulated inverse adds < 1e-4 relative)
    assert abs(r.mean() - mean) < 5 * std / math.sqrt(N)
    assert abs(r.std() - std) < 5 * std / math.sqrt(2 * N) + 1e-4 * std


def test_lognormal_median_and_geometric_spread():
    # bounds 4 geometric standard deviations out: the truncation is negligible (6e-5 of the mass)
    med, gsd = 1.5e-3, 1.3
    g = Grading("lognormal", med / gsd**4, med * gsd**4, r_median=med, gsd=gsd)
    r = draw_radii(g, N, np.random.default_rng(2), 3)
    s = math.log(gsd)
    assert abs(np.log(r).mean() - math.log(med)) < 5 * s / math.sqrt(N)
    assert abs(np.log(r).std() - s) / s < 0.01


@pytest.mark.parametrize("k", [2, 3])
def test_a_bed_drawn_from_a_sieve_curve_passes_its_sieves(k):
    sizes, pct = (0.5e-3, 1e-3, 2e-3, 4e-3, 6e-3), (0, 12, 45, 90, 100)
    g = Grading("sieve", 0.25e-3, 3e-3, sizes=sizes, passing=pct)
    r = draw_radii(g, 1_000_000, np.random.default_rng(3), k)
    got = passing(r, sizes, k)
    # percent by mass is carried by the few largest grains: over 8 seeds at 2e5 grains the
    # spread was 0.54 points (k = 3) and 0.27 (k = 2), so ~0.24 and ~0.12 at 1e6; 1 point is
    # four of those and far below any bias a wrong mass-to-number conversion gives (~10 points)
    assert np.allclose(got, pct, atol=1.0), got
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


def test_a_sieve_curve_is_cut_to_the_bounds():
    # a measured curve with fines below 1 mm and stones above 4 mm: the bed between 1 and 4 mm
    # holds the curve's mass there, renormalised (12..90 % of the whole -> 0..100 %)
    sizes, pct = (0.5e-3, 1e-3, 2e-3, 4e-3, 6e-3), (5, 12, 45, 90, 100)
    g = Grading("sieve", 0.5e-3, 2e-3, sizes=sizes, passing=pct)
    r = draw_radii(g, 400_000, np.random.default_rng(4), 3)
    assert r.min() >= 0.5e-3 and r.max() <= 2e-3
    want = 100 * (np.array([12, 45, 90]) - 12) / (90 - 12)
    assert np.allclose(passing(r, [1e-3, 2e-3, 4e-3], 3), want, atol=1.0)


def test_characteristic_diameters_by_count_are_those_of_the_particles():
    r = np.random.default_rng(5).uniform(1e-3, 2e-3, 50)
    values, counts = np.unique(np.concatenate([r, r, r]), return_counts=True)
    assert characteristic_diameters(values, 3, counts=counts) == characteristic_diameters(np.repeat(r, 3), 3)


SIEVE = {"sizes": (1e-3, 2e-3, 4e-3), "passing": (0, 40, 100)}


@pytest.mark.parametrize(
    "g,needle",
    [
        (Grading("gravel", 1e-3, 2e-3), "kind"),
        (Grading("uniform", 2e-3, 1e-3), "r_min"),
        (Grading("normal", 1e-3, 1e-3, r_mean=1e-3, r_std=1e-4), "r_min < r_max"),
        (Grading("normal", 1e-3, 2e-3, r_mean=1.5e-3, r_std=0.0), "r_std"),
        (Grading("normal", 1e-3, 2e-3, r_mean=2.5e-3, r_std=1e-4), "r_mean"),
        (Grading("lognormal", 1e-3, 2e-3, r_median=1.5e-3, gsd=1.0), "gsd"),
        (Grading("normal", 1e-3, 2e-3, r_mean=1.5e-3, r_std=1e-12), "too narrow"),
        (Grading("lognormal", 1e-3, 2e-3, r_median=0.5e-3, gsd=1.2), "r_median"),
        (Grading("sieve", 0.5e-3, 2e-3, sizes=(1e-3,), passing=(0,)), "2 to"),
        (Grading("sieve", 0.5e-3, 2e-3, sizes=(2e-3, 1e-3), passing=(0, 100)), "increase"),
        (Grading("sieve", 0.5e-3, 2e-3, sizes=(1e-3, 2e-3), passing=(0, 101)), "[0, 100]"),
        (Grading("sieve", 0.5e-3, 2e-3, sizes=(1e-3, 2e-3, 3e-3), passing=(0, 100)), "one percent a sieve"),
        (Grading("sieve", 0.5e-3, 2e-3, sizes=(1e-3, 2e-3, 3e-3, 4e-3), passing=(0, 60, 50, 100)), "not decrease"),
        (Grading("sieve", 2.5e-3, 3e-3, **SIEVE), "no mass"),
    ],
)
def test_bad_gradings_are_named(g, needle):
    assert needle in check_grading(g)
    with pytest.raises(ValueError, match=re.escape(needle)):
        draw_radii(g, 10, np.random.default_rng(0), 3)


# ---------------------------------------------------------------- the scenario's grading


@pytest.mark.parametrize(
    "sets,needle",
    [
        (['soil.grading.kind="gravel"'], "soil.grading.kind"),
        (["soil.grading.r_mean=0.002"], "soil.grading.r_mean"),  # a key of another kind
        (['soil.grading.kind="normal"', "soil.grading.r_mean=0.002", "soil.grading.r_std=0"], "soil.grading.r_std"),
        (['soil.grading.kind="normal"', "soil.grading.r_mean=0.003", "soil.grading.r_std=1e-4"], "r_mean"),
        (['soil.grading.kind="lognormal"', "soil.grading.r_median=0.002", "soil.grading.gsd=0.9"], "gsd"),
        (['soil.grading.kind="sieve"', "soil.grading.sizes=[4e-3, 3e-3]", "soil.grading.passing=[0, 100]"], "increase"),
        (['soil.grading.kind="sieve"', "soil.grading.sizes=[3e-3, 5e-3]", "soil.grading.passing=[50, 20]"], "decrease"),
        (['soil.grading.kind="sieve"', "soil.grading.sizes=[3e-3, 5e-3]", "soil.grading.passing=[0, 120]"], "[0, 100]"),
        (['soil.grading.kind="sieve"', "soil.grading.sizes=[3e-3, 5e-3]", "soil.grading.passing=[0]"], "passing"),
        (['soil.grading.kind="sieve"', "soil.grading.sizes=[5e-3, 6e-3]", "soil.grading.passing=[0, 100]"], "no mass"),
        (['soil.grading.kind="sieve"', 'soil.grading.sizes="3 mm"'], "soil.grading.sizes"),
    ],
)
def test_a_bad_grading_is_a_one_line_error(sets, needle):
    cp = cli_in_process("check", "quick", *sum((["--set", s] for s in sets), []))
    one_line_error(cp, needle)


def test_a_grading_that_holds_is_checked_and_kept_in_the_scenario():
    sets = [
        'soil.grading.kind="lognormal"',
        "soil.grading.r_median=0.002",
        "soil.grading.gsd=1.1",
    ]
    assert cli_in_process("check", "quick", *sum((["--set", s] for s in sets), [])).returncode == 0
    sc = load_scenario("quick", sets)
    assert sc.soil.grading.kind == "lognormal" and sc.hash() != load_scenario("quick").hash()
    assert sc.bed_hash() != load_scenario("quick").bed_hash()  # another bed, another cache entry


def test_a_graded_scenario_is_stored_and_read_back_and_the_default_leaves_the_hashes():
    from ooc_dem.model.scenario import scenario_from_toml

    sets = [
        'soil.grading.kind="sieve"',
        "soil.grading.sizes=[3.6e-3, 4e-3, 4.4e-3]",
        "soil.grading.passing=[0, 45, 100]",
    ]
    sc = load_scenario("quick", sets)
    assert sc.soil.grading.sizes == (3.6e-3, 4e-3, 4.4e-3) and sc.soil.grading.passing == (0.0, 45.0, 100.0)
    back = scenario_from_toml(sc.to_toml())
    assert back == sc and back.hash() == sc.hash()
    # the default grading is no part of the hashes: every scenario keeps its hash and cached bed
    assert "grading" not in load_scenario("quick")._hash_dict()["soil"]
    assert "grading" in sc._hash_dict()["soil"]
