"""MPI mode: ranks own serial DDM's sub-domains (slabs along x).

Serial DDM (live.py) keeps every sub-domain with its halo in RAM; a sweep is (1) every
halo copy refreshed from its owner's time-n copy, (2) ownership from x, (3) every
sub-domain K steps with THE per-domain step. Here rank r holds the ``LiveDomains`` of
its own sub-domains only (``rank_domains``: contiguous ranges cut by disc count, or a
scattered share-out when one sub-domain is too large for the cut to balance), plus
*ghost* sub-domains: each run of x between and beyond them that other ranks own. A
ghost is never advanced; its rows are the copies of the discs the other ranks own
within a strip (halo + membership skin) of this rank's intervals, and they are what
halo rows of the rank's own sub-domains are refreshed from. So the refresh of copies
whose owner is on another rank becomes, once per block, an exchange with the ranks
within that strip (the neighbours): one round in which every rank posts its sends of
one float64 buffer of disc rows (``row_words``: the id and the moving fields) and
receives each partner's at its probed size, written into the ghost rows by compiled
kernels. A disc that crosses into another rank's sub-domain is in that rank's ghost
already (it was within the strip), so migration needs nothing more: after the refresh
the new owner has its time-n state and ownership from x hands it over, contact
history included.

Why the bits equal serial DDM's (and so the monolithic run's): each sub-domain's local
set is exactly the one serial DDM builds (every disc within halo + membership skin of
its slab), every halo row holds its owner's time-n state before the step, and the step
is the same; memory order and extra discs never change a result (docs/design.md §3).
Everything that decides the schedule - re-decompositions (the wheel leaving its slab),
the wheel's slab, rebuilds of the local sets (a disc moved beyond the membership skin
anywhere) - is computed identically on every rank from data every rank has (the
bounds, the wheel state and the largest move, both from the block's ``Allreduce``), so
the ranks never disagree about what comes next.

The wheel lives on the rank that owns its slab. One ``Allreduce`` (MAX) ends each
block: every rank's largest disc move since the local sets were built, and the wheel's
state and the block's wheel records from the wheel's rank (-inf from the others). The
halo refresh from the owners' rows and the ownership update run inside the compiled
sweep. Re-decompositions use the serial rule on
the x histogram of every disc (``decomposition.XHistogram``, an ``Allreduce`` of its
integer counts) and share the sub-domains out again by disc count. A rebuild sends every
rank the discs within its strip (``alltoall`` of pickled parts: first cut, only
neighbours get non-empty ones).

Driving: rank 0 runs the ordinary ``Simulation`` (store, metrics, trajectory, outputs)
with an ``MpiEngine``; every engine call broadcasts a command that the other ranks'
``worker_loop`` runs collectively. Checkpoints: rank 0 gathers the owned discs of each
sub-domain (one epoch in rank 0's RAM: first cut) and commits the epoch through the
store exactly as serial DDM does, so any epoch resumes with any number of ranks, or
serially. A failure on any rank aborts the whole job (``MPI_Abort``), never a hang.
"""
from __future__ import annotations

import os
import pickle
import sys
import time

import numpy as np
from numba import njit

from ..model.checkpoint import record_to_particles
from ..model.decomposition import XHistogram, owner, wheel_slab_index, wheel_slab_ok
from ..physics.layout import AX_X, WS_SIZE, WS_X
from ..model.state import Particles, fields
from .interface import write_epoch
from .live import SWEEPS_REBUILD, LiveDomains
from .stepper import N_REC, EngineError, Model
from ..model.checkpoint import open_epoch
from .sweep import OocEngine, slab_bounds

# the environment a launcher gives each process: (world size, rank) variable names
_LAUNCHER_ENV = (("PMI_SIZE", "PMI_RANK"),                                # MPICH hydra, Intel MPI
                 ("OMPI_COMM_WORLD_SIZE", "OMPI_COMM_WORLD_RANK"),        # Open MPI
                 ("MV2_COMM_WORLD_SIZE", "MV2_COMM_WORLD_RANK"))          # MVAPICH
# the state fields a refresh copies (id, r, mass, inertia and mat are fixed per disc)
_MOVING = ("pos", "vel", "spin", "hist_n", "hist_id", "hist_s", "hist_m")


def launched() -> tuple[int, int]:
    """(world size, rank) as the MPI launcher set them, without initialising MPI;
    (1, 0) for a process not started by mpiexec."""
    for size, rank in _LAUNCHER_ENV:
        if size in os.environ:
            try:
                return int(os.environ[size]), int(os.environ.get(rank, "0"))
            except ValueError:
                break
    return 1, 0


def world():
    """MPI.COMM_WORLD (mpi4py initialises MPI on first import; a lone process is a
    one-rank world)."""
    try:
        from mpi4py import MPI
    except ImportError:
        raise EngineError("--mode mpi needs mpi4py and an MPI: pip install 'ooc-dem[mpi]'") from None
    return MPI.COMM_WORLD


def row_words(dim: int, cap: int) -> int:
    """Words (float64) of one disc's row in the exchange buffers: its id and ``_MOVING``
    fields, in that order (``_rows_io``). Integers travel as float64, exact below 2**53."""
    f = fields(dim, cap)
    return sum(int(np.prod(f[k][1], dtype=np.int64)) for k in ("id", *_MOVING))


def _exchange_fields(p: Particles) -> tuple:
    """p's id and ``_MOVING`` fields, in the exchange row's order (``_rows_io``)."""
    return (p.id, *(getattr(p, k) for k in _MOVING))


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
def _unpack_rows(buf, state_rows, ids, pos, vel, spin, hist_n, hist_id, hist_s, hist_m):
    _rows_io(buf, state_rows, ids, pos, vel, spin, hist_n, hist_id, hist_s, hist_m, False)


