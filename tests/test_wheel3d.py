"""The lugged wheel in 3D (rim cylinder and lug plates spanning the wheel's width).

Two levels:
- contact geometry through THE per-domain step (``DomainStepper`` on a few spheres): the
  rim's curved surface, an end face, a lug plate, a sphere beside the wheel (no contact),
  the reaction on the wheel equal and opposite to the spheres' forces, the torque sign;
- whole runs on a small 3D bin (``WHEEL3D``): the wheel sinks into the bed while settling
  with omega = 0, then rolls; monolithic, serial DDM D = 6 and out-of-core HDF5 and zarr
  (D = 6, K = 4), each with re-decompositions of the wheel-following slabs, and a run
  resumed from a mid-run epoch all give the same bits.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from support.cli import cli_in_process, run_cli
from support.stores import committed_step

import ooc_dem
from ooc_dem.engine.stepper import DomainStepper, Model
from ooc_dem.physics.layout import ID_LUG0, ID_RIM, REC_FX, REC_FY, REC_NC, REC_TQ, WS_SIZE, WS_X, WS_Y
from ooc_dem.model.scenario import ScenarioError, load_scenario
from ooc_dem.model.state import Particles

# mode-equivalence and whole-run checks: outside the fast subset (pytest -m "not slow")
pytestmark = pytest.mark.slow

R = 0.1
Z0 = 0.06  # quick-3d: bin width 0.12, wheel width 0.06 centred at mid-width


def _sphere_set(sc, pos, r=0.005):
    """Particles of a few spheres at pos (N, 3), at rest, soil material."""
    pos = np.array(pos, np.float64).reshape(-1, 3)
    n = len(pos)
    p = Particles.empty(n, dim=3, hist_cap=sc.hist_cap)
    p.id[:] = np.arange(n)
    p.pos[:] = pos
    p.r[:] = r
    p.mass[:] = sc.soil.density * 4.0 / 3.0 * math.pi * r**3
    p.inertia[:] = 0.4 * p.mass * r * r
    p.mat[:] = 0
    return p


def _one_step(sc, pos, ws_over=None, r=0.005):
    """One step of the spheres at pos with the wheel at (0.15, 0.2), theta = 0, at rest
    (settle phase: omega = 0). Returns (stepper, wheel record, first-step history ids)."""
    p = _sphere_set(sc, pos, r)
    ws = np.zeros(WS_SIZE)
    ws[WS_X], ws[WS_Y] = 0.15, 0.2
    for k, v in (ws_over or {}).items():
        ws[k] = v
    st = DomainStepper(p, Model.from_scenario(sc), ws, reorder=False, keep_forces=True)
    rec = st.advance(0, 1)
    return st, rec[0]


@pytest.fixture(scope="module")
def sc():
    return load_scenario("quick-3d")


def test_scenarios_load_and_the_paper_bin_is_twice_the_wheel():
    p = load_scenario("paper2008-3d")
    w = p.wheel
    assert p.dim == 3 and w.enabled and w.radius == 0.1 and w.width == 0.1 and w.n_lugs == 18
    assert math.isclose(w.lug_tip_radius - w.radius, 0.01) and w.load == 19.6
    assert w.omega == 0.138 and w.drawbar_load == 10.0
    assert p.bin.width >= 2 * w.width
    q = load_scenario("quick-3d")
    assert q.dim == 3 and q.wheel.enabled and q.soil.n < 3000 and q.bin.width >= 2 * q.wheel.width


def test_wheel_must_fit_across_the_bin():
    with pytest.raises(ScenarioError) as e:
        load_scenario("quick-3d", ["wheel.z0=0.02"])
    assert "wheel.z0" in str(e.value) and "\n" not in str(e.value)
    cp = cli_in_process("run", "quick-3d", "--set", "wheel.width=0.2", "--steps", "1")
    assert cp.returncode == 2 and "wheel.z0" in cp.stderr and "Traceback" not in cp.stderr


def test_rim_contact_pushes_down_and_the_wheel_gets_the_reaction(sc):
    # a sphere under the rim at mid-width, overlapping it by 0.5 mm
    st, rec = _one_step(sc, [[0.15, 0.2 - R - 0.0045, Z0]])
    assert rec[REC_NC] == 1
    f = st.force[0]
    assert f[1] < 0 and abs(f[0]) < 1e-12 * abs(f[1]) and abs(f[2]) < 1e-12 * abs(f[1])
    assert rec[REC_FY] == -f[1] and rec[REC_FX] == -f[0]
    assert st.p.hist_n[0] == 1 and st.p.hist_id[0, 0] == ID_RIM


def test_beside_the_wheel_no_contact_at_the_end_face_a_lateral_push(sc):
    half = 0.5 * sc.wheel.width
    st, rec = _one_step(
        sc,
        [
            [0.15, 0.2 - R - 0.0045, Z0 + half + 0.0051],  # beside: free
            [0.15, 0.2 - 0.05, Z0 + half + 0.0045],
        ],
    )  # at the end face
    assert rec[REC_NC] == 1
    order = np.argsort(st.p.id)
    f_free, f_face = st.force[order[0]], st.force[order[1]]
    assert np.all(f_free == 0.0)
    assert f_face[2] > 0 and f_face[0] == 0.0 and f_face[1] == 0.0
    assert rec[REC_FX] == 0.0 and rec[REC_FY] == 0.0  # the lateral force goes to the axle


def test_lug_plate_contact_at_every_z_of_the_width(sc):
    # lug 0 points along +x at theta = 0: a sphere just beyond its face, at three z
    cap = 0.5 * sc.wheel.lug_thickness
    half = 0.5 * sc.wheel.width
    zs = [Z0 - 0.9 * half, Z0, Z0 + 0.9 * half]
    pos = [[0.15 + R + 0.005, 0.2 + cap + 0.0045, z] for z in zs]
    st, rec = _one_step(sc, pos)
    assert rec[REC_NC] == 3
    order = np.argsort(st.p.id)
    for k in order:
        assert st.p.hist_id[k, 0] == ID_LUG0 and st.force[k, 1] > 0
    fy = st.force[order, 1]
    assert fy[0] == fy[1] == fy[2]  # the plate is the same across the width


def test_spinning_wheel_pushes_the_soil_back_and_feels_a_resisting_torque():
    # travel phase at t = 0 (no settling): clockwise spin, the rim's bottom moves in -x,
    # pushes the sphere back and the wheel forward (traction); the torque resists the drive
    sc = load_scenario("quick-3d", ["wheel.settle_time=0"])
    st, rec = _one_step(sc, [[0.15, 0.2 - R - 0.0045, Z0]])
    f = st.force[0]
    assert f[0] < 0 and rec[REC_FX] == -f[0]
    assert rec[REC_TQ] > 0 and math.isclose(rec[REC_TQ], R * rec[REC_FX], rel_tol=1e-12)


# a small 3D bin: the quick-3d rig with a narrower wheel on a tiled bed of two 750-sphere
# tiles (fast to settle on a fresh machine), 0.4 m long so that the wheel's slab is one of
# several. BASE: 0.04 s of settling with omega = 0, then 0.1 s of rolling under a drawbar.
BASE = [
    "soil.n=1500",
    "bed.tile=750",
    "bin.length=0.4",
    "bin.width=0.07",
    "wheel.width=0.035",
    "wheel.x0=0.2",
    "wheel.settle_time=0.04",
    "wheel.drawbar_ramp=0.02",
    "wheel.drawbar_load=2.0",
    "wheel.travel_time=0.1",
    "wheel.omega=2.0",
    "output.steady_start=0.03",
    "output.steady_end=0.1",
    "output.series_interval=0.002",
]
# the modes' segment: the wheel placed on the bed (no gap), 100 steps of settling, then 300
# steps rolling at a prescribed slip fast enough to redefine its slab (margin 1 mm) twice
WHEEL3D = BASE + [
    "wheel.drop_gap=0",
    "wheel.settle_time=0.002",
    "wheel.travel_time=0.006",
    "wheel.control=slip",
    "wheel.slip=0.2",
    "wheel.omega=10.0",
    "output.steady_start=0.002",
    "output.steady_end=0.006",
    "output.series_interval=0.0005",
    "decomposition.margin=0.001",
]
WHEEL3D_STEPS = 400


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    work = tmp_path_factory.mktemp("wheel3d")
    out = {"_work": work}
    kw = dict(overrides=WHEEL3D, steps=WHEEL3D_STEPS)
    out["monolithic"] = ooc_dem.run("quick-3d", work / "mono", **kw)
    out["ddm-6"] = ooc_dem.run("quick-3d", work / "ddm6", mode="ddm", domains=6, **kw)
    for backend in ("hdf5", "zarr"):
        out[f"ooc-{backend}"] = ooc_dem.run(
            "quick-3d",
            work / f"ooc-{backend}",
            mode="ooc",
            backend=backend,
            domains=6,
            block=4,
            checkpoint_every=100,
            **kw,
        )
    return out


def test_the_wheel_settles_into_the_bed_then_rolls(tmp_path):
    res = ooc_dem.run("quick-3d", tmp_path / "base", overrides=BASE, figures=True)
    s = res.summary
    assert s["n_discs"] == 1500
    ser = np.loadtxt(tmp_path / "base" / "series.csv", delimiter=",", skiprows=1)
    settling = ser[ser[:, 1] < 0]  # t_travel < 0: omega = 0, x held
    assert np.all(settling[:, 2] == 0.2) and np.all(settling[:, 5] == 0.0)
    # placed 2 mm above the bed, it sank into it (no drop shock: it came to rest)
    assert settling[0, 3] - settling[-1, 3] > 0.003
    assert ser[-1, 3] > 0.1 - 0.05  # rolling, it digs in, but stays on the 5 cm bed
    assert s["travel_distance"]["whole_travel"]["value"] > 0.002
    assert 0.0 < s["slip"]["steady"]["value"] < 1.0
    assert s["gross_traction"]["steady"]["value"] > 0.0
    # the 3D views and the wheel's surface mesh for ParaView
    figs = tmp_path / "base" / "figures"
    for name in ("series.png", "deformation.png", "deformation_midwidth.png", "rut.png", "lateral_flow.png"):
        assert (figs / name).stat().st_size > 10_000, name
    import meshio

    mesh = meshio.read(tmp_path / "base" / "wheel.vtk")
    sc = load_scenario("quick-3d", BASE)
    n_lugs = sc.wheel.n_lugs
    pts = mesh.points  # two rim rings of 72, the caps' centres, 8 corners a lug
    assert pts.shape == (2 * 72 + 2 + 8 * n_lugs, 3)
    assert mesh.cells[0].type == "triangle" and len(mesh.cells[0].data) == 4 * 72 + 12 * n_lugs
    assert np.isclose(pts[:, 2].min(), 0.035 - 0.0175) and np.isclose(pts[:, 2].max(), 0.035 + 0.0175)
    rad = np.hypot(pts[:, 0] - pts[:72, 0].mean(), pts[:, 1] - pts[:72, 1].mean())
    assert np.allclose(rad[:144], 0.1) and rad.max() <= 0.11 * (1 + 1e-9) + 0.002


def test_every_mode_with_the_wheel_gives_the_same_bits(runs):
    ref = runs["monolithic"]
    h = ref.summary["state_hash"]
    s0 = ref.state()
    assert s0["pos"].shape == (1500, 3)
    for name in ("ddm-6", "ooc-hdf5"):
        eng = runs[name].summary["engine"]
        assert eng["redecompositions"] >= 1 and eng["domains"] == 6, (name, eng)
    for name, res in runs.items():
        if name.startswith("_") or name == "monolithic":
            continue
        assert res.summary["state_hash"] == h, name
        s = res.state()
        for k in s0:
            assert np.array_equal(s0[k], s[k]), (name, k)
        for k in ("slip", "net_traction", "gross_traction", "sinkage"):
            assert res.summary[k] == ref.summary[k], (name, k)
    a = np.loadtxt(runs["_work"] / "mono" / "series.csv", delimiter=",", skiprows=1)
    b = np.loadtxt(runs["_work"] / "ddm6" / "series.csv", delimiter=",", skiprows=1)
    assert len(a) >= 10 and np.array_equal(a, b, equal_nan=True)  # slip is nan while omega = 0
    assert a[-1, 2] - a[0, 2] > 0.003  # the wheel rolled (x column)


def test_resume_from_a_mid_run_epoch_gives_the_same_bits(runs, tmp_path):
    """An out-of-core run ended at step 2000 (the wheel rolling) and resumed from its last
    epoch to step 4000 ends with the uninterrupted run's bits."""
    ref = runs["ooc-hdf5"]
    out = tmp_path / "resumed"
    half = ooc_dem.run(
        "quick-3d",
        out,
        mode="ooc",
        domains=6,
        block=4,
        checkpoint_every=100,
        overrides=WHEEL3D,
        steps=WHEEL3D_STEPS // 2,
    )
    assert half.summary["steps"] == WHEEL3D_STEPS // 2
    res = ooc_dem.resume(out, steps=WHEEL3D_STEPS)
    assert res.summary["state_hash"] == ref.summary["state_hash"]
    a, b = res.state(), ref.state()
    for k in a:
        assert np.array_equal(a[k], b[k]), k


