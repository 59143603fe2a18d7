"""The memory model of a run, and the memory budget (``--memory``) that chooses D and K.

Bytes per particle are measured, per dimension (2D discs, 3D spheres), as peak RSS
above the post-warm-up baseline in fresh processes (``tools/memsweep.py``; the numbers
and commands are in ``MEASURED`` below) and rounded up. A run's peak is

    baseline + (monolithic)  N x monolithic
               (ddm)         N x resident x (1 + D x halo) + N x state (the RAM epoch)
               (ooc)         max(fixed + resident x (slab + halo), set-up, final hash)

where an out-of-core slab holds N (1/D + 2 K hop / length) particles (its owned ones
plus a halo K contact hops wide on both sides) and ``resident`` covers a resident
particle with its neighbour list, forces and the I/O copies of a sweep (the pieces
read, their concatenation, the record written). With a fixed slab size the sweep's
part is independent of N. The streamed set-up counts x in a fixed histogram for the
slab bounds and the state hash streams group by group (statehash.py), so their terms
(``streamed_setup``, ``final_hash``, ``hash_chunk``) are 0: what they hold is one group
(at most a slab's owned particles), below the slab's own peak. They stay named so a
path that ever holds per-particle data of the whole bed again is modelled, not hidden.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..model.state import bytes_per_disc
from .modes import MODES


@dataclass(frozen=True)
class ByteModel:
    """Bytes a run holds per particle of one dimension (measured, rounded up)."""

    dim: int
    state: int  # one copy of a particle's state (state.bytes_per_disc)
    monolithic: int  # a monolithic run: state + neighbour list + forces + set-up copies
    resident: int  # a particle resident in a sub-domain (slab or halo), I/O copies included
    ooc_setup: int  # out-of-core set-up from a bed held in RAM, per particle of the bed
    streamed_setup: int  # out-of-core set-up of a streamed bed, per particle of the bed
    final_hash: int  # out-of-core: the state hash at the run's end, per particle of the bed
    hash_chunk: int  # ... and per particle of its chunk (min(N, HASH_CHUNK) rows at a time)
    ooc_fixed: int  # out-of-core sweeps, whatever the slab: storage libraries' buffers
    baseline: int  # the interpreter, numpy, numba and the compiled kernels


MIB = 1 << 20

# Measured on this project's 2-core machine, rounded up. Whole `ooc-dem run` processes
# (memlimit.run_limited's peak RSS, numba's cache warm; hdf5; one sweep):
#   baseline: `ooc-dem run bed-300 --set bed.tile=0 --mode ooc --domains 2 --steps 2`:
#         192 MB in 2D and 3D (the first run after an edit compiles: 220 MB 2D, 310 MB 3D)
#   2D  bed-200000 --mode ooc --block 10: D = 2 (101 163 resident) 336 MB, D = 8 (26 163)
#         272 MB, and --memory 330MB (D = 4, K = 42: 54 900 resident) 272 MB
#         -> 1383 B per resident disc + ~4 MB; below ~55 000 resident the final hash sets
#         the peak (80 MB above baseline at 200k discs)
#   3D  bed3d-30000 --mode ooc --block 3: D = 1 (30 000 resident) 285 MB, D = 4 (9 975) 227 MB
#         -> 2891 B per resident sphere + ~6 MB
# and tools/memsweep.py (a fresh process each, after JIT warm-up, peak above baseline):
#   2D  --sizes 1e5,4e5 (monolithic) 1072, 1048 B/disc (fit 1040)
#       --sizes 1e5,4e5,1.6e6 --slab-discs 12500 --modes ooc (~13 700 resident each):
#         43, 108, 253 MB, the final hash's (in-process phases at 4e5: set-up 25 MB, sweeps
#         57 MB, hash 111 MB): ~230 B per disc of its chunk (2^18) + ~130 B per disc
#   3D  --family bed3d --sizes 2e4,1e5 (monolithic) 2355, 2388 B/sphere (fit 2396)
#       3D hash: not separated (below the sweeps' peak at 3e4); 1.5x the 2D figures
# Since ooc-dem processes fix malloc's mmap threshold (heap.py: a freed slab's arrays go
# back to the system instead of fragmenting the heap), re-measured in a fresh clone and venv
# (`pip install ".[test]"`, numba's cache warm), 2026-12-03:
#   baseline (the bed-300 / bed3d soil.n=300 runs above): 180.6 / 181.8 MiB in that venv,
#         183.4 / 184.7 MiB in an editable install
#   2D  bed-100000 --memory 270MB (D = 3, K = 28, 36 589 resident): 223.7 MB
#         -> ~840 B per resident disc above 185 MiB + 8 MiB
#   3D  bed3d-30000 --memory 260MB (D = 4, K = 1, 8 325 resident): 212.5 MB
#         -> ~2300 B per resident sphere above 185 MiB + 8 MiB (the 3D run loads more kernels:
#         its baseline is kept 5 MiB higher)
# The 1400 / 3000 B and 200 / 215 MiB before the fix over-estimated these peaks by 20-22 %.
BYTE_MODELS = {
    2: ByteModel(
        dim=2,
        state=bytes_per_disc(2),
        monolithic=1100,
        resident=1000,
        ooc_setup=400,
        streamed_setup=0,
        final_hash=0,
        hash_chunk=0,
        ooc_fixed=8 * MIB,
        baseline=185 * MIB,
    ),
    3: ByteModel(
        dim=3,
        state=bytes_per_disc(3),
        monolithic=2500,
        resident=2400,
        ooc_setup=900,
        streamed_setup=0,
        final_hash=0,
        hash_chunk=0,
        ooc_fixed=8 * MIB,
        baseline=190 * MIB,
    ),
}
HASH_CHUNK = 1 << 18  # rows a field is hashed in at a time (checkpoint.hash_epoch's chunk)


def byte_model(dim: int) -> ByteModel:
    return BYTE_MODELS[dim]


def hop(sc) -> float:
    """One contact hop: the farthest a contact reaches (2 r_max) plus the Verlet skin."""
    return 2.0 * sc.soil.r_max + sc.bed.skin


def slab_fraction(sc, mode: str, domains: int, block: int) -> float:
    """The share of the bed one sub-domain holds with its halo strips: out-of-core's halo
    is K hops (sweep.py), serial DDM's K + 1 (live.py)."""
    hops = block if MODES[mode].out_of_core else block + 1
    return min(1.0, 1.0 / domains + 2.0 * hops * hop(sc) / sc.bin.length)


