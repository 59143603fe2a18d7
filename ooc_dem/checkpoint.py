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
