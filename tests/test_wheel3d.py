"""Issue 16: the lugged wheel in 3D (rim cylinder and lug plates spanning the wheel's width).

Two levels:
- contact geometry through THE per-domain step (``DomainStepper`` on a few spheres): the
  rim's curved surface, an end face, a lug plate, a sphere beside the wheel (no contact),
  the reaction on the wheel equal and opposite to the spheres' forces, the torque sign;
- whole runs on a small 3D bin (``WHEEL3D``): the wheel sinks into the bed while settling
  with omega = 0, then rolls; monolithic, serial DDM D = 6 (with re-decompositions),
  out-of-core HDF5 and zarr, and a resumed run all give the same bits.
"""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
from conftest import run_cli

import ooc_dem
from ooc_dem.engine.stepper import DomainStepper, Model
from ooc_dem.physics.layout import (ID_LUG0, ID_RIM, REC_FX, REC_FY, REC_NC, REC_TQ, WS_SIZE,
                                    WS_WZ, WS_X, WS_Y)
from ooc_dem.scenario import ScenarioError, load_scenario
from ooc_dem.state import Particles

R = 0.1
Z0 = 0.06     # quick-3d: bin width 0.12, wheel width 0.06 centred at mid-width


def _sphere_set(sc, pos, r=0.005):
    """Particles of a few spheres at pos (N, 3), at rest, soil material."""
    pos = np.array(pos, np.float64).reshape(-1, 3)
    n = len(pos)
    p = Particles.empty(n, dim=3, hist_cap=sc.hist_cap)
    p.id[:] = np.arange(n)
    p.pos[:] = pos
    p.r[:] = r
    p.mass[:] = sc.soil.density * 4.0 / 3.0 * math.pi * r ** 3
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
    cp = run_cli("run", "quick-3d", "--set", "wheel.width=0.2", "--steps", "1")
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
    st, rec = _one_step(sc, [[0.15, 0.2 - R - 0.0045, Z0 + half + 0.0051],   # beside: free
                             [0.15, 0.2 - 0.05, Z0 + half + 0.0045]])        # at the end face
    assert rec[REC_NC] == 1
    order = np.argsort(st.p.id)
    f_free, f_face = st.force[order[0]], st.force[order[1]]
    assert np.all(f_free == 0.0)
    assert f_face[2] > 0 and f_face[0] == 0.0 and f_face[1] == 0.0
    assert rec[REC_FX] == 0.0 and rec[REC_FY] == 0.0     # the lateral force goes to the axle


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
    assert fy[0] == fy[1] == fy[2]          # the plate is the same across the width


def test_spinning_wheel_drags_the_sphere_and_feels_a_resisting_torque(sc):
    # clockwise spin (wz < 0): the rim's bottom moves in +x and drags the sphere along
    st, rec = _one_step(sc, [[0.15, 0.2 - R - 0.0045, Z0]], {WS_WZ: -1.0})
    f = st.force[0]
    assert f[0] > 0 and rec[REC_FX] < 0
    assert rec[REC_TQ] > 0                  # counter-clockwise: resists the drive


@pytest.fixture(scope="module")
def quick3d_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("w3d") / "q"
    res = ooc_dem.run("quick-3d", out, overrides=WHEEL3D, steps=WHEEL3D_STEPS)
    return out, res


# a small 3D bin: the quick-3d rig with a narrower wheel in a shorter, narrower bin
WHEEL3D = ["soil.n=900", "bin.length=0.3", "bin.width=0.07", "wheel.width=0.035",
           "wheel.x0=0.13", "wheel.settle_time=0.04", "wheel.drawbar_ramp=0.02",
           "wheel.travel_time=0.2", "wheel.omega=2.0", "output.steady_start=0.05",
           "output.steady_end=0.2", "decomposition.margin=0.002"]
WHEEL3D_STEPS = 4000
