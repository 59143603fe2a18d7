"""A 3D wheel loaded from a triangle mesh (wheel.mesh; physics.mesh, model.mesh_wheel).

- the contact kernel itself (``d3.bodies.body_rows``, the function the step calls, on one
  sphere): a sphere pressed and dragged on a flat two-triangle square gives the force
  history of the same sphere on the analytic floor; sliding across the square's shared
  diagonal it feels no jump; at an edge and a vertex the closest point, normal and
  overlap are the hand-computed ones;
- whole runs: quick-3d with its built-in wheel against the same wheel as a mesh
  (tools/make_wheel_meshes.py), and a mesh wheel run in every mode (same bits);
- refusals: a missing file, a garbage file, a 2D scenario with a mesh.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from support.cli import run_cli
from support.sim3d import make_spheres

from ooc_dem.engine.stepper import Model
from ooc_dem.model.scenario import ScenarioError, load_scenario
from ooc_dem.physics.d3 import bodies
from ooc_dem.physics.d3.layout import (
    BODY_ROW,
    ID_LUG0,
    ID_WALL_BOTTOM,
    T_SOIL,
    T_WALL,
    T_WHEEL,
    WHEEL_GEOMETRY,
    WHEEL_STATE,
    contact_table,
    hertz_params,
    walls_record,
)
from ooc_dem.physics.layout import ID_RIM, LUG_DIRECTION, no_mesh, no_plates
from ooc_dem.physics.wheel import lug_directions
from ooc_dem.physics.mesh import closest_on_triangle, mesh_contact, mesh_wheel
from ooc_dem.physics.plates import plate_scene

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))
from make_wheel_meshes import grousered_wheel  # noqa: E402

R_SPHERE = 0.005
DT = 2.0e-5
# the floor and the wheel of one material, so that the two contacts differ in geometry only
LAW = hertz_params(5.0e7, 0.3, 0.3, mu=0.5, mur=0.1, zr=0.3)
CP = contact_table({(T_SOIL, T_SOIL): LAW, (T_WALL, T_SOIL): LAW, (T_WHEEL, T_SOIL): LAW})
HEAVY = 2.0**1000  # the wheel's mass: m M / (m + M) is exactly the sphere's own mass m


def flat_square(half=0.5):
    """Two triangles making the square |x|, |z| <= half at y = 0, facing +y, sharing the
    diagonal from (-half, 0, -half) to (half, 0, half)."""
    a, b, c, d = (-half, 0, -half), (half, 0, -half), (half, 0, half), (-half, 0, half)
    return np.array([[a, c, b], [a, d, c]], np.float64)


def _scene(mesh_on: bool):
    walls = walls_record(1.0, 1.0, left=False, right=False, bottom=not mesh_on, front=False, back=False)
    wg = np.zeros(1, WHEEL_GEOMETRY)
    ws = np.zeros(1, WHEEL_STATE)
    if mesh_on:
        wg[0]["enabled"] = 1.0
        wg[0]["radius"] = 0.1
        wg[0]["mass"] = HEAVY
        wg[0]["width"] = 1.0
    return bodies.body_scene(walls, wg, ws)


def _rows(spheres, scene, mesh):
    """The sphere's body rows of one step (body_rows, as produce calls it)."""
    body = np.zeros(8, BODY_ROW)
    lugdir = np.zeros(1, LUG_DIRECTION)
    n, full = bodies.body_rows(
        0, spheres.discs(), CP, scene, False, plate_scene(no_plates().table), lugdir, mesh, body, 0, 8, DT
    )
    assert not full
    return body[:n]


def _keep_history(spheres, rows):
    """The rows' springs as the sphere's history (what the step's gather does)."""
    s = spheres
    s.hist_n[0] = len(rows)
    for k, row in enumerate(rows):
        s.hist_id[0, k] = row["pid"]
        s.hist_s[0, k] = (row["sx"], row["sy"], row["sz"])
        s.hist_m[0, k] = (row["mx"], row["my"], row["mz"])


FORCE = ("bx", "by", "bz", "tx", "ty", "tz", "sx", "sy", "sz", "mx", "my", "mz")


