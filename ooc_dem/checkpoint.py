"""State <-> store records, epochs as checkpoints, and the canonical state hash.

A domain's record is a dict of flat arrays: the per-disc scalars plus the
contact history in CSR form (``hist_n`` counts, then ``hist_id``, ``hist_ft``,
``hist_mr`` concatenated row after row, each row sorted by partner id).
"""
from __future__ import annotations

import hashlib
import math

import numpy as np

from .physics.layout import WS_SIZE
from .scenario import show
from .state import HIST_CAP, HIST_FIELDS, SCALAR_FIELDS, Particles, canonical_bytes


class StateError(ValueError):
    """A stored state is not one this engine could have written (one-line message).

    A store is untrusted input: an epoch whose checksums pass may still have been
    edited consistently (NaN positions, a history count beyond capacity, duplicated
    disc ids). Such a state is refused before it is stepped, hashed or exported.
    """


# per-disc fields that must hold finite numbers; radii, masses and inertias must be > 0 too
_FINITE_FIELDS = ("x", "y", "vx", "vy", "w", "r", "mass", "inertia")
_POSITIVE_FIELDS = ("r", "mass", "inertia")
_FINITE_HISTORY = ("hist_ft", "hist_mr")


def validate_record(rec: dict, where: str) -> None:
    """Refuse a domain record that this engine could not have written (StateError).

    Checks names, dtypes and lengths of every field, finite kinematics, positive
    radii/masses/inertias, non-negative ids and materials, ids unique within the
    record, history counts within [0, HIST_CAP] that add up to the CSR entries, and
    each disc's partners in strictly ascending id order (the sum order of the
    determinism contract) and never itself.
    """
    for name, dt in {**SCALAR_FIELDS, **HIST_FIELDS}.items():
        a = rec.get(name)
        if a is None:
            raise StateError(f"{where}: array {name!r} missing")
        if a.ndim != 1 or a.dtype != dt:
            raise StateError(f"{where}: array {name!r} is {a.dtype} with shape {a.shape}, "
                             f"expected 1-D {dt}")
    n = len(rec["id"])
    for name in SCALAR_FIELDS:
        if len(rec[name]) != n:
            raise StateError(f"{where}: array {name!r} has {len(rec[name])} rows, 'id' has {n}")
    for name in _FINITE_FIELDS + _FINITE_HISTORY:
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
    if n and (hist_n.min() < 0 or hist_n.max() > HIST_CAP):
        raise StateError(f"{where}: hist_n outside [0, {HIST_CAP}] (contact history capacity)")
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
    rec = {k: np.ascontiguousarray(getattr(p, k), d) for k, d in SCALAR_FIELDS.items()}
    used = np.arange(HIST_CAP)[None, :] < p.hist_n[:, None]
    for k, d in HIST_FIELDS.items():
        rec[k] = np.ascontiguousarray(getattr(p, k)[used], d)
    return rec


def record_to_particles(rec: dict[str, np.ndarray]) -> Particles:
    n = len(rec["id"])
    p = Particles.empty(n)
    for k in SCALAR_FIELDS:
        getattr(p, k)[:] = rec[k]
    if n and (int(p.hist_n.max(initial=0)) > HIST_CAP or int(p.hist_n.min(initial=0)) < 0):
        raise StateError(f"contact history counts outside [0, {HIST_CAP}] (capacity)")
    used = np.arange(HIST_CAP)[None, :] < p.hist_n[:, None]
    total = int(p.hist_n.sum())
    for k in HIST_FIELDS:
        flat = rec[k]
        if len(flat) != total:
            raise StateError(f"{k}: {len(flat)} entries, expected {total} from hist_n")
        getattr(p, k)[used] = flat
    return p


def hash_particles(p: Particles, wheel, step: int) -> str:
    h = hashlib.sha256()
    for chunk in canonical_bytes(p, wheel, step):
        h.update(chunk)
    return h.hexdigest()


def validate_epoch(reader, where: str) -> None:
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
        validate_record(rec, at)
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
        if (np.diff(rec["x"]) < 0).any():   # halo reads bisect the rows by x
            raise StateError(f"{at}: discs not sorted by x")
        if len(rec["x"]) and (rec["x"].min() < dattrs.get("xmin", -math.inf)
                              or rec["x"].max() > dattrs.get("xmax", math.inf)):
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
    h = hashlib.sha256()
    h.update(np.int64(int(attrs["step"])).tobytes())
    h.update(np.int64(n).tobytes())

    def split(pos):
        """(domain index k, positions in the chunk, rows within domain k) for each domain hit."""
        k_of = np.searchsorted(off, pos, "right") - 1
        for k in np.unique(k_of):
            sel = np.flatnonzero(k_of == k)
            yield int(k), sel, pos[sel] - off[k]

    for name, dt in SCALAR_FIELDS.items():
        for c0 in range(0, n, chunk):
            pos = order[c0:c0 + chunk]
            out = np.empty(len(pos), dt)
            for k, sel, rows in split(pos):
                out[sel] = reader.read_domain(doms[k], [name], rows=rows)[name]
            h.update(out.tobytes())
    hist_off = {}
    for name, dt in HIST_FIELDS.items():
        for c0 in range(0, n, chunk):
            pos = order[c0:c0 + chunk]
            out = np.zeros((len(pos), HIST_CAP), dt)
            for k, sel, rows in split(pos):
                if k not in hist_off:   # CSR offsets of one domain at a time
                    hist_off.clear()
                    hn = reader.read_domain(doms[k], ["hist_n"])["hist_n"].astype(np.int64)
                    if len(hn) and (hn.min() < 0 or hn.max() > HIST_CAP):
                        raise StateError(f"epoch {reader.step} domain {doms[k]}: hist_n outside "
                                         f"[0, {HIST_CAP}] (contact history capacity)")
                    hist_off[k] = (hn, np.concatenate([[0], np.cumsum(hn)]))
                hn, hoff = hist_off[k]
                cnt = hn[rows]
                used = np.arange(HIST_CAP)[None, :] < cnt[:, None]
                entries = (hoff[rows][:, None] + np.arange(HIST_CAP)[None, :])[used]
                vals = reader.read_domain(doms[k], [name], rows=entries)[name]
                block = np.zeros((len(rows), HIST_CAP), dt)
                block[used] = vals
                out[sel] = block
            h.update(out.tobytes())
    wheel = arrays.get("wheel_state")
    if wheel is not None:
        h.update(np.ascontiguousarray(wheel, "<f8").tobytes())
    return h.hexdigest()