def _slots_of(uids, ids) -> np.ndarray:
    """The slot (index in the sorted local ids ``uids``) of each received id, -1 for an id
    this rank does not hold."""
    ids = np.asarray(ids).astype(np.int64)
    at = np.minimum(np.searchsorted(uids, ids), max(len(uids) - 1, 0))
    found = uids[at] == ids if len(uids) else np.zeros(len(ids), np.bool_)
    return np.where(found, at, -1).astype(np.int64)


@njit(cache=True)
def _claim_ghosts(slots, ghost_row, owner_row, stamp, tick):
    """The ghost row of each received disc (by its slot, ``_slots_of``; -1: not one of this
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
def _largest_move(rows, x, x_built):
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
    _pack_rows(buf, rows, *_exchange_fields(p))
    return buf[:len(rows)]


def rank_starts(counts: np.ndarray, ranks: int) -> np.ndarray:
    """starts[r]: the first sub-domain of rank r (contiguous ranges, R + 1 entries),
    cut so that each rank owns about as many discs; every rank gets a sub-domain
    while there are enough of them."""
    D = len(counts)
    before = np.concatenate([[0], np.cumsum(counts)])
    total = before[-1]
    starts = [0]
    for r in range(1, ranks):
        # the boundary nearest the ideal cut (the first one past it could leave almost a
        # whole sub-domain too many on the ranks before: bed-1m, D = 8, R = 2 cut 5 | 3)
        target = r * total / ranks
        s = int(np.searchsorted(before, target, "left"))
        if 0 < s <= D and target - before[s - 1] <= before[s] - target:
            s -= 1
        lo, hi = starts[-1] + 1, D - (ranks - r)
        s = min(lo, D) if hi < lo else min(max(s, lo), hi)
        starts.append(s)
    starts.append(D)
    return np.array(starts, np.int64)


# a scattered share-out is taken only when it lowers the busiest rank's discs by more than
# this fraction of a rank's mean: each sub-domain it separates from its neighbours adds an
# exchange partner, and disc counts are only a proxy for a rank's work
SCATTER_GAIN = 0.05


def rank_domains(counts: np.ndarray, ranks: int) -> np.ndarray:
    """owner[d]: the rank of sub-domain d. Contiguous ranges cut by disc count
    (``rank_starts``), unless giving the largest sub-domains first to the least loaded rank
    balances the ranks clearly better (``SCATTER_GAIN``). That happens when one sub-domain
    holds about 1/R of the discs: the paper's wheel slab is half of paper2008's bin, so
    with the wheel mid-bin two contiguous ranges split 71/29 and {wheel slab}, {left,
    right} 49/51. The ranks compute the same owner from the same (reduced) counts."""
    counts = np.asarray(counts, np.int64)
    D = len(counts)
    contiguous = np.repeat(np.arange(ranks, dtype=np.int64), np.diff(rank_starts(counts, ranks)))
    scattered = np.zeros(D, np.int64)
    load = np.zeros(ranks, np.int64)
    for d in sorted(range(D), key=lambda d: (-counts[d], d)):
        r = int(np.argmin(load))   # the first of the least loaded
        scattered[d] = r
        load[r] += counts[d]
    busiest = lambda own: int(np.bincount(own, weights=counts, minlength=ranks).max())
    if busiest(scattered) < busiest(contiguous) - SCATTER_GAIN * counts.sum() / ranks:
        return scattered
    return contiguous


def rank_intervals(owner: np.ndarray, bounds: np.ndarray, r: int) -> np.ndarray:
    """The x intervals [lo, hi) rank r owns (its runs of neighbouring sub-domains, merged),
    shape (k, 2); empty for a rank without sub-domains."""
    out = []
    for d in np.flatnonzero(owner == r):
        if out and out[-1][1] == d:
            out[-1][1] = d + 1
        else:
            out.append([d, d + 1])
    return np.array([[bounds[a], bounds[b]] for a, b in out], np.float64).reshape(-1, 2)


def rank_segments(owner: np.ndarray, bounds: np.ndarray, r: int) -> tuple[np.ndarray, np.ndarray]:
    """Rank r's local decomposition: (segment bounds, the global sub-domain of each segment
    or -1). Its own sub-domains are segments as they are; each run of other ranks'
    sub-domains between them (and beyond them) is one *ghost* segment."""
    lb, glob = [-np.inf], []
    for d in range(len(owner)):
        if owner[d] != r and glob and glob[-1] < 0:
            lb[-1] = bounds[d + 1]   # the ghost before grows
        else:
            glob.append(int(d) if owner[d] == r else -1)
            lb.append(bounds[d + 1])
    return np.array(lb, np.float64), np.array(glob, np.int64)


@njit(cache=True)
def _near_rows(rows, x, intervals, width):
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


class MpiEngine:
    """The sub-domains of this rank (``LiveDomains`` with its ghosts) and the collective
    block step; on rank 0 also the engine interface ``Simulation`` drives."""

    name = "mpi"
    epoch_each_advance = False
    writes_frame_parts = False

    def __init__(self, sc, model: Model, block: int, domains: int, comm, redecompositions=None):
        self.sc = sc
        self.model = model
        self.model_nowheel = model.without_wheel()
        self.K = int(block)
        self.D = int(domains)
        self.comm = comm
        self.rank, self.R = comm.Get_rank(), comm.Get_size()
        # the same geometry as the serial sweep (sweep.SweepEngine)
        hop = 2.0 * sc.soil.r_max + sc.bed.skin
        self.halo = self.K * hop
        w = sc.wheel
        self.reach = max(w.radius, w.lug_tip_radius) + sc.soil.r_max if w.enabled else 0.0
        self.margin_required = self.halo + 2.0 * sc.soil.r_max + self.K * sc.physics.dt * 1.0
        self.membership_skin = hop
        # a rank is sent the discs within `strip` of its range when its sub-domains are
        # built (what their local sets need), and at each block those within `window`
        # (the strip plus the motion a built set tolerates)
        self.strip = self.halo + self.membership_skin
        self.window = self.strip + self.membership_skin
        self.words = row_words(model.dim, model.hist_cap)   # a disc's row in the exchange buffers
        self.ws = np.zeros(WS_SIZE)
        self.bounds = np.array([-np.inf, np.inf])
        self.owner = np.zeros(self.D, np.int64)   # the rank of each sub-domain (rank_domains)
        self.glob = np.zeros(0, np.int64)         # this rank's segments' sub-domains (-1: a ghost)
        self._iv: list[np.ndarray] = []           # each rank's x intervals (rank_intervals)
        self.rank_discs: list[int] = []   # discs owned by each rank at the last share-out
        self.live: LiveDomains | None = None
        self.ghost_row = np.zeros(0, np.int64)
        self.stamp = np.zeros(0, np.int64)
        self._tick = 0
        self.moved = 0.0   # the largest x move of any disc since the local sets were built
        self._fresh = False
        self._pairs = None   # the exchange's (dest, source) pairs for the current ranges
        self.wslab = -1
        self.n = 0
        self.redecompositions = list(redecompositions or ())
        self.store = None   # rank 0: where `commit` writes
        self.preferred_chunk = max(self.K, (2000 // self.K) * self.K)
        self.builds = 0
        self.blocks = 0
        self.halo_rows_sent = 0
        self.messages = 0

    # ------------------------------------------------------------ rank 0: set-up
    @classmethod
    def default_block(cls, sc, domains: int) -> int:
        """Serial DDM's K (the epochs are serial DDM's)."""
        from .sweep import DdmEngine
        return DdmEngine.default_block(sc, domains)

    @classmethod
    def _open(cls, sc, model: Model, block: int, domains: int, store, redecompositions=()) -> "MpiEngine":
        comm = world()
        eng = cls(sc, model, block, domains, comm, redecompositions)
        eng.store = store
        eng._call("init", (sc.to_toml(), model.hist_cap, block, domains))
        return eng

    @classmethod
    def create(cls, sc, model: Model, particles: Particles, wheel_state: np.ndarray, *, domains: int,
               block: int, store=None) -> "MpiEngine":
        """Rank 0 holds the bed; the scenario's policy splits it (as serial DDM at step 0)."""
        eng = cls._open(sc, model, block, domains, store)
        eng._call("start", (None, 0, np.asarray(wheel_state, np.float64)), mine=particles)
        return eng

    @classmethod
    def reopen(cls, sc, model: Model, reader, wheel_state: np.ndarray, engine_attrs: dict, *, store,
               redecompositions=()) -> "MpiEngine":
        """From a committed epoch (any mode's, any rank count): its bounds and K are kept."""
        bounds = np.array([-np.inf, *engine_attrs["bounds"], np.inf])
        eng = cls._open(sc, model, int(engine_attrs["block"]), len(bounds) - 1, store, redecompositions)
        ws = np.asarray(wheel_state, np.float64)
        doms = reader.domains()
        if eng.R == 1 or store.backend == "memory":   # one process holds the store
            parts = [record_to_particles(reader.read_domain(d), model.hist_cap) for d in doms]
            eng._call("start", (bounds, int(reader.step), ws), mine=Particles.concat(parts, model.dim, model.hist_cap))
            return eng
        # every rank reads its share of the groups itself (contiguous, by the manifest's
        # counts; rank 0 has verified the epoch's checksums): no rank holds the whole bed
        split = rank_starts(np.array([reader.domain_len(d) for d in doms], np.int64), eng.R)
        shares = [doms[split[r]:split[r + 1]] for r in range(eng.R)]
        eng._call("start_from_store", (bounds, int(reader.step), ws, str(store.path), shares), reader=reader)
        return eng

    def _call(self, name: str, args: tuple, **local):
        """Rank 0: every rank runs op `name` with `args` (broadcast; `local` stays here)."""
        if self.R > 1:
            send_command(self.comm, (name, args))
        if name == "init":
            return None
        out = getattr(self, "_op_" + name)(*args, **local)
        _WorkerState.idle = True
        return out

    # -------------------------------------------------- rank 0: engine interface
    def advance(self, step0: int, nsteps: int, frame=None) -> np.ndarray:
        return self._call("advance", (int(step0), int(nsteps)))

    @property
    def wheel_state(self) -> np.ndarray:
        return self.ws

    def n_discs(self) -> int:
        return self.n

    def particles(self) -> Particles:
        groups = self._call("gather", ())
        m = self.model
        return Particles.concat([q for q in groups if len(q)], m.dim, m.hist_cap)

    def state_parts(self, names=()):
        yield self.particles()

    def _group(self, q: Particles) -> tuple[dict, dict]:
        """One sub-domain's epoch group: its owned discs in cell order (as serial DDM's groups)."""
        from .sweep import group_record
        return group_record(q, None, self.model.order_cell, self.sc.bin.length)

    def write_domains(self, writer) -> None:
        for d, q in enumerate(self._call("gather", ())):
            writer.write_domain(d, *self._group(q))

    def commit(self, step: int, arrays: dict, attrs: dict, durable: bool = False) -> None:
        """One epoch, as serial DDM's. On disk with several ranks, a two-phase commit: every
        rank writes its own sub-domains' groups into its own part of the epoch (phase 1,
        ``storage.write_part``), rank 0 gathers their checksums and commits the manifest
        that names them all (phase 2); an epoch with a missing part never becomes current.
        A memory store (one process's) gets the groups gathered to rank 0."""
        if self.store is None:
            raise RuntimeError("MPI run without a store to commit to")
        if self.R == 1 or self.store.backend == "memory":
            write_epoch(self.store, step, self.write_domains, arrays, attrs, durable)
            return
        writer = self.store.begin_epoch(step)
        try:
            parts = self._call("write_parts", (str(self.store.path), int(step), writer.basename, bool(durable)),
                               writer=writer)
            failed = [x for x in parts if isinstance(x, str)]
            for part in parts:
                if not isinstance(part, str):
                    writer.add_part(part)   # from here on, an abort removes it too
            if failed:
                from ooc_dem.storage import StoreError
                raise StoreError(failed[0])
            writer.write_globals(arrays, attrs)
            writer.commit(durable=durable)
        except BaseException:
            writer.abort()
            raise

    def info(self) -> dict:
        return {"domains": self.D, "block": self.K, "halo_m": self.halo,
                "bounds": [float(v) for v in self.bounds[1:-1]],
                "redecompositions": len(self.redecompositions),
                "ranks": self.R, "rank_domains": [int(r) for r in self.owner],
                # each rank's owned discs at the last re-cut (the load balance)
                "rank_discs": list(self.rank_discs),
                "local_set_builds": self.builds,
                # rank 0's share of the exchange (a first measure of the halo traffic)
                "rank0_halo_rows_sent": self.halo_rows_sent, "rank0_messages": self.messages}

    # ------------------------------------------------------ collective operations
    def _op_start(self, bounds, step: int, ws, mine: Particles | None = None) -> None:
        m = self.model
        mine = Particles.empty(0, m.dim, m.hist_cap) if mine is None else mine
        self.ws = np.array(ws, np.float64)
        self.n = int(self.comm.allreduce(len(mine)))
        self.bounds = (self._decompose(self._histogram(mine), step) if bounds is None
                       else np.asarray(bounds, np.float64))
        if len(self.bounds) - 1 != self.D:
            raise EngineError(f"MPI: {len(self.bounds) - 1} slab bounds for {self.D} sub-domains")
        self._distribute(mine, recut=True)

    def _op_start_from_store(self, bounds, step: int, ws, path: str, shares, reader=None) -> None:
        """Start from epoch `step` of the store at `path`: this rank reads the groups of
        ``shares[rank]`` (rank 0 through its own `reader`, the others open the store
        read-only), then the discs go where they belong (``_op_start``)."""
        m = self.model
        mine = shares[self.rank]
        store = None
        try:
            if reader is None and mine:
                from ooc_dem.storage import open_store
                from ..model.checkpoint import open_epoch
                store = open_store(path, repair=False)
                reader = open_epoch(store, step, verify=False)
            parts = [record_to_particles(reader.read_domain(d), m.hist_cap) for d in mine]
        finally:
            if store is not None:
                store.close()
        self._op_start(bounds, step, ws, mine=Particles.concat(parts, m.dim, m.hist_cap))

    def _op_advance(self, step0: int, nsteps: int) -> np.ndarray:
        recs = []
        s, end = step0, step0 + nsteps
        while s < end:
            k = min(self.K, end - s)
            recs.append(self._block(s, k))
            s += k
        return np.concatenate(recs) if recs else np.zeros((0, N_REC))

    def _part_number(self) -> int:
        """This rank's part of an epoch: 1 + the ranks before it (rank 0 aside, whose groups
        are in the epoch's main file) that own sub-domains; 0 for rank 0 or no sub-domain."""
        owns = lambda r: bool((self.owner == r).any())
        if self.rank == 0 or not owns(self.rank):
            return 0
        return 1 + sum(1 for r in range(1, self.rank) if owns(r))

    def _op_write_parts(self, path: str, step: int, basename: str, durable: bool, writer=None):
        """Phase 1: this rank's sub-domains (their owned discs) into its part of the epoch
        (rank 0: into ``writer``, the epoch's main file). Rank 0 gets every other rank's
        part (what ``write_part`` returned, or the one-line error it met)."""
        groups = []
        if self.live is not None:
            live = self.live
            for j, d in enumerate(self.glob):
                if d >= 0:
                    groups.append((int(d), *self._group(live.p.take(live.owned_rows(j)))))
        part = None
        if self.rank == 0:
            for d, rec, attrs in groups:
                writer.write_domain(d, rec, attrs)
        elif groups:
            from ooc_dem.storage import StoreError, write_part
            try:
                part = write_part(path, step, basename, self._part_number(), groups, durable)
            except StoreError as e:
                part = f"rank {self.rank}: {e}"
        got = self.comm.gather(part, root=0)
        return None if self.rank != 0 else [x for x in got[1:] if x is not None]

    def _op_gather(self) -> list[Particles]:
        """Rank 0 gets each sub-domain's owned discs (ownership at the start of the last
        sweep, as serial DDM's epoch groups); the others None."""
        mine = {}
        if self.live is not None:
            live = self.live
            for j, d in enumerate(self.glob):
                if d >= 0:
                    mine[int(d)] = live.p.take(live.owned_rows(j))
        got = self.comm.gather(mine, root=0)
        if self.rank != 0:
            return None
        m = self.model
        groups = [Particles.empty(0, m.dim, m.hist_cap) for _ in range(self.D)]
        for part in got:
            for d, q in part.items():
                groups[d] = q
        total = sum(len(q) for q in groups)
        if total != self.n:
            raise EngineError(f"MPI gather found {total} of {self.n} discs: decomposition error")
        return groups

    # ----------------------------------------------------------------- the block
    def _redecomposes(self) -> bool:
        sc = self.sc
        return sc.wheel.enabled and sc.decomposition.policy == "wheel" and self.D > 1

    def _decompose(self, hist: XHistogram, step: int) -> np.ndarray:
        """The serial rule (sweep.slab_bounds) on the histogram of every disc's x."""
        b = slab_bounds(self.sc, hist, self.D, float(self.ws[WS_X]), self.reach, self.margin_required)
        if self.rank == 0:
            self.redecompositions.append({"step": int(step), "bounds": [float(v) for v in b[1:-1]]})
        return b

    def _block(self, step0: int, k: int) -> np.ndarray:
        """One sweep of k <= K steps over every rank's sub-domains (serial DDM's
        ``_sweep_live``, with the refresh across ranks an exchange)."""
        self.blocks += 1
        wheel = self.sc.wheel.enabled
        if self._redecomposes() and not wheel_slab_ok(self.bounds, float(self.ws[WS_X]), self.reach,
                                                      self.margin_required):
            mine = self._mine()
            self.bounds = self._decompose(self._histogram(mine), step0)
            self._distribute(mine, recut=True)
        elif wheel and wheel_slab_index(self.bounds, float(self.ws[WS_X])) != self.wslab:
            self._distribute(self._mine(), recut=True)   # every rebuild re-balances the ranks
        elif self.moved > self.membership_skin:
            # a disc may have come within the halo of a sub-domain whose local set lacks it
            self._distribute(self._mine(), recut=True)   # every rebuild re-balances the ranks
        elif not self._fresh:   # (local sets just built hold every disc's current state)
            self._refresh_ghosts()
        rec = np.zeros((0, N_REC))
        live = self.live
        if live is not None:
            # this rank's sub-domains (not its ghosts): every halo row refreshed from its
            # owner's row and ownership from x (unless the local sets are fresh), then K steps;
            # 2D in one compiled sweep that does both
            if live.compiled:
                r, _, status = live.run_sweeps(step0, 1, k, not self._fresh, -1.0)
                unseen = status == SWEEPS_REBUILD
            else:
                # kernels without a one-thread twin: each sub-domain with its own stepper,
                # after the same refresh and ownership (serial DDM's per-sub-domain sweep)
                unseen = not self._fresh and not live.refresh()
                if not unseen:
                    r, _ = live.advance(step0, k)
            if unseen:   # never: self.moved bounds every local row's move
                raise EngineError(f"MPI rank {self.rank}: a disc moved beyond the membership skin "
                                  f"unseen at step {step0}: exchange error")
            if live.wslab >= 0:
                rec = r
                self.ws = live.steppers[live.wslab].ws.copy()
        self._fresh = False
        return self._end_block(rec, k)

    def _end_block(self, rec: np.ndarray, k: int) -> np.ndarray:
        """One ``Allreduce`` (MAX) after the sweep gives every rank what the next block
        decides on: the largest x move of any disc since the local sets were built (each
        rank's over the discs it owned in the sweep, whose copies the next refresh makes)
        and, with a wheel, the wheel's state and the block's records from the wheel's rank
        (every other rank gives -inf there, so the maximum is that rank's values, bit for
        bit). Returns the records."""
        from mpi4py import MPI
        wheel = self.sc.wheel.enabled
        buf = np.full(1 + (WS_SIZE + 1 + k * N_REC if wheel else 0), -np.inf)
        live = self.live
        if live is not None:
            buf[0] = _largest_move(live.owned_active_rows(), live.p.pos[:, AX_X], live.x_built)
            if wheel and live.wslab >= 0:
                buf[1:1 + WS_SIZE] = self.ws
                buf[1 + WS_SIZE] = len(rec)
                buf[2 + WS_SIZE:2 + WS_SIZE + rec.size] = rec.ravel()
        if self.R > 1:
            self.comm.Allreduce(MPI.IN_PLACE, buf, op=MPI.MAX)
            self.messages += 1
        self.moved = float(buf[0])
        if not wheel:
            return rec
        self.ws = buf[1:1 + WS_SIZE].copy()
        rows = int(buf[1 + WS_SIZE])
        return buf[2 + WS_SIZE:2 + WS_SIZE + rows * N_REC].reshape(rows, N_REC).copy()

    # ------------------------------------------------------ ownership and exchange
    def _intervals(self, r: int) -> np.ndarray:
        """Rank r's x intervals (fixed between share-outs: ``_distribute`` computes them)."""
        return self._iv[r]

    def _partners(self, width: float) -> list[tuple[int, int]]:
        """(dest, source) pairs of the exchange, in an order every rank walks alike: at
        offset o, send to rank + o and receive from rank - o, then the mirror; a pair
        exchanges when both have sub-domains and one interval of each are within `width`."""
        from mpi4py import MPI
        iv = [self._intervals(r) for r in range(self.R)]
        near = lambda a, b: (0 <= a < self.R and 0 <= b < self.R
                             and any(max(jb[0] - ja[1], ja[0] - jb[1]) < width for ja in iv[a] for jb in iv[b]))
        far = max([abs(a - b) for a in range(self.R) for b in range(self.R) if a != b and near(a, b)],
                  default=0)
        out = []
        for o in range(1, far + 1):
            for sgn in (1, -1):
                dest, src = self.rank + sgn * o, self.rank - sgn * o
                out.append((dest if near(self.rank, dest) else MPI.PROC_NULL,
                            src if near(src, self.rank) else MPI.PROC_NULL))
        return out

    def _exchange(self, sends: list[np.ndarray]) -> list[np.ndarray]:
        """One round for all partners: sends[i] (whole disc rows) goes to self._pairs[i]'s
        dest, and what its source sent comes back (empty for MPI.PROC_NULL). Every send is
        posted first, then each message is received at its probed size (no count message),
        so a block costs one latency, not two per partner."""
        from mpi4py import MPI
        reqs = []
        for (dest, _), send in zip(self._pairs, sends):
            if dest != MPI.PROC_NULL:
                reqs.append(self.comm.Isend([send, MPI.DOUBLE], dest=dest, tag=12))
                self.messages += 1
                self.halo_rows_sent += len(send)
        got = []
        status = MPI.Status()
        for i, (_, source) in enumerate(self._pairs):
            if source == MPI.PROC_NULL:
                got.append(self._recv[i][:0])
                continue
            self.comm.Probe(source=source, tag=12, status=status)
            n = status.Get_count(MPI.DOUBLE) // self.words
            self._recv[i] = room(self._recv[i], n)
            self.comm.Recv([self._recv[i], n * self.words, MPI.DOUBLE], source=source, tag=12)
            got.append(self._recv[i][:n])
        MPI.Request.Waitall(reqs)
        return got

    def _mine(self) -> Particles:
        m = self.model
        if self.live is None:
            return Particles.empty(0, m.dim, m.hist_cap)
        return self.live.p.take(self.live.owned_active_rows())

    def _sum(self, counts: np.ndarray) -> np.ndarray:
        """Element-wise sum of an int64 array over the ranks (exact: any order)."""
        from mpi4py import MPI
        out = np.zeros_like(counts)
        self.comm.Allreduce(np.ascontiguousarray(counts), out, op=MPI.SUM)
        return out

    def _histogram(self, mine: Particles) -> XHistogram:
        """The x histogram of every rank's discs (the serial policies' input; integer
        counts, so the sum is the serial one whatever the split)."""
        h = XHistogram.of(mine.pos[:, AX_X], self.sc.bin.length)
        h.counts = self._sum(h.counts)
        return h

    def _distribute(self, mine: Particles, recut: bool = False) -> None:
        """(Re)build every rank's sub-domains from the discs the ranks own now; `recut`:
        the ranks' ranges are cut again by disc count first."""
        m = self.model
        x = mine.pos[:, AX_X]
        if recut:
            counts = self._sum(np.bincount(owner(self.bounds, x), minlength=self.D).astype(np.int64))
            self.owner = rank_domains(counts, self.R)
            self.rank_discs = [int(counts[self.owner == r].sum()) for r in range(self.R)]
        self._iv = [rank_intervals(self.owner, self.bounds, r) for r in range(self.R)]
        every = np.arange(len(mine), dtype=np.int64)
        sends = [mine.take(_near_rows(every, x, self._intervals(q), self.strip)) for q in range(self.R)]
        got = self.comm.alltoall(sends) if self.R > 1 else sends
        local = Particles.concat([g for g in got if len(g)], m.dim, m.hist_cap)
        self.wslab = wheel_slab_index(self.bounds, float(self.ws[WS_X])) if self.sc.wheel.enabled else -1
        self.live = None
        self._pairs = None
        self.moved = 0.0
        self._fresh = True   # the next sweep starts from the states just shared out
        self.glob = np.zeros(0, np.int64)
        if (self.owner == self.rank).any():
            lb, self.glob = rank_segments(self.owner, self.bounds, self.rank)
            at = np.flatnonzero(self.glob == self.wslab) if self.wslab >= 0 else []
            wl = int(at[0]) if len(at) else -1
            real = self.glob >= 0   # the ghosts: copies of the other ranks' discs
            self.live = LiveDomains(local, lb, self.halo, self.membership_skin, self.model,
                                    self.model_nowheel, self.ws, wl, active=real,
                                    whole_refresh=False)
            live = self.live
            ghosts = np.concatenate([np.arange(live.off[j], live.off[j + 1]) for j in np.flatnonzero(~real)]
                                    or [np.zeros(0, np.int64)])
            self.ghost_rows = ghosts
            self.ghost_row = np.full(len(live.owner_row), -1, np.int64)   # by live.slot
            self.ghost_row[live.slot[ghosts]] = ghosts
            self.stamp = np.zeros(len(live.p), np.int64)   # the refresh (tick) that last wrote a ghost row
        owned = len(self.live.owned_active_rows()) if self.live is not None else 0
        total = int(self.comm.allreduce(owned))
        if total != self.n:
            raise EngineError(f"MPI ranks own {total} of {self.n} discs (bounds {self.bounds.tolist()}): "
                              f"decomposition error")
        self.builds += 1

    def _refresh_ghosts(self) -> None:
        """Ghost rows <- the owners' time-n rows (the exchange); the rebuild decision was
        taken before, over all ranks, from the last block's largest move. The sweep that
        follows refreshes the halo rows of this rank's sub-domains from their owners' rows
        and takes ownership from x (``live._run_sweeps``' refresh_first)."""
        live = self.live
        if self._pairs is None:   # fixed between rebuilds (bounds and ranges unchanged)
            self._pairs = self._partners(self.window)
            self._send = [np.empty((0, self.words)) for _ in self._pairs]
            self._recv = [np.empty((0, self.words)) for _ in self._pairs]
        self._tick += 1
        if live is not None:
            p = live.p
            owned_rows = live.owned_active_rows()
            sends = []
            for i, (dest, _) in enumerate(self._pairs):
                rows = (_near_rows(owned_rows, p.pos[:, AX_X], self._intervals(dest), self.window)
                        if dest >= 0 else np.zeros(0, np.int64))
                self._send[i] = room(self._send[i], len(rows))
                sends.append(pack(p, rows, self._send[i]))
        else:
            sends = [b[:0] for b in self._send]
        for recv in self._exchange(sends):
            if live is not None and len(recv):
                rows = _claim_ghosts(_slots_of(live.uids, recv[:, 0]), self.ghost_row, live.owner_row,
                                     self.stamp, self._tick)
                _unpack_rows(recv, rows, *_exchange_fields(live.p))
        if live is None:
            return
        # every disc a ghost owned must have come from its owner (else a halo row is stale)
        ghost_owned = self.ghost_rows[live.owned[self.ghost_rows]]
        missing = self.stamp[ghost_owned] != self._tick
        if missing.any():
            raise EngineError(f"MPI rank {self.rank}: {int(missing.sum())} halo discs were not sent by "
                              f"their owners (bounds {self.bounds.tolist()}): exchange error")