def _history(mesh_on: bool, path):
    """The rows of a sphere following ``path`` (positions, velocities, spins) over the floor
    or the square mesh, its springs carried from step to step."""
    sp = make_spheres([(0.0, 0.0, 0.0)], R_SPHERE, density=2650.0)
    scene = _scene(mesh_on)
    mesh = mesh_wheel(flat_square(), 2.0 * R_SPHERE) if mesh_on else no_mesh()
    out = []
    for pos, vel, spin in path:
        sp.pos[0], sp.vel[0], sp.spin[0] = pos, vel, spin
        rows = _rows(sp, scene, mesh)
        _keep_history(sp, rows)
        assert len(rows) == 1 and rows[0]["pid"] == (ID_LUG0 if mesh_on else ID_WALL_BOTTOM)  # mesh: part 0
        out.append([rows[0][f] for f in FORCE])
    return np.array(out)


def test_a_sphere_on_a_flat_mesh_feels_the_floor():
    """Pressed in, then dragged across the square (over its diagonal) while spinning: the
    same force, torque and springs as on the analytic floor, step by step, bit for bit."""
    path = []
    for k in range(400):
        y = R_SPHERE - 1e-6 - 1e-5 * min(k, 100) / 100.0 - 5e-7 * math.sin(k / 20.0)
        x = -0.03 + 1.5e-4 * k
        path.append(((x, y, 0.004 - 2e-5 * k), (0.3, -0.01 * math.cos(k / 20.0), -0.04), (1.0, -2.0, 3.0)))
    floor = _history(False, path)
    mesh = _history(True, path)
    assert np.all(np.isfinite(floor)) and np.abs(floor[:, 1]).max() > 0.0
    # the face's closest point is the centre projected along the unit normal: on a plane
    # normal to y, exactly the floor's point, normal and overlap, so exactly its bits
    assert np.array_equal(mesh, floor)


def test_no_jump_across_the_shared_edge():
    """Positions straddling the diagonal edge of the two coplanar triangles: one contact,
    the same distance and normal on both sides, the force continuous."""
    sp = make_spheres([(0.0, 0.0, 0.0)], R_SPHERE, density=2650.0)
    scene = _scene(True)
    mesh = mesh_wheel(flat_square(), 2.0 * R_SPHERE)
    forces = []
    y = R_SPHERE - 2e-5
    for e in np.linspace(-1e-9, 1e-9, 21):
        sp.pos[0] = (0.01 + e, y, 0.01 - e)  # across the line x = z
        sp.hist_n[0] = 0
        rows = _rows(sp, scene, mesh)
        assert len(rows) == 1
        forces.append([rows[0]["bx"], rows[0]["by"], rows[0]["bz"]])
        found, part, qx, qy, qz, dist, more = mesh_contact(mesh, sp.pos[0, 0], y, sp.pos[0, 2], R_SPHERE, -1)
        assert found and part == 0 and not more and abs(dist - y) <= 1e-15 and abs(qy) <= 1e-18
    f = np.array(forces)
    jump = np.abs(np.diff(f, axis=0)).max() / np.abs(f).max()
    assert jump <= 1e-12, jump
    assert np.all(f[:, 1] > 0.0) and np.abs(f[:, [0, 2]]).max() <= 1e-12 * f[:, 1].max()


