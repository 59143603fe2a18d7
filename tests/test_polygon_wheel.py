"""A 2D wheel given as an outline (``wheel.outline``, physics.outline): the disc–polyline
contact against hand-computed values (a flat segment is the analytic floor contact, a
vertex between two collinear segments changes nothing, a convex vertex, a centre inside
the outline), the built-in wheel's outline (``builtin_outline``) against the built-in
wheel, the same bits in every mode and after a SIGKILL, and the refusals."""

from __future__ import annotations

import math

import numpy as np
import pytest
from support.cli import cli_in_process, one_line_error
from support.modes import assert_same_state, killed_and_resumed

import ooc_dem
from ooc_dem.engine.stepper import Model
from ooc_dem.model.scenario import ScenarioError, load_scenario
from ooc_dem.model.state import Particles
from ooc_dem.model.wheel_outline import builtin_outline, check_outline
from ooc_dem.physics.d2.bodies import outline_rows
from ooc_dem.physics.d2.contact import contact
from ooc_dem.physics.d2.layout import BODY_ROW
from ooc_dem.physics.detmath import det_cos, det_sin
from ooc_dem.physics.layout import ID_RIM, T_WHEEL, discs_of
from ooc_dem.physics.outline import nearest_point, wheel_outline

H = 0.05  # half side of the square test outline
SQUARE = np.array([(-H, -H), (H, -H), (H, H), (-H, H)])
# the same square with its top split at x = 0 (two collinear segments)
SPLIT = np.array([(-H, -H), (H, -H), (H, H), (0.0, H), (-H, H)])
DT = 1e-5


@pytest.fixture(scope="module")
def sc():
    return load_scenario("quick")


def _disc(sc, x, y, r=0.002, v=(0.0, 0.0), w=0.0):
    p = Particles.empty(1, dim=2, hist_cap=sc.hist_cap)
    p.id[0] = 0
    p.pos[0] = (x, y)
    p.vel[0] = v
    p.spin[0, 0] = w
    p.r[0] = r
    p.mass[0] = sc.soil.density * math.pi * r * r * sc.physics.thickness
    p.inertia[0] = 0.5 * p.mass[0] * r * r
    return p


def _row(sc, vert, p, wheel=(0.0, 0.0, 0.0, 0.0, 0.0, 0.0), mass=2.0):
    """The disc's outline row (None: no contact) for a wheel at (X, Y), velocity (VX, VY),
    spin WZ and angle theta."""
    X, Y, VX, VY, WZ, theta = wheel
    cp = Model.from_scenario(sc).records()[0]
    body = np.zeros(2, BODY_ROW)
    oscene = (True, X, Y, VX, VY, WZ, det_cos(theta), det_sin(theta), mass)
    ol = wheel_outline(vert, 2.0 * sc.soil.r_max)
    bat, full = outline_rows(0, discs_of(p), cp, oscene, ol, body, 0, 2, DT)
    assert not full
    return body[0] if bat == 1 else None


def _expected(sc, p, nx, ny, delta, vq, q, mass=2.0, wz=0.0):
    """The row's (bx, by, tq, wt) by hand: the law at normal n, the disc's velocity
    relative to the wheel's point q (offset from the axle), the reaction's torque about it."""
    cp = Model.from_scenario(sc).records()[0]
    mi = p.mass[0]
    fn, ft, _, mom, _ = contact(
        cp[T_WHEEL, 0],
        nx,
        ny,
        delta,
        p.vel[0, 0] - vq[0],
        p.vel[0, 1] - vq[1],
        wz,
        p.spin[0, 0],
        0.0,
        p.r[0],
        mi * mass / (mi + mass),
        p.inertia[0],
        p.r[0],
        0.0,
        0.0,
        DT,
    )
    bx = fn * nx + ft * ny
    by = fn * ny - ft * nx
    return bx, by, p.r[0] * ft + mom, q[0] * (-by) - q[1] * (-bx) - mom


def _close(row, want, rel=1e-12):
    """The row's force and torques as want, each to rel of the largest (a force near 0)."""
    got = (row["bx"], row["by"], row["tq"], row["wt"])
    scale = max(abs(w) for w in want)
    for g, w in zip(got, want):
        assert abs(g - w) <= rel * scale, (got, want)


def test_a_disc_on_a_flat_segment_is_the_analytic_floor_contact(sc):
    r, delta = 0.002, 1e-4
    p = _disc(sc, 0.013, H + r - delta, r, v=(0.03, -0.02), w=1.5)
    row = _row(sc, SQUARE, p)
    assert row is not None and row["pid"] == ID_RIM
    _close(row, _expected(sc, p, 0.0, 1.0, delta, (0.0, 0.0), (0.013, H)))


