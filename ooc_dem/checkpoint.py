"""State <-> store records, epochs as checkpoints, and the canonical state hash.

A domain's record (store format 2) is a dict of arrays: the per-disc fields ``id`` (n,),
``pos``/``vel`` (n, D), ``spin`` (n, R), ``r, mass, inertia, mat, hist_n`` (n,), plus the
contact history in CSR form (``hist_id`` (E,), ``hist_s`` (E, S), ``hist_m`` (E, M), the
used slots disc after disc, each disc's sorted by partner id; E = sum of hist_n).
Format-1 epochs (2D components as their own arrays) are read through ``V1Epoch``.
"""
from __future__ import annotations

import hashlib
import math

import numpy as np

from .physics.layout import AX_X, WS_SIZE
from .scenario import show
from .state import (DISC_FIELDS, FIELD_DTYPES, HIST_FIELDS, V1_ARRAYS, Particles, default_hist_cap,
                    canonical_bytes, canonical_columns, hash_width, record_fields, stack_v1, upgrade_v1)

# the run format (run meta ``format_version``, = the store format): 2 = per-particle vectors
# (pos, vel (n, D), spin (n, R), hist_s (E, S), hist_m (E, M)); 1 = the 2D components as
# their own arrays (x, y, vx, vy, w, hist_ft, hist_mr), read through ``V1Epoch``
FORMAT_VERSION = 2
SUPPORTED_VERSIONS = (1, 2)


class StateError(ValueError):
    """A stored state is not one this engine could have written (one-line message).

    A store is untrusted input: an epoch whose checksums pass may still have been
    edited consistently (NaN positions, a history count beyond capacity, duplicated
    disc ids). Such a state is refused before it is stepped, hashed or exported.
    """


# fields that must hold finite numbers; radii, masses and inertias must be > 0 too
_FINITE_FIELDS = ("pos", "vel", "spin", "r", "mass", "inertia", "hist_s", "hist_m")
_POSITIVE_FIELDS = ("r", "mass", "inertia")


def validate_record(rec: dict, where: str, dim: int = 2, hist_cap: int | None = None) -> None:
    """Refuse a domain record that this engine could not have written (StateError).

    Checks names, dtypes and shapes of every field (``state.record_fields(dim)``: pos must
    be (n, dim) etc.), finite kinematics and springs, positive radii/masses/inertias,
    non-negative ids and materials, ids unique within the record, history counts within
    [0, hist_cap] that add up to the CSR entries, and each disc's partners in strictly
    ascending id order (the sum order of the determinism contract) and never itself.
    """
    spec = record_fields(dim)
    for name, (dt, tail) in spec.items():
        a = rec.get(name)
        if a is None:
            raise StateError(f"{where}: array {name!r} missing")
        if a.ndim != 1 + len(tail) or a.shape[1:] != tail or a.dtype != dt:
            want = "(rows" + "".join(f", {k}" for k in tail) + ")"
            raise StateError(f"{where}: array {name!r} is {a.dtype} with shape {a.shape}, "
                             f"expected {want} {dt} ({dim}D)")
    n = len(rec["id"])
    for name in DISC_FIELDS:
        if len(rec[name]) != n:
            raise StateError(f"{where}: array {name!r} has {len(rec[name])} rows, 'id' has {n}")
    for name in _FINITE_FIELDS:
        if not np.isfinite(rec[name]).all():
            raise StateError(f"{where}: array {name!r} holds non-finite values")
    for name in _POSITIVE_FIELDS:
        if n and not (rec[name] > 0).all():
            raise StateError(f"{where}: array {name!r} holds values <= 0")
    for name in ("id", "mat"):
        if n and rec[name].min() < 0:
            raise StateError(f"{where}: array {name!r} holds negative values")
    check_unique_sorted(np.sort(rec["id"]), where)
    hist_n = rec["hist_n"]
    hist_cap = default_hist_cap(dim) if hist_cap is None else hist_cap
    if n and (hist_n.min() < 0 or hist_n.max() > hist_cap):
        raise StateError(f"{where}: hist_n outside [0, {hist_cap}] (contact history capacity)")
    total = int(hist_n.sum(dtype=np.int64))
    for name in HIST_FIELDS:
        if len(rec[name]) != total:
            raise StateError(f"{where}: array {name!r} has {len(rec[name])} entries, hist_n adds up "
                             f"to {total}")
    owner = np.repeat(rec["id"], hist_n)
    partner = rec["hist_id"]
    if (partner == owner).any():
        raise StateError(f"{where}: a disc's contact history names the disc itself")
    same_disc = owner[1:] == owner[:-1]
    if (same_disc & (partner[1:] <= partner[:-1])).any():
        raise StateError(f"{where}: contact history not in strictly ascending partner-id order")


