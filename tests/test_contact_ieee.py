"""The compiled contact laws give the bits of their own Python source run by the interpreter.

The determinism contract (docs/design.md §3) holds between machines only if the compiler
keeps IEEE-754 semantics: no fast-math, no fused multiply-adds, no reassociation. numba
promises that without ``fastmath``; this checks it on the machine the suite runs on, for
the 2D law and the 3D Hertz and linear laws (with rolling resistance): random contacts —
new, sticking and sliding springs — evaluated compiled in this process and interpreted
(``NUMBA_DISABLE_JIT=1``) in a subprocess, compared with ``np.array_equal``.
"""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

LAWS = ("2d", "3d-hertz", "3d-linear")
N = 1500


def _table(law):
    """A material pair's CONTACT_PARAMS record (attribute access in both modes)."""
    if law == "2d":
        from ooc_dem.physics.d2 import layout as L

        tab = np.zeros(1, L.CONTACT_PARAMS)
        tab[0] = L.linear_params(2.0e5, 2.0e5 / 3.0, 0.7, 0.5, 0.5, 0.1, 0.3)
        return np.rec.array(tab)[0]
    from ooc_dem.physics.d3 import layout as L3

    if law == "3d-hertz":
        params = L3.hertz_params(1.0e8, 0.3, 0.5, mu=0.5, mur=0.1, zr=0.3)
    else:
        params = L3.linear_params(5.0e4, 5.0e4 / 3.0, 0.3, 0.3, mu=0.5, mur=0.1, zr=0.3)
    tab = np.zeros(1, L3.CONTACT_PARAMS)
    tab[0] = params
    return np.rec.array(tab)[0]


def _inputs(law):
    """N contacts' arguments (after the record), one row each; the springs' sizes span
    new (zero), sticking and sliding contacts."""
    rng = np.random.default_rng(20261205)
    dim = 2 if law == "2d" else 3
    n = rng.normal(size=(N, dim))
    n /= np.linalg.norm(n, axis=1)[:, None]
    ra, rb = rng.uniform(0.002, 0.005, (2, N))
    reff = ra * rb / (ra + rb)
    ma, mb = rng.uniform(1e-4, 5e-4, (2, N))
    meff = ma * mb / (ma + mb)
    ieff = 0.4 * meff * reff * reff
    delta = rng.uniform(1e-7, 5e-5, N)
    scale = 10.0 ** rng.uniform(-6, 1.5, (N, 1))  # springs from 1 uN to 30 N: sticking and sliding
    scale[::7] = 0.0  # new contacts
    dt = np.full(N, 1e-5)
    if dim == 2:
        cols = [
            n[:, 0],
            n[:, 1],
            delta,
            *(0.05 * rng.normal(size=(2, N))),
            *(5.0 * rng.normal(size=(2, N))),
            ra,
            rb,
            meff,
            ieff,
            reff,
            (scale * rng.normal(size=(N, 1)))[:, 0],
            (1e-3 * scale * rng.normal(size=(N, 1)))[:, 0],
            dt,
        ]
    else:
        cols = [
            n[:, 0],
            n[:, 1],
            n[:, 2],
            delta,
            *(0.05 * rng.normal(size=(3, N))),
            *(5.0 * rng.normal(size=(6, N))),
            ra,
            rb,
            meff,
            ieff,
            reff,
            *(scale * rng.normal(size=(N, 3))).T,
            *(1e-3 * scale * rng.normal(size=(N, 3))).T,
            dt,
        ]
    return np.column_stack(cols)


def evaluate(law):
    """Every contact's outputs, flattened (whatever the JIT state of this process)."""
    if law == "2d":
        from ooc_dem.physics.d2.contact import contact
    else:
        from ooc_dem.physics.d3.contact import contact
    c = _table(law)
    out = [np.array(contact(c, *map(float, row)), np.float64).ravel() for row in _inputs(law)]
    return np.array(out)


def _interpreted(tmp_path):
    """The same contacts through the interpreter (numba's JIT off) in a fresh process."""
    out = tmp_path / "interpreted.npz"
    code = (
        "import sys, numpy as np; sys.path.insert(0, sys.argv[1]); import test_contact_ieee as t; "
        "np.savez(sys.argv[2], **{law: t.evaluate(law) for law in t.LAWS})"
    )
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    subprocess.run([sys.executable, "-c", code, str(Path(__file__).parent), str(out)], check=True, env=env, timeout=600)
    return np.load(out)


@pytest.fixture(scope="module")
def interpreted(tmp_path_factory):
    return _interpreted(tmp_path_factory.mktemp("ieee"))


@pytest.mark.parametrize("law", LAWS)
def test_compiled_law_gives_the_interpreters_bits(law, interpreted):
    compiled = evaluate(law)
    want = interpreted[law]
    assert compiled.shape == want.shape and np.isfinite(want).all()
    assert np.array_equal(compiled, want), (
        f"{law}: {int((compiled != want).any(axis=1).sum())} of {len(want)} contacts differ "
        "between the compiled law and its interpreted source (a non-IEEE compile)"
    )