def _layer(xs, zs, top, r=0.005):
    """A square lattice of spheres at the given x and z whose tops lie at ``top``."""
    gx, gz = np.meshgrid(xs, zs, indexing="ij")
    pos = np.c_[gx.ravel(), np.full(gx.size, top - r), gz.ravel()]
    p = Particles.empty(len(pos), dim=3, hist_cap=4)
    p.pos[:] = pos
    p.r[:] = r
    return p


def test_sinkage_surface_is_the_bed_top_under_the_wheel_not_the_highest_sphere_across():
    """The 3D surface (sinkage's zero) is the mean of the local tops in the wheel's band:
    a ridge outside the band (soil heaped at a side wall) does not raise it, and a bed
    part that starts away from x = 0 (streamed beds) gets its own columns."""
    from ooc_dem.app.bed import surface_height, wheel_footprint

    sc = load_scenario("paper2008-3d")
    lo, hi = wheel_footprint(sc)
    assert np.allclose((lo, hi), (0.05, 0.15), rtol=0, atol=1e-15)
    xs = np.arange(0.005, 0.6, 0.01)
    bed = _layer(xs, np.arange(0.005, 0.2, 0.01), 0.07)
    ridge = _layer(xs, [0.195], 0.09)  # against the far side wall
    p = Particles.concat([bed, ridge], dim=3, hist_cap=4)
    r_max = sc.soil.r_max
    assert math.isclose(surface_height(p, 0.6, r_max, across=(lo, hi)), 0.07, rel_tol=1e-12)
    assert math.isclose(surface_height(p, 0.6, r_max), 0.09, rel_tol=1e-12)  # the max across
    # a part of the bed from x = 0.3 to 0.6: its own columns, not all clipped into the last
    half = _layer(np.arange(0.305, 0.6, 0.01), np.arange(0.055, 0.15, 0.01), 0.05)
    half.pos[half.pos[:, 0] > 0.45, 1] -= 0.02  # the far half 2 cm lower
    s = surface_height(half, 0.3, r_max, x_origin=0.3, across=(lo, hi))
    assert 0.035 < s < 0.045, s
    assert wheel_footprint(load_scenario("paper2008")) is None


