"""How a domain's particles are cut for the parallel phases (numba, no I/O).

``produce`` and ``gather_integrate`` run over N_CHUNKS contiguous chunks of the particles
first..end-1 (the body rows are buffered per chunk, in particle order); ``load_history``
and ``sync_history`` over the same chunks of the whole domain. The chunking never
changes a result: every particle's sums run in its own partner-id order.
"""

from numba import njit

N_CHUNKS = 64


@njit(inline="always", cache=True)
def chunks_range(c0, c1, first, end):
    """Chunks c0..c1-1 of particles first..end-1 as one index range [lo, hi) (N_CHUNKS
    contiguous pieces; empty past end)."""
    size = (end - first + N_CHUNKS - 1) // N_CHUNKS
    lo = first + c0 * size
    hi = min(end, first + c1 * size)
    return lo, max(lo, hi)


@njit(inline="always", cache=True)
def chunk_range(c, first, end):
    """Chunk c of particles first..end-1 (N_CHUNKS contiguous pieces)."""
    return chunks_range(c, c + 1, first, end)
