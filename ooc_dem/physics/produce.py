"""Phase 1 of a step: contacts as data, each evaluated once (numba, no I/O; written once,
compiled per dimension by ``physics.step.instantiate``).

A step's forces come in two phases (Nishiura & Sakaguchi 2011, J. Comput. Phys.
230:1923: a pair list with a per-particle pair-index table, Newton's third law without
write conflicts); ``produce`` is the first: one row per contact at time n.

- Body rows first, in a pass of their own: each particle's contacts with the wheel's
  parts, the plates and the walls (the dimension's ``body_rows``: its geometry and law) go to per-chunk
  buffers (``layout.Bodies``) in particle order, ascending partner id within a particle.
  When a chunk's buffer is full, err[ERR_BODY_CAPACITY] is set and no pair row is made:
  the pair rows still hold the springs of the last step, so the step can be rerun after
  growing the buffers and gives the same rows.
- Then the pairs, from the HALF neighbour list (``neighbors.build_pairs``: each pair once,
  stored with its lower global id a), so the law is evaluated once per pair in canonical
  orientation; the row (the dimension's pair-row layout) goes to the pair's slot of the
  list. The touching pairs are listed in blocks (their law arguments as columns, the
  dimension's ``LawIn``) and the dimension's block law runs on a block in one vectorised
  loop (SIMD) whose per-pair arithmetic is that of a pair evaluated alone: the same bits.
  Listing is two passes: the distance test writes every candidate to the block's next
  column and moves on by one only when the pair touches (about half of a settled bed's
  candidates do: a branch on it would be mispredicted every other pair), then
  ``fill_block`` reads what the law needs of the touching ones. A pair's springs of the
  last step are its row's when it was in contact (on[q]), else zero.

A producer only reads the time-n state and writes rows, so it can be rerun without
changing anything.
"""

import numpy as np
from numba import njit, prange

from .axes import DIM, SPIN
from .chunks import N_CHUNKS, chunk_range, chunks_range
from .outline import builtin_off, outline_scene
from .plates import plate_scene
from .layout import AX_X, ERR_BODY_CAPACITY, LAW_BLOCK, LAW_ROW, N_TYPES
from .twins import slot

# ---------------------------------- what each dimension binds (its law, rows and bodies)
LawIn = slot(
    "LawIn: the rows of a block's law inputs (IntEnum): dx (then the other axes' "
    "offsets), vrx (then the others), ra, rb, ma, mb, ia, ib, material"
)
N_LAW_IN = slot("N_LAW_IN: the rows of a block's law inputs")
N_LAW_OUT = slot("N_LAW_OUT: the rows of a block's law results")
LAW_IN_WA = slot("LAW_IN_WA: the LawIn row of a's first spin component (SPIN rows)")
LAW_IN_WB = slot("LAW_IN_WB: the LawIn row of b's first spin component (SPIN rows)")
CHUNKS_PER_GROUP = slot("CHUNKS_PER_GROUP: chunks whose pairs share one set of block columns (allocated once a group)")
springs_into_block = slot(
    "springs_into_block(law_in, t, row, on_last): pair t's springs of the last step, its row's if on_last else zero"
)
block_law = slot(
    "block_law(k, law_in, law_out, dt, rows, cp, uniform): the law on a filled "
    "block of k pairs (uniform: one material pair)"
)
put_pair_rows = slot("put_pair_rows(k, slot, law_out, rows): a block's results into their rows")
body_scene = slot("body_scene(walls, wg, ws): the walls' and the wheel's geometry this step, as a tuple")
body_rows = slot(
    "body_rows(i, d, cp, scene, with_plates, pscene, lugdir, mesh, body, bat, bend, dt): particle i's rows "
    "with the wheel (mesh: layout.MeshWheel, its triangles if it has any), the plates and the walls from body row bat on (bend: the chunk's end); "
    "with_plates: a constant at each call (False: no plate, and the plates' code folds away), "
    "pscene: plates.plate_scene of the table; returns (next row, whether one did not fit)"
)
outline_rows = slot(
    "outline_rows(i, d, cp, oscene, ol, body, bat, bend, dt): particle i's row with a wheel given as "
    "an outline (physics.outline; oscene: outline.outline_scene), before its body_rows; returns (next row, "
    "whether it did not fit); optional (physics.outline.no_outline_rows: none)"
)


