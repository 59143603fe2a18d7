"""THE per-domain step (numba, no I/O), written once for every dimension: ``run_steps``,
and ``instantiate``, which compiles the whole step machinery for one dimension.

A step: the wheel's controls and lug directions (``physics.wheel``), ``produce`` (one
row per contact), ``gather_integrate`` (each particle sums its rows in ascending
partner-id order and is advanced), the wheel's reaction summed in ascending particle id,
the wheel's record and leapfrog, the plates' records and motion (``physics.plates``,
when there are plates), and a rebuild of the half pair list when some particle
has moved half the skin.

The machinery's templates (this module's ``run_steps``; ``produce``, ``gather``,
``history``, ``neighbors``) leave what differs between dimensions to ``Slot``s: the
axes, the contact law and its block columns, the pair and body rows, the walls' and the
wheel's contact geometry, the cell geometry. A dimension's package (``physics.d2``,
``physics.d3``) holds only those and calls ``instantiate``, which binds them
(``twins.specialise``) and compiles each template once for the dimension, plus the
one-thread twins serial DDM runs its sub-domains with.
"""

from types import SimpleNamespace

import numpy as np

from . import gather, history, outline as outline_mod, plates as plates_mod, produce as produce_mod
from .chunks import N_CHUNKS
from .layout import AX_Y, ERR_BODY_CAPACITY, ERR_HIST_OVERFLOW, ERR_PAIR_CAPACITY, LUG_DIRECTION
from .twins import slot, bindings, no_parfors, slots_of, specialise
from .wheel import apply_wheel_controls, lug_directions, record_and_integrate_wheel, wheel_reaction

# the dimension's phases (instantiate binds them)
produce = slot("produce: the dimension's phase 1 (physics.produce)")
gather_integrate = slot("gather_integrate: the dimension's phase 2 (physics.gather)")
load_history = slot("load_history: the dimension's (physics.history)")
sync_history = slot("sync_history: the dimension's (physics.history)")
build_pairs = slot("build_pairs: the dimension's neighbour build (physics.neighbors)")
plates_step = slot("plates_step: the dimension's (physics.plates)")


def run_steps(nsteps, step0, kp, d, pl, bd, forces, ws, pt, err, rec, rebuild_now, pairs_done, role, spans):
    """Advance particles 0..len(d.gid)-1 (and the wheel when kp.wg.enabled) nsteps from
    global step step0.

    kp: layout.KernelParams (dt, gravity (D,), skin, the dimension's CONTACT_PARAMS table
    cp and WALLS, wg, wc, mesh: the wheel's triangles, layout.MeshWheel, outline: the 2D wheel's
    outline, layout.WheelOutline); d: layout.Discs; pl: Pairs; bd: Bodies; forces: layout.Forces
    (length 0: not kept); ws: WHEEL_STATE record; pt: layout.Plates (the plates' table,
    moved, and their records: P rows a step; P = 0, ``layout.no_plates()``: none); rec:
    WHEEL_RECORD rows, one per step (wheel runs). Returns (steps done, rebuilds). Stops early with err[ERR_PAIR_CAPACITY]
    = pairs needed (grow the pair list, call again with rebuild_now),
    err[ERR_BODY_CAPACITY] (grow the body buffers, call again with pairs_done: that step
    is redone, nothing was advanced) or err[ERR_HIST_OVERFLOW] (fatal). pairs_done: the
    call that stopped on ERR_BODY_CAPACITY left the pair rows as they were (``produce``
    makes no pair row when a body buffer is full): they are kept, not reloaded. role:
    each particle's history.ROLE_* bits in a serial-DDM sub-domain, which pair rows are
    reloaded (length 0: every row, and every particle's history written back at the end
    and on ERR_BODY_CAPACITY, so the particles leave whole; else the caller writes back
    what it needs with sync_history). spans: (m, 2) index ranges [first, end): step s of
    this call advances only particles spans[s] (the shrinking light cone of an
    out-of-core slab, ``engine.sweep.cone_spans``); steps past the m-th, and every step
    when m = 0, advance all particles.

    A pair's contact history lives in its row of the pair list while the steps run
    (``physics.history``): ``load_history`` fills the rows from the particles' histories
    at the start and after each rebuild, ``sync_history`` writes them back before each
    rebuild and at the end."""
    n = d.gid.shape[0]
    dt = kp.dt
    skin = kp.skin
    wg = kp.wg
    wc = kp.wc
    gy = kp.gravity[AX_Y]
    wheel = wg[0].enabled > 0.5
    nlugs = int(wg[0].nlugs)
    lugdir = np.empty(max(1, nlugs), LUG_DIRECTION)  # set by lug_directions before use
    part = np.empty(N_CHUNKS)  # scratch of gather_integrate
    every = role[:0]
    whole = role.shape[0] == 0  # the particles leave whole (no caller-side sync)
    has_plates = pt.table.shape[0] > 0
    if rebuild_now:
        npairs = build_pairs(
            d.pos, d.r, d.gid, n, skin, pl.half_off, pl.pair_b, pl.pair_a, pl.inc_off, pl.inc_k, pl.ref
        )
        if npairs > pl.pair_b.shape[0]:
            err[ERR_PAIR_CAPACITY] = npairs
            return 0, 0
    if not pairs_done:
        load_history(n, d, pl, every if rebuild_now else role)
    half2 = 0.25 * skin * skin
    rebuilds = 0
    for s in range(nsteps):
        t = (step0 + s) * dt
        if wheel:
            apply_wheel_controls(t, ws, wg, wc)
            lug_directions(ws[0].theta, nlugs, lugdir)
        first = 0
        end = n
        if s < spans.shape[0]:
            first = spans[s, 0]
            end = spans[s, 1]
        produce(first, end, d, pl, bd, kp.cp, kp.walls, wg, ws, pt.table, lugdir, kp.mesh, kp.outline, dt, err)
        if err[ERR_BODY_CAPACITY] != 0:
            # no pair row of this step was made (produce): the rows still hold the springs
            # of the last step, so the sync leaves the particles whole; nothing was advanced
            if whole:
                sync_history(n, d, pl, err, every, 0)
            return s, rebuilds
        disp2 = gather_integrate(first, end, d, pl, bd, forces.force, forces.torque, kp.gravity, dt, part, err)
        if err[ERR_HIST_OVERFLOW] != 0:
            return s, rebuilds  # fatal; step s is not done (its wheel is not advanced)
        if wheel:
            wfx, wfy, wtq, cnt = wheel_reaction(d.gid, bd)
            record_and_integrate_wheel(rec, s, t, ws, wg, wc, wfx, wfy, wtq, cnt, gy, dt)
        if has_plates:
            plates_step(s, t, d.gid, bd, pt, dt)
        if disp2 > half2:
            rebuilds += 1
            sync_history(n, d, pl, err, every, 0)
            npairs = build_pairs(
                d.pos, d.r, d.gid, n, skin, pl.half_off, pl.pair_b, pl.pair_a, pl.inc_off, pl.inc_k, pl.ref
            )
            if npairs > pl.pair_b.shape[0]:
                err[ERR_PAIR_CAPACITY] = npairs
                return s + 1, rebuilds
            load_history(n, d, pl, every)
    if whole:
        sync_history(n, d, pl, err, every, 0)
    return nsteps, rebuilds


