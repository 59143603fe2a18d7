"""The bits of the pinned 3D Hertz case (quick-3d), stage by stage (tools/trace_bits.py),
against the fixture recorded with this repository: when the pinned Hertz hashes of
test_kernel_bits.py differ on a machine, this test names the first stage that differs (a
set-up constant, the generated bed, a settling or run step) and its arrays or fields, with
the machine's facts and the path of the machine's own trace (docs/reference/bits.md).

- the trace of this machine is the fixture's, stage by stage, and ends at the state hash
  pinned for `ooc-dem run quick-3d --steps 3000`;
- the set-up values are correctly rounded: the contact table's constants made with ln
  (exactmath) and sqrt(5/6), every sphere's mass and inertia (exact operations in the
  model's order, no pow); the lugs' cos and sin (detmath) are counted only;
- a doctored trace is reported at its first differing stage with the entries that differ.
"""

from __future__ import annotations

import copy
import json
import subprocess
import sys
from pathlib import Path

import pytest

import trace_bits
from test_kernel_bits import QUICK3D_3000

FIXTURE = Path(__file__).parent / "data" / "trace_hertz_quick3d.json"
TOOL = Path(trace_bits.__file__)


@pytest.fixture(scope="module")
def this_trace(tmp_path_factory):
    """This machine's trace, kept in the test's tmp dir (the file to send on a mismatch)."""
    t = trace_bits.trace()
    path = tmp_path_factory.mktemp("trace") / "trace_hertz_quick3d.json"
    path.write_text(json.dumps(t, indent=1) + "\n")
    print(f"this machine's trace: {path}")
    return t, path


def test_trace_is_the_fixtures(this_trace):
    got, path = this_trace
    want = json.loads(FIXTURE.read_text())
    assert want["state_hash"] == QUICK3D_3000  # the fixture is a trace of the pinned run
    problem = trace_bits.first_difference(want, got)
    if problem is None:
        return
    cache = got["cached_bed"]
    if not cache["present"]:
        cached = "absent"
    else:
        cached = cache.get("error") or (f"differs in {', '.join(cache['differ'])}" if cache["differ"] else "equal")
    pytest.fail(
        f"the 3D Hertz bits differ from {FIXTURE.name}'s: {problem}\n"
        f"  this machine:    {trace_bits.machine_line(got['machine'])}\n"
        f"    not correctly rounded: {trace_bits.rounding_line(got)}\n"
        f"  fixture machine: {trace_bits.machine_line(want['machine'])}\n"
        f"    not correctly rounded: {trace_bits.rounding_line(want)}\n"
        f"  this machine's cached quick-3d bed against the one settled here: {cached} ({cache['path']})\n"
        f"  this machine's trace: {path} (send it; `python tools/trace_bits.py --compare FILE` "
        f"compares two machines' traces)",
        pytrace=False,
    )


def test_setup_values_are_correctly_rounded(this_trace):
    """The contact table's constants made with ln (exactmath: decimal, no libm) and sqrt(5/6)
    are the correctly rounded values; every mass and inertia of the pinned fills is its
    formula's value with each operation correctly rounded (r * r * r, not a SIMD pow)."""
    got, _ = this_trace
    checked = [c for c in got["correctly_rounded"] if c["kind"] in ("constant", "array")]
    assert {c["name"] for c in checked} >= {"ln(0.3)", "sqrt(5/6)"}
    assert sum(1 for c in checked if c["kind"] == "array") == 2  # quick-3d and bed3d-20000's tile
    wrong = [
        f"{c['name']} = {c['value']} (correct: {c['correct']}) in {c['where']}"
        if c["kind"] == "constant"
        else f"{c['name']}: {c['wrong']} wrong in {c['where']}"
        for c in checked
        if not c["ok"]
    ]
    assert not wrong, "not correctly rounded: " + "; ".join(wrong)


def test_first_difference_names_the_stage_and_entries(this_trace):
    got, _ = this_trace
    assert trace_bits.first_difference(got, got) is None
    stages = [s["stage"] for s in got["stages"]]
    k = stages.index("run step 7")
    bad = copy.deepcopy(got)
    bad["stages"][k]["entries"]["pos[y]"] = "0" * 32
    bad["stages"][k]["entries"]["wheel.theta"] = "0x1.0000000000000p+0"
    bad["stages"][k + 3]["entries"]["vel[x]"] = "0" * 32
    msg = trace_bits.first_difference(got, bad)
    assert msg is not None and "'run step 7'" in msg and "2 entries differ" in msg, msg
    assert "pos[y]" in msg and "wheel.theta (0x1.0000000000000p+0 here" in msg and "1 differ" in msg, msg
    k = stages.index("constants quick-3d")
    bad = copy.deepcopy(got)
    bad["stages"][k]["entries"]["cp[soil,wheel].beta"] = "-0x1.0000000000000p-2"
    msg = trace_bits.first_difference(got, bad)
    assert msg is not None and "'constants quick-3d'" in msg and "cp[soil,wheel].beta (-0x1.0000000000000p-2" in msg, (
        msg
    )


def test_tool_refuses_an_unreadable_trace(tmp_path):
    cp = subprocess.run(
        [sys.executable, str(TOOL), "--compare", str(tmp_path / "none.json")], capture_output=True, text=True
    )
    assert cp.returncode == 2 and len(cp.stderr.strip().splitlines()) == 1 and "none.json" in cp.stderr, cp.stderr
