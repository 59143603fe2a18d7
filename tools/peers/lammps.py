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
NO_ROLLING = ["contact.soil_soil.rolling_friction=0", "contact.soil_soil.rolling_damping=0",
              "contact.soil_wall.rolling_friction=0", "contact.soil_wall.rolling_damping=0"]
LMP_NAMES = ("lmp", "lmp_mpi", "lmp_openmpi", "lmp_serial")
BASELINE_STEPS = 50


def log(msg: str) -> None:
    print(f"[peers/lammps {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


# ------------------------------------------------------------------ LAMMPS binary

def find_lmp(name: str | None) -> str:
    for c in ([name] if name else LMP_NAMES):
        p = c if os.sep in c else shutil.which(c)
        if p and os.path.isfile(p) and os.access(p, os.X_OK):
            return os.path.abspath(p)
    raise SystemExit(f"LAMMPS binary not found ({name or ', '.join(LMP_NAMES)}): give --lmp PATH")


def _run_lmp_serial(lmp: str, workdir: Path, script: str, data: str) -> str:
    (workdir / "probe.data").write_text(data)
    (workdir / "in.probe").write_text(script)
    env = dict(os.environ, OMP_NUM_THREADS="1")
    out = subprocess.run([lmp, "-in", "in.probe", "-log", "none", "-echo", "none"], cwd=workdir,
                         env=env, capture_output=True, text=True, timeout=120, check=False)
    return out.stdout + out.stderr


def probe(lmp: str, workdir: Path) -> dict:
    """What this binary does: its version, the 2d sphere mass convention (mass of a disc
    of diameter 0.2 and density 1000 read from a data file), wall/gran limit_damping."""
    workdir.mkdir(parents=True, exist_ok=True)
    data = ("probe\n\n1 atoms\n1 atom types\n\n0 1 xlo xhi\n0 1 ylo yhi\n-0.5 0.5 zlo zhi\n\n"
            "Atoms # sphere\n\n1 1 0.2 1000 0.5 0.5 0\n")
    head = ("units si\ndimension 2\nboundary f f p\natom_style sphere\natom_modify map array\n"
            "read_data probe.data\ncomm_modify vel yes\n"
            "pair_style gran/hooke/history 2e5 1e5 10 5 0.5 1 limit_damping\npair_coeff * *\n")
    text = _run_lmp_serial(lmp, workdir, head + 'variable m equal mass[1]\nprint "PROBE_MASS ${m}"\n', data)
    m = re.search(r"PROBE_MASS (\S+)", text)
    v = re.search(r"LAMMPS \(([^)]*)\)", text)
    if not m:
        raise SystemExit(f"{lmp}: the probe run failed (no GRANULAR package / atom_style sphere?):\n{text[-2000:]}")
    mass = float(m.group(1))
    sphere = 1000 * 4.0 / 3.0 * math.pi * 0.1 ** 3
    disc = 1000 * math.pi * 0.1 ** 2
    if abs(mass / sphere - 1) < 1e-9:
        conv = "sphere"
    elif abs(mass / disc - 1) < 1e-9:
        conv = "disc"
    else:
        raise SystemExit(f"{lmp}: 2d sphere mass {mass} is neither rho 4/3 pi r^3 nor rho pi r^2")
    wall = _run_lmp_serial(lmp, workdir, head + "fix w all wall/gran hooke/history 2e5 1e5 10 5 0.5 1 "
                           "yplane 0 NULL limit_damping\nrun 0\n", data)
    return {"binary": lmp, "version": v.group(1) if v else None, "mass_convention": conv,
            "wall_limit_damping": "ERROR" not in wall}


def lammps_volume(conv: str, r):
    """Volume LAMMPS multiplies a data file's density by (per atom)."""
    return 4.0 / 3.0 * math.pi * r ** 3 if conv == "sphere" else math.pi * r ** 2


# ------------------------------------------------------------------ the law

def map_law(sc, bed) -> dict:
    """LAMMPS coefficients of the scenario's soil-soil and soil-wall laws on this bed."""
    import numpy as np
    n = len(bed)
    cap = bed.hist_id.shape[1]
    used = np.arange(cap)[None, :] < bed.hist_n[:, None]
    pid = bed.hist_id
    order = np.argsort(bed.id, kind="stable")
    rows, cols = np.nonzero(used & (pid > bed.id[:, None]))     # each disc-disc contact once
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
        return {"where": where, "kn": pair.kn, "kt": pair.ks, "gamma_n": gn, "gamma_t": gt,
                "xmu": pair.friction, "dampflag": 1 if pair.damping_t > 0 else 0,
                "zeta_n": pair.damping_n, "zeta_t": pair.damping_t, "m_ref": mref,
                "contacts_used_for_m_ref": len(meff),
                "lammps_zeta_over_ours_min": round(float(spread.min()), 4),
                "lammps_zeta_over_ours_max": round(float(spread.max()), 4)}

    ss, sw = sc.contact.soil_soil, sc.contact.soil_wall
    for name, c in (("soil_soil", ss), ("soil_wall", sw)):
        if c.rolling_friction != 0.0:
            raise SystemExit(f"contact.{name}.rolling_friction = {c.rolling_friction}: "
                             f"gran/hooke/history has no rolling resistance; set it to 0")
    return {"pair": one(ss, meff_pair, 0.5 * mbar, "pair_style gran/hooke/history"),
            "wall": one(sw, meff_wall, mbar, "fix wall/gran hooke/history (bottom, both ends)"),
            "dt": sc.physics.dt, "skin": sc.bed.skin, "gravity": sc.physics.gravity,
            "formula": "gamma = 2 zeta sqrt(k / m_ref), m_ref = (mean_contacts sqrt(m_eff))^2; "
                       "LAMMPS density_i = m_i / (4/3 pi r_i^3), m_i = rho pi r_i^2 thickness"}


def write_data(path: Path, sc, bed, conv: str) -> None:
    import numpy as np
    from ooc_dem.physics.layout import AX_X, AX_Y
    n = len(bed)
    order = np.argsort(bed.id, kind="stable")
    r = bed.r[order]
    dens = bed.mass[order] / lammps_volume(conv, r)
    zh = 2.0 * sc.soil.r_max
    head = (f"ooc-dem settled bed of {sc.name} (tools/peers/lammps.py): {n} discs, "
            f"mass = rho pi r^2 thickness\n\n{n} atoms\n1 atom types\n\n"
            f"0 {sc.bin.length!r} xlo xhi\n0 {sc.bin.height!r} ylo yhi\n{-zh!r} {zh!r} zlo zhi\n\n"
            f"Atoms # sphere\n\n")
    cols = np.column_stack([np.arange(1, n + 1), np.ones(n), 2.0 * r, dens, bed.pos[order, AX_X], bed.pos[order, AX_Y],
                            np.zeros(n)])
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
# pair: zeta_n {p['zeta_n']} zeta_t {p['zeta_t']} m_ref {p['m_ref']!r} kg
# wall: zeta_n {w['zeta_n']} zeta_t {w['zeta_t']} m_ref {w['m_ref']!r} kg
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

compute         cc all contact/atom
compute         ccsum all reduce sum c_cc
variable        cpp equal c_ccsum/atoms
variable        mtot equal mass(all)
variable        kin equal ke
thermo_modify   norm no
thermo_style    custom step atoms ke
thermo          0

run             {warmup}
run             {steps}
thermo_style    custom step atoms ke v_cpp
run             0 post no
print           "OOC_CONTACTS_PER_PARTICLE ${{cpp}}"
print           "OOC_TOTAL_MASS ${{mtot}}"
print           "OOC_KINETIC_ENERGY ${{kin}}"
"""


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


def run_lammps(lmp: str, mpirun: str | None, ranks: int, workdir: Path, script: str, tag: str,
               warmup: int) -> dict:
    """Run one input; peak RSS = sum over the lmp ranks of each rank's VmHWM (polled)."""
    import psutil
    (workdir / f"in.{tag}").write_text(script)
    logf = f"log.{tag}"
    cmd = [lmp, "-in", f"in.{tag}", "-log", logf, "-echo", "none"]
    if mpirun:
        cmd = [mpirun, "-np", str(ranks), "--allow-run-as-root", "--bind-to", "none"] + cmd
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
    k = 1 if warmup > 0 else 0          # the timed run
    el, procs, steps, atoms = float(loops[k][0]), int(loops[k][1]), int(loops[k][2]), int(loops[k][3])
    peak = sum(hwm.values())
    return {"ranks": procs, "steps": steps, "atoms": atoms, "seconds": el,
            "particle_steps_per_s": atoms * steps / el, "neighbour_rebuilds": int(builds[k]) if builds else None,
            "dangerous_builds": int(dang[k]) if dang else None,
            "contacts_per_particle": float(cpp.group(1)) if cpp else None,
            "total_mass": float(mtot.group(1)) if mtot else None,
            "kinetic_energy_end_J": float(kin.group(1)) if kin else None,
            "peak_rss_bytes": peak, "ranks_seen": len(hwm),
            "lammps_estimate_bytes": (float(mem[k][1]) * 2 ** 20 * procs) if mem else None,
            "process_wall_s": round(wall, 2)}


# ------------------------------------------------------------------ running ooc-dem

def ours_child(n: int, steps: int, threads: int, warmup: int, overrides: list[str]) -> dict:
    """tools/bench.py's measurement (its ``one``) on bed-n with the overrides applied, plus
    contacts split into disc-disc and wall contacts."""
    import importlib.util

    import numpy as np
    spec = importlib.util.spec_from_file_location("ooc_dem_bench", BENCH)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    import ooc_dem.engine.stepper as E
    import ooc_dem.scenario as S
    from ooc_dem.physics.layout import AX_X, AX_Y
    orig = S.load_scenario
    S.load_scenario = lambda src, ov=None: orig(src, list(ov or []) + overrides)
    made = []

    class Recorded(E.DomainStepper):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            made.append(self)

    E.DomainStepper = Recorded
    res = bench.one(n, steps, threads, warmup)
    p = made[-1].p
    used = np.arange(p.hist_id.shape[1])[None, :] < p.hist_n[:, None]
    res["pair_contacts_per_disc"] = round(float(np.sum(used & (p.hist_id >= 0))) / n, 3)
    res["wall_contacts_per_disc"] = round(float(np.sum(used & (p.hist_id < 0))) / n, 4)
    vx, vy = p.vel[:, AX_X], p.vel[:, AX_Y]
    res["kinetic_energy_end_J"] = float(0.5 * np.sum(p.mass * (vx * vx + vy * vy)))
    return res


def run_ours(n: int, steps: int, threads: int, warmup: int, overrides: list[str]) -> dict:
    cmd = [sys.executable, str(HERE), "--ours", str(n), "--steps", str(steps), "--threads", str(threads),
           "--warmup", str(warmup)] + [f"--set={o}" for o in overrides]
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT)] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    out = subprocess.run(cmd, capture_output=True, text=True, env=env, check=False)
    if out.returncode != 0:
        raise SystemExit(f"ooc-dem bench failed (rc {out.returncode}):\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


# ------------------------------------------------------------------ main

def export_bed(n: int, overrides: list[str], info: dict, outdir: Path, warmup: int, steps: int):
    from ooc_dem.bed import settled_bed
    from ooc_dem.scenario import load_scenario
    sc = load_scenario(f"bed-{n}", overrides)
    t = time.time()
    bed = settled_bed(sc)
    law = map_law(sc, bed)
    outdir.mkdir(parents=True, exist_ok=True)
    write_data(outdir / "bed.data", sc, bed, info["mass_convention"])
    script = input_script(sc, law, "bed.data", warmup, steps, info["wall_limit_damping"])
    log(f"bed-{n}: {len(bed)} discs exported to {outdir} in {time.time() - t:.1f} s")
    law["total_mass_ours"] = float(bed.mass.sum())
    return len(bed), law, script


def per_particle(peak: int, base: int, n: int, n0: int):
    return round((peak - base) / (n - n0), 1) if n > n0 else None


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="7000,100000,1000000")
    ap.add_argument("--steps", type=int, default=500, help="timed steps (both codes)")
    ap.add_argument("--warmup", type=int, default=300, help="untimed steps before them (both codes)")
    ap.add_argument("--lmp", default=None, help="LAMMPS binary (default: lmp, lmp_mpi, lmp_serial on PATH)")
    ap.add_argument("--ranks", default="1,2")
    ap.add_argument("--threads", type=int, default=2, help="ooc-dem threads")
    ap.add_argument("--out", default=None, help="keep data files, inputs and logs here")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="extra scenario override (both codes)")
    ap.add_argument("--ours", type=int, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.ours:
        print(json.dumps(ours_child(a.ours, a.steps, a.threads, a.warmup, a.set)))
        return
    overrides = NO_ROLLING + a.set
    sizes = [int(float(s)) for s in a.sizes.split(",")]
    ranks = [int(r) for r in a.ranks.split(",")]
    lmp = find_lmp(a.lmp)
    mpirun = shutil.which("mpirun")
    keep = a.out is not None
    out = Path(a.out) if keep else Path(tempfile.mkdtemp(prefix="peers-lammps-"))
    out.mkdir(parents=True, exist_ok=True)
    info = probe(lmp, out / "probe")
    log(f"LAMMPS {info['version']} at {lmp}: 2d mass convention '{info['mass_convention']}', "
        f"wall limit_damping {'yes' if info['wall_limit_damping'] else 'no'}")
    load0 = os.getloadavg()
    sys.path.insert(0, str(ROOT))
    from ooc_dem.scenario import load_scenario
    n0 = load_scenario("bed-1000", overrides).bed.tile   # one settled tile: the tiny system

    # baseline: the tiny system, same inputs, a few steps
    n0, _, script0 = export_bed(n0, overrides, info, out / f"bed-{n0}", 10, BASELINE_STEPS)
    base_l = {}
    for r in ranks:
        base_l[r] = run_lammps(lmp, mpirun, r, out / f"bed-{n0}", script0, f"np{r}", 10)
    base_o = run_ours(n0, BASELINE_STEPS, a.threads, 10, overrides)
    log(f"baseline ({n0} discs): LAMMPS " + ", ".join(f"{r} rank(s) {v['peak_rss_bytes'] / 2**20:.1f} MiB"
                                                    for r, v in base_l.items())
        + f"; ooc-dem {base_o['peak_rss_bytes'] / 2**20:.1f} MiB")

    results = []
    for n in sizes:
        d = out / f"bed-{n}"
        n_real, law, script = export_bed(n, overrides, info, d, a.warmup, a.steps)
        lam = {}
        for r in ranks:
            log(f"bed-{n}: LAMMPS on {r} rank(s), {a.warmup} + {a.steps} steps")
            v = run_lammps(lmp, mpirun, r, d, script, f"np{r}", a.warmup)
            v["peak_rss_bytes_per_particle"] = round(v["peak_rss_bytes"] / n_real, 1)
            if v["total_mass"]:
                v["total_mass_over_ours_minus_1"] = float(f"{v['total_mass'] / law['total_mass_ours'] - 1:.3g}")
            v["peak_rss_bytes_per_particle_above_baseline"] = per_particle(
                v["peak_rss_bytes"], base_l[r]["peak_rss_bytes"], n_real, n0)
            lam[str(r)] = v
            log(f"bed-{n}: LAMMPS {r} rank(s): {v['particle_steps_per_s']:.3g} particle-steps/s")
        log(f"bed-{n}: ooc-dem (tools/bench.py), {a.threads} threads")
        o = run_ours(n, a.steps, a.threads, a.warmup, overrides)
        o["peak_rss_bytes_per_particle_above_baseline"] = per_particle(
            o["peak_rss_bytes"], base_o["peak_rss_bytes"], n_real, n0)
        log(f"bed-{n}: ooc-dem: {o['particle_steps_per_s']:.3g} particle-steps/s")
        ratio = {}
        for r, v in lam.items():
            ratio[f"speed_vs_{r}_rank"] = round(o["particle_steps_per_s"] / v["particle_steps_per_s"], 3)
            a_, b_ = o["peak_rss_bytes_per_particle_above_baseline"], v["peak_rss_bytes_per_particle_above_baseline"]
            ratio[f"rss_above_baseline_vs_{r}_rank"] = round(a_ / b_, 3) if a_ and b_ else None
        results.append({
            "n": n_real, "scenario": f"bed-{n}",
            "ooc_dem": {"threads": a.threads, "particle_steps_per_s": o["particle_steps_per_s"],
                        "seconds": o["seconds"], "steps": o["steps"], "neighbour_rebuilds": o["neighbour_rebuilds"],
                        "peak_rss_bytes": o["peak_rss_bytes"],
                        "peak_rss_bytes_per_particle": o["peak_rss_bytes_per_disc"],
                        "peak_rss_bytes_per_particle_above_baseline": o["peak_rss_bytes_per_particle_above_baseline"],
                        "contacts_per_particle": o["pair_contacts_per_disc"],
                        "contacts_per_particle_with_walls": o["contacts_per_disc"],
                        "kinetic_energy_end_J": o["kinetic_energy_end_J"]},
            "lammps": lam, "ratio_ooc_dem_over_lammps": ratio, "law": law})
    load1 = os.getloadavg()
    report = {
        "tool": "tools/peers/lammps.py", "lammps": info, "mpirun": mpirun,
        "steps": a.steps, "warmup_steps": a.warmup, "overrides": overrides,
        "machine": {"cpus": os.cpu_count(), "loadavg_before": [round(x, 2) for x in load0],
                    "loadavg_after": [round(x, 2) for x in load1]},
        "notes": [("particle-steps/s of the timed steps only (LAMMPS: Loop time of the timed run; "
                   "ooc-dem: tools/bench.py's timing after its warm-up)"),
                  ("contacts_per_particle: disc-disc contacts per disc (LAMMPS compute contact/atom; "
                   "ooc-dem its contact history), walls excluded"),
                  ("peak RSS: LAMMPS = sum over ranks of each rank's VmHWM; ooc-dem = ru_maxrss of the "
                   "bench process; above_baseline = (peak - peak of the one-tile bed) / (N - N_tile)"),
                  "LAMMPS starts without tangential history (a data file holds none); the warm-up reloads it",
                  ("kinetic_energy_end_J: translational, after the timed steps (a sanity check of the "
                   "mapped law, not an equality: ooc-dem's are leapfrog half-step velocities)")],
        "baseline": {"n": n0, "lammps_peak_rss_bytes": {str(r): v["peak_rss_bytes"] for r, v in base_l.items()},
                     "ooc_dem_peak_rss_bytes": base_o["peak_rss_bytes"]},
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