def broadcast_wheel(comm, root: int, ws: np.ndarray, rec: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Rank `root`'s wheel state and its (at most k) wheel records, on every rank: one
    ``Bcast`` of one buffer."""
    buf = np.zeros(WS_SIZE + 1 + k * N_REC)
    if comm.Get_rank() == root:
        buf[:WS_SIZE] = ws
        buf[WS_SIZE] = len(rec)
        buf[WS_SIZE + 1:WS_SIZE + 1 + rec.size] = rec.ravel()
    if comm.Get_size() > 1:
        comm.Bcast(buf, root=root)
    rows = int(buf[WS_SIZE])
    return buf[:WS_SIZE].copy(), buf[WS_SIZE + 1:WS_SIZE + 1 + rows * N_REC].reshape(rows, N_REC).copy()


class _WorkerState:
    """Rank 0's knowledge of where the other ranks are: waiting for a command (none sent
    yet, or the last op returned on rank 0, so theirs did too), or inside one, where a
    collective may wait for rank 0."""
    idle = True


def send_command(comm, command) -> None:
    """Rank 0 -> every rank: its length (a non-blocking broadcast, which the others poll
    with sleeps), then the pickled command."""
    from mpi4py import MPI
    _WorkerState.idle = command[0] == "stop"
    data = bytearray(pickle.dumps(command))
    comm.Ibcast(np.array([len(data)], np.int64), root=0).Wait()
    comm.Bcast([data, MPI.BYTE], root=0)


def receive_command(comm):
    """The other ranks: wait for rank 0's next command without spinning. Between
    commands rank 0 alone works (commits, outputs); a busy-waiting MPI would take the
    cores from it when ranks share them."""
    from mpi4py import MPI
    n = np.zeros(1, np.int64)
    req = comm.Ibcast(n, root=0)
    while not req.Test():
        time.sleep(0.002)
    data = bytearray(int(n[0]))
    comm.Bcast([data, MPI.BYTE], root=0)
    return pickle.loads(data)


def worker_loop(comm) -> None:
    """Ranks other than 0: run rank 0's commands until it says stop."""
    from ..model.scenario import scenario_from_toml
    eng = None
    while True:
        name, args = receive_command(comm)
        if name == "stop":
            return
        if name == "init":
            toml, hist_cap, block, domains = args
            sc = scenario_from_toml(toml)
            model = Model.from_scenario(sc)
            model.hist_cap = hist_cap
            eng = MpiEngine(sc, model, block, domains, comm)
            continue
        if name == "init_ooc":
            toml, hist_cap, block, bounds, fixed, path = args
            sc = scenario_from_toml(toml)
            model = Model.from_scenario(sc)
            model.hist_cap = hist_cap
            eng = MpiOocEngine(sc, model, np.zeros(WS_SIZE), block, np.array(bounds), comm=comm, path=path)
            eng.fixed = fixed
            continue
        getattr(eng, "_op_" + name)(*args)


