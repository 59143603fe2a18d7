"""What `check`, `run` and `sweep` warn about before a run: a scenario that passes every
check but will not measure what its user wants (a bed too shallow for the wheel, side walls
inside the soil the wheel moves, lugs a grain high, a steady window past the end of the
travel or shorter than three lug passages, an out-of-core run writing the whole bed every
step, a file whose unset keys take the defaults of the other dimension). Warnings, not errors: each is one line and the run may go ahead.

The estimates and the rules they are checked against are stated in each message and here.
"""

from __future__ import annotations

import math
from typing import Any

from ..engine.modes import MODES
from ..engine.sweep import auto_block
from ..model.grading import grading_of_soil, mean_power
from ..model.scenario import Scenario
from ..model.schema import Wheel, show
from .plan import RunPlan
from .run_stats import MIN_BLOCKS, SMOOTH_BLOCK_ANGLE, block_period, planned_blocks

# solid fraction of a poured, settled bed: 2D discs ~0.80 (paper2008's 1165-disc tile is
# 0.18 m deep over 0.1 m: 0.82), 3D spheres ~0.60 (paper2008-3d's 10000 spheres make ~7 cm:
# 0.63); the estimate of the bed's depth from soil.n and the bin
SOLID_FRACTION = {2: 0.80, 3: 0.60}
# the wheel's expected sinkage as a fraction of its radius: paper2008's rig (R = 0.1 m) sinks
# 5-12 mm standing and 15-35 mm while travelling (docs/reference/paper2008.md), 11-16 mm
# standing in 3D (README); 0.3 R is the upper part of the travelling range
SINKAGE_PER_RADIUS = 0.3
# grain diameters across a lug's height below which the lugs barely engage the soil as
# grains (paper2008's 2D rig has 10 mm lugs over 4 mm discs: 2.5)
MIN_GRAINS_PER_LUG = 2.5
# side clearance (nearer side wall to the wheel's side face) below which the walls stand in
# the wheel's zone of influence: tools/influence_zone.py measured the 2 % edge 8.8-12.1 cm
# off the face of paper2008-3d's 0.1 m wide wheel (README), i.e. 1.25 wheel widths
MIN_SIDE_CLEARANCE_PER_WIDTH = 1.25
# keys a 3D file must state (the defaults are paper2008's 2D bin and discs)
DIMENSIONED_KEYS = (
    ("soil", "n"),
    ("soil", "r_min"),
    ("soil", "r_max"),
    ("bin", "length"),
    ("bin", "width"),
    ("bin", "height"),
)
KEYS_3D = (("bin", "width"), ("bed", "tiles_across"), ("wheel", "z0"), ("physics", "impact_speed"))


def bed_depth(sc: Scenario) -> float:
    """Estimated depth of the settled bed, m: the grains' volume (2D: area) over the bin's
    floor, at the solid fraction SOLID_FRACTION of a poured bed."""
    g = grading_of_soil(sc.soil)
    if sc.dim == 3:
        solid = sc.soil.n * (4.0 / 3.0) * math.pi * mean_power(g, 3, 3)
        floor = sc.bin.length * sc.bin.width
    else:
        solid = sc.soil.n * math.pi * mean_power(g, 2, 2)
        floor = sc.bin.length
    return solid / (SOLID_FRACTION[sc.dim] * floor)


def scenario_warnings(
    sc: Scenario, plan: RunPlan | None = None, tables: dict[str, Any] | None = None, base: str | None = None
) -> list[str]:
    """One line per thing worth a second look before running ``sc`` (with its plan, and the
    raw tables of the file it came from: ``scenario.scenario_tables``)."""
    out: list[str] = []
    if sc.wheel.enabled:
        out += _wheel_warnings(sc)
    if plan is not None:
        out += _block_warnings(sc, plan)
    if tables is not None and base is None:
        out += _dimension_warnings(sc, tables)
    return out


