"""State <-> store records, epochs as checkpoints, and the canonical state hash.

A domain's record is a dict of flat arrays: the per-disc scalars plus the
contact history in CSR form (``hist_n`` counts, then ``hist_id``, ``hist_ft``,
``hist_mr`` concatenated row after row, each row sorted by partner id).
"""
from __future__ import annotations

import hashlib

import numpy as np

from .state import HIST_CAP, HIST_FIELDS, SCALAR_FIELDS, Particles, canonical_bytes


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
    if n and int(p.hist_n.max(initial=0)) > HIST_CAP:
        raise ValueError(f"contact history of {int(p.hist_n.max())} entries exceeds capacity {HIST_CAP}")
    used = np.arange(HIST_CAP)[None, :] < p.hist_n[:, None]
    total = int(p.hist_n.sum())
    for k in HIST_FIELDS:
        flat = rec[k]
        if len(flat) != total:
            raise ValueError(f"{k}: {len(flat)} entries, expected {total} from hist_n")
        getattr(p, k)[used] = flat
    return p


def hash_particles(p: Particles, wheel, step: int) -> str:
    h = hashlib.sha256()
    for chunk in canonical_bytes(p, wheel, step):
        h.update(chunk)
    return h.hexdigest()


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
    del all_ids
    if len(order) < 2**31:
        order = order.astype(np.int32)   # 4 bytes a disc kept while the fields stream by
    n = len(order)
    arrays, attrs = reader.read_globals()
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
