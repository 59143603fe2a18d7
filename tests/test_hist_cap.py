"""The contact-history capacity is a model value (issue 14): a run with a smaller capacity
holds less RAM per disc and gives the same bits (the canonical hash pads the history to a
content-defined width, so the capacity never enters it); a state that does not fit is refused."""
import dataclasses

import numpy as np
import pytest

from ooc_dem.bed import settled_bed
from ooc_dem.checkpoint import particles_to_record, record_to_particles
from ooc_dem.engine.run import place_wheel
from ooc_dem.engine.stepper import DomainStepper, EngineError, Model
from ooc_dem.scenario import load_scenario
from ooc_dem.state import HIST_CAP, bytes_per_disc, fields, state_hash

SETS = ["wheel.settle_time=0.0", "wheel.drop_gap=0.0", "wheel.control=slip", "wheel.slip=0.2"]


def test_fields_come_from_dim_and_capacity():
    f = fields(2, 12)
    assert f["pos"][1] == (2,) and f["spin"][1] == (1,) and f["hist_s"][1] == (12, 1)
    f3 = fields(3, 8)
    assert f3["pos"][1] == (3,) and f3["spin"][1] == (3,) and f3["hist_s"][1] == (8, 3)
    assert bytes_per_disc(2, 12) == 368 and bytes_per_disc(2, 6) == 368 - 6 * 24


def test_a_smaller_capacity_gives_the_same_bits():
    sc = load_scenario("quick", SETS)
    bed = settled_bed(sc)
    ws = place_wheel(sc, bed)
    hashes = []
    for cap in (HIST_CAP, 8):
        model = dataclasses.replace(Model.from_scenario(sc), hist_cap=cap)
        st = DomainStepper(bed.with_hist_cap(cap), model, ws)
        st.advance(0, 400)
        assert st.p.hist_id.shape == (len(bed), cap)
        hashes.append(state_hash(st.p, st.ws, 400))
        # the store record does not depend on the capacity either
        rec = particles_to_record(st.p)
        assert state_hash(record_to_particles(rec, cap), st.ws, 400) == hashes[-1]
    assert hashes[0] == hashes[1]


def test_a_state_beyond_the_capacity_is_refused():
    sc = load_scenario("quick", SETS)
    bed = settled_bed(sc)
    with pytest.raises(ValueError, match="more than 2"):
        bed.with_hist_cap(2)
    with pytest.raises(EngineError, match="capacity"):
        DomainStepper(bed.with_hist_cap(8), Model.from_scenario(sc))
    assert int(np.max(bed.hist_n)) <= HIST_CAP
