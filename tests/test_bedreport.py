"""The bed's report (model/bedreport.py) against packings with analytic answers; a bed drawn
from a sieve curve reports the grading asked for; the report in bed.json, summary.json and
the printed output of `run`, in memory and streamed out of core."""

import json
import math

import numpy as np
import pytest

from ooc_dem.model.bedreport import BedMeasure, bed_report, volume_below
from ooc_dem.model.grading import characteristic_diameters, draw_radii, grading_of_soil
from ooc_dem.model.scenario import load_scenario
from ooc_dem.model.state import Particles
from ooc_dem.physics.layout import ID_WALL_BOTTOM
from support.cli import run_cli

R = 0.002
DENSITY = 2650.0
THICKNESS = 0.1


def _lattice(dim: int, across: int, rows: int) -> tuple[Particles, int]:
    """Equal grains of radius R on a square (2D) or simple cubic (3D) lattice of pitch 2R
    filling a box of ``across`` grains along x (and z) and ``rows`` layers on the floor, each
    grain's history holding its lattice neighbours and the floor (bottom layer); returns the
    grains and the number of grain-grain contacts."""
    axes = [np.arange(across), np.arange(rows)] + ([np.arange(across)] if dim == 3 else [])
    idx = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, dim)
    p = Particles.new(R + 2 * R * idx, np.full(len(idx), R), DENSITY, THICKNESS, hist_cap=8)
    key = {tuple(c): i for i, c in enumerate(idx)}
    pairs = 0
    for i, c in enumerate(idx):
        partners = [ID_WALL_BOTTOM] if c[1] == 0 else []
        for ax in range(dim):
            for step in (-1, 1):
                n = list(c)
                n[ax] += step
                if tuple(n) in key:
                    partners.append(key[tuple(n)])
                    pairs += step == 1
        p.hist_n[i] = len(partners)
        p.hist_id[i, : len(partners)] = sorted(partners)
    return p, pairs


@pytest.mark.parametrize("dim,solid", [(2, math.pi / 4), (3, math.pi / 6)])
def test_a_lattice_reports_its_analytic_porosity_density_and_coordination(dim, solid):
    across, rows = 12, 7
    p, pairs = _lattice(dim, across, rows)
    length = width = 2 * R * across
    rep = bed_report(p, length, R, THICKNESS, width)
    # measured up to the middle of the top layer: the lattice's own solid fraction
    assert rep["measured_to_height_m"] == pytest.approx(R * (2 * rows - 1), rel=1e-12)
    assert rep["porosity"] == pytest.approx(1 - solid, rel=1e-12)
    assert rep["bulk_density_kg_m3"] == pytest.approx(DENSITY * solid, rel=1e-12)
    assert rep["coordination_number"] == pytest.approx(2 * pairs / len(p), rel=1e-15)
    assert rep["wall_contacts"] == across ** (dim - 1)
    assert rep["grading"] == pytest.approx({"d10_m": 2 * R, "d50_m": 2 * R, "d60_m": 2 * R, "cu": 1.0})


def test_a_bed_measured_in_parts_is_the_bed_measured_whole():
    p, _ = _lattice(2, 12, 7)
    whole = bed_report(p, 24 * R, R, THICKNESS, 0.0)
    left = p.pos[:, 0] < 12 * R
    m = BedMeasure(2, THICKNESS, 0.0)
    plane = whole["measured_to_height_m"]
    m.add(p.take(np.flatnonzero(left)), plane, 12 * R)
    m.add(p.take(np.flatnonzero(~left)), plane, 12 * R)
    parts = m.report()
    for key in ("porosity", "bulk_density_kg_m3", "coordination_number", "measured_to_height_m"):
        assert parts[key] == pytest.approx(whole[key], rel=1e-12), key
    assert parts["wall_contacts"] == whole["wall_contacts"] and parts["grading"] == whole["grading"]


@pytest.mark.parametrize("dim", [2, 3])
def test_the_part_of_a_grain_below_a_plane(dim):
    r = np.array([1.0, 1.0, 1.0, 1.0, 2.0])
    y = np.array([0.0, 0.0, 0.0, 0.0, 0.0])
    full = math.pi if dim == 2 else 4 * math.pi / 3
    for h, frac in ((-1.0, 0.0), (0.0, 0.5), (1.0, 1.0), (5.0, 1.0)):
        assert volume_below(y[:1], r[:1], h, dim)[0] == pytest.approx(frac * full, abs=1e-15)
    # a quarter of the radius above the centre, against the segment / cap formulas' numbers
    t = 0.25
    want = (math.acos(-t) + t * math.sqrt(1 - t * t)) if dim == 2 else math.pi * (1 + t) ** 2 * (2 - t) / 3
    assert volume_below(y[:1], r[:1], t, dim)[0] == pytest.approx(want, rel=1e-14)


# ---------------------------------------------------------------- the scenario's grading


# a bare 2D bed of 400 discs between the 3 and 6 mm sieves: d10, d50 and d60 by mass (discs:
# mass as d^2) read off the log-linear curve are 3.302, 4.472 and 4.729 mm
SIZES, PASSING = (3e-3, 4e-3, 5e-3, 6e-3), (0, 30, 70, 100)
SIEVE_BED = [
    "--set",
    "soil.n=400",
    "--set",
    "bed.tile=0",
    "--set",
    "bin.length=0.08",
    "--set",
    "soil.r_min=0.0015",
    "--set",
    "soil.r_max=0.003",
    "--set",
    'soil.grading.kind="sieve"',
    "--set",
    f"soil.grading.sizes={list(SIZES)}",
    "--set",
    f"soil.grading.passing={list(PASSING)}",
]
REPORT_KEYS = {
    "surface_height_m",
    "measured_to_height_m",
    "bulk_density_kg_m3",
    "porosity",
    "coordination_number",
    "wall_contacts",
    "grading",
}