@njit(inline="always", cache=True)
def one_material(k, law_in, material_row):
    """Whether a block's k pairs all have one material pair (row material_row of the
    block's columns: type_a * n_types + type_b); the block law then takes its record once
    for the block."""
    m0 = law_in[material_row, 0]
    same = True
    for t in range(1, k):
        same = same & (law_in[material_row, t] == m0)
    return same


@njit(inline="always", cache=True)
def effective(ma, mb, ia, ib, ra, rb):
    """A pair's effective mass, inertia and radius (the block laws' arguments of the law)."""
    return ma * mb / (ma + mb), ia * ib / (ia + ib), ra * rb / (ra + rb)


@njit(inline="always", cache=True)
def copy_pair_params(k, law_in, material_row, first_row, cp):
    """Each of a block's k pairs' parameters into its columns: the record of its material
    pair (row material_row: type_a * n_types + type_b) of the contact table cp, field by
    field in the record's order from row first_row on."""
    # the table's records as float64 (all their fields are): row a holds records [a, b]
    # one after another
    n_types = cp.shape[1]
    fields = cp.view(np.float64)
    n_fields = fields.shape[1] // n_types
    for t in range(k):
        m = np.int64(law_in[material_row, t])
        a = m // n_types
        at = (m % n_types) * n_fields
        for f in range(n_fields):
            law_in[first_row + f, t] = fields[a, at + f]


def list_pair(law_in, k, pos, r, i, b):
    """Pair (i, b)'s offset pos[b] - pos[i] and radii into column k of a block; returns its
    contact flag (1: the pair touches; the test "d2 >= rs^2 or d2 == 0: no contact" as one
    flag)."""
    e = pos[b, AX_X] - pos[i, AX_X]
    law_in[LawIn.dx, k] = e
    d2 = e * e
    for a in range(AX_X + 1, DIM):
        e = pos[b, a] - pos[i, a]
        law_in[LawIn.dx + a, k] = e
        d2 += e * e
    ri = r[i]
    rb = r[b]
    law_in[LawIn.ra, k] = ri
    law_in[LawIn.rb, k] = rb
    rs = ri + rb
    return np.uint8(not d2 >= rs * rs) & np.uint8(d2 != 0.0)


def fill_block(k, law_in, slot, side_a, side_b, was_on, d, rows):
    """The law arguments of a block's k touching pairs besides their offsets and radii
    (list_pair wrote those): relative velocity, spins, masses, inertias, their material
    pair and their springs of the last step."""
    vel, spin, mass, inertia, mat = d.vel, d.spin, d.mass, d.inertia, d.mat
    for t in range(k):
        a = side_a[t]
        b = side_b[t]
        for x in range(DIM):
            law_in[LawIn.vrx + x, t] = vel[b, x] - vel[a, x]
        for x in range(SPIN):
            law_in[LAW_IN_WA + x, t] = spin[a, x]
            law_in[LAW_IN_WB + x, t] = spin[b, x]
        law_in[LawIn.ma, t] = mass[a]
        law_in[LawIn.mb, t] = mass[b]
        law_in[LawIn.ia, t] = inertia[a]
        law_in[LawIn.ib, t] = inertia[b]
        law_in[LawIn.material, t] = mat[a] * N_TYPES + mat[b]
        springs_into_block(law_in, t, rows[slot[t]], was_on[t] != 0)


def pair_rows(k, law_in, law_out, slot, side_a, side_b, was_on, d, rows, cp, dt):
    """The rows of a block's k touching pairs: their law arguments, the law, the rows put
    into their slots (the order of evaluation never changes a row: each depends only on
    its own arguments)."""
    fill_block(k, law_in, slot, side_a, side_b, was_on, d, rows)
    block_law(k, law_in, law_out, dt, rows, cp, one_material(k, law_in, LawIn.material))
    put_pair_rows(k, slot, law_out, rows)


def body_chunk(
    ch, first, end, d, cp, scene, with_plates, pscene, lugdir, mesh, oscene, ol, body, bcount, bcap, dt, err, any_full
):
    """Chunk ch's body rows (the first pass of ``produce``); with_plates is a constant at
    each call, so that a step without plates compiles to the loop it had before plates.
    A wheel given as an outline (oscene[0]; ol: layout.WheelOutline) makes its row first
    (its id is the rim's, below the plates' and the walls')."""
    lo, hi = chunk_range(ch, first, end)
    bat = ch * bcap
    bend = bat + bcap
    full = False
    with_outline = oscene[0]
    for i in range(lo, hi):
        if with_outline:
            bat, over = outline_rows(i, d, cp, oscene, ol, body, bat, bend, dt)
            full = full or over
        bat, over = body_rows(i, d, cp, scene, with_plates, pscene, lugdir, mesh, body, bat, bend, dt)
        full = full or over
    bcount[ch] = bat - ch * bcap
    if full:
        err[ERR_BODY_CAPACITY] = 1
        any_full[0] = True


