"""The canonical state hash (version 2): a multiset hash that streams in O(slab) memory.

The hash of a state is a function of the SET of its discs, not of their order, so it
can be taken group by group, slab by slab, in any partition and any row order, and is
equal across modes, sub-domain counts D, blocks K, backends, thread counts and restarts
by construction (no global sort by id, nothing of the whole bed in RAM).

Per disc, a canonical message of little-endian 64-bit words (``disc_words`` documents
it): id, pos (D), vel (D), spin (R), r, mass, inertia, mat, hist_n, then each of the
disc's hist_n contacts in the stored (ascending partner id) order: partner id, hist_s
(S), hist_m (M). Floats enter as their IEEE-754 bits, integers as int64. Its digest is
four XXH64 hashes of the message bytes (seeds 0, 1, 2, 3: 256 bits, four lanes); the
digests of all discs are added lane by lane mod 2^64 (as LtHash combines its digests),
which is commutative and associative, so partial sums of groups simply add up. The
hash string is ``PREFIX`` + SHA-256(tag, step, n, the four lane sums, the wheel state)
in hex.

XXH64 (the xxHash algorithm, checked against the ``xxhash`` package in the tests) is
compiled with numba here because a Python call per disc would dominate. This is an
equality check between runs, NOT a security boundary: XXH64 is not collision-resistant
against someone who crafts a state on purpose, and the lane sums can be steered by such
a person. Untrusted stores are protected by validation (state_check.py), not by the hash.

Version 1 (engines before this hash) was an unprefixed SHA-256 of the state sorted by id; it
needed all ids in RAM.
"""

from __future__ import annotations

import hashlib

import numpy as np
from numba import njit, prange

PREFIX = "mset-v2:"  # the version of the hash string (v1: 64 bare hex digits)
LANES = 4  # XXH64 digests per disc (seeds 0 .. LANES-1): 256 bits
_TAG = b"ooc-dem canonical state hash v2\x00"

_P1 = np.uint64(0x9E3779B185EBCA87)
_P2 = np.uint64(0xC2B2AE3D27D4EB4F)
_P3 = np.uint64(0x165667B19E3779F9)
_P4 = np.uint64(0x85EBCA77C2B2AE63)
_P5 = np.uint64(0x27D4EB2F165667C5)


@njit(inline="always")
def _rotl(x, r):
    return (x << np.uint64(r)) | (x >> np.uint64(64 - r))


@njit(inline="always")
def _round(acc, lane):
    acc = acc + lane * _P2
    acc = _rotl(acc, 31)
    return acc * _P1


@njit(inline="always")
def _merge(acc, v):
    acc = acc ^ _round(np.uint64(0), v)
    return acc * _P1 + _P4


@njit(cache=True)
def xxh64_words(words, n, seed):
    """XXH64 of the 8*n bytes of words[:n] (uint64, little-endian) with a uint64 seed.

    The xxHash specification restricted to lengths that are multiples of 8 (the 4- and
    1-byte tails never occur): equal to ``xxhash.xxh64(bytes, seed).intdigest()``."""
    i = 0
    if n >= 4:
        v1 = seed + _P1 + _P2
        v2 = seed + _P2
        v3 = seed
        v4 = seed - _P1
        while i + 4 <= n:
            v1 = _round(v1, words[i])
            v2 = _round(v2, words[i + 1])
            v3 = _round(v3, words[i + 2])
            v4 = _round(v4, words[i + 3])
            i += 4
        h = _rotl(v1, 1) + _rotl(v2, 7) + _rotl(v3, 12) + _rotl(v4, 18)
        h = _merge(h, v1)
        h = _merge(h, v2)
        h = _merge(h, v3)
        h = _merge(h, v4)
    else:
        h = seed + _P5
    h = h + np.uint64(8 * n)
    while i < n:
        h = h ^ _round(np.uint64(0), words[i])
        h = _rotl(h, 27) * _P1 + _P4
        i += 1
    h = h ^ (h >> np.uint64(33))
    h = h * _P2
    h = h ^ (h >> np.uint64(29))
    h = h * _P3
    h = h ^ (h >> np.uint64(32))
    return h


@njit(cache=True, parallel=True)
def _disc_digests(idw, posw, velw, spinw, rw, massw, inertw, matw, hnw, off, hidw, hsw, hmw, max_words, out):
    """out[i, lane] = XXH64(message of disc i, seed = lane). The message is assembled in a
    per-disc scratch of max_words words (the caller's bound from the largest hist_n)."""
    n = len(idw)
    D = posw.shape[1]
    R = spinw.shape[1]
    S = hsw.shape[1]
    M = hmw.shape[1]
    lanes = out.shape[1]
    for i in prange(n):
        w = np.empty(max_words, np.uint64)
        k = 0
        w[k] = idw[i]
        k += 1
        for c in range(D):
            w[k] = posw[i, c]
            k += 1
        for c in range(D):
            w[k] = velw[i, c]
            k += 1
        for c in range(R):
            w[k] = spinw[i, c]
            k += 1
        w[k] = rw[i]
        w[k + 1] = massw[i]
        w[k + 2] = inertw[i]
        w[k + 3] = matw[i]
        w[k + 4] = hnw[i]
        k += 5
        for e in range(off[i], off[i + 1]):
            w[k] = hidw[e]
            k += 1
            for c in range(S):
                w[k] = hsw[e, c]
                k += 1
            for c in range(M):
                w[k] = hmw[e, c]
                k += 1
        for lane in range(lanes):
            out[i, lane] = xxh64_words(w, k, np.uint64(lane))