def test_edge_and_vertex_contacts():
    t = np.array([[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.0, 0.01, 0.0]])
    # beyond the hypotenuse (x + y = 0.01), above the plane: the edge's point (0.005, 0.005, 0)
    p = (0.007, 0.007, 0.003)
    assert np.allclose(closest_on_triangle(*p, t), (0.005, 0.005, 0.0), atol=1e-16)
    # beyond the vertex (0.01, 0, 0)
    assert closest_on_triangle(0.012, -0.001, 0.002, t) == (0.01, 0.0, 0.0)
    # over the face
    assert np.allclose(closest_on_triangle(0.002, 0.003, -0.004, t), (0.002, 0.003, 0.0), atol=1e-18)
    mesh = mesh_wheel(t[None], 0.01)
    r = 0.005
    found, _, qx, qy, qz, dist, _ = mesh_contact(mesh, *p, r, -1)
    d_edge = math.sqrt(2 * 0.002**2 + 0.003**2)
    assert found and math.isclose(dist, d_edge, rel_tol=1e-14)
    # the row's force lies along the rounded normal (p - q) / |p - q| (no sliding: normal only)
    sp = make_spheres([(0.1 + p[0], p[1], p[2])], r, density=2650.0)
    wg = np.zeros(1, WHEEL_GEOMETRY)
    wg[0]["enabled"], wg[0]["radius"], wg[0]["mass"], wg[0]["width"] = 1.0, 0.1, HEAVY, 1.0
    ws = np.zeros(1, WHEEL_STATE)
    ws[0]["x"] = 0.1  # the axle at (0.1, 0, 0): the triangle at x = 0.1 .. 0.11 in the world
    scene = bodies.body_scene(walls_record(1.0, 1.0, False, False, False, False, False), wg, ws)
    rows = _rows(sp, scene, mesh)
    assert len(rows) == 1
    f = np.array([rows[0]["bx"], rows[0]["by"], rows[0]["bz"]])
    n = np.array([0.002, 0.002, 0.003]) / d_edge
    assert np.allclose(f / np.linalg.norm(f), n, rtol=0, atol=1e-12)
    # the vertex: normal from (0.01, 0, 0), overlap r - |p - v|
    pv = (0.012, -0.001, 0.002)
    found, _, qx, qy, qz, dist, _ = mesh_contact(mesh, *pv, r, -1)
    assert found and (qx, qy, qz) == (0.01, 0.0, 0.0) and math.isclose(dist, math.sqrt(9e-6), rel_tol=1e-14)
    sp.pos[0] = (0.1 + pv[0], pv[1], pv[2])
    f = np.array([[row["bx"], row["by"], row["bz"]] for row in _rows(sp, scene, mesh)])[0]
    assert np.allclose(f / np.linalg.norm(f), np.array([0.002, -0.001, 0.002]) / 0.003, rtol=0, atol=1e-12)
    # out of reach: no contact
    assert not mesh_contact(mesh, 0.0, 0.0, 0.0051, r, -1)[0]


def test_the_wheel_turns_its_mesh():
    """theta turns the mesh with the wheel: a sphere below a quarter-turned mesh touches
    the triangle that lay beside the axle at theta = 0."""
    t = np.array([[[0.05, -0.01, -0.01], [0.05, 0.01, -0.01], [0.05, 0.0, 0.01]]])  # x = 0.05
    mesh = mesh_wheel(t, 0.01)
    wg = np.zeros(1, WHEEL_GEOMETRY)
    wg[0]["enabled"], wg[0]["radius"], wg[0]["mass"], wg[0]["width"] = 1.0, 0.05, HEAVY, 0.1
    ws = np.zeros(1, WHEEL_STATE)
    ws[0]["theta"] = -0.5 * math.pi  # a quarter-turn clockwise: the triangle now lies at y = -0.05
    scene = bodies.body_scene(walls_record(1.0, 1.0, False, False, False, False, False), wg, ws)
    sp = make_spheres([(0.0, -0.05 - 0.004, 0.0)], R_SPHERE, density=2650.0)
    rows = _rows(sp, scene, mesh)
    assert len(rows) == 1 and rows[0]["by"] < 0.0
    assert abs(rows[0]["bx"]) <= 1e-12 * abs(rows[0]["by"])


# ------------------------------------------------------------------ parts


def test_surface_parts_are_the_pieces_joined_by_shared_vertices():
    """Two boxes apart, then overlapping (no shared vertex): two parts each; the parts are
    numbered in the order of their first triangle, interleaved triangles included."""
    from ooc_dem.physics.mesh import surface_parts

    a = np.asarray(trimesh.creation.box((1.0, 1.0, 1.0)).triangles)
    b = np.asarray(trimesh.creation.box((1.0, 1.0, 1.0)).apply_translation((3.0, 0, 0)).triangles)
    c = np.asarray(trimesh.creation.box((0.5, 2.0, 0.5)).triangles)  # through a, no vertex shared
    assert np.array_equal(surface_parts(np.concatenate([b, a])), np.repeat([0, 1], 12))
    assert np.array_equal(surface_parts(np.concatenate([a, c])), np.repeat([0, 1], 12))
    mixed = np.empty((24, 3, 3))
    mixed[0::2], mixed[1::2] = b, a
    assert np.array_equal(surface_parts(mixed), np.tile([0, 1], 12))
    sphere = np.asarray(trimesh.creation.icosphere(subdivisions=3).triangles)
    assert np.array_equal(surface_parts(sphere), np.zeros(len(sphere), np.int64))