def produce(first, end, d, pl, bd, cp, walls, wg, ws, plates, lugdir, mesh, ol, dt, err):
    """Phase 1: one row per contact of particles first..end-1 at time n (module doc): their
    wall and wheel rows and the rows of their own half lists (pairs whose lower id is one
    of them).

    d: layout.Discs, pl: layout.Pairs (half list + rows), bd: layout.Bodies (per-chunk
    body rows), cp: the dimension's CONTACT_PARAMS table [type_a, type_b], walls: its
    WALLS record (1,); wg / ws: WHEEL_GEOMETRY / WHEEL_STATE records (1,), plates: the
    PLATE table (physics.plates; length 0: none), lugdir:
    LUG_DIRECTION of each lug at the wheel's angle, mesh: the wheel's triangles
    (layout.MeshWheel; none: the built-in rim and lugs), ol: the 2D wheel's outline
    (layout.WheelOutline; no vertex: the built-in rim and lugs). Sets err[ERR_BODY_CAPACITY] when a
    chunk's body buffer is full (grow, rerun): then no pair row is made."""
    pos, r = d.pos, d.r
    half_off, pair_a, pair_b, on, rows = pl.half_off, pl.pair_a, pl.pair_b, pl.on, pl.rows
    body, bcount = bd.rows, bd.count
    bcap = body.shape[0] // N_CHUNKS
    scene = body_scene(walls, wg, ws)
    oscene = outline_scene(wg, ws, ol)
    if oscene[0]:  # the outline replaces the built-in rim and lugs
        scene = body_scene(walls, builtin_off(wg), ws)
    pscene = plate_scene(plates)
    any_full = np.zeros(1, np.bool_)
    # two loops, the flag a constant in each: without plates the plates' code is not there
    if plates.shape[0] == 0:
        for ch in prange(N_CHUNKS):
            body_chunk(
                ch,
                first,
                end,
                d,
                cp,
                scene,
                False,
                pscene,
                lugdir,
                mesh,
                oscene,
                ol,
                body,
                bcount,
                bcap,
                dt,
                err,
                any_full,
            )
    else:
        for ch in prange(N_CHUNKS):
            body_chunk(
                ch,
                first,
                end,
                d,
                cp,
                scene,
                True,
                pscene,
                lugdir,
                mesh,
                oscene,
                ol,
                body,
                bcount,
                bcap,
                dt,
                err,
                any_full,
            )
    if any_full[0]:
        return  # no pair row made: rerunnable after growing the body rows
    # ---------------------------------------------------------- pairs (i = a, lower id)
    for grp in prange(N_CHUNKS // CHUNKS_PER_GROUP):
        lo, hi = chunks_range(grp * CHUNKS_PER_GROUP, (grp + 1) * CHUNKS_PER_GROUP, first, end)
        law_in = np.empty((N_LAW_IN, LAW_ROW))
        law_out = np.empty((N_LAW_OUT, LAW_ROW))
        slot = np.empty(LAW_ROW, np.int64)  # the pair's slot in the list
        side_a = np.empty(LAW_ROW, np.int64)  # its particles a and b
        side_b = np.empty(LAW_ROW, np.int64)
        was_on = np.empty(LAW_ROW, np.uint8)  # in contact at the last step
        k = 0
        # the group's pairs in one loop (a loop per particle would end at a count that
        # varies from particle to particle, another mispredicted branch)
        # (a group past the span's end is empty: lo == hi may exceed it, so no index)
        for q in range(half_off[lo] if lo < hi else 0, half_off[hi] if lo < hi else 0):
            i = np.int64(pair_a[q])
            b = np.int64(pair_b[q])
            touch = list_pair(law_in, k, pos, r, i, b)
            slot[k] = q
            side_a[k] = i
            side_b[k] = b
            was_on[k] = on[q]
            on[q] = touch
            k += touch
            if k == LAW_BLOCK:
                pair_rows(k, law_in, law_out, slot, side_a, side_b, was_on, d, rows, cp, dt)
                k = 0
        if k > 0:
            pair_rows(k, law_in, law_out, slot, side_a, side_b, was_on, d, rows, cp, dt)
