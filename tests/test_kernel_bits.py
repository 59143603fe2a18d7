"""The kernel's bits, pinned: final state hashes recorded on main (444869d)
BEFORE the kernel layer was rebuilt (pair rows + per-disc CSR gather). A change of the
kernels that keeps the bits keeps these hashes; a change that alters them must say why.

The hash's version 2 changed the hash, not the states: version 2 (``mset-v2:``, ooc_dem/model/statehash.py,
a multiset hash that streams) replaced version 1 (SHA-256 of the state sorted by id). The
version-2 values below are the new hash of the SAME states: each case's run was repeated
with the code of 2a1c594 (version 1), its summary and `checkpoint hash` gave the version-1
values (kept below for the record), then `checkpoint hash` of those very stores with the
version-2 code gave the new values.

Every case is a real `ooc-dem run` in a fresh interpreter; the hash is the run's
``state_hash`` (summary.json, = `ooc-dem checkpoint hash STORE`). The recording
commands are those below with `PYTHONPATH=/work/main` (main's code), e.g.

    ooc-dem run quick --set wheel.control=slip ... --steps 6000 --out /tmp/q --no-progress --no-figures

Cases (each exercises different parts of the kernel):
- quick, slip control, short lugs (4 mm) and no drop gap: the wheel travels ~2.3 cm in
  6000 steps with rim AND lug contacts (up to ~10 wheel contacts), walls on three sides;
  monolithic, serial DDM with 6 sub-domains, out-of-core (HDF5, 2 sub-domains, K = 25):
  one hash for all three modes;
- paper2008 (the full 6986-disc bed, drawbar control, paper omega): 3500 steps of
  settling then 3500 of travel, lugs and rim in the soil, 2 threads;
- bed-100k (tiled bed, no wheel): 150 steps at the tile seams.

3D cases, recorded on main at 9965678, before the 3D pair law ran in blocks
(``d3.forces.law_block``):
- quick-3d (the wheel, Hertz spheres with rolling resistance): 3000 steps, monolithic
  and serial DDM with 3 sub-domains (pairs' springs in the discs' histories, not held);
- bed3d-20000 on the Hertz law (walls too) and on the LAMMPS comparison's linear law
  without rolling (``tools/peers/lammps.py``'s overrides: the sliding row layout).

The bits moved once, on purpose, so that they are the same on every machine
(docs/reference/bits.md): sphere masses as r * r * r (numpy's r**3 was its own AVX-512 pow
on CPUs that have it, glibc's pow elsewhere), the restitution's ln correctly rounded
(exactmath, not libm's log), the lugs' cos and sin a fixed polynomial in + - * (detmath, not
libm's). Every case with lugs (quick, paper2008, quick-3d) and every 3D case moved; bed-100k
(2D, no wheel) kept its value. Before, the Hertz cases had two values, one on machines with
AVX-512 and one on others; now each case has one. The new values were recorded on an AMD
EPYC (Zen 5, AVX-512) with the code that made the move; the mode-equivalence checks (one
value for every mode of a case) held unchanged.
"""

from __future__ import annotations

import json

import pytest

from support.cli import cli_in_process, run_cli

# mode-equivalence and whole-run checks: outside the fast subset (pytest -m "not slow")
pytestmark = pytest.mark.slow

QUICK = [
    "wheel.control=slip",
    "wheel.slip=0.2",
    "wheel.omega=5.0",
    "wheel.settle_time=0.002",
    "wheel.drop_gap=0.0",
    "wheel.lug_tip_radius=0.104",
    "decomposition.margin=0.001",
]
PAPER = ["wheel.settle_time=0.035", "wheel.drop_gap=0.0"]

# version 1 (before the streamed hash): the states of the values before the move to the same
# bits on every machine (for the record; no test reads them)
QUICK_6000_V1 = "8567c40dcfacd4544f00f5771b6bb7ebede381f80690d65467a4c05dfb404a88"
PAPER2008_7000_V1 = "9f35eead0fde6961bf107dfbe88ccfa7afe92fa4f0e9f964246049e8ec6502ce"
BED100K_150_V1 = "d336a4b2c1a003284f51bd03a3e5b6b545a522e81604891b85968fbed24953c6"  # the old tile

# before the move (libm's cos and sin of the lugs): QUICK_6000 mset-v2:8d035f96…c2c0ee,
# PAPER2008_7000 mset-v2:b2bf3778…c3b6ae
QUICK_6000 = "mset-v2:28e22a5f4971d394ece8b3b995232919997294022a4e0311b23891adc9f97ed7"
PAPER2008_7000 = "mset-v2:813f0bed9eea29b7ec252f2fbbf58e31e8044654561a472b66c91bf2b59ea5c9"
# bed-100k's tile was 8.6 m / 86 = 0.09999999999999999 m long until scenario.tile_share took the
# division's rounding noise away: it is now the 0.1 m tile of bed-1000000 (the same settled
# tile), so its bits changed by a bed, not by the kernel (before: mset-v2:b096e188…b25e0)
BED100K_150 = "mset-v2:bd623b5985dec3c4272d35d05f00dd4ac42e8453687dabfdb73cb01c4e9d443e"

