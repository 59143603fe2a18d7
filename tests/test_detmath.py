"""physics.detmath: sin and cos in + - * only (the same bits on every machine), against
libm's over a dense sample, exact at 0, symmetric, and rounding as Python's doubles do
(compiled without FMA contraction); the wheel's lug directions are theirs."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import numpy as np
from numba import njit

from ooc_dem.physics.detmath import det_cos, det_sin, reduce_pio2


@njit(cache=True)
def _both(x, s, c):
    for i in range(x.size):
        s[i] = det_sin(x[i])
        c[i] = det_cos(x[i])


def _sample():
    rng = np.random.default_rng(7)
    k = np.arange(1.0, 6400.0)
    near = k * (math.pi / 2)  # arguments close to multiples of pi/2: the reduction's hard cases
    return np.concatenate(
        [
            np.linspace(-20.0, 20.0, 100001),
            rng.uniform(-1e4, 1e4, 100000),
            rng.uniform(-1e-3, 1e-3, 2000),
            near,
            np.nextafter(near, 0.0),
            np.nextafter(near, 1e5),
            [1e-300, 5e-324, 0.7853981633974483, 0.7853981633974484, 1.5e6],
        ]
    )


def _ulps(a, b):
    return np.abs(a - b) / np.spacing(np.maximum(np.abs(a), np.abs(b)))


def test_within_two_ulps_of_libm():
    x = _sample()
    s, c = np.empty_like(x), np.empty_like(x)
    _both(x, s, c)
    libm_s = np.array([math.sin(v) for v in x.tolist()])
    libm_c = np.array([math.cos(v) for v in x.tolist()])
    assert _ulps(s, libm_s).max() <= 2.0 and _ulps(c, libm_c).max() <= 2.0
    assert np.all(np.abs(s) <= 1.0) and np.all(np.abs(c) <= 1.0)


def test_exact_at_zero_symmetric_and_nan():
    assert det_sin(0.0) == 0.0 and math.copysign(1.0, det_sin(-0.0)) == -1.0 and det_cos(0.0) == 1.0
    x = _sample()[::7]
    for v in x.tolist():
        assert det_sin(-v) == -det_sin(v) and det_cos(-v) == det_cos(v)
    for v in (math.inf, -math.inf, math.nan):
        assert math.isnan(det_sin(v)) and math.isnan(det_cos(v))


def test_reduction():
    n, y0, y1 = reduce_pio2(4.0 * math.pi)
    assert n == 8 and abs(y0) < 1e-15 and abs(y1) < abs(y0) * 1e-15
    n, y0, _ = reduce_pio2(-3.0)
    assert n == -2 and abs(y0 - (-3.0 + math.pi)) < 1e-15


def test_compiled_bits_are_pythons():
    """The same operations run by Python (numba's JIT off, every operation a correctly
    rounded double) give the compiled bits: no fused multiply-add, no reordering."""
    x = _sample()[::50]
    s, c = np.empty_like(x), np.empty_like(x)
    _both(x, s, c)
    code = (
        "import json, sys\n"
        "from ooc_dem.physics.detmath import det_cos, det_sin\n"
        "x = json.load(sys.stdin)\n"
        "print(json.dumps([[det_sin(v).hex(), det_cos(v).hex()] for v in x]))\n"
    )
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    cp = subprocess.run(
        [sys.executable, "-c", code], input=json.dumps(x.tolist()), capture_output=True, text=True, env=env, check=True
    )
    py = json.loads(cp.stdout)
    assert [a for a, _ in py] == [float(v).hex() for v in s]
    assert [b for _, b in py] == [float(v).hex() for v in c]


def test_lug_directions_are_detmaths():
    from ooc_dem.physics.layout import LUG_DIRECTION
    from ooc_dem.physics.wheel import lug_directions

    lugdir = np.zeros(12, LUG_DIRECTION)
    for theta in (0.0, -0.3, -1.7, -4.9, 1234.5):
        lug_directions(theta, 12, lugdir)
        phi = [theta + 2.0 * math.pi * k / 12 for k in range(12)]
        assert np.array_equal(lugdir["ux"], [det_cos(p) for p in phi])
        assert np.array_equal(lugdir["uy"], [det_sin(p) for p in phi])