def _wheel_warnings(sc: Scenario) -> list[str]:
    out = []
    w, s = sc.wheel, sc.soil
    grain = "spheres" if sc.dim == 3 else "discs"
    lug = w.lug_tip_radius - w.radius
    depth = bed_depth(sc)
    sinkage = SINKAGE_PER_RADIUS * w.radius
    if depth < sinkage + lug:
        need = math.ceil(s.n * (sinkage + lug) / depth)
        out.append(
            f"bed about {depth * 1e3:.1f} mm deep (soil.n = {s.n} {grain} at a solid fraction "
            f"{SOLID_FRACTION[sc.dim]:g}), less than the wheel's expected sinkage plus its lugs: "
            f"{sinkage * 1e3:.0f} mm ({SINKAGE_PER_RADIUS:g} wheel.radius, paper2008's travelling "
            f"sinkage) + {lug * 1e3:.0f} mm of lug; the wheel will reach the floor: soil.n >= {need} "
            f"for that depth"
        )
    d_mean = 2.0 * mean_power(grading_of_soil(s), 1, sc.dim)
    # (a relative margin: paper2008's 2.5 is 2.5 to within rounding and is not warned of)
    if w.n_lugs > 0 and lug < MIN_GRAINS_PER_LUG * d_mean * (1.0 - 1e-9):
        out.append(
            f"the lugs are {lug * 1e3:.1f} mm high (wheel.lug_tip_radius - wheel.radius), {lug / d_mean:.1f} "
            f"mean grain diameters ({d_mean * 1e3:.1f} mm): fewer than about 3 grains across a lug's "
            f"height and the lugs barely bite as lugs (paper2008 has {MIN_GRAINS_PER_LUG:g}); "
            f"smaller grains or taller lugs"
        )
    if sc.dim == 3:
        z0 = w.z0 if w.z0 > 0.0 else 0.5 * sc.bin.width
        clearance = min(z0 - 0.5 * w.width, sc.bin.width - z0 - 0.5 * w.width)
        want = MIN_SIDE_CLEARANCE_PER_WIDTH * w.width
        if clearance < want:
            out.append(
                f"side walls {clearance * 1e3:.0f} mm from the wheel's side face: inside its zone of "
                f"influence (the soil moves >= 2 % of its displacement under the wheel out to about "
                f"{MIN_SIDE_CLEARANCE_PER_WIDTH:g} wheel widths off the face, tools/influence_zone.py), "
                f"so the walls hold soil the wheel moves and bias its traction and sinkage; "
                f"bin.width >= {w.width + 2.0 * want:.3g} m with the wheel at mid-width"
            )
    unused = _unused_control_keys(sc)
    if unused:
        shown = ", ".join(f"wheel.{k} = {show(getattr(w, k))}" for k in unused)
        out.append(
            f"{shown}: {'has' if len(unused) == 1 else 'have'} no effect with wheel.control = "
            f"{show(w.control)} (torque, torque_ramp, carriage: control = torque; inertia: torque, "
            f"towed; speed: towed, or torque with carriage = speed)"
        )
    # the scenario's own travel (a run cut short by --steps or --duration is the user's choice)
    travel = w.travel_time
    o = sc.output
    if travel < o.steady_end:
        covered = max(0.0, travel - o.steady_start)
        what = "the window is empty" if covered == 0.0 else f"the steady means cover only {covered:.3g} s of it"
        out.append(
            f"the wheel travels {travel:.3g} s but the steady window is output.steady_start .. "
            f"steady_end = {o.steady_start:g} .. {o.steady_end:g} s of travel: {what}; travel "
            f"longer (wheel.travel_time) or end the window sooner"
        )
    end = min(travel, o.steady_end)
    blocks = planned_blocks(sc)
    if end > o.steady_start and blocks < MIN_BLOCKS:
        period = block_period(sc)
        if not math.isfinite(period):
            unit = "blocks (the wheel does not turn: wheel.omega = 0)"
        elif w.n_lugs > 0:
            unit = f"lug passages (2 pi / (wheel.n_lugs wheel.omega) = {period:.3g} s each)"
        else:
            unit = f"blocks ({period:.3g} s each, the rim turning {math.degrees(SMOOTH_BLOCK_ANGLE):g} degrees)"
        out.append(
            f"the steady window {o.steady_start:g} .. {end:g} s of travel holds {blocks:.2f} {unit}: fewer "
            f"than {MIN_BLOCKS}, so the steady means have no reliable confidence interval (one block per "
            f"passage) and the summary flags them; travel longer (wheel.travel_time, output.steady_end) or "
            f"start the window sooner (output.steady_start)"
        )
    return out


def _unused_control_keys(sc: Scenario) -> list[str]:
    """The free-spin and carriage keys set away from their defaults that wheel.control ignores."""
    w, default = sc.wheel, Wheel()
    used = {"torque", "torque_ramp", "carriage", "inertia"} if w.control == "torque" else set()
    if w.control == "towed":
        used |= {"inertia", "speed"}
    if w.control == "torque" and w.carriage == "speed":
        used.add("speed")
    keys = ("torque", "torque_ramp", "carriage", "inertia", "speed")
    return [k for k in keys if k not in used and getattr(w, k) != getattr(default, k)]


def _block_warnings(sc: Scenario, plan: RunPlan) -> list[str]:
    """An out-of-core run of K = 1 commits an epoch (the whole bed written) every step."""
    if not MODES[plan.mode].out_of_core or plan.block != 1 or plan.steps <= 1:
        return []
    k = auto_block(sc, plan.domains, sc.bin.length)
    if k > 1:
        hint = f"--block {k} (its halo is 10 % of a slab)"
    else:
        fewer = [(d, auto_block(sc, d, sc.bin.length)) for d in range(plan.domains - 1, 0, -1)]
        wider = [(d, kd) for d, kd in fewer if kd > 1]
        hint = (
            f"--domains {wider[0][0]} --block {wider[0][1]} (slabs wide enough for a 10 % halo)"
            if wider
            else "a larger --block (each step of a block adds a contact hop of halo to each slab)"
        )
    return [
        f"out-of-core with block K = 1 commits an epoch, the whole bed written to the store, every "
        f"step ({plan.steps} epochs); {hint}"
    ]


def _dimension_warnings(sc: Scenario, tables: dict[str, Any]) -> list[str]:
    """A file without a base whose unset keys take the defaults of the other dimension."""

    def given(sec: str, key: str) -> bool:
        t = tables.get(sec)
        return isinstance(t, dict) and key in t

    if sc.dim == 3:
        keys = list(DIMENSIONED_KEYS) + ([("wheel", "width")] if sc.wheel.enabled else [])
        unset = [f"{sec}.{key}" for sec, key in keys if not given(sec, key)]
        if unset:
            return [
                f"physics.dim = 3 but {', '.join(unset)} {'is' if len(unset) == 1 else 'are'} not set and "
                f"take{'s' if len(unset) == 1 else ''} the 2D defaults (paper2008's 0.6 m x 0.1 m bin of "
                f'6986 grains of r 1.8-2.2 mm); start the file with base = "quick-3d" (or '
                f'"paper2008-3d") and set only what differs'
            ]
    elif not given("physics", "dim"):
        set3d = [f"{sec}.{key}" for sec, key in KEYS_3D if given(sec, key)]
        if set3d:
            return [
                f"{', '.join(set3d)} {'is a key' if len(set3d) == 1 else 'are keys'} of 3D scenarios, but "
                f'physics.dim is not set and is 2 (discs); set physics.dim = 3, or start the file with base = "quick-3d"'
            ]
    return []