# Before the move the Hertz cases had two values, the second on machines with AVX-512 (an
# Intel Xeon and an AMD EPYC Zen 5; numpy's SIMD pow of the masses' r**3 was one cause):
# QUICK3D_3000 mset-v2:2d0621bb…3fcc99a / 2c733ac1…5911026, BED3D_HERTZ_400
# mset-v2:57c64f88…d1229e8 / 3833b19b…5003a73e; BED3D_LINEAR_400 was mset-v2:a597d010…a6bc89e.
QUICK3D_3000 = "mset-v2:cb35e0ce03941ca3a275957bb2888ff677698821edbfb9d57e2b954a1ddf53dd"
BED3D_HERTZ_400 = "mset-v2:2874366e63c4d0b3e3a583f07c34fc7b3d8211f10efab0681fed1d3b2c602083"
BED3D_LINEAR_400 = "mset-v2:16c69432082475f56bf8f89507eece160b4ed35be284f1402434be93b08c2693"
HERTZ = ["contact.soil_soil.law=hertz", "contact.soil_wall.law=hertz"]
LINEAR = [
    "contact.soil_soil.rolling_friction=0",
    "contact.soil_soil.rolling_damping=0",
    "contact.soil_wall.rolling_friction=0",
    "contact.soil_wall.rolling_damping=0",
    'contact.soil_soil.law="linear"',
    "contact.soil_soil.kn=50000.0",
    "contact.soil_soil.ks=16666.666666666668",
    "contact.soil_soil.damping_n=0.3",
    "contact.soil_soil.damping_t=0.3",
    "contact.soil_soil.friction=0.5",
]

# a fresh numba cache (compiled for that target, not read from the host's) and bed cache
GENERIC = {"NUMBA_CPU_NAME": "generic", "NUMBA_CACHE_DIR": None, "OOC_DEM_CACHE": None}

CASES = {
    "quick-monolithic": (["quick", *QUICK, "--steps", 6000], {}, QUICK_6000),
    "quick-ddm6": (["quick", *QUICK, "--steps", 6000, "--mode", "ddm", "--domains", 6], {}, QUICK_6000),
    # one numba thread: serial DDM runs its sweeps in one compiled call (live.run_sweeps)
    "quick-ddm6-1thread": (
        ["quick", *QUICK, "--steps", 6000, "--mode", "ddm", "--domains", 6],
        {"NUMBA_NUM_THREADS": "1"},
        QUICK_6000,
    ),
    "quick-ooc": (["quick", *QUICK, "--steps", 6000, "--mode", "ooc", "--domains", 2, "--block", 25], {}, QUICK_6000),
    "paper2008-2threads": (["paper2008", *PAPER, "--steps", 7000], {"NUMBA_NUM_THREADS": "2"}, PAPER2008_7000),
    "bed-100k": (["bed-100k", "--steps", 150], {}, BED100K_150),
    "quick-3d": (["quick-3d", "--steps", 3000], {}, QUICK3D_3000),
    "quick-3d-ddm3": (["quick-3d", "--steps", 3000, "--mode", "ddm", "--domains", 3], {}, QUICK3D_3000),
    "bed3d-hertz": (["bed3d-20000", *HERTZ, "--steps", 400], {}, BED3D_HERTZ_400),
    "bed3d-linear": (["bed3d-20000", *LINEAR, "--steps", 400], {}, BED3D_LINEAR_400),
    # the kernels compiled for numba's generic x86-64 (no AVX, no FMA), the bed settled by
    # them too (an empty bed cache): the bits may not depend on the instructions the host's
    # compile chose (docs/reference/bits.md)
    "quick-generic": (["quick", *QUICK, "--steps", 6000], GENERIC, QUICK_6000),
    "quick-3d-generic": (["quick-3d", "--steps", 3000], GENERIC, QUICK3D_3000),
}


def _args(spec):
    """Scenario name, then --set for every key=value, then the plain options."""
    name, rest = spec[0], spec[1:]
    out = [name]
    for a in rest:
        if isinstance(a, str) and "=" in a and not a.startswith("--"):
            out += ["--set", a]
        else:
            out.append(a)
    return out


@pytest.mark.parametrize("case", list(CASES))
def test_state_hash_unchanged(case, tmp_path):
    spec, env, expected = CASES[case]
    env = {k: str(tmp_path / k.lower()) if v is None else v for k, v in env.items()}
    out = tmp_path / "run"
    run_cli("run", *_args(spec), "--out", out, "--no-progress", "--no-figures", check=True, env=env)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["state_hash"] == expected, f"{case}: the kernel's bits changed"
    if case == "quick-monolithic":
        cp = cli_in_process("checkpoint", "hash", out, check=True)
        assert cp.stdout.strip() == expected