def validate_globals(arrays: dict, attrs: dict, where: str) -> None:
    """Refuse an epoch's globals group that lacks what a resume needs (StateError)."""
    if not isinstance(attrs, dict):
        raise StateError(f"{where}: globals attributes are not an object")
    ws = arrays.get("wheel_state")
    if ws is None:
        raise StateError(f"{where}: globals hold no wheel_state")
    if ws.shape != (WS_SIZE,) or ws.dtype.kind != "f" or not np.isfinite(ws).all():
        raise StateError(f"{where}: wheel_state must be {WS_SIZE} finite floats, got {ws.dtype} "
                         f"{ws.shape}")
    step = attrs.get("step")
    if type(step) is not int or step < 0:
        raise StateError(f"{where}: globals attribute 'step' = {show(step)}: must be an integer >= 0")
    for key in ("time", "surface", "wall_time"):
        v = attrs.get(key, 0.0)
        if type(v) not in (int, float) or not math.isfinite(v):
            raise StateError(f"{where}: globals attribute {key!r} = {show(v)}: must be a finite number")
    red = attrs.get("redecompositions", [])
    if not isinstance(red, list):
        raise StateError(f"{where}: globals attribute 'redecompositions' must be a list")


def particles_to_record(p: Particles) -> dict[str, np.ndarray]:
    """The store record (format 2) of a state: the disc fields as they are, the history
    fields as CSR (the used slots, disc after disc)."""
    rec = {k: np.ascontiguousarray(getattr(p, k), FIELD_DTYPES[k]) for k in DISC_FIELDS}
    used = np.arange(p.hist_cap)[None, :] < p.hist_n[:, None]
    for k in HIST_FIELDS:
        rec[k] = np.ascontiguousarray(getattr(p, k)[used], FIELD_DTYPES[k])
    return rec


def record_to_particles(rec: dict[str, np.ndarray], hist_cap: int | None = None) -> Particles:
    """A state from a store record (format 2; a format-1 record is converted first)."""
    rec = upgrade_v1(rec)
    pos = rec.get("pos")
    if pos is None or pos.ndim != 2 or pos.shape[1] not in (2, 3):
        raise StateError(f"pos: shape {None if pos is None else pos.shape}, expected (n, 2) or (n, 3)")
    n, dim = pos.shape
    hist_cap = default_hist_cap(dim) if hist_cap is None else hist_cap
    p = Particles.empty(n, dim, hist_cap)
    for k in DISC_FIELDS:
        getattr(p, k)[:] = rec[k]
    if n and (int(p.hist_n.max(initial=0)) > hist_cap or int(p.hist_n.min(initial=0)) < 0):
        raise StateError(f"contact history counts outside [0, {hist_cap}] (capacity)")
    used = np.arange(hist_cap)[None, :] < p.hist_n[:, None]
    total = int(p.hist_n.sum())
    for k in HIST_FIELDS:
        flat = rec[k]
        if len(flat) != total:
            raise StateError(f"{k}: {len(flat)} entries, expected {total} from hist_n")
        getattr(p, k)[used] = flat
    return p


