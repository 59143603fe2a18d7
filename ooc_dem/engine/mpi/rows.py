"""The exchange rows of MPI mode: one float64 row per disc (its id and the fields a refresh
copies), packed and unpacked by compiled kernels, and the kernels that find the rows a
rank sends and claims."""

from __future__ import annotations

import numpy as np
from numba import njit

from ...model.state import Particles, fields

# the state fields a refresh copies (id, r, mass, inertia and mat are fixed per disc)
_MOVING = ("pos", "vel", "spin", "hist_n", "hist_id", "hist_s", "hist_m")


def row_words(dim: int, cap: int) -> int:
    """Words (float64) of one disc's row in the exchange buffers: its id and ``_MOVING``
    fields, in that order (``_rows_io``). Integers travel as float64, exact below 2**53."""
    f = fields(dim, cap)
    return sum(int(np.prod(f[k][1], dtype=np.int64)) for k in ("id", *_MOVING))


def exchange_fields(p: Particles) -> tuple:
    """p's id and ``_MOVING`` fields, in the exchange row's order (``_rows_io``)."""
    return (p.id, p.pos, p.vel, p.spin, p.hist_n, p.hist_id, p.hist_s, p.hist_m)


@njit(inline="always")
def _field_io(buf, i, w, f, r, into_buf):
    """Columns w.. of buffer row i <-> row r of the 2D field f; returns the next column."""
    for c in range(f.shape[1]):
        if into_buf:
            buf[i, w + c] = f[r, c]
        else:
            f[r, c] = buf[i, w + c]
    return w + f.shape[1]


@njit(inline="always")
def _rows_io(buf, state_rows, ids, pos, vel, spin, hist_n, hist_id, hist_s, hist_m, into_buf):
    """Buffer row i <-> state row state_rows[i] (skipped when negative), into the buffer
    (into_buf) or out of it: the id and ``_MOVING`` fields in turn, each field's components
    row-major (any dimension and history width; buf has row_words columns)."""
    n = len(ids)
    fields_1d = (ids.reshape(n, 1), hist_n.reshape(n, 1))
    hist_s2, hist_m2 = hist_s.reshape(n, -1), hist_m.reshape(n, -1)
    for i in range(len(state_rows)):
        r = state_rows[i]
        if r < 0:
            continue
        w = _field_io(buf, i, 0, fields_1d[0], r, into_buf)
        w = _field_io(buf, i, w, pos, r, into_buf)
        w = _field_io(buf, i, w, vel, r, into_buf)
        w = _field_io(buf, i, w, spin, r, into_buf)
        w = _field_io(buf, i, w, fields_1d[1], r, into_buf)
        w = _field_io(buf, i, w, hist_id, r, into_buf)
        w = _field_io(buf, i, w, hist_s2, r, into_buf)
        _field_io(buf, i, w, hist_m2, r, into_buf)


# the two directions compiled apart, each with its direction a constant in the loops
@njit(cache=True)
def _pack_rows(buf, state_rows, ids, pos, vel, spin, hist_n, hist_id, hist_s, hist_m):
    _rows_io(buf, state_rows, ids, pos, vel, spin, hist_n, hist_id, hist_s, hist_m, True)


@njit(cache=True)
def unpack_rows(buf, state_rows, ids, pos, vel, spin, hist_n, hist_id, hist_s, hist_m):
    _rows_io(buf, state_rows, ids, pos, vel, spin, hist_n, hist_id, hist_s, hist_m, False)


def slots_of(uids, ids) -> np.ndarray:
    """The slot (index in the sorted local ids ``uids``) of each received id, -1 for an id
    this rank does not hold."""
    ids = np.asarray(ids).astype(np.int64)
    at = np.minimum(np.searchsorted(uids, ids), max(len(uids) - 1, 0))
    found = uids[at] == ids if len(uids) else np.zeros(len(ids), np.bool_)
    return np.where(found, at, -1).astype(np.int64)


@njit(cache=True)
def claim_ghosts(slots, ghost_row, owner_row, stamp, tick):
    """The ghost row of each received disc (by its slot, ``slots_of``; -1: not one of this
    rank's ghost discs); each claimed row becomes its disc's owner row and is stamped `tick`."""
    rows = np.full(len(slots), -1, np.int64)
    for i in range(len(slots)):
        g = slots[i]
        if 0 <= g < len(ghost_row) and ghost_row[g] >= 0:
            rows[i] = ghost_row[g]
            owner_row[g] = rows[i]
            stamp[rows[i]] = tick
    return rows


@njit(cache=True)
def largest_move(rows, x, x_built):
    """max |x - x_built| over the rows (0 for none)."""
    moved = 0.0
    for r in rows:
        d = abs(x[r] - x_built[r])
        if d > moved:
            moved = d
    return moved


def room(buf: np.ndarray, rows: int) -> np.ndarray:
    """buf if it has `rows` rows, else a larger one (a quarter more): the exchange reuses
    its buffers, since fresh ones of a few hundred kB cost their page faults every block."""
    return buf if len(buf) >= rows else np.empty((rows + rows // 4 + 16, buf.shape[1]))


def pack(p: Particles, rows, buf: np.ndarray) -> np.ndarray:
    """The rows' exchange rows in buf's first len(rows) rows (a view)."""
    rows = np.asarray(rows, np.int64)
    _pack_rows(buf, rows, *exchange_fields(p))
    return buf[: len(rows)]


@njit(cache=True)
def near_rows(rows, x, intervals, width):
    """The rows among `rows` whose x lies within `width` of one of the intervals [lo, hi)."""
    out = np.empty(len(rows), np.int64)
    n = 0
    for i in range(len(rows)):
        v = x[rows[i]]
        for k in range(intervals.shape[0]):
            if v >= intervals[k, 0] - width and v < intervals[k, 1] + width:
                out[n] = rows[i]
                n += 1
                break
    return out[:n]