def run_everywhere(comm, command) -> int:
    """Every rank runs ``command()`` (its share of a job such as the sweep's runs); an
    uncaught exception anywhere aborts every rank instead of leaving the others waiting."""
    try:
        rc = command()
    except BaseException:
        import traceback
        traceback.print_exc()
        sys.stderr.flush()
        comm.Abort(1)
        raise
    sys.stdout.flush()
    sys.stderr.flush()
    return rc


def run_ranks(command) -> int:
    """A `run` or `resume` under mpiexec with python -m mpi4py semantics: rank 0 runs
    `command()` (the ordinary command, which drives the engine), the others serve it;
    an exception anywhere aborts every rank. A non-zero exit of rank 0 (an error already
    said in one line) stops the waiting ranks and ends the job with that exit code; only
    if they are inside an op (a collective may wait for rank 0) is the job aborted."""
    comm = world()
    if comm.Get_rank() != 0:
        run_everywhere(comm, lambda: worker_loop(comm))
        return 0
    rc = run_everywhere(comm, command)
    if rc and not _WorkerState.idle:
        # MPI_Abort ends the job at once, so the launcher may not forward what rank 0 has
        # just written (the one-line error went missing under load): only when it must.
        # The error is said (one line, flushed); MPI's own abort notice would be a second
        sys.stdout.flush()
        sys.stderr.flush()
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, 2)
        comm.Abort(int(rc))
    send_command(comm, ("stop", ()))
    return rc