def _corner(joined: bool):
    """A floor square (y = 0) and a wall square (x = 0.02, facing -x) meeting along z:
    one part if they share the corner's vertices, else two."""
    floor = flat_square(0.02)  # its corners (0.02, 0, -0.02) and (0.02, 0, 0.02) among them
    gap = 0.0 if joined else 1e-3  # apart: the wall starts 1 mm above the floor
    w0, w1, w2, w3 = (0.02, gap, -0.02), (0.02, gap, 0.02), (0.02, 0.04, 0.02), (0.02, 0.04, -0.02)
    wall = np.array([[w0, w2, w1], [w0, w3, w2]], np.float64)
    return np.concatenate([floor, wall])


def test_a_grain_between_two_parts_feels_both():
    """A sphere pressed into the corner of a floor and a wall: as two parts, two contacts
    (partner ids ID_LUG0 + 0 and + 1, ascending), each the force of its face alone; as one
    part (the corner's vertices shared), one contact, the nearer face's."""
    from ooc_dem.physics.mesh import surface_parts

    joined, apart = _corner(True), _corner(False)
    assert surface_parts(joined).max() == 0 and surface_parts(apart).max() == 1
    sp = make_spheres([(0.02 - R_SPHERE + 2e-5, R_SPHERE - 3e-5, 0.0)], R_SPHERE, density=2650.0)
    scene = _scene(True)
    rows = _rows(sp, scene, mesh_wheel(apart, 2.0 * R_SPHERE))
    assert list(rows["pid"]) == [ID_LUG0, ID_LUG0 + 1]
    floor_only = _rows(sp, scene, mesh_wheel(apart[:2], 2.0 * R_SPHERE))
    wall_only = _rows(sp, scene, mesh_wheel(apart[2:], 2.0 * R_SPHERE))
    for row, alone in ((rows[0], floor_only[0]), (rows[1], wall_only[0])):
        assert [row[f] for f in FORCE] == [alone[f] for f in FORCE]
    assert rows[0]["by"] > 0.0 and rows[1]["bx"] < 0.0
    one = _rows(sp, scene, mesh_wheel(joined, 2.0 * R_SPHERE))
    assert len(one) == 1 and one[0]["pid"] == ID_LUG0 and one[0]["by"] > 0.0  # the floor: 30 um in


def test_the_builtin_wheel_and_its_fine_mesh_give_the_same_forces():
    """quick-3d's wheel, built in and as a finely tessellated mesh (rim facets within
    0.12 um of the circle, lug tips within 0.15 um), at rest, with spheres pressed 0.2 mm
    into the rim between two lugs, into the corner of a lug and the rim (two contacts on
    both wheels: lug and rim) and onto a lug's tip: every contact's force within 5e-3 of
    the built-in wheel's (the facets' distance from the true surface over the overlap,
    times 3/2 for Hertz), the normals within the facets' angle."""
    sc = load_scenario("quick-3d")
    w = sc.wheel
    n, R, cap, r, dl = w.n_lugs, w.radius, 0.5 * w.lug_thickness, R_SPHERE, 2e-4
    lug_out = w.lug_tip_radius - cap
    C = np.array([0.3, 0.2])

    def u(phi):
        return np.array([math.cos(phi), math.sin(phi)])

    k = 3 * n // 4  # a lug near the bottom
    phik = 2.0 * math.pi * k / n
    along = math.sqrt((R + r - dl) ** 2 - (cap + r - dl) ** 2)
    v = np.array([-math.sin(phik), math.cos(phik)])  # across lug k
    centres = [
        C + (R + r - dl) * u(2.0 * math.pi * (k + 0.5) / n),  # the rim between lugs k and k + 1
        C + along * u(phik) + (cap + r - dl) * v,  # lug k's side and the rim
        C + (lug_out + cap + r - dl) * u(2.0 * math.pi * (k - 1) / n),  # lug k - 1's tip
    ]
    sp = make_spheres([(x, y, 0.0) for x, y in centres], r, density=2650.0)
    mesh = grousered_wheel(R, w.width, n, w.lug_tip_radius, w.lug_thickness, segments=2048, tip_segments=128)
    forces = {}
    for label, model in (("builtin", Model.from_scenario(sc)), ("mesh", None)):
        if model is None:
            model = dataclasses.replace(Model.from_scenario(sc), mesh=mesh_wheel(np.asarray(mesh.triangles), 2.0 * r))
        cp, walls, wg, _ = model.records()
        ws = np.zeros(1, WHEEL_STATE)
        ws[0]["x"], ws[0]["y"] = C
        wg = wg.copy()
        wg[0]["z0"] = 0.0
        scene = bodies.body_scene(walls, wg, ws)
        lugdir = np.empty(n, LUG_DIRECTION)
        lug_directions(0.0, n, lugdir)
        body = np.zeros(8, BODY_ROW)
        got = []
        for i in range(len(sp)):
            cnt, full = bodies.body_rows(
                i,
                sp.discs(),
                cp,
                scene,
                False,
                plate_scene(no_plates().table),
                lugdir,
                model.kernel_params()[7],
                body,
                0,
                8,
                DT,
            )
            assert not full
            rows = body[:cnt]
            rows = rows[rows["pid"] <= ID_RIM]  # the wheel's rows
            got.append(sorted((tuple(float(row[f]) for f in ("bx", "by", "bz")) for row in rows)))
        forces[label] = got
    for i, (b, m) in enumerate(zip(forces["builtin"], forces["mesh"])):
        assert len(b) == len(m) == (2 if i == 1 else 1), (i, b, m)
        for fb, fm in zip(b, m):
            fb, fm = np.array(fb), np.array(fm)
            assert np.linalg.norm(fm - fb) <= 5e-3 * np.linalg.norm(fb), (i, fb, fm)


