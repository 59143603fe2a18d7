"""Out-of-core (``OocEngine``): the sweep (``sweep.SlabSweep``) over epochs in a store, one
slab and its halo in RAM at a time; the epochs are the store's, written a sweep at a time."""

from __future__ import annotations

from typing import TYPE_CHECKING, Iterable, Self

import numpy as np

from ..model.checkpoint import open_epoch, particles_to_record, record_to_particles, records_to_particles
from ..model.decomposition import XHistogram, owner
from ..model.state import Particles
from ..physics.layout import AX_X
from .stepper import N_REC, DomainStepper, EngineError, Model
from . import sweep
from .sweep import SlabSweep, auto_block, group_of, group_record, read_strip

if TYPE_CHECKING:
    from ..storage.epoch import EpochWriter


class OocEngine(SlabSweep):
    """Out-of-core: each sweep reads the committed epoch slab by slab from the store and
    writes the next one; only one slab and its halo are ever resident.

    One ``advance`` is one sweep (``preferred_chunk`` = K): it leaves the epoch it wrote
    open and returns the sweep's wheel records; the run loop folds them and commits the
    epoch (``commit``, with its globals) before the next sweep reads it. A trajectory
    frame due at the sweep's end gets each slab's owned discs (``advance``'s ``frame``)
    as the sweep passes them."""

    name = "ooc"
    epoch_each_advance = True
    writes_frame_parts = True

    def __init__(
        self,
        sc,
        model: Model,
        wheel_state: np.ndarray,
        block: int,
        bounds,
        *,
        store,
        io_overlap: bool = False,
        redecompositions=(),
    ):
        super().__init__(sc, model, wheel_state, block, bounds, redecompositions)
        self.store = store
        self.preferred_chunk = self.K  # one sweep an advance: the next reads its epoch
        self._writer: EpochWriter | None = None  # the epoch being written
        self._store_reader = None  # the current committed epoch
        self.committed_step: int | None = None
        # read ahead and write behind in threads (``_slabs``)
        self.io_overlap = bool(io_overlap)
        self._pairs_per_disc = 0.0  # candidate pairs per resident disc of the last slab

    @classmethod
    def default_block(cls, sc, domains: int) -> int:
        """K without --block: chosen from the geometry (``auto_block``), at least the
        scenario's."""
        return max(sc.decomposition.block, auto_block(sc, domains, sc.bin.length))

    @classmethod
    def create(
        cls,
        sc,
        model: Model,
        particles: Particles,
        wheel_state: np.ndarray,
        *,
        domains: int,
        block: int,
        store,
        io_overlap: bool = False,
        bounds=None,
    ) -> Self:
        """Split the discs into `domains` slabs by the scenario's policy (or at `bounds`)
        and write them as the store's first epoch (committed by the first ``commit``)."""
        eng = cls(sc, model, wheel_state, block, [-np.inf, np.inf], store=store, io_overlap=io_overlap)
        eng._writer = store.begin_epoch(0)
        eng._populate(particles, domains, bounds)
        return eng

    @classmethod
    def create_streamed(
        cls,
        sc,
        model: Model,
        parts: Iterable[Particles],
        wheel_state: np.ndarray,
        *,
        domains: int,
        block: int,
        store,
        io_overlap: bool = False,
    ) -> Self:
        """Start from a bed produced in x-ordered parts (``parts``, iterated twice: each
        pass produces them again), never holding the whole bed: pass 1 counts the discs in
        x bins (for the bounds), pass 2 writes each sub-domain's group as soon as no later
        part can add to it."""
        eng = cls(sc, model, wheel_state, block, [-np.inf, np.inf], store=store, io_overlap=io_overlap)
        eng.D = domains
        hist = XHistogram(sc.bin.length)
        for part in parts:
            hist.add_x(part.pos[:, AX_X])
        eng._n = hist.n
        eng.bounds = eng.decompose(hist, step=0)
        eng._writer = store.begin_epoch(0)
        pending: dict[int, list] = {d: [] for d in range(eng.D)}
        written = set()

        def flush(upto: float):
            for d in range(eng.D):
                if d not in written and eng.bounds[d + 1] <= upto:
                    eng._stage(d, *group_of(Particles.concat(pending.pop(d)), None, model.order_cell))
                    written.add(d)

        for part in parts:
            flush(float(part.pos[:, AX_X].min()))
            g = owner(eng.bounds, part.pos[:, AX_X])
            for d in np.unique(g):
                if int(d) in written:
                    raise RuntimeError("bed parts are not in x order")
                pending[int(d)].append(part.take(np.flatnonzero(g == d)))
        flush(np.inf)
        return eng

    @classmethod
    def reopen(
        cls,
        sc,
        model: Model,
        reader,
        wheel_state: np.ndarray,
        engine_attrs: dict,
        *,
        store,
        io_overlap: bool = False,
        redecompositions=(),
    ) -> Self:
        """Continue from the committed epoch `reader` reads (its step is the engine's)."""
        K, bounds = cls._stored_geometry(engine_attrs)
        eng = cls(
            sc, model, wheel_state, K, bounds, store=store, io_overlap=io_overlap, redecompositions=redecompositions
        )
        eng._store_reader = open_epoch(store, reader.step)
        eng.committed_step = int(reader.step)
        eng._n = sum(reader.domain_len(d) for d in reader.domains())
        return eng

    def _stage(self, d, q: Particles, attrs):
        self._write_group(d, particles_to_record(q), self._summarised(q, attrs))

    def _write_group(self, d: int, rec: dict, attrs: dict) -> None:
        """Write group d (a store record and its attrs) into the epoch being written."""
        if self._writer is None:
            raise RuntimeError("out-of-core sweep without an open epoch writer")
        self._writer.write_domain(d, rec, attrs)

    def _source(self):
        return self._store_reader

    def commit(self, step: int, arrays: dict, attrs: dict, durable: bool = False) -> None:
        """Finish the epoch the last sweep (or the set-up) wrote: its globals, then the
        manifest commit."""
        writer, self._writer = self._writer, None
        if writer is None:
            raise RuntimeError(f"out-of-core commit of step {step} without an epoch being written")
        try:
            writer.write_globals(arrays, attrs)
            writer.commit(durable=durable)
        except BaseException:
            writer.abort()
            raise
        self.committed_step = step
        if self._store_reader is not None:
            self._store_reader.close()
        self._store_reader = open_epoch(self.store)

    def advance(self, step0: int, nsteps: int, frame=None) -> np.ndarray:
        """One sweep of nsteps steps (1 to K: the halo is sized for K); its epoch is left
        open for ``commit``."""
        if not 1 <= nsteps <= self.K:
            raise ValueError(
                f"out-of-core advance of {nsteps} steps: one sweep is 1 to K = {self.K} "
                f"steps (its epoch is committed before the next sweep reads it)"
            )
        return self.sweep(step0, nsteps, frame)

    def _begin_epoch(self, step: int):
        """The writer of epoch ``step``, once the previous one is committed (a sweep reads it)."""
        if self._writer is not None:
            raise RuntimeError(f"out-of-core sweep to step {step} before the last epoch was committed")
        self._writer = self.store.begin_epoch(step)
        return self._writer

    def sweep(self, step0: int, k: int, frame=None) -> np.ndarray:
        """Advance every slab k <= K steps: each slab rebuilt from epoch e, advanced, its
        owned discs written to e+1 (and to ``frame``, if given); e+1 stays open."""
        self._step = step0
        wslab = self._wheel_check()
        src = self._source()
        self._begin_epoch(step0 + k)
        try:
            return self._sweep_domains(src, step0, k, wslab, frame)
        except BaseException:
            if self._writer is not None:
                self._writer.abort()
                self._writer = None
            raise

    def _read_slab(self, src, d: int) -> Particles:
        """Slab d's discs and its halo from epoch ``src``: the strips of its groups, in x
        order, read as records and filled into one state. The strips are cell-ordered
        (group_order), so the slab is already in the kernels' cache-friendly order: no
        spatial re-sort."""
        lo, hi = self.bounds[d], self.bounds[d + 1]
        pieces = [q for g in src.domains() if (q := read_strip(src, g, lo - self.halo, hi + self.halo)) is not None]
        return records_to_particles(pieces, self.model.hist_cap, self.model.dim)

    def _advance_slab(self, src, d: int, step0: int, k: int, wslab: int, local=None):
        """Slab d of the sweep: its discs and halo (``local``, else read from epoch ``src``),
        advanced k steps; (the advanced local set, the rows of its owned discs, the wheel
        records, the wheel state after (the slab of the wheel only, else None))."""
        lo, hi = self.bounds[d], self.bounds[d + 1]
        if local is None:
            local = self._read_slab(src, d)
        # the list sized from the last slab's pairs per disc: one neighbour build, not two
        hint = int(self._pairs_per_disc * len(local))
        if d == wslab:
            st = DomainStepper(local, self.model, self.ws, reorder=False, pairs_hint=hint)
        else:
            st = DomainStepper(local, self.model_nowheel, None, reorder=False, pairs_hint=hint)
        owned = np.flatnonzero((st.p.pos[:, AX_X] >= lo) & (st.p.pos[:, AX_X] < hi))
        cone = sweep.cone_spans(st.p.pos[:, AX_X], lo, hi, self.hop, k)
        rec = st.advance(step0, k, cone) if len(local) else np.zeros((0, N_REC))
        if len(local):
            self._pairs_per_disc = st.pairs / len(local)
        return st.p, owned, rec, (st.ws.copy() if d == wslab else None)

    def _owned_group(self, local: Particles, owned: np.ndarray) -> tuple[dict, dict]:
        """A slab's owned discs (rows `owned` of its advanced local set) as an epoch group
        (``group_record``)."""
        return group_record(local, owned, self.model.order_cell, self.sc.bin.length)

    def _stage_owned(self, d: int, local: Particles, owned: np.ndarray) -> dict:
        """Write slab d's owned discs as group d of the epoch being written; returns the
        group's record."""
        rec, attrs = self._owned_group(local, owned)
        self._write_group(d, rec, attrs)
        return rec

    def _slabs(self, src, step0: int, k: int, wslab: int, stage):
        """Every slab in turn (``_advance_slab``), each result passed to ``stage(d, local,
        owned)``; yields (d, owned count, rec, ws, resident). With ``io_overlap`` the reads
        of slab d + 1 and the staging (gather and write) of slab d - 1 run in two threads
        while slab d computes (the kernel releases the GIL): the same slabs, read and
        written in the same order, so the same bits; up to three slabs are resident
        instead of one."""
        if not self.io_overlap:
            for d in range(self.D):
                local, owned, rec, ws = self._advance_slab(src, d, step0, k, wslab)
                stage(d, local, owned)
                yield d, len(owned), rec, ws, len(local)
            return
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(1, "ooc-read") as reads, ThreadPoolExecutor(1, "ooc-write") as writes:
            ahead = reads.submit(self._read_slab, src, 0)
            written = None
            for d in range(self.D):
                local = ahead.result()
                if d + 1 < self.D:
                    ahead = reads.submit(self._read_slab, src, d + 1)
                local, owned, rec, ws = self._advance_slab(src, d, step0, k, wslab, local)
                if written is not None:
                    written.result()  # one write in flight: memory stays three slabs
                written = writes.submit(stage, d, local, owned)
                yield d, len(owned), rec, ws, len(local)
                del local
            if written is not None:
                written.result()

    def _sweep_domains(self, src, step0: int, k: int, wslab: int, frame=None) -> np.ndarray:
        rec_wheel = np.zeros((0, N_REC))
        new_ws = self.ws
        resident = []
        owned_total = 0

        def stage(d, local, owned):
            group = self._stage_owned(d, local, owned)
            if frame is not None:  # a frame due at the sweep's end: each slab's part as it passes
                frame.write_part(group)

        for d, n_owned, rec, ws, n_local in self._slabs(src, step0, k, wslab, stage):
            resident.append(n_local)
            if d == wslab:
                rec_wheel, new_ws = rec, ws
            owned_total += n_owned
        if self._n is not None and owned_total != self._n:
            raise EngineError(
                f"sweep at step {step0} kept {owned_total} of {self._n} discs "
                f"(bounds {self.bounds.tolist()}): decomposition error"
            )
        self.ws = new_ws
        self._note_resident(resident)
        return rec_wheel

    def particles(self) -> Particles:
        src = self._source()
        m = self.model
        return Particles.concat(
            [record_to_particles(src.read_domain(d), m.hist_cap) for d in src.domains()], m.dim, m.hist_cap
        )

    def state_parts(self, names=()):
        """Each group of the committed epoch in turn (never the whole bed)."""
        src = self._source()
        for d in src.domains():
            yield src.read_domain(d, list(names))