class V1Epoch:
    """A format-1 epoch read as format 2 (the one place the old format is converted):
    ``read_domain`` stacks x, y -> pos, vx, vy -> vel, w -> spin, hist_ft -> hist_s,
    hist_mr -> hist_m (``state.V1_ARRAYS``), with the same row selection; everything
    else is the wrapped reader's."""

    format_version = 2

    def __init__(self, reader):
        self._reader = reader

    def __getattr__(self, name):
        return getattr(self._reader, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._reader.close()
        return False

    def _names(self, d) -> list[str]:
        raw = list(self._reader.domain_arrays(d))
        comps = {c for cs in V1_ARRAYS.values() for c in cs}
        out = [k for k in raw if k not in comps]
        out += [k for k, cs in V1_ARRAYS.items() if all(c in raw for c in cs)]
        return out

    def domain_arrays(self, d):
        raw = self._reader.domain_arrays(d)
        out = {k: v for k, v in raw.items() if not any(k in cs for cs in V1_ARRAYS.values())}
        for k, cs in V1_ARRAYS.items():
            if all(c in raw for c in cs):
                shape, dt = raw[cs[0]]
                out[k] = (tuple(shape) + (len(cs),), dt)
        return out

    def read_domain(self, d, names=None, rows=None):
        names = self._names(d) if names is None else names
        want = []
        for k in names:
            want += list(V1_ARRAYS.get(k, (k,)))
        raw = self._reader.read_domain(d, want, rows)
        out = {}
        for k in names:
            if k in V1_ARRAYS:
                try:
                    out[k] = stack_v1(k, [raw[c] for c in V1_ARRAYS[k]])
                except ValueError as e:
                    raise StateError(f"epoch {self._reader.step} domain {d}: {e}") from None
            else:
                out[k] = raw[k]
        return out


def open_epoch(store, step: int | None = None, verify: bool = True):
    """``store.read_epoch`` seen in the current format (a format-1 epoch through V1Epoch)."""
    reader = store.read_epoch(step, verify=verify)
    v = getattr(reader, "format_version", FORMAT_VERSION)
    if v not in SUPPORTED_VERSIONS:
        reader.close()
        raise StateError(f"epoch {reader.step}: format version {show(v)} is not supported")
    return V1Epoch(reader) if v == 1 else reader


def read_all_particles(reader, dim: int = 2, hist_cap: int | None = None) -> Particles:
    """All discs of an epoch (every domain group), sorted by id."""
    parts = [record_to_particles(reader.read_domain(d), hist_cap) for d in reader.domains()]
    return Particles.concat(parts, dim, hist_cap).sorted_by_id()


def hash_particles(p: Particles, wheel, step: int) -> str:
    h = hashlib.sha256()
    for chunk in canonical_bytes(p, wheel, step):
        h.update(chunk)
    return h.hexdigest()


def validate_epoch(reader, where: str, dim: int = 2, hist_cap: int | None = None) -> None:
    """Refuse an epoch that this engine could not have written (StateError), domain by domain.

    Every domain record passes ``validate_record`` and its stored attrs agree with it;
    ids are unique across domains; the globals pass ``validate_globals``. Held in RAM:
    one domain at a time plus the sorted ids (8 bytes a disc, as the hash holds).
    """
    arrays, attrs = reader.read_globals()
    validate_globals(arrays, attrs, f"{where}: epoch {reader.step}")
    ids = []
    for d in reader.domains():
        at = f"{where}: epoch {reader.step} domain {d}"
        rec = reader.read_domain(d)
        validate_record(rec, at, dim, hist_cap)
        dattrs = reader.domain_attrs(d)
        if not isinstance(dattrs, dict):
            raise StateError(f"{at}: attributes are not an object")
        for key in ("xmin", "xmax"):
            v = dattrs.get(key, 0.0)
            if type(v) not in (int, float) or not math.isfinite(v):
                raise StateError(f"{at}: attribute {key!r} = {show(v)}: must be a finite number")
        if "n" in dattrs and dattrs["n"] != len(rec["id"]):
            raise StateError(f"{at}: attribute 'n' = {show(dattrs['n'])}, the domain holds "
                             f"{len(rec['id'])} discs")
        x = rec["pos"][:, AX_X]
        if (np.diff(x) < 0).any():   # halo reads bisect the rows by x
            raise StateError(f"{at}: discs not sorted by x")
        if len(x) and (x.min() < dattrs.get("xmin", -math.inf)
                       or x.max() > dattrs.get("xmax", math.inf)):
            raise StateError(f"{at}: discs outside the domain's stored x range")
        ids.append(rec["id"])
        del rec
    all_ids = np.sort(np.concatenate(ids)) if ids else np.empty(0, np.int64)
    del ids
    check_unique_sorted(all_ids, f"{where}: epoch {reader.step}")


def check_unique_sorted(sorted_ids: np.ndarray, where: str) -> None:
    dup = np.flatnonzero(sorted_ids[1:] == sorted_ids[:-1])
    if len(dup):
        raise StateError(f"{where}: disc id {int(sorted_ids[dup[0]])} appears more than once")


def hash_epoch(reader, chunk: int = 1 << 18) -> str:
    """The canonical state hash of an epoch, streamed: equal to ``hash_particles`` of all its
    discs, without ever holding them. Kept in RAM: the discs' ids while they are sorted (then
    only their id order, 4 bytes a disc) and one chunk of one field, so a store larger than RAM
    hashes too and hashing never sets an out-of-core run's memory peak."""
    doms = list(reader.domains())
    ids = [reader.read_domain(d, ["id"])["id"] for d in doms]
    off = np.concatenate([[0], np.cumsum([len(a) for a in ids], dtype=np.int64)])
    all_ids = np.concatenate(ids) if ids else np.empty(0, np.int64)
    del ids
    order = np.argsort(all_ids, kind="stable")
    check_unique_sorted(all_ids[order], f"epoch {reader.step}")
    del all_ids
    if len(order) < 2**31:
        order = order.astype(np.int32)   # 4 bytes a disc kept while the fields stream by
    n = len(order)
    arrays, attrs = reader.read_globals()
    validate_globals(arrays, attrs, f"epoch {reader.step}")
    # the canonical history width: content-defined (state.hash_width), one pass over hist_n
    max_hn = 0
    for k, d in enumerate(doms):
        hn = reader.read_domain(d, ["hist_n"])["hist_n"]
        entries = reader.domain_arrays(d).get("hist_id", ((0,), None))[0]
        if len(hn) and hn.min() < 0 or int(hn.sum(dtype=np.int64)) != (entries[0] if entries else 0):
            raise StateError(f"epoch {reader.step} domain {d}: hist_n outside [0, capacity] or "
                             f"not adding up to the {entries[0] if entries else 0} history entries")
        max_hn = max(max_hn, int(hn.max(initial=0)))
        del hn
    width = hash_width(max_hn)
    h = hashlib.sha256()
    h.update(np.int64(int(attrs["step"])).tobytes())
    h.update(np.int64(n).tobytes())

    def split(pos):
        """(domain index k, positions in the chunk, rows within domain k) for each domain hit."""
        k_of = np.searchsorted(off, pos, "right") - 1
        for k in np.unique(k_of):
            sel = np.flatnonzero(k_of == k)
            yield int(k), sel, pos[sel] - off[k]

    def columns(name, a):
        return list(canonical_columns(name, a)) if a.ndim > 1 else [a]

    for name in DISC_FIELDS:
        dt = FIELD_DTYPES[name]
        ncols = None
        c = 0
        while ncols is None or c < ncols:   # one column (vector component) at a time
            for c0 in range(0, n, chunk):
                pos = order[c0:c0 + chunk]
                out = np.empty(len(pos), dt)
                for k, sel, rows in split(pos):
                    cols = columns(name, reader.read_domain(doms[k], [name], rows=rows)[name])
                    ncols = len(cols)
                    out[sel] = cols[c]
                h.update(out.tobytes())
            if ncols is None:   # no discs: the vector width does not matter
                break
            c += 1
    hist_off = {}
    for name in HIST_FIELDS:
        dt = FIELD_DTYPES[name]
        ncols = None
        c = 0
        while ncols is None or c < ncols:
            for c0 in range(0, n, chunk):
                pos = order[c0:c0 + chunk]
                out = np.zeros((len(pos), width), dt)
                for k, sel, rows in split(pos):
                    if k not in hist_off:   # CSR offsets of one domain at a time
                        hist_off.clear()
                        hn = reader.read_domain(doms[k], ["hist_n"])["hist_n"].astype(np.int64)
                        hist_off[k] = (hn, np.concatenate([[0], np.cumsum(hn)]))
                    hn, hoff = hist_off[k]
                    cnt = hn[rows]
                    used = np.arange(width)[None, :] < cnt[:, None]
                    entries = (hoff[rows][:, None] + np.arange(width)[None, :])[used]
                    vals = reader.read_domain(doms[k], [name], rows=entries)[name]
                    ncols = 1 if vals.ndim == 1 else vals.shape[1]
                    block = np.zeros((len(rows), width), dt)
                    block[used] = vals if vals.ndim == 1 else vals[:, c]
                    out[sel] = block
                h.update(out.tobytes())
            if ncols is None:
                break
            c += 1
    wheel = arrays.get("wheel_state")
    if wheel is not None:
        h.update(np.ascontiguousarray(wheel, "<f8").tobytes())
    return h.hexdigest()