# ------------------------------------------------------------------ refusals


def _mesh_file(tmp_path, mesh, name="wheel.stl"):
    path = tmp_path / name
    mesh.export(path)
    return path


def test_a_scenario_loads_its_mesh_relative_to_its_file(tmp_path):
    _mesh_file(tmp_path, trimesh.creation.box((0.2, 0.2, 0.06)), "m.obj")
    (tmp_path / "s.toml").write_text('base = "quick-3d"\n[wheel]\nmesh = "m.obj"\nmesh_scale = 1.0\n')
    sc = load_scenario(tmp_path / "s.toml")
    assert sc.wheel.mesh == str(tmp_path / "m.obj")
    assert sc.hash() != load_scenario("quick-3d").hash()
    m = Model.from_scenario(sc)
    assert m.mesh is not None and m.mesh.tri.shape == (12, 3, 3)
    assert m.mesh.grid[3] == 2.0 * sc.soil.r_max
    # millimetres, turned a quarter about x and moved: the same box in metres
    _mesh_file(tmp_path, trimesh.creation.box((200.0, 60.0, 200.0)), "mm.stl")
    sc = load_scenario(
        "quick-3d", [f"wheel.mesh={tmp_path / 'mm.stl'}", "wheel.mesh_scale=0.001", "wheel.mesh_rotate=[90, 0, 0]"]
    )
    tri = Model.from_scenario(sc).mesh.tri
    assert np.allclose(tri.reshape(-1, 3).max(axis=0), (0.1, 0.1, 0.03))


def _box_and_specks(n):
    """A box about the axle and n separate small triangles beside it: n + 1 parts."""
    specks = [
        trimesh.Trimesh(
            vertices=[(0.3 + 1e-3 * k, 0, 0), (0.3 + 1e-3 * k, 1e-3, 0), (0.3 + 1e-3 * k, 0, 1e-3)],
            faces=[(0, 1, 2)],
            process=False,
        )
        for k in range(n)
    ]
    return trimesh.util.concatenate([trimesh.creation.box((0.2, 0.2, 0.06)), *specks])


@pytest.mark.parametrize(
    "make, message",
    [
        (None, "no such file"),
        (lambda p: p.write_bytes(b"solid garbage\nthis is not an stl\n" * 3), "wheel.mesh"),
        (lambda p: p.write_bytes(bytes(range(256)) * 7), "wheel.mesh"),
        (lambda p: trimesh.creation.box((0.05, 0.05, 0.05)).apply_translation((0.2, 0, 0)).export(p), "enclose"),
        (lambda p: _box_and_specks(900).export(p), "901 separate parts"),
    ],
)
def test_bad_meshes_are_refused(tmp_path, make, message):
    path = tmp_path / "bad.stl"
    if make is not None:
        make(path)
    sc = load_scenario("quick-3d", [f"wheel.mesh={path}"])
    with pytest.raises(ScenarioError) as e:
        Model.from_scenario(sc)
    assert message in str(e.value) and "\n" not in str(e.value)


