"""physics.exactmath: ln, exp and log10 correctly rounded without libm (decimal), against
values known to many digits and by their round trips; the restitution's damping built on it."""

from __future__ import annotations

import math
from decimal import Decimal

import numpy as np
import pytest

from ooc_dem.physics import exactmath
from ooc_dem.physics.d3.layout import beta_of_restitution

# known to 60 digits; float() of a decimal string is the correctly rounded double
LN2 = "0.693147180559945309417232121458176568075500134360255254120680"
LN10 = "2.30258509299404568401799145468436420760110148862877297603333"
E = "2.71828182845904523536028747135266249775724709369995957496697"


def test_known_values():
    assert exactmath.ln(2.0) == float(LN2)
    assert exactmath.ln(0.5) == -float(LN2)
    assert exactmath.ln(10.0) == float(LN10)
    assert exactmath.ln(1.0) == 0.0
    assert exactmath.exp(1.0) == float(E) == math.e
    assert exactmath.exp(0.0) == 1.0
    assert exactmath.exp(float(LN2)) == 2.0
    assert exactmath.log10(1000.0) == 3.0 and exactmath.log10(1e-3) == -3.0 and exactmath.log10(1.0) == 0.0
    assert exactmath.ln(0.25) == -2.0 * float(LN2) and exactmath.ln(8.0) == float(3 * Decimal(LN2))
    assert exactmath.ln(1e-3) == float(-3 * Decimal(LN10))


def test_extremes_and_refusals():
    assert exactmath.exp(-1000.0) == 0.0 and exactmath.exp(1000.0) == math.inf
    assert exactmath.exp(-745.0) == 5e-324  # the smallest subnormal
    for x in (0.0, -1.0, math.nan):
        with pytest.raises(ValueError):
            exactmath.ln(x)
        with pytest.raises(ValueError):
            exactmath.log10(x)
    with pytest.raises(ValueError):
        exactmath.ln_array([1.0, 0.0])


def test_round_trips_and_arrays():
    rng = np.random.default_rng(3)
    x = np.concatenate([rng.uniform(1e-6, 10.0, 2000), rng.uniform(0.5, 2.0, 2000)])
    ln = exactmath.ln_array(x)
    assert np.array_equal(ln, [exactmath.ln(v) for v in x.tolist()])
    back = exactmath.exp_array(ln)
    assert np.array_equal(back, [exactmath.exp(v) for v in ln.tolist()])
    # exp(ln x) near x: ln's rounding (half an ulp of ln x) scaled by x, then exp's
    assert np.all(np.abs(back - x) <= x * np.spacing(np.abs(ln)) + np.spacing(x))
    # and within an ulp of libm's, which is nearly correctly rounded
    assert np.all(np.abs(ln - np.log(x)) <= np.spacing(np.abs(ln)))
    assert exactmath.exp_array(np.zeros((2, 3))).shape == (2, 3)


def test_restitution_damping_uses_the_correctly_rounded_log():
    for e in (0.1, 0.3, 0.5, 0.9):
        le = exactmath.ln(e)
        assert beta_of_restitution(e) == le / math.sqrt(le * le + math.pi * math.pi)
    assert beta_of_restitution(1.0) == 0.0