def _u64(a, dt: str) -> np.ndarray:
    """The array as little-endian `dt`, then its 64-bit words (int32 widened to int64)."""
    a = np.ascontiguousarray(a, dt)
    if a.dtype.itemsize == 4:
        a = a.astype("<i8")
    return a.view(np.uint64)


def disc_words(dim_widths: tuple[int, int, int, int], hist_n: int) -> int:
    """Words in one disc's message: id, pos (D), vel (D), spin (R), r, mass, inertia, mat,
    hist_n, then hist_n contacts of (partner id, hist_s (S), hist_m (M))."""
    D, R, S, M = dim_widths
    return 1 + 2 * D + R + 5 + hist_n * (1 + S + M)


def digests(rec: dict) -> np.ndarray:
    """The (n, LANES) uint64 digests of the discs of one record (the store's format-2
    record: per-disc ``id, pos, vel, spin, r, mass, inertia, mat, hist_n`` and the CSR
    history ``hist_id, hist_s, hist_m``, each disc's entries in stored order).

    ValueError if hist_n is negative or does not add up to the history entries (the
    kernel would read beyond them)."""
    n = len(rec["id"])
    pos = np.asarray(rec["pos"])
    spin = np.asarray(rec["spin"])
    hs, hm = np.asarray(rec["hist_s"]), np.asarray(rec["hist_m"])
    if pos.ndim != 2 or spin.ndim != 2 or hs.ndim != 2 or hm.ndim != 2:
        raise ValueError("pos, spin, hist_s and hist_m must be 2-D arrays")
    hn = np.ascontiguousarray(rec["hist_n"], "<i8")
    if n and hn.min() < 0:
        raise ValueError("hist_n holds negative counts")
    off = np.zeros(n + 1, np.int64)
    np.cumsum(hn, out=off[1:])
    E = len(rec["hist_id"])
    if int(off[-1]) != E or len(hs) != E or len(hm) != E:
        raise ValueError(f"hist_n adds up to {int(off[-1])}, the history holds {E}, {len(hs)}, {len(hm)} entries")
    widths = (pos.shape[1], spin.shape[1], hs.shape[1], hm.shape[1])
    out = np.zeros((n, LANES), np.uint64)
    if n:
        _disc_digests(
            _u64(rec["id"], "<i8"),
            _u64(pos, "<f8"),
            _u64(rec["vel"], "<f8"),
            _u64(spin, "<f8"),
            _u64(rec["r"], "<f8"),
            _u64(rec["mass"], "<f8"),
            _u64(rec["inertia"], "<f8"),
            _u64(rec["mat"], "<i4"),
            hn.view(np.uint64),
            off,
            _u64(rec["hist_id"], "<i8"),
            _u64(hs, "<f8"),
            _u64(hm, "<f8"),
            disc_words(widths, int(hn.max())),
            out,
        )
    return out


def lane_sums(rec: dict) -> np.ndarray:
    """The four lane sums (mod 2^64) of one record's disc digests: add these over any
    partition of the discs (``combine``) for the sums of the whole state."""
    return digests(rec).sum(axis=0, dtype=np.uint64)


def combine(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Lane-wise sum mod 2^64 (uint64 addition wraps)."""
    return np.add(a, b, dtype=np.uint64)


def zero() -> np.ndarray:
    return np.zeros(LANES, np.uint64)


def finish(sums: np.ndarray, n: int, step: int, wheel) -> str:
    """The hash string of a state from its lane sums, disc count, step and wheel state
    (None: no wheel state hashed)."""
    h = hashlib.sha256(_TAG)
    h.update(np.int64(step).tobytes())
    h.update(np.int64(n).tobytes())
    h.update(np.ascontiguousarray(sums, "<u8").tobytes())
    if wheel is None:
        h.update(np.int64(-1).tobytes())
    else:
        w = np.ascontiguousarray(wheel, "<f8").ravel()
        h.update(np.int64(len(w)).tobytes())
        h.update(w.tobytes())
    return PREFIX + h.hexdigest()


def hash_records(records, wheel, step: int) -> str:
    """The hash of a state given as records (any partition, any order)."""
    sums, n = zero(), 0
    for rec in records:
        sums = combine(sums, lane_sums(rec))
        n += len(rec["id"])
    return finish(sums, n, step, wheel)