# ============================================================== out-of-core ranks

class MpiOocEngine(OocEngine):
    """Out-of-core on MPI ranks (``--mode mpi-ooc``): every rank streams its own range of
    slabs, one slab and its halo at a time, from the committed epoch in a store all ranks
    see (a shared file system), and writes their groups into its own part of the next
    epoch (``storage.write_part``); rank 0 commits it (two-phase, as ``MpiEngine``). The
    halos need no message: a slab's halo is read from its neighbours' groups of epoch e
    (Jacobi), wherever they lie. So the epochs, the bits and the memory per rank are the
    serial out-of-core run's, and a bed none of the machines could hold runs on them.

    The slabs are shared out again at every sweep, contiguous and by disc count (the x
    histogram of the groups' stored summaries, computed alike on every rank). The rank of
    the wheel's slab broadcasts the wheel's state and the sweep's wheel records."""

    name = "mpi-ooc"
    writes_frame_parts = False   # frames stream the committed epoch's groups on rank 0

    def __init__(self, sc, model: Model, wheel_state: np.ndarray, block: int, bounds, *, store=None,
                 io_overlap: bool = False, redecompositions=(), comm=None, path=None):
        super().__init__(sc, model, wheel_state, block, bounds, store=store, io_overlap=io_overlap,
                         redecompositions=redecompositions)
        self.comm = comm if comm is not None else world()
        self.rank, self.R = self.comm.Get_rank(), self.comm.Get_size()
        self.path = str(path if path is not None else store.path)
        self._ro_store = None        # ranks > 0: the store opened read-only
        self.starts = np.zeros(self.R + 1, np.int64)
        self._epoch_hist = None      # (step, x histogram) of the epoch the sweeps read

    def _call(self, name: str, args: tuple, **local):
        if self.R > 1:
            send_command(self.comm, (name, args))
        out = getattr(self, "_op_" + name)(*args, **local)
        _WorkerState.idle = True
        return out

    def _announce(self) -> None:
        """Rank 0: the other ranks make their engine like this one (same geometry)."""
        if self.R > 1:
            send_command(self.comm, ("init_ooc", (self.sc.to_toml(), self.model.hist_cap, self.K,
                                                  [float(v) for v in self.bounds], self.fixed, self.path)))

    @classmethod
    def reopen(cls, sc, model: Model, reader, wheel_state: np.ndarray, engine_attrs: dict, *,
               store, io_overlap: bool = False, redecompositions=()) -> "MpiOocEngine":
        eng = super().reopen(sc, model, reader, wheel_state, engine_attrs, store=store, io_overlap=io_overlap,
                             redecompositions=redecompositions)
        eng._announce()
        return eng

    def commit(self, step: int, arrays: dict, attrs: dict, durable: bool = False) -> None:
        first = self.committed_step is None
        super().commit(step, arrays, attrs, durable)
        if first:   # the initial epoch (written by rank 0 alone) is in: the ranks join
            self._announce()

    def sweep(self, step0: int, k: int, frame=None) -> np.ndarray:
        """Rank 0: every rank sweeps its slabs of the committed epoch into the next one
        (left open for ``commit``; frames are written from the committed epoch)."""
        writer = self._begin_epoch(step0 + k)
        try:
            return self._call("sweep_ranks", (int(step0), int(k), int(self.committed_step), writer.basename,
                                              self.ws.copy()))
        except BaseException:
            if self._writer is not None:
                self._writer.abort()
                self._writer = None
            raise

    def _source(self):
        return self._store_reader

    def _open_source(self, step: int) -> None:
        """Ranks > 0: the committed epoch `step`, read-only (rank 0 verified it)."""
        from ooc_dem.storage import open_store
        if self._store_reader is not None:
            if self._store_reader.step == step:
                return
            self._store_reader.close()
        if self._ro_store is not None:   # reopened to see the epochs rank 0 committed since
            self._ro_store.close()
        self._ro_store = open_store(self.path, repair=False)
        self._store_reader = open_epoch(self._ro_store, step, verify=False)

    def _x_histogram(self):
        # built once per source epoch: a sweep's re-decomposition (``_wheel_check``) and
        # its share-out both need it, and each build reads every group's attrs
        step = self._source().step
        if self._epoch_hist is None or self._epoch_hist[0] != step:
            self._epoch_hist = (step, super()._x_histogram())
        return self._epoch_hist[1]

    def _share_out(self) -> np.ndarray:
        """starts[r]: the first slab of rank r, contiguous ranges of about equal disc counts
        (from the epoch's x histogram: the same on every rank; the outer bounds are
        infinite, which ``below`` counts as 0 and n)."""
        hist = self._x_histogram()
        return rank_starts(np.diff([hist.below(float(b)) for b in self.bounds]), self.R)

    def _op_sweep_ranks(self, step0: int, k: int, epoch_step: int, basename: str, ws) -> np.ndarray | None:
        if self.rank != 0:
            self._open_source(epoch_step)
            self.ws = np.asarray(ws, np.float64).copy()
        self._step = step0
        wslab = self._wheel_check()
        src = self._source()
        self.starts = self._share_out()
        lo_d, hi_d = int(self.starts[self.rank]), int(self.starts[self.rank + 1])
        done = {"owned": 0, "resident": [], "rec": np.zeros((0, N_REC)), "ws": None}

        def groups():
            for d in range(lo_d, hi_d):
                local, owned, rec, new_ws = self._advance_slab(src, d, step0, k, wslab)
                done["owned"] += len(owned)
                done["resident"].append(len(local))
                if d == wslab:
                    done["rec"], done["ws"] = rec, new_ws
                yield (d, *self._owned_group(local, owned))
                del local

        part, failure = None, None
        if self.rank == 0:
            for d, rec, attrs in groups():
                self._writer.write_domain(d, rec, attrs)
        elif hi_d > lo_d:
            from ooc_dem.storage import StoreError, write_part
            owners = [r for r in range(1, self.R) if self.starts[r + 1] > self.starts[r]]
            try:
                part = write_part(self.path, step0 + k, basename, owners.index(self.rank) + 1, groups())
            except StoreError as e:
                failure = f"rank {self.rank}: {e}"
        got = self.comm.gather((part, failure, done["owned"], done["resident"]), root=0) if self.R > 1 \
            else [(part, failure, done["owned"], done["resident"])]
        rec_wheel = self._share_sweep_wheel(wslab, done, k)
        if self.rank != 0:
            return None
        for p, _f, _o, _r in got:
            if p is not None:
                self._writer.add_part(p)
        failed = [f for _p, f, _o, _r in got if f]
        if failed:
            from ooc_dem.storage import StoreError
            raise StoreError(failed[0])
        owned_total = sum(o for _p, _f, o, _r in got)
        if self._n is not None and owned_total != self._n:
            raise EngineError(f"sweep at step {step0} kept {owned_total} of {self._n} discs "
                              f"(bounds {self.bounds.tolist()}): decomposition error")
        self._note_resident([x for _p, _f, _o, r in got for x in r])
        return rec_wheel

    def _share_sweep_wheel(self, wslab: int, done: dict, k: int) -> np.ndarray:
        """The wheel's rank broadcasts its new state and the sweep's wheel records."""
        if wslab < 0:
            return np.zeros((0, N_REC))
        root = int(np.searchsorted(self.starts, wslab, "right") - 1)
        ws = done["ws"] if self.rank == root else self.ws
        self.ws, rec = broadcast_wheel(self.comm, root, ws, done["rec"], k)
        return rec

    def info(self) -> dict:
        return {**super().info(), "ranks": self.R, "rank_starts": [int(s) for s in self.starts]}