def test_a_run_with_the_wheel_sigkilled_mid_roll_resumes_to_the_same_bits(runs, tmp_path):
    """`ooc-dem run` (out-of-core, D = 6, the wheel rolling over re-decompositions) killed
    with SIGKILL as soon as an epoch past the start is committed; `ooc-dem resume` ends
    with the uninterrupted run's bits and writes the 3D figures and the wheel's mesh; a
    resume after those were lost writes them again."""
    import signal
    import subprocess
    import sys
    import time
    from ooc_dem.app.plots import figure_files

    out = tmp_path / "killed"
    sets = [a for kv in WHEEL3D for a in ("--set", kv)]
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "ooc_dem.cli",
            "run",
            "quick-3d",
            *sets,
            "--mode",
            "ooc",
            "--domains",
            "6",
            "--block",
            "4",
            "--checkpoint-every",
            "20",
            "--steps",
            str(WHEEL3D_STEPS),
            "--out",
            str(out),
            "--no-progress",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    deadline = time.time() + 600
    while time.time() < deadline and proc.poll() is None and committed_step(out) <= 0:
        time.sleep(0.01)
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=60)
    assert proc.returncode == -signal.SIGKILL, proc.stderr.read()
    killed_at = committed_step(out)
    assert 0 < killed_at < WHEEL3D_STEPS, killed_at
    cp = run_cli("resume", out, "--no-progress")
    assert cp.returncode == 0, cp.stderr
    ref = runs["ooc-hdf5"].summary
    got = json.loads((out / "summary.json").read_text())
    assert got["state_hash"] == ref["state_hash"] and f"state hash: {ref['state_hash']}" in cp.stdout
    for k in ("slip", "net_traction", "gross_traction", "sinkage"):
        assert got[k] == ref[k], k
    files = figure_files(load_scenario("quick-3d", WHEEL3D))
    assert "wheel.vtk" in files and "figures/rut.png" in files
    for f in files:
        assert (out / f).stat().st_size > 1000, f
    (out / "figures" / "rut.png").unlink()
    (out / "wheel.vtk").unlink()
    cp = run_cli("resume", out, "--no-progress")
    assert cp.returncode == 0 and "missing outputs: figures" in cp.stdout, cp.stdout + cp.stderr
    for f in files:
        assert (out / f).is_file(), f
    cli_in_process("checkpoint", "verify", out, check=True)