def _curve_diameter(percent):
    return float(np.exp(np.interp(percent, PASSING, np.log(SIZES))))


@pytest.fixture(scope="module")
def sieve_bed(tmp_path_factory):
    root = tmp_path_factory.mktemp("sieve")
    cp = run_cli(
        "prepare",
        "bed",
        *SIEVE_BED,
        "--out",
        root / "bed",
        "--no-progress",
        check=True,
        env={"OOC_DEM_CACHE": str(root / "cache")},
    )
    return root, cp


def test_a_sieve_bed_gives_back_its_grading(sieve_bed):
    root, cp = sieve_bed
    info = json.loads((root / "bed" / "bed.json").read_text())
    assert json.loads(cp.stdout.strip().splitlines()[-1]) == info
    assert REPORT_KEYS <= set(info) and info["n_discs"] == 400
    r = np.load(root / "bed" / "bed.npz")["r"]
    # the bed's radii are the generator's draw from the curve, with the mass of discs (d^2)
    sc = load_scenario("bed", [s for s in SIEVE_BED if s != "--set"])
    want = draw_radii(grading_of_soil(sc.soil), 400, np.random.default_rng(sc.soil.seed), 2)
    assert np.array_equal(np.sort(r), np.sort(want))
    assert r.min() >= 1.5e-3 and r.max() <= 3e-3
    g, c = info["grading"], characteristic_diameters(r, 2)
    assert g == {"d10_m": c["d10"], "d50_m": c["d50"], "d60_m": c["d60"], "cu": c["cu"]}
    # over 400 seeds the d10, d50 and d60 of 400 discs drawn from this curve scattered by
    # 0.037, 0.065 and 0.070 mm (their means within 0.005 mm of the curve's): 4 of those is
    # the tolerance; a bed drawn uniform in [r_min, r_max] has d50 = 4.96 mm, one drawn by
    # number as if number were mass 4.85 mm
    for key, percent, sd in (("d10_m", 10, 0.037e-3), ("d50_m", 50, 0.065e-3), ("d60_m", 60, 0.070e-3)):
        assert abs(g[key] - _curve_diameter(percent)) < 4 * sd, (key, g[key], _curve_diameter(percent))
    # a settled bed of frictional discs: porosity of a loose 2D packing, about 3 contacts a disc
    assert 0.1 < info["porosity"] < 0.35 and 2.0 < info["coordination_number"] < 4.5
    assert info["bulk_density_kg_m3"] == pytest.approx(2650.0 * (1 - info["porosity"]), rel=1e-9)
    assert info["measured_to_height_m"] < info["surface_height_m"]


def test_a_run_reports_its_bed_in_summary_and_output_and_keeps_it_on_resume(sieve_bed, tmp_path):
    root, _ = sieve_bed
    out = tmp_path / "run"
    args = ["bed", *SIEVE_BED, "--bed", root / "bed", "--no-progress", "--no-figures"]
    cp = run_cli("run", *args, "--out", out, "--steps", "20", "--checkpoint-every", "10", check=True)
    bed = json.loads((root / "bed" / "bed.json").read_text())
    assert json.loads((out / "bed.json").read_text()) == bed  # the same bed, the same report
    summary = json.loads((out / "summary.json").read_text())
    assert summary["bed"] == bed
    line = next(ln for ln in cp.stdout.splitlines() if ln.startswith("bed: "))
    assert f"porosity {bed['porosity']:.3f}" in line and f"Cu {bed['grading']['cu']:.2f}" in line
    cp = run_cli("resume", out, "--steps", "30", "--no-progress", "--no-figures", check=True)
    assert json.loads((out / "summary.json").read_text())["bed"] == bed and "bed: bulk density" in cp.stdout


def test_a_streamed_bed_reports_itself_as_the_bed_in_memory(tmp_path):
    """A tiled bare bed run out of core is measured part by part as it streams into the store:
    its report is that of the same bed in memory but for the measuring planes, each part's
    own (the parts' tops, not the bed's, as its surface height)."""
    env = {"OOC_DEM_CACHE": str(tmp_path / "cache")}
    common = ["bed-2330", "--steps", "2", "--no-progress", "--no-figures"]
    run_cli("run", *common, "--out", tmp_path / "mem", env=env, check=True)
    run_cli("run", *common, "--mode", "ooc", "--out", tmp_path / "ooc", env=env, check=True)
    mem = json.loads((tmp_path / "mem" / "summary.json").read_text())["bed"]
    ooc = json.loads((tmp_path / "ooc" / "summary.json").read_text())["bed"]
    assert set(mem) == set(ooc) and ooc["n_discs"] == 2330
    assert ooc["coordination_number"] == mem["coordination_number"]
    assert ooc["wall_contacts"] == mem["wall_contacts"] and ooc["grading"] == mem["grading"]
    for key in ("porosity", "bulk_density_kg_m3", "measured_to_height_m"):
        assert ooc[key] == pytest.approx(mem[key], rel=0.01), key