def test_a_2d_scenario_with_a_mesh_is_refused(tmp_path):
    with pytest.raises(ScenarioError, match="physics.dim = 3"):
        load_scenario("quick", ["wheel.mesh=wheel.stl"])


def test_the_cli_refuses_a_missing_mesh_with_exit_2(tmp_path):
    cp = run_cli(
        "run",
        "quick-3d",
        "--set",
        f"wheel.mesh={tmp_path / 'none.stl'}",
        "--steps",
        "1",
        "--out",
        str(tmp_path / "o"),
        "--no-progress",
        "--no-figures",
    )
    assert cp.returncode == 2, cp.stderr
    assert "no such file" in cp.stderr and len(cp.stderr.strip().splitlines()) == 1


# ------------------------------------------------------------------ the wheel's inertia


def test_a_closed_mesh_gives_the_inertia_of_its_solid():
    """solid_axle_inertia against trimesh's mass properties (the same solid: 1e-12) and the
    analytic m R^2 / 2 of a cylinder and m (a^2 + b^2) / 2 of a tube (their tessellation:
    2e-4 at 512 segments); the sign of the winding and the order of the triangles do not
    change it (the order: not one bit)."""
    from ooc_dem.model.mesh_wheel import is_closed_surface, solid_axle_inertia

    m = 3.0
    for mesh, exact in (
        (trimesh.creation.cylinder(radius=0.15, height=0.1, sections=512), 0.5 * m * 0.15**2),
        (trimesh.creation.annulus(r_min=0.12, r_max=0.15, height=0.1, sections=512), 0.5 * m * (0.12**2 + 0.15**2)),
    ):
        tri = np.ascontiguousarray(mesh.triangles, np.float64)
        assert is_closed_surface(tri)
        got = solid_axle_inertia(tri, m)
        assert got == pytest.approx(m / mesh.volume * mesh.moment_inertia[2, 2], rel=1e-12)
        assert got == pytest.approx(exact, rel=2e-4)
        # inward winding: both integrals flip sign (each term rounded anew: equal to 1e-14)
        assert solid_axle_inertia(tri[:, ::-1], m) == pytest.approx(got, rel=1e-14)
        assert solid_axle_inertia(tri[::-1], m) == got  # fsum: exactly rounded in any order


def test_a_free_spinning_mesh_wheel_takes_its_meshs_inertia(tmp_path):
    """torque and towed control: the model's inertia is the mesh solid's at the wheel's mass
    (wheel.inertia, when given, wins); slip control keeps the disc's (omega is prescribed);
    an open surface under free spin is refused in one line, naming wheel.inertia."""
    from ooc_dem.model.mesh_wheel import body_frame_triangles, solid_axle_inertia
    from ooc_dem.physics.layout import WHEEL_CONTROLS, record

    path = _mesh_file(tmp_path, trimesh.creation.cylinder(radius=0.1, height=0.1, sections=64))
    towed = [f"wheel.mesh={path}", "wheel.control=towed", "wheel.speed=0.05"]
    sc = load_scenario("quick-3d", towed)
    want = solid_axle_inertia(body_frame_triangles(sc), sc.wheel_mass)
    assert record(Model.from_scenario(sc).wc, WHEEL_CONTROLS)["inertia"] == want
    sc = load_scenario("quick-3d", [*towed, "wheel.inertia=0.02"])
    assert record(Model.from_scenario(sc).wc, WHEEL_CONTROLS)["inertia"] == 0.02
    sc = load_scenario("quick-3d", [f"wheel.mesh={path}"])
    assert sc.wheel.control != "towed"
    assert record(Model.from_scenario(sc).wc, WHEEL_CONTROLS)["inertia"] == 0.5 * sc.wheel_mass * sc.wheel.radius**2
    open_cup = trimesh.creation.cylinder(radius=0.1, height=0.1, sections=64)
    open_cup.update_faces(open_cup.face_normals[:, 2] < 0.5)  # the top cap removed
    path = _mesh_file(tmp_path, open_cup, "cup.stl")
    sc = load_scenario("quick-3d", [f"wheel.mesh={path}", "wheel.control=towed", "wheel.speed=0.05"])
    with pytest.raises(ScenarioError, match="not a closed surface.*wheel.inertia") as e:
        Model.from_scenario(sc)
    assert "\n" not in str(e.value)


