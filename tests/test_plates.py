"""Rigid plates (physics.plates): contact within the extent only, the reaction recorded,
prescribed and force-controlled motion, the canonical sum, and a box of plates that
reproduces the fixed walls bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from ooc_dem.engine.stepper import DomainStepper, EngineError, Model
from ooc_dem.model.state import Particles
from ooc_dem.physics.d2 import layout as L2
from ooc_dem.physics.layout import AX_X, AX_Y, AX_Z, ID_PLATE0, MAX_PLATES, SP_Z, WC_SIZE, WG_SIZE
from ooc_dem.physics.plates import plate

G = 9.81
KN = 1.0e5
R = 0.01
RHO = 2000.0
B = 0.1  # disc thickness
DT = 1.0e-5


def model2(walls=(1.0e3, 0.0, 0.0, 0.0), mu=0.5, gy=-G) -> Model:
    cp = np.zeros((3, 3, L2.N_FIELDS))
    cp[0, 0] = L2.linear_params(KN, KN / 3, 0.5, 0.5, mu)
    cp[1, 0] = cp[0, 1] = L2.linear_params(KN, KN / 3, 0.5, 0.5, mu)
    return Model(
        dt=DT,
        gravity=np.array([0.0, gy]),
        skin=0.2 * R,
        cp=cp,
        walls=np.array(walls, float),
        wg=np.zeros(WG_SIZE),
        wc=np.zeros(WC_SIZE),
        wheel_enabled=False,
        r_max=R,
    )


def discs(x, y, r=R) -> Particles:
    x = np.atleast_1d(np.asarray(x, float))
    pos = np.column_stack([x, np.broadcast_to(np.asarray(y, float), x.shape)])
    return Particles.new(pos, np.broadcast_to(np.asarray(r, float), x.shape).copy(), RHO, B)


def test_a_disc_rests_on_a_plate_and_its_weight_is_recorded():
    """One disc on a horizontal plate (normal +y): at rest the plate carries its weight
    (fy = -m g on the plate, N = m g) and the overlap is m g / kn."""
    p = discs(0.0, 0.1 + R)
    st = DomainStepper(p, model2(), plates=plate(AX_Y, 1, 0.1, (-0.05, 0.05)))
    st.advance(0, 30_000)
    rec = st.plate_records[-1, 0]
    w = float(p.mass[0]) * G
    assert rec["contacts"] == 1
    assert rec["load"] == pytest.approx(w, rel=1e-6)
    assert rec["fy"] == pytest.approx(-w, rel=1e-6)
    assert rec["fx"] == 0.0 and rec["fz"] == 0.0
    assert st.p.pos[0, AX_Y] == pytest.approx(0.1 + R - w / KN, abs=1e-9)
    # between steps its history holds the plate's entry under the plate's partner id
    assert st.p.hist_n[0] == 1 and st.p.hist_id[0, 0] == ID_PLATE0


@pytest.mark.parametrize("x", [0.0601, -0.0601])
def test_a_disc_beyond_the_extent_falls_past(x):
    """The contact needs the centre's projection within the extent: a disc whose centre is
    beyond an edge falls past the plate (no edge contact)."""
    p = discs(x, 0.1 + R)
    st = DomainStepper(p, model2(), plates=plate(AX_Y, 1, 0.1, (-0.06, 0.06)))
    st.advance(0, 10_000)
    assert st.plate_records["contacts"].max() == 0
    assert st.p.pos[0, AX_Y] < 0.1 - R


def test_the_active_side_only():
    """A plate pushes only on its active side: a disc under a plate whose face looks up
    falls away from it, as from nothing."""
    p = discs(0.0, 0.1 - 0.5 * R)
    st = DomainStepper(p, model2(), plates=plate(AX_Y, 1, 0.1, (-0.05, 0.05)))
    st.advance(0, 1000)
    assert st.plate_records["contacts"].max() == 0


def test_a_prescribed_plate_moves_and_drags_a_disc_to_a_third_of_its_speed():
    """A frictional plate sliding at v under a disc: the disc ends rolling without slip,
    its centre at v / (1 + m r^2 / I) = v / 3 (a disc: I = m r^2 / 2); the plate's extent
    has moved by v t."""
    v = 0.05
    p = discs(0.0, 0.1 + R - 1e-5)
    st = DomainStepper(p, model2(), plates=plate(AX_Y, 1, 0.1, (-0.5, 0.5), velocity=(v, 0.0, 0.0)))
    n = 40_000
    st.advance(0, n)
    assert st.p.vel[0, AX_X] == pytest.approx(v / 3, rel=1e-3)
    # rolling without slip: the contact point moves with the plate
    assert st.p.vel[0, AX_X] + st.p.spin[0, SP_Z] * R == pytest.approx(v, rel=1e-3)
    assert st.plates[0]["lo1"] == pytest.approx(-0.5 + v * n * DT, rel=1e-9)
    assert st.plates[0]["hi1"] == pytest.approx(0.5 + v * n * DT, rel=1e-9)
    assert st.plates[0]["pos"] == 0.1


def test_a_force_controlled_lid_holds_its_load():
    """A lid (normal -y) under load F presses a disc onto a floor plate: the lid comes to
    rest at a normal force F, the overlaps F / kn (lid) and (F + m g) / kn (floor). Then
    the floor is let down at a steady speed: the lid, a rigid body, follows it pressing
    with F (a servo would lag by an error that moves it)."""
    F = 5.0
    p = discs(0.0, R)
    floor = plate(AX_Y, 1, 0.0, (-0.05, 0.05))
    lid = plate(AX_Y, -1, 2 * R + 0.002, (-0.05, 0.05), load=F, mass=0.05, vmax=0.1)
    st = DomainStepper(p, model2(), plates=np.concatenate([floor, lid]))
    st.advance(0, 30_000)
    rec = st.plate_records[-1]
    w = float(p.mass[0]) * G
    assert rec[1]["load"] == pytest.approx(F, rel=1e-6)
    assert rec[0]["load"] == pytest.approx(F + w, rel=1e-6)
    assert abs(rec[1]["vy"]) < 1e-8
    y = st.p.pos[0, AX_Y]
    assert y == pytest.approx(R - (F + w) / KN, rel=1e-6)
    assert st.plates[1]["pos"] == pytest.approx(y + R - F / KN, rel=1e-6)
    v = 0.01
    st.plates[0]["vy"] = -v
    st.advance(30_000, 30_000)
    rec = st.plate_records[-1]
    assert rec[1]["vy"] == pytest.approx(-v, rel=1e-6)
    assert rec[1]["load"] == pytest.approx(F, rel=1e-5)


def test_the_plates_sums_do_not_depend_on_the_memory_order():
    """Each plate's force is summed in ascending particle id: the same records, bit for
    bit, whatever order the discs are held in (no spatial reorder; a reversed copy)."""
    rng = np.random.default_rng(3)
    n = 40
    x = np.arange(n) * 2.2 * R - 0.4
    y = 0.1 + R + rng.uniform(0, 0.5 * R, n)
    a = discs(x, y)
    a.vel[:, AX_Y] = rng.normal(0, 0.05, n)
    b = a.take(np.arange(n)[::-1])
    plates = np.concatenate(
        [plate(AX_Y, 1, 0.1, (-0.5, 0.5)), plate(AX_Y, -1, 0.1 + 2.4 * R, (-0.5, 0.0), load=20.0, mass=0.05, vmax=0.1)]
    )
    recs = []
    for p in (a, b):
        st = DomainStepper(p, model2(), reorder=False, plates=plates)
        st.advance(0, 3000)
        recs.append(st.plate_records.copy())
    assert recs[0]["contacts"].max() > 10
    assert np.array_equal(recs[0], recs[1])


def test_a_box_of_plates_is_the_walls_bit_for_bit():
    """With the end walls switched off and plates in their place (the same planes, in the
    walls' order: right, then left), a settling bed's discs move exactly as between the
    walls (only the partner ids in their histories differ)."""
    rng = np.random.default_rng(5)
    n = 150
    length = 0.2
    col, row = np.arange(n) % 8, np.arange(n) // 8
    x = 0.02 + col * 2.3 * R + rng.uniform(-0.1 * R, 0.1 * R, n)
    y = R + row * 2.3 * R + rng.uniform(0, 0.1 * R, n)
    base = discs(x, y, r=rng.uniform(0.8 * R, R, n))
    base.vel[:, AX_X] = rng.normal(0, 0.05, n)
    walls = DomainStepper(base.take(np.arange(n)), model2(walls=(length, 1.0, 1.0, 1.0)))
    plates = np.concatenate(
        [plate(AX_X, -1, length, (-1.0, 1.0)), plate(AX_X, 1, 0.0, (-1.0, 1.0))]  # right, left
    )
    boxed = DomainStepper(base.take(np.arange(n)), model2(walls=(length, 0.0, 0.0, 1.0)), plates=plates)
    for st in (walls, boxed):
        st.advance(0, 20_000)
    assert boxed.plate_records["contacts"].sum() > 0
    a, b = walls.p.sorted_by_id(), boxed.p.sorted_by_id()
    for k in ("pos", "vel", "spin", "hist_n", "hist_s", "hist_m"):
        assert np.array_equal(getattr(a, k), getattr(b, k)), k
    ida = np.where(a.hist_id == -3, ID_PLATE0, np.where(a.hist_id == -2, ID_PLATE0 + 1, a.hist_id))
    assert np.array_equal(ida, b.hist_id)


def test_plate_refusals():
    with pytest.raises(ValueError, match="axis"):
        plate(3, 1, 0.0, (0.0, 1.0))
    with pytest.raises(ValueError, match="low to high"):
        plate(AX_X, 1, 0.0, (1.0, 0.0))
    with pytest.raises(ValueError, match="mass"):
        plate(AX_X, 1, 0.0, (0.0, 1.0), load=1.0)
    too_many = np.concatenate([plate(AX_X, 1, 0.0, (0.0, 1.0))] * (MAX_PLATES + 1))
    with pytest.raises(EngineError, match="at most"):
        DomainStepper(discs(0.5, 0.5), model2(), plates=too_many)


# ------------------------------------------------------------------ 3D
def test_3d_a_sphere_rests_on_a_plate_within_its_rectangle_only():
    """3D: a sphere on a horizontal plate carries its weight (N = m g, overlap m g / kn);
    one beyond the rectangle's z edge falls past it."""
    from ooc_dem.physics.d3 import layout as L3

    cp = L3.contact_table(
        {(0, 0): L3.linear_params(KN, KN / 3, 0.5, 0.5, 0.5), (1, 0): L3.linear_params(KN, KN / 3, 0.5, 0.5, 0.5)}
    )
    cpf = np.ascontiguousarray(cp).view(np.float64).reshape(L3.N_TYPES, L3.N_TYPES, L3.N_FIELDS).copy()
    walls = L3.walls_record(1.0, 1.0, False, False, False, False, False).view(np.float64).copy()
    m = Model(
        dt=DT,
        gravity=np.array([0.0, -G, 0.0]),
        skin=0.2 * R,
        cp=cpf,
        walls=walls,
        wg=np.zeros(WG_SIZE),
        wc=np.zeros(WC_SIZE),
        wheel_enabled=False,
        r_max=R,
        dim=3,
    )
    pos = np.array([[0.0, 0.1 + R, 0.0], [0.0, 0.1 + R, 0.0601]])
    p = Particles.new(pos, np.full(2, R), RHO, B)
    st = DomainStepper(p, m, plates=plate(AX_Y, 1, 0.1, (-0.05, 0.05), (-0.06, 0.06)))
    st.advance(0, 30_000)
    rec = st.plate_records[-1, 0]
    w = float(p.mass[0]) * G
    assert rec["contacts"] == 1
    assert rec["load"] == pytest.approx(w, rel=1e-6)
    q = st.p.sorted_by_id()
    assert q.pos[0, AX_Y] == pytest.approx(0.1 + R - w / KN, abs=1e-9)
    assert q.pos[1, AX_Y] < 0.1 - R
    assert q.pos[0, AX_Z] == 0.0


def test_with_walls_switches_fixed_walls():
    m = model2(walls=(1.0, 1.0, 1.0, 1.0)).with_walls(left=False)
    assert m.walls.tolist() == [1.0, 0.0, 1.0, 1.0]
    with pytest.raises(ValueError, match="no wall 'front' in 2D"):
        model2().with_walls(front=False)


def test_3d_a_box_of_plates_is_the_walls_bit_for_bit():
    """3D: the end and side walls off and plates in their planes (in the walls' order:
    back, front, right, left): settling spheres move exactly as between the walls."""
    from ooc_dem.physics.d3 import layout as L3

    pair = L3.hertz_params(1e7, 0.3, 0.5, mu=0.5, mur=0.1, zr=0.3)
    cp = L3.contact_table({(0, 0): pair, (1, 0): L3.linear_params(KN, KN / 3, 0.5, 0.5, 0.5)})
    cpf = np.ascontiguousarray(cp).view(np.float64).reshape(L3.N_TYPES, L3.N_TYPES, L3.N_FIELDS).copy()
    length, width = 0.1, 0.1

    def model(on):
        walls = L3.walls_record(length, width, on, on, True, on, on).view(np.float64).copy()
        return Model(
            DT, np.array([0.0, -G, 0.0]), 0.2 * R, cpf, walls, np.zeros(WG_SIZE), np.zeros(WC_SIZE), False, R, 3
        )

    rng = np.random.default_rng(9)
    n = 120
    k = np.arange(n)
    pos = np.column_stack(
        [0.012 + (k % 4) * 2.3 * R, R + (k // 16) * 2.3 * R, 0.012 + ((k // 4) % 4) * 2.3 * R]
    ) + rng.uniform(0, 0.1 * R, (n, 3))
    base = Particles.new(pos, rng.uniform(0.8 * R, R, n), RHO, B)
    base.vel[:] = rng.normal(0, 0.05, (n, 3))
    big = (-1.0, 1.0)
    plates = np.concatenate(
        [
            plate(AX_Z, -1, width, big, big),  # back
            plate(AX_Z, 1, 0.0, big, big),  # front
            plate(AX_X, -1, length, big, big),  # right
            plate(AX_X, 1, 0.0, big, big),  # left
        ]
    )
    walls = DomainStepper(base.take(np.arange(n)), model(True))
    boxed = DomainStepper(base.take(np.arange(n)), model(False), plates=plates)
    for st in (walls, boxed):
        st.advance(0, 8000)
    assert boxed.plate_records["contacts"].sum() > 0
    a, b = walls.p.sorted_by_id(), boxed.p.sorted_by_id()
    for key in ("pos", "vel", "spin", "hist_n", "hist_s", "hist_m"):
        assert np.array_equal(getattr(a, key), getattr(b, key)), key