def test_a_disc_crossing_a_vertex_between_collinear_segments_feels_no_jump(sc):
    # within a few ulps of the vertex the distances to the two segments tie in floating
    # point and the vertex (the lower segment's end) is taken: the normal then leans by
    # |x| / distance, 5e-13 at x = 1e-15; no jump
    r, delta = 0.002, 1e-4
    for x in (*np.linspace(-1e-6, 1e-6, 41), -1e-15, 0.0, 1e-15, 0.004):
        p = _disc(sc, x, H + r - delta, r, v=(0.03, -0.02), w=1.5)
        one = _row(sc, SQUARE, p)
        split = _row(sc, SPLIT, p)
        _close(split, (one["bx"], one["by"], one["tq"], one["wt"]), rel=1e-9)


def test_a_disc_at_a_convex_vertex_against_hand_values(sc):
    r, a, b = 0.002, 0.0009, 0.0012  # the centre off the corner (H, H); distance 0.0015
    p = _disc(sc, H + a, H + b, r, v=(0.01, 0.02), w=-0.7)
    X, Y, VX, VY, WZ = 0.0, 0.0, 0.05, -0.01, -1.0
    row = _row(sc, SQUARE, p, (X, Y, VX, VY, WZ, 0.0))
    dist = 0.0015
    vq = (VX - WZ * H, VY + WZ * H)  # V + W x (q - C), q = (H, H)
    _close(row, _expected(sc, p, a / dist, b / dist, r - dist, vq, (H, H), wz=WZ), rel=1e-9)


def test_a_rotated_and_moved_wheel_gives_the_rotated_contact(sc):
    r, delta, theta = 0.002, 1e-4, 0.3
    X, Y = 0.2, 0.15
    c, s = det_cos(theta), det_sin(theta)
    lx, ly = 0.01, H + r - delta  # the centre in the body frame
    p = _disc(sc, X + c * lx - s * ly, Y + s * lx + c * ly, r)
    row = _row(sc, SQUARE, p, (X, Y, 0.0, 0.0, 0.0, theta))
    q = (c * 0.01 - s * H, s * 0.01 + c * H)
    _close(row, _expected(sc, p, -s, c, delta, (0.0, 0.0), q), rel=1e-9)


def test_a_centre_inside_the_outline_is_pushed_out(sc):
    r, depth = 0.002, 0.0005
    p = _disc(sc, 0.01, H - depth, r)
    row = _row(sc, SQUARE, p)
    _close(row, _expected(sc, p, 0.0, 1.0, r + depth, (0.0, 0.0), (0.01, H)), rel=1e-9)
    assert row["by"] > 0.0
    assert _row(sc, SQUARE, _disc(sc, 0.01, H + r + 1e-6, r)) is None  # apart: no row


def test_nearest_point_ties_go_to_the_lower_segment():
    ol = wheel_outline(SQUARE, 0.01)
    k, qx, qy, dist, inside = nearest_point(ol, H + 0.001, H + 0.001, 0.01)
    assert (k, qx, qy, inside) == (1, H, H, False)  # segments 1 and 2 end at (H, H)
    k, _, _, _, inside = nearest_point(ol, 0.0, H - 0.001, 0.01)
    assert (k, inside) == (2, True)


def test_the_builtin_outline_is_within_the_deviation_and_valid():
    pts = builtin_outline(0.1, 18, 0.11, 0.002)
    check_outline(pts, 0.11)
    rho = np.hypot(pts[:, 0], pts[:, 1])
    assert rho.max() <= 0.11 + 1e-15
    # the rim's chords leave the circle by less than 0.1 mm
    rim = np.isclose(rho, 0.1, rtol=0, atol=1e-12)
    a = np.arctan2(pts[rim, 1], pts[rim, 0])
    gaps = np.diff(np.sort(a))
    assert 0.1 * (1 - np.cos(0.5 * gaps.max())) < 1e-4
    assert len(builtin_outline(0.1, 0, 0.1, 0.002)) >= 3