# ------------------------------------------------------------------ whole runs


def _wheel_mesh_file(tmp_path, sc_name, overrides=()):
    """The scenario's built-in wheel written as a mesh (tools/make_wheel_meshes.py)."""
    w = load_scenario(sc_name, list(overrides)).wheel
    path = tmp_path / f"{sc_name}-wheel.stl"
    grousered_wheel(w.radius, w.width, w.n_lugs, w.lug_tip_radius, w.lug_thickness).export(path)
    return path


QUANTITIES = ("net_traction", "torque", "sinkage", "slip")
NOISE = 0.15  # relative (test_quick_3d_with_its_wheel_as_a_mesh)


@pytest.mark.slow
def test_quick_3d_with_its_wheel_as_a_mesh(tmp_path):
    """quick-3d with the built-in wheel and with the same wheel loaded from a mesh: the
    steady means of drawbar pull (net traction), torque and sinkage agree within NOISE.

    Not 2 %: one quick-3d run's steady means are not that reproducible. The built-in
    wheel placed 1 um further along (wheel.x0 = 0.120001) moved net traction by 7 %,
    torque by 2 % and sinkage by 2 %; the mesh wheel differs by 7 %, 5 % and 10 %.
    Part of that is the model: the mesh gives a sphere one contact with the wheel (the
    nearest surface), the built-in wheel one with each lug and the rim, so a grain
    wedged between a lug and the rim is held by both only there."""
    import ooc_dem

    mesh = _wheel_mesh_file(tmp_path, "quick-3d")
    builtin = ooc_dem.run("quick-3d", tmp_path / "builtin").summary
    meshed = ooc_dem.run("quick-3d", tmp_path / "mesh", overrides=[f"wheel.mesh={mesh}"]).summary
    pairs = {q: (builtin[q]["steady"]["value"], meshed[q]["steady"]["value"]) for q in QUANTITIES}
    for q, (a, b) in pairs.items():
        print(f"{q}: built-in {a!r} mesh {b!r} ({(b - a) / abs(a):+.2%})")
    for q in ("net_traction", "torque", "sinkage"):  # slip: printed only
        a, b = pairs[q]
        assert abs(b - a) <= NOISE * abs(a), (q, a, b)


def test_films_and_exports_draw_the_mesh_at_the_kernels_pose():
    """The films' and exports' wheel surface of a mesh wheel is the mesh itself (its
    triangles, not the built-in rim and lugs), turned as the kernel turns it: the body
    frame's point (R, 0, 0) at angle pi/2 is straight above the axle."""
    from ooc_dem.app.wheel_surface import WheelGeometry, mesh_at_pose, wheel_surface

    mesh = Path(__file__).resolve().parents[1] / "examples" / "meshes" / "chevron.stl"
    sc = load_scenario("paper2008-3d", overrides=[f"wheel.mesh={mesh}"])
    g = WheelGeometry.of_scenario(sc)
    assert g.mesh is not None
    verts, tris = wheel_surface(g, 0.3, 0.2, 0.7)
    assert tris.shape == (len(g.mesh), 3) and verts.shape == (3 * len(g.mesh), 3)
    assert np.array_equal(verts[tris].reshape(-1, 3), mesh_at_pose(g, 0.3, 0.2, 0.7).reshape(-1, 3))
    g1 = WheelGeometry(g.radius, g.width, g.z_centre, 0, 0.0, 0.0, np.array([[[0.1, 0.0, 0.0]] * 3]))
    p = mesh_at_pose(g1, 0.3, 0.2, math.pi / 2)[0, 0]
    assert p == pytest.approx([0.3, 0.3, g.z_centre], abs=1e-15)
    # the kernel's body frame: the centre d turned by -theta (bodies.mesh_rows)
    d = p[:2] - np.array([0.3, 0.2])
    c, s = math.cos(math.pi / 2), math.sin(math.pi / 2)
    assert [c * d[0] + s * d[1], c * d[1] - s * d[0]] == pytest.approx([0.1, 0.0], abs=1e-15)
