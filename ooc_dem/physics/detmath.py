"""sin and cos of the same bits on every machine (numba; + - *, floor and frexp only).

A libm's sin and cos (glibc's, picked per CPU, or Intel's SVML when numba finds it) round as
each implementation does; the wheel's lugs take their directions from them every step, so a
one-ulp difference between machines would move the run's bits. These are fdlibm's
algorithms (Sun Microsystems' freely distributable libm, as FreeBSD's msun carries them),
written with IEEE operations only, in a fixed order, compiled without fastmath (no FMA
contraction): the argument reduced by pi/2 with a three-part Cody-Waite split (fdlibm's
``__ieee754_rem_pio2``, medium range, its extra rounds chosen by the exponents as there),
then fdlibm's degree-13 sin and degree-14 cos polynomials on [-pi/4, pi/4] with the
reduction's tail, each in Horner order. Error below one ulp (fdlibm's bound) for
|x| < 2^19 pi (about 1.6e6 rad); beyond that (a wheel that has turned 260 000 times) the
reduction is not exact and the value, still the same on every machine, is less accurate.
"""

import math

from numba import njit

# pi/2 split into parts of 33 bits (n * part exact for n < 2^20) and their tails
_INV_PIO2 = float.fromhex("0x1.45f306dc9c883p-1")  # 2/pi
_PIO2_1 = float.fromhex("0x1.921fb54400000p+0")
_PIO2_1T = float.fromhex("0x1.0b4611a626331p-34")
_PIO2_2 = float.fromhex("0x1.0b4611a600000p-34")
_PIO2_2T = float.fromhex("0x1.3198a2e037073p-69")
_PIO2_3 = float.fromhex("0x1.3198a2e000000p-69")
_PIO2_3T = float.fromhex("0x1.b839a252049c1p-104")
_PIO4 = float.fromhex("0x1.921fb54442d18p-1")  # below this |x| needs no reduction

# fdlibm k_sin.c: sin x ~ x + S1 x^3 + ... + S6 x^13 on [-pi/4, pi/4]
_S1 = float.fromhex("-0x1.5555555555549p-3")
_S2 = float.fromhex("0x1.111111110f8a6p-7")
_S3 = float.fromhex("-0x1.a01a019c161d5p-13")
_S4 = float.fromhex("0x1.71de357b1fe7dp-19")
_S5 = float.fromhex("-0x1.ae5e68a2b9cebp-26")
_S6 = float.fromhex("0x1.5d93a5acfd57cp-33")
# fdlibm k_cos.c: cos x ~ 1 - x^2/2 + C1 x^4 + ... + C6 x^14 on [-pi/4, pi/4]
_C1 = float.fromhex("0x1.555555555554cp-5")
_C2 = float.fromhex("-0x1.6c16c16c15177p-10")
_C3 = float.fromhex("0x1.a01a019cb159p-16")
_C4 = float.fromhex("-0x1.27e4f809c52adp-22")
_C5 = float.fromhex("0x1.1ee9ebdb4b1c4p-29")
_C6 = float.fromhex("-0x1.8fae9be8838d4p-37")


@njit(cache=True)
def _sin_kernel(x, y):
    """sin(x + y) for |x| <= pi/4, y the tail of x (|y| < ulp(x) / 2)."""
    z = x * x
    v = z * x
    r = _S2 + z * (_S3 + z * (_S4 + z * (_S5 + z * _S6)))
    return x - ((z * (0.5 * y - v * r) - y) - v * _S1)


@njit(cache=True)
def _cos_kernel(x, y):
    """cos(x + y) for |x| <= pi/4, y the tail of x."""
    z = x * x
    r = z * (_C1 + z * (_C2 + z * (_C3 + z * (_C4 + z * (_C5 + z * _C6)))))
    hz = 0.5 * z
    w = 1.0 - hz
    return w + (((1.0 - w) - hz) + (z * r - x * y))


@njit(cache=True)
def _exponent(x):
    return math.frexp(x)[1]


@njit(cache=True)
def reduce_pio2(x):
    """(n, y0, y1) with x = n pi/2 + y0 + y1, |y0 + y1| <= pi/4 (about), y1 the tail of y0."""
    ax = abs(x)
    n = math.floor(ax * _INV_PIO2 + 0.5)
    fn = float(n)
    r = ax - fn * _PIO2_1  # exact: fn * _PIO2_1 has at most 53 bits
    w = fn * _PIO2_1T
    y0 = r - w
    j = _exponent(ax)
    if y0 == 0.0 or j - _exponent(y0) > 16:  # cancellation: a second part of pi/2
        t = r
        w = fn * _PIO2_2
        r = t - w
        w = fn * _PIO2_2T - ((t - r) - w)
        y0 = r - w
        if y0 == 0.0 or j - _exponent(y0) > 49:  # and a third
            t = r
            w = fn * _PIO2_3
            r = t - w
            w = fn * _PIO2_3T - ((t - r) - w)
            y0 = r - w
    y1 = (r - y0) - w
    if x < 0.0:
        return -n, -y0, -y1
    return n, y0, y1


@njit(cache=True)
def det_sin(x):
    """sin x, the same bits on every machine (error below one ulp for |x| < 1.6e6)."""
    if abs(x) <= _PIO4:
        return _sin_kernel(x, 0.0)
    if not math.isfinite(x):
        return x - x  # nan
    n, y0, y1 = reduce_pio2(x)
    q = n & 3
    if q == 0:
        return _sin_kernel(y0, y1)
    if q == 1:
        return _cos_kernel(y0, y1)
    if q == 2:
        return -_sin_kernel(y0, y1)
    return -_cos_kernel(y0, y1)


@njit(cache=True)
def det_cos(x):
    """cos x, the same bits on every machine (error below one ulp for |x| < 1.6e6)."""
    if abs(x) <= _PIO4:
        return _cos_kernel(x, 0.0)
    if not math.isfinite(x):
        return x - x  # nan
    n, y0, y1 = reduce_pio2(x)
    q = n & 3
    if q == 0:
        return _cos_kernel(y0, y1)
    if q == 1:
        return -_sin_kernel(y0, y1)
    if q == 2:
        return -_cos_kernel(y0, y1)
    return _sin_kernel(y0, y1)