# ------------------------------------------------------------------ refusals
BAD = {
    "two points": ("[[0.0, -0.1], [0.1, 0.1]]", "at least 3"),
    "clockwise": ("[[0.0, 0.05], [0.05, -0.05], [-0.05, -0.05]]", "clockwise"),
    "crossing": ("[[-0.05, -0.05], [0.05, 0.05], [0.05, -0.05], [-0.05, 0.05]]", "cross"),
    "not around the axle": ("[[0.01, 0.01], [0.05, 0.01], [0.05, 0.05]]", "enclose"),
    "beyond the tips": ("[[-0.05, -0.05], [0.2, -0.05], [0.0, 0.05]]", "beyond"),
    "not a point": ("[[0.0, -0.1], [0.1], [0.0, 0.1]]", "[x, y]"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_a_bad_inline_outline_is_refused(case, tmp_path):
    value, needle = BAD[case]
    cp = cli_in_process("run", "quick", "--set", f"wheel.outline={value}", "--steps", "1", "--out", tmp_path / "o")
    one_line_error(cp, "wheel.outline", needle)


@pytest.mark.parametrize(
    "text,needle",
    [("", "at least 3"), ("0 0.1\n0.1 nan\n-0.1 0\n", "finite"), ("0 0.1 3\n", "x y"), ("a b\n", "cannot read")],
)
def test_a_bad_outline_file_is_refused(text, needle, tmp_path):
    (tmp_path / "w.xy").write_text(text)
    (tmp_path / "s.toml").write_text('base = "quick"\n[wheel]\noutline = "w.xy"\n')
    cp = cli_in_process("run", tmp_path / "s.toml", "--steps", "1", "--out", tmp_path / "o")
    one_line_error(cp, "wheel.outline", needle)
    cp = cli_in_process("run", "quick", "--set", "wheel.outline=nowhere.xy", "--steps", "1", "--out", tmp_path / "p")
    one_line_error(cp, "wheel.outline", "no such file")


def test_an_outline_of_too_many_points_is_refused(tmp_path):
    a = np.linspace(0.0, 2.0 * np.pi, 100_001, endpoint=False)
    np.savetxt(tmp_path / "w.xy", 0.1 * np.column_stack([np.cos(a), np.sin(a)]))
    with pytest.raises(ScenarioError, match="100001 points; an outline has at most 100000"):
        load_scenario("quick", [f"wheel.outline={tmp_path / 'w.xy'}"])


def test_a_3d_scenario_with_an_outline_is_refused():
    with pytest.raises(ScenarioError, match="physics.dim = 2"):
        load_scenario("quick-3d", ["wheel.outline=[[0.0, -0.1], [0.1, 0.1], [-0.1, 0.1]]"])


def test_an_outline_file_is_taken_from_the_scenario_files_directory(tmp_path):
    np.savetxt(tmp_path / "w.xy", SQUARE)
    (tmp_path / "s.toml").write_text('base = "quick"\n[wheel]\noutline = "w.xy"\n')
    sc = load_scenario(tmp_path / "s.toml")
    assert sc.wheel.outline == str(tmp_path / "w.xy")
    assert Model.from_scenario(sc).outline.vert.shape == (4, 2)
    assert Model.from_scenario(load_scenario("quick")).outline is None


# ------------------------------------------------------------------ whole runs
STEPS, EVERY = 3000, 1000
# quick's steady means move by about 2 % between runs that differ by nothing that matters
# (the built-in wheel dropped from 0.1 um higher: torque -2.3 %, sinkage +2.1 %, slip +4.9 %),
# so the outline's copy is held to a little more than that
TOLERANCE = 0.03


@pytest.mark.slow
def test_every_mode_gives_the_same_bits_with_an_outline_wheel(tmp_path):
    np.savetxt(tmp_path / "w.xy", builtin_outline(0.1, 18, 0.11, 0.002), fmt="%.17g")
    over = [
        f"wheel.outline={tmp_path / 'w.xy'}",
        "wheel.drop_gap=0.0",
        "wheel.settle_time=0.01",
        "output.series_interval=0.001",
    ]
    kw = dict(overrides=over, steps=STEPS)
    ref = ooc_dem.run("quick", tmp_path / "mono", **kw)
    assert ref.summary["vertical_force"]["whole_travel"]["value"] > 0.0
    runs = {
        "ddm-3": ooc_dem.run("quick", tmp_path / "ddm", mode="ddm", domains=3, **kw),
        "ooc-3-10": ooc_dem.run(
            "quick", tmp_path / "ooc", mode="ooc", domains=3, block=10, checkpoint_every=EVERY, **kw
        ),
    }
    runs["killed-resumed"] = killed_and_resumed("quick", over, STEPS, EVERY, tmp_path / "killed")
    for name, res in runs.items():
        assert_same_state(ref, res, name)
        assert np.array_equal(res.series["torque"], ref.series["torque"]), name


@pytest.mark.slow
def test_the_builtin_wheel_as_an_outline_pulls_as_the_builtin_wheel(tmp_path):
    """The quick scenario whole (2.2 s, about a minute a run) with the built-in wheel and
    with builtin_outline's copy of it: the steady drawbar pull, torque and sinkage agree
    within TOLERANCE (the copy's rim is a polygon within 0.1 mm of the circle and a disc
    touching a lug's side and the rim at once has one contact there, not two)."""
    np.savetxt(tmp_path / "w.xy", builtin_outline(0.1, 18, 0.11, 0.002), fmt="%.17g")
    over = ["output.snapshot_interval=0.0"]
    ref = ooc_dem.run("quick", tmp_path / "builtin", overrides=over).summary
    got = ooc_dem.run("quick", tmp_path / "outline", overrides=[*over, f"wheel.outline={tmp_path / 'w.xy'}"]).summary
    for q in ("net_traction", "torque", "sinkage"):
        a, b = ref[q]["steady"]["value"], got[q]["steady"]["value"]
        assert abs(b - a) <= TOLERANCE * abs(a), (q, a, b)