# what a dimension's package gives instantiate: every Slot of these templates' modules
DIMENSION_SLOTS = tuple(sorted({name for mod in (history, gather, produce_mod, plates_mod) for name in slots_of(mod)}))
# the slots a dimension may leave out, with what they then are (3D has no outline wheel)
OPTIONAL_SLOTS = {"outline_rows": outline_mod.no_outline_rows}


def instantiate(name: str, *modules) -> SimpleNamespace:
    """The step machinery compiled for one dimension (``name``: 'd2', 'd3'): the templates
    of ``physics.history``, ``gather``, ``produce``, ``plates`` and ``run_steps`` with the dimension's
    kernels and constants bound (every DIMENSION_SLOTS name, from ``modules``: its layout,
    rows, bodies and geometry, the last with its neighbour build ``build_pairs`` and
    ``build_pairs_serial``, ``neighbors.instantiate``). Returns the phases
    (``produce``, ``gather_integrate``, ``load_history``, ``sync_history``,
    ``build_pairs``), ``run_steps``, and the one-thread twins serial DDM runs its
    sub-domains with (``run_steps_serial``, ``sync_history_serial``): the same source
    compiled without a parallel region, calling each other's twins."""
    given = [n for n in DIMENSION_SLOTS if n not in OPTIONAL_SLOTS or any(hasattr(m, n) for m in modules)]
    par = {**OPTIONAL_SLOTS, **bindings(given, *modules)}
    # the phases' inline helpers (no parallel loop): one compilation serves both variants
    for t in (
        produce_mod.list_pair,
        produce_mod.fill_block,
        produce_mod.pair_rows,
        produce_mod.body_chunk,
        gather.advance,
    ):
        par[t.__name__] = specialise(t, f"{t.__name__}_{name}", par, inline="always")
    ser = dict(par)
    for phase in (history.load_history, history.sync_history, gather.gather_integrate, produce_mod.produce):
        par[phase.__name__] = specialise(phase, f"{phase.__name__}_{name}", par, parallel=True)
        ser[phase.__name__] = specialise(phase, f"{phase.__name__}_{name}_serial", ser, parallel=no_parfors())
    # one-thread code in both variants (a few plates' sums, after the parallel phases)
    par["plates_step"] = ser["plates_step"] = specialise(plates_mod.plates_step, f"plates_step_{name}", par)
    build = bindings(("build_pairs", "build_pairs_serial"), *modules)
    par["build_pairs"] = build["build_pairs"]
    ser["build_pairs"] = build["build_pairs_serial"]
    # nogil: an out-of-core sweep reads and writes slabs in other threads while this runs
    return SimpleNamespace(
        produce=par["produce"],
        gather_integrate=par["gather_integrate"],
        load_history=par["load_history"],
        sync_history=par["sync_history"],
        build_pairs=par["build_pairs"],
        run_steps=specialise(run_steps, f"run_steps_{name}", par, nogil=True),
        run_steps_serial=specialise(run_steps, f"run_steps_{name}_serial", ser, parallel=no_parfors()),
        sync_history_serial=ser["sync_history"],
    )
