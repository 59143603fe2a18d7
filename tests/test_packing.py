"""Pouring friction (bed.fill_friction): the packing procedure a measured bulk density is
reached with. Grains that slide past each other while they fall pack denser."""

from __future__ import annotations

import numba
import pytest

from ooc_dem.app.bed import initial_fill, pour_scenario, settle
from ooc_dem.model.bedreport import bed_report
from ooc_dem.model.scenario import load_scenario

SMALL = ["soil.n=600", "bin.length=0.12", "wheel.enabled=false"]


@pytest.fixture(autouse=True, scope="module")
def _one_numba_thread():
    old = numba.get_num_threads()
    numba.set_num_threads(1)
    yield
    numba.set_num_threads(old)


def _porosity(sc):
    bed, _ = settle(sc, initial_fill(sc))
    return bed_report(bed, sc.bin.length, sc.soil.r_max, sc.physics.thickness, sc.bin.width)["porosity"]


def test_frictionless_pouring_packs_denser():
    """600 discs poured with the soil's friction (0.5) and frictionless: the frictionless
    bed's porosity is lower by more than 0.01 (measured: see the assertion message)."""
    rough = load_scenario("quick", SMALL)
    smooth = load_scenario("quick", [*SMALL, "bed.fill_friction=0.0"])
    assert pour_scenario(smooth).contact.soil_soil.friction == 0.0
    assert pour_scenario(rough) is rough
    n_rough, n_smooth = _porosity(rough), _porosity(smooth)
    assert n_smooth < n_rough - 0.01, (n_rough, n_smooth)


def test_the_default_changes_no_hash_and_a_fill_friction_changes_the_bed_key():
    sc = load_scenario("quick")
    assert load_scenario("quick", ["bed.fill_friction=-1.0"]).hash() == sc.hash()
    other = load_scenario("quick", ["bed.fill_friction=0.1"])
    assert other.bed_hash() != sc.bed_hash()
    # the run's own contact law is untouched: only the pouring uses the fill friction
    assert other.contact.soil_soil.friction == sc.contact.soil_soil.friction