def state_peak(sc, mode: str, backend: str, domains: int, block: int, streamed: bool, slabs: int = 1) -> dict:
    """The parts of a run's peak (bytes) that scale with its particles, by name (mpi-ooc: of
    rank 0, which sets up the first epoch alone and streams its slabs as out-of-core does).
    ``slabs``: out-of-core slabs resident at once (3 with --io-overlap: one read ahead, one
    computing, one being written)."""
    m = byte_model(sc.dim)
    n = sc.soil.n
    parts = {"baseline": m.baseline}
    if not MODES[mode].decomposes:
        parts["state"] = n * m.monolithic
    elif not MODES[mode].out_of_core:  # mpi: rank 0 holds the bed at the start (first cut)
        halo = slab_fraction(sc, mode, domains, block) - 1.0 / domains
        parts["state"] = n * (m.resident * (1.0 + domains * halo) + m.state)
    else:
        # the sweeps, the set-up and the final hash come one after another: the largest counts
        phases = {
            "slab": m.ooc_fixed + slabs * n * m.resident * slab_fraction(sc, mode, domains, block),
            "setup": n * (m.streamed_setup if streamed else m.ooc_setup),
            "hash": n * m.final_hash + min(n, HASH_CHUNK) * m.hash_chunk,
        }
        top = max(phases, key=phases.__getitem__)
        parts[top] = phases[top]
    if backend == "memory":
        parts["memory_store"] = 3 * n * m.state  # the in-process store: current, previous, being written
    return parts


def estimate_peak(
    sc, mode: str, backend: str, domains: int, block: int, streamed: bool, series_bytes: float = 0.0, slabs: int = 1
) -> int:
    return int(sum(state_peak(sc, mode, backend, domains, block, streamed, slabs).values()) + series_bytes)


def choose_decomposition(
    sc, budget: int, block_of, max_domains: int, backend: str, streamed: bool, series_bytes: float = 0.0, slabs: int = 1
) -> tuple[int, int, int] | None:
    """The fewest out-of-core sub-domains D (and their K = ``block_of(D)``) whose peak fits
    ``budget`` bytes: (D, K, peak), or None when even ``max_domains`` does not fit.

    The slab share falls as D grows (auto K grows with the slab width, so the halo stays
    ~10 % of it), so the first D that fits is the largest slab that fits."""
    for D in range(1, max_domains + 1):
        K = block_of(D)
        peak = estimate_peak(sc, "ooc", backend, D, K, streamed, series_bytes, slabs)
        if peak <= budget:
            return D, K, peak
    return None


def fmt_bytes(n: float) -> str:
    for unit, size in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6)):
        if n >= size:
            return f"{n / size:.1f} {unit}"
    return f"{n / 1e3:.1f} kB"


def parse_memory(text: str) -> int:
    """A memory size from the command line: '2GB', '1.5G', '512MiB', '300MB', '2e9' (bytes)."""
    from .memlimit import parse_size

    return parse_size(text)


def smallest_fit_message(
    sc, budget: int, block_of, max_domains: int, backend: str, streamed: bool, series_bytes: float = 0.0, slabs: int = 1
) -> str:
    """Why a budget cannot be met: the parts of the smallest out-of-core peak (at the most
    sub-domains the bed allows)."""
    parts = state_peak(sc, "ooc", backend, max_domains, block_of(max_domains), streamed, slabs)
    if series_bytes:
        parts["series"] = series_bytes
    names = {
        "baseline": "interpreter and kernels",
        "slab": f"a slab of D = {max_domains} with its halo",
        "memory_store": "--backend memory store",
        "setup": "set-up (B per particle of the whole bed)",
        "hash": "the final state hash (holds every id)",
        "series": "the wheel series",
    }
    detail = " + ".join(f"{names.get(k, k)} {fmt_bytes(v)}" for k, v in parts.items())
    return (
        f"--memory {fmt_bytes(budget)}: out-of-core needs at least about "
        f"{fmt_bytes(sum(parts.values()))} for soil.n = {sc.soil.n} ({detail})"
    )


__all__ = [
    "ByteModel",
    "BYTE_MODELS",
    "byte_model",
    "choose_decomposition",
    "estimate_peak",
    "fmt_bytes",
    "hop",
    "parse_memory",
    "slab_fraction",
    "smallest_fit_message",
    "state_peak",
]
