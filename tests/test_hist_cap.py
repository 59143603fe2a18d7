"""The contact-history capacity is a model value: a run with a smaller capacity
holds less RAM per disc and gives the same bits (the canonical hash pads the history to a
content-defined width, so the capacity never enters it); a state that does not fit is refused."""

import dataclasses

import numpy as np
import pytest

from ooc_dem.app.bed import settled_bed
from ooc_dem.model.checkpoint import particles_to_record, record_to_particles
from ooc_dem.app.run_setup import place_wheel
from ooc_dem.engine.stepper import DomainStepper, EngineError, Model
from ooc_dem.model.scenario import load_scenario
from ooc_dem.model.state import HIST_CAP, HIST_CAP_BY_DIM, bytes_per_disc, fields, state_hash

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
    for cap in (12, HIST_CAP, 6):
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
        DomainStepper(bed.with_hist_cap(12), Model.from_scenario(sc))
    assert int(np.max(bed.hist_n)) <= HIST_CAP


def test_the_capacity_comes_from_the_dimension_or_the_scenario():
    assert HIST_CAP_BY_DIM == {2: 8, 3: 12}
    sc = load_scenario("quick")
    assert sc.hist_cap == 8 and Model.from_scenario(sc).hist_cap == 8
    assert load_scenario("bed3d").hist_cap == 12
    sc10 = load_scenario("quick", ["physics.history_capacity=10"])
    assert Model.from_scenario(sc10).hist_cap == 10
    assert settled_bed(sc10).hist_cap == 10 and settled_bed(sc).hist_cap == 8
    # the capacity is no part of the scenario's or the bed's hash when left at its default
    assert load_scenario("quick", ["physics.history_capacity=0"]).hash() == sc.hash()


def test_a_run_resumes_with_the_capacity_it_was_written_with(tmp_path):
    """A store whose meta records a larger capacity (2D runs were written with 12) resumes
    with it, to the same bits as a run that never stopped."""
    from ooc_dem.app.run import Simulation, RunOptions, resume_simulation
    from ooc_dem.storage import open_store

    sc = load_scenario("quick", SETS)
    bed = settled_bed(sc)
    out = tmp_path / "run"
    sim = Simulation(sc, out, RunOptions(steps=300, progress=False, figures=False))
    sim.model.hist_cap = 12  # as a run of the earlier default wrote it
    sim.start(bed.with_hist_cap(12))
    sim.run()
    sim.close()
    ref = Simulation(sc, tmp_path / "ref", RunOptions(steps=600, progress=False, figures=False))
    ref.start(bed.take(np.arange(len(bed))))
    ref.run()
    want = ref.state_hash()
    ref.close()
    with open_store(out, repair=False) as st:
        assert st.meta["hist_cap"] == 12
    sim = resume_simulation(out, steps=600, progress=False, figures=False)
    assert sim.model.hist_cap == 12
    sim.run()
    assert sim.state_hash() == want
    sim.close()
