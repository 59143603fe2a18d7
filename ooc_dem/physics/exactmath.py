"""Correctly rounded ln, exp and log10 of doubles, without libm.

IEEE 754 rounds ``+ - * /`` and ``sqrt`` correctly on every machine; a libm's ``log``,
``exp`` or ``pow`` (and numpy's own SIMD versions) round as each implementation does, so a
set-up value computed with them may differ by an ulp between machines, and every step
after it. The values here go through ``decimal``: its ``ln``, ``exp`` and ``log10`` are
correctly rounded at the context's precision (``PRECISION`` digits, far more than a
double's 17), and ``float(Decimal)`` rounds that to the nearest double. The result is the
correctly rounded double but for a value lying within 10^-(PRECISION - 17) of a midpoint
between two doubles; whatever it is, it is the same on every machine.

Scalars for the set-up constants; ``exp_array`` and ``ln_array`` for the grid and the draws
of a non-uniform grading (one value at a time: docs/benchmarks.md says what that costs).
"""

from __future__ import annotations

from decimal import Context, Decimal

import numpy as np
from numpy.typing import ArrayLike, NDArray

PRECISION = 40
_CONTEXT = Context(prec=PRECISION)


def ln(x: float) -> float:
    """The natural logarithm of x > 0, correctly rounded."""
    if not x > 0.0:
        raise ValueError(f"ln({x!r}): defined for x > 0 only")
    return float(_CONTEXT.ln(Decimal(float(x))))


def exp(x: float) -> float:
    """e^x, correctly rounded (0.0 below the smallest subnormal, inf above the largest double)."""
    return float(_CONTEXT.exp(Decimal(float(x))))


def log10(x: float) -> float:
    """The base-10 logarithm of x > 0, correctly rounded (exact at powers of ten)."""
    if not x > 0.0:
        raise ValueError(f"log10({x!r}): defined for x > 0 only")
    return float(_CONTEXT.log10(Decimal(float(x))))


def exp_array(a: ArrayLike) -> NDArray[np.float64]:
    """exp of every value of a float64 array, each correctly rounded."""
    x = np.asarray(a, np.float64)
    c = _CONTEXT
    return np.array([float(c.exp(Decimal(v))) for v in x.ravel().tolist()], np.float64).reshape(x.shape)


def ln_array(a: ArrayLike) -> NDArray[np.float64]:
    """ln of every value (> 0) of a float64 array, each correctly rounded."""
    x = np.asarray(a, np.float64)
    if x.size and not np.all(x > 0.0):
        raise ValueError("ln of an array: defined for values > 0 only")
    c = _CONTEXT
    return np.array([float(c.ln(Decimal(v))) for v in x.ravel().tolist()], np.float64).reshape(x.shape)
