"""``MpiEngine`` (``--mode mpi``): serial DDM's sub-domains owned by the ranks, the halo
refresh across ranks an exchange of disc rows once per block (see the package's docstring)."""

from __future__ import annotations

from typing import Any, Callable, ClassVar

import numpy as np

from ...model.checkpoint import record_to_particles
from ...model.decomposition import XHistogram, owner, wheel_slab_index, wheel_slab_ok
from ...model.state import Particles
from ...physics.layout import AX_X, WS_SIZE, WS_X
from ..interface import write_epoch
from ..live import LiveDomains
from ..live_kernels import SWEEPS_REBUILD
from ..stepper import N_REC, EngineError, Model
from ..sweep import slab_bounds
from .comm import announce, collective, world
from .rows import claim_ghosts, exchange_fields, largest_move, near_rows, pack, room, row_words, slots_of, unpack_rows
from .shares import rank_domains, rank_intervals, rank_segments, rank_starts


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
        self.words = row_words(model.dim, model.hist_cap)  # a disc's row in the exchange buffers
        self.ws = np.zeros(WS_SIZE)
        self.bounds = np.array([-np.inf, np.inf])
        self.owner = np.zeros(self.D, np.int64)  # the rank of each sub-domain (rank_domains)
        self.glob = np.zeros(0, np.int64)  # this rank's segments' sub-domains (-1: a ghost)
        self._iv: list[np.ndarray] = []  # each rank's x intervals (rank_intervals)
        self.rank_discs: list[int] = []  # discs owned by each rank at the last share-out
        self.live: LiveDomains | None = None
        self.ghost_row = np.zeros(0, np.int64)
        self.stamp = np.zeros(0, np.int64)
        self._tick = 0
        self.moved = 0.0  # the largest x move of any disc since the local sets were built
        self._fresh = False
        self._pairs: list[tuple[int, int]] | None = None  # the exchange's (dest, source) pairs for the current ranges
        self.wslab = -1
        self.n = 0
        self.redecompositions = list(redecompositions or ())
        self.store = None  # rank 0: where `commit` writes
        self.preferred_chunk = max(self.K, (2000 // self.K) * self.K)
        self.builds = 0
        self.blocks = 0
        self.halo_rows_sent = 0
        self.messages = 0

    # ------------------------------------------------------------ rank 0: set-up
    @classmethod
    def default_block(cls, sc, domains: int) -> int:
        """Serial DDM's K (the epochs are serial DDM's)."""
        from ..sweep import DdmEngine

        return DdmEngine.default_block(sc, domains)

    @classmethod
    def _open(cls, sc, model: Model, block: int, domains: int, store, redecompositions=()) -> "MpiEngine":
        comm = world()
        eng = cls(sc, model, block, domains, comm, redecompositions)
        eng.store = store
        announce(eng, (sc.to_toml(), model.hist_cap, block, domains))
        return eng

    @classmethod
    def on_worker(cls, comm, toml: str, hist_cap: int, block: int, domains: int) -> "MpiEngine":
        """A rank other than 0: the engine rank 0 announced (``_open``), serving its operations."""
        from ...model.scenario import scenario_from_toml

        sc = scenario_from_toml(toml)
        model = Model.from_scenario(sc)
        model.hist_cap = hist_cap
        return cls(sc, model, block, domains, comm)

    @classmethod
    def create(
        cls, sc, model: Model, particles: Particles, wheel_state: np.ndarray, *, domains: int, block: int, store=None
    ) -> "MpiEngine":
        """Rank 0 holds the bed; the scenario's policy splits it (as serial DDM at step 0)."""
        eng = cls._open(sc, model, block, domains, store)
        collective(eng, "start", (None, 0, np.asarray(wheel_state, np.float64)), mine=particles)
        return eng

    @classmethod
    def reopen(
        cls, sc, model: Model, reader, wheel_state: np.ndarray, engine_attrs: dict, *, store, redecompositions=()
    ) -> "MpiEngine":
        """From a committed epoch (any mode's, any rank count): its bounds and K are kept."""
        bounds = np.array([-np.inf, *engine_attrs["bounds"], np.inf])
        eng = cls._open(sc, model, int(engine_attrs["block"]), len(bounds) - 1, store, redecompositions)
        ws = np.asarray(wheel_state, np.float64)
        doms = reader.domains()
        if eng.R == 1 or store.backend == "memory":  # one process holds the store
            parts = [record_to_particles(reader.read_domain(d), model.hist_cap) for d in doms]
            collective(
                eng, "start", (bounds, int(reader.step), ws), mine=Particles.concat(parts, model.dim, model.hist_cap)
            )
            return eng
        # every rank reads its share of the groups itself (contiguous, by the manifest's
        # counts; rank 0 has verified the epoch's checksums): no rank holds the whole bed
        split = rank_starts(np.array([reader.domain_len(d) for d in doms], np.int64), eng.R)
        shares = [doms[split[r] : split[r + 1]] for r in range(eng.R)]
        collective(eng, "start_from_store", (bounds, int(reader.step), ws, str(store.path), shares), reader=reader)
        return eng

    # -------------------------------------------------- rank 0: engine interface
    def advance(self, step0: int, nsteps: int, frame=None) -> np.ndarray:
        return collective(self, "advance", (int(step0), int(nsteps)))

    @property
    def wheel_state(self) -> np.ndarray:
        return self.ws

    def n_discs(self) -> int:
        return self.n

    def particles(self) -> Particles:
        groups = collective(self, "gather", ())
        m = self.model
        return Particles.concat([q for q in groups if len(q)], m.dim, m.hist_cap)

    def state_parts(self, names=()):
        yield self.particles()

    def _group(self, q: Particles) -> tuple[dict, dict]:
        """One sub-domain's epoch group: its owned discs in cell order (as serial DDM's groups)."""
        from ..sweep import group_record

        return group_record(q, None, self.model.order_cell, self.sc.bin.length)

    def write_domains(self, writer) -> None:
        for d, q in enumerate(collective(self, "gather", ())):
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
            parts = collective(
                self, "write_parts", (str(self.store.path), int(step), writer.basename, bool(durable)), writer=writer
            )
            failed = [x for x in parts if isinstance(x, str)]
            for part in parts:
                if not isinstance(part, str):
                    writer.add_part(part)  # from here on, an abort removes it too
            if failed:
                from ooc_dem.storage import StoreError

                raise StoreError(failed[0])
            writer.write_globals(arrays, attrs)
            writer.commit(durable=durable)
        except BaseException:
            writer.abort()
            raise

    def info(self) -> dict:
        return {
            "domains": self.D,
            "block": self.K,
            "halo_m": self.halo,
            "bounds": [float(v) for v in self.bounds[1:-1]],
            "redecompositions": len(self.redecompositions),
            "ranks": self.R,
            "rank_domains": [int(r) for r in self.owner],
            # each rank's owned discs at the last re-cut (the load balance)
            "rank_discs": list(self.rank_discs),
            "local_set_builds": self.builds,
            # rank 0's share of the exchange (a first measure of the halo traffic)
            "rank0_halo_rows_sent": self.halo_rows_sent,
            "rank0_messages": self.messages,
        }

    # ------------------------------------------------------ collective operations
    def _op_start(self, bounds, step: int, ws, mine: Particles | None = None) -> None:
        m = self.model
        mine = Particles.empty(0, m.dim, m.hist_cap) if mine is None else mine
        self.ws = np.array(ws, np.float64)
        self.n = int(self.comm.allreduce(len(mine)))
        self.bounds = self._decompose(self._histogram(mine), step) if bounds is None else np.asarray(bounds, np.float64)
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
                from ...model.checkpoint import open_epoch

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
        part: dict[str, Any] | str | None = None  # what write_part returned, or its error
        if self.rank == 0:
            for domain, rec, attrs in groups:
                writer.write_domain(domain, rec, attrs)
        elif groups:
            from ooc_dem.storage import StoreError, write_part

            try:
                part = write_part(path, step, basename, self._part_number(), groups, durable)
            except StoreError as e:
                part = f"rank {self.rank}: {e}"
        got = self.comm.gather(part, root=0)
        return None if self.rank != 0 else [x for x in got[1:] if x is not None]

    def _op_gather(self) -> list[Particles] | None:
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

    #: the collective operations by the name rank 0 sends (``comm.collective``)
    OPS: ClassVar[dict[str, Callable[..., Any]]] = {
        "start": _op_start,
        "start_from_store": _op_start_from_store,
        "advance": _op_advance,
        "write_parts": _op_write_parts,
        "gather": _op_gather,
    }

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
        if self._redecomposes() and not wheel_slab_ok(
            self.bounds, float(self.ws[WS_X]), self.reach, self.margin_required
        ):
            mine = self._mine()
            self.bounds = self._decompose(self._histogram(mine), step0)
            self._distribute(mine, recut=True)
        elif wheel and wheel_slab_index(self.bounds, float(self.ws[WS_X])) != self.wslab:
            self._distribute(self._mine(), recut=True)  # every rebuild re-balances the ranks
        elif self.moved > self.membership_skin:
            # a disc may have come within the halo of a sub-domain whose local set lacks it
            self._distribute(self._mine(), recut=True)  # every rebuild re-balances the ranks
        elif not self._fresh:  # (local sets just built hold every disc's current state)
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
            if unseen:  # never: self.moved bounds every local row's move
                raise EngineError(
                    f"MPI rank {self.rank}: a disc moved beyond the membership skin "
                    f"unseen at step {step0}: exchange error"
                )
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
            buf[0] = largest_move(live.owned_active_rows(), live.p.pos[:, AX_X], live.x_built)
            if wheel and live.wslab >= 0:
                buf[1 : 1 + WS_SIZE] = self.ws
                buf[1 + WS_SIZE] = len(rec)
                buf[2 + WS_SIZE : 2 + WS_SIZE + rec.size] = rec.ravel()
        if self.R > 1:
            self.comm.Allreduce(MPI.IN_PLACE, buf, op=MPI.MAX)
            self.messages += 1
        self.moved = float(buf[0])
        if not wheel:
            return rec
        self.ws = buf[1 : 1 + WS_SIZE].copy()
        rows = int(buf[1 + WS_SIZE])
        return buf[2 + WS_SIZE : 2 + WS_SIZE + rows * N_REC].reshape(rows, N_REC).copy()

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
        near = lambda a, b: (
            0 <= a < self.R
            and 0 <= b < self.R
            and any(max(jb[0] - ja[1], ja[0] - jb[1]) < width for ja in iv[a] for jb in iv[b])
        )
        far = max([abs(a - b) for a in range(self.R) for b in range(self.R) if a != b and near(a, b)], default=0)
        out = []
        for o in range(1, far + 1):
            for sgn in (1, -1):
                dest, src = self.rank + sgn * o, self.rank - sgn * o
                out.append(
                    (dest if near(self.rank, dest) else MPI.PROC_NULL, src if near(src, self.rank) else MPI.PROC_NULL)
                )
        return out

    def _exchange(self, sends: list[np.ndarray]) -> list[np.ndarray]:
        """One round for all partners: sends[i] (whole disc rows) goes to self._pairs[i]'s
        dest, and what its source sent comes back (empty for MPI.PROC_NULL). Every send is
        posted first, then each message is received at its probed size (no count message),
        so a block costs one latency, not two per partner."""
        from mpi4py import MPI

        pairs = self._pairs
        assert pairs is not None, "the pairs are chosen before the first exchange (_refresh_ghosts)"
        reqs = []
        for (dest, _), send in zip(pairs, sends):
            if dest != MPI.PROC_NULL:
                reqs.append(self.comm.Isend([send, MPI.DOUBLE], dest=dest, tag=12))
                self.messages += 1
                self.halo_rows_sent += len(send)
        got = []
        status = MPI.Status()
        for i, (_, source) in enumerate(pairs):
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
        sends = [mine.take(near_rows(every, x, self._intervals(q), self.strip)) for q in range(self.R)]
        got = self.comm.alltoall(sends) if self.R > 1 else sends
        local = Particles.concat([g for g in got if len(g)], m.dim, m.hist_cap)
        self.wslab = wheel_slab_index(self.bounds, float(self.ws[WS_X])) if self.sc.wheel.enabled else -1
        self.live = None
        self._pairs = None
        self.moved = 0.0
        self._fresh = True  # the next sweep starts from the states just shared out
        self.glob = np.zeros(0, np.int64)
        if (self.owner == self.rank).any():
            lb, self.glob = rank_segments(self.owner, self.bounds, self.rank)
            at = np.flatnonzero(self.glob == self.wslab) if self.wslab >= 0 else np.zeros(0, np.intp)
            wl = int(at[0]) if len(at) else -1
            real = self.glob >= 0  # the ghosts: copies of the other ranks' discs
            self.live = LiveDomains(
                local,
                lb,
                self.halo,
                self.membership_skin,
                self.model,
                self.model_nowheel,
                self.ws,
                wl,
                active=real,
                whole_refresh=False,
            )
            live = self.live
            ghosts = np.concatenate(
                [np.arange(live.off[j], live.off[j + 1]) for j in np.flatnonzero(~real)] or [np.zeros(0, np.int64)]
            )
            self.ghost_rows = ghosts
            self.ghost_row = np.full(len(live.owner_row), -1, np.int64)  # by live.slot
            self.ghost_row[live.slot[ghosts]] = ghosts
            self.stamp = np.zeros(len(live.p), np.int64)  # the refresh (tick) that last wrote a ghost row
        owned = len(self.live.owned_active_rows()) if self.live is not None else 0
        total = int(self.comm.allreduce(owned))
        if total != self.n:
            raise EngineError(
                f"MPI ranks own {total} of {self.n} discs (bounds {self.bounds.tolist()}): decomposition error"
            )
        self.builds += 1

    def _refresh_ghosts(self) -> None:
        """Ghost rows <- the owners' time-n rows (the exchange); the rebuild decision was
        taken before, over all ranks, from the last block's largest move. The sweep that
        follows refreshes the halo rows of this rank's sub-domains from their owners' rows
        and takes ownership from x (``live_kernels._run_sweeps``' refresh_first)."""
        live = self.live
        pairs = self._pairs
        if pairs is None:  # fixed between rebuilds (bounds and ranges unchanged)
            pairs = self._pairs = self._partners(self.window)
            self._send = [np.empty((0, self.words)) for _ in pairs]
            self._recv = [np.empty((0, self.words)) for _ in pairs]
        self._tick += 1
        if live is not None:
            p = live.p
            owned_rows = live.owned_active_rows()
            sends = []
            for i, (dest, _) in enumerate(pairs):
                rows = (
                    near_rows(owned_rows, p.pos[:, AX_X], self._intervals(dest), self.window)
                    if dest >= 0
                    else np.zeros(0, np.int64)
                )
                self._send[i] = room(self._send[i], len(rows))
                sends.append(pack(p, rows, self._send[i]))
        else:
            sends = [b[:0] for b in self._send]
        for recv in self._exchange(sends):
            if live is not None and len(recv):
                rows = claim_ghosts(
                    slots_of(live.uids, recv[:, 0]), self.ghost_row, live.owner_row, self.stamp, self._tick
                )
                unpack_rows(recv, rows, *exchange_fields(live.p))
        if live is None:
            return
        # every disc a ghost owned must have come from its owner (else a halo row is stale)
        ghost_owned = self.ghost_rows[live.owned[self.ghost_rows]]
        missing = self.stamp[ghost_owned] != self._tick
        if missing.any():
            raise EngineError(
                f"MPI rank {self.rank}: {int(missing.sum())} halo discs were not sent by "
                f"their owners (bounds {self.bounds.tolist()}): exchange error"
            )
