"""``MpiOocEngine`` (``--mode mpi-ooc``): out-of-core with each rank streaming its own slabs."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Callable, ClassVar, Self

import numpy as np

from ...model.checkpoint import open_epoch
from ...physics.layout import WS_SIZE
from ..stepper import N_REC, EngineError, Model
from ..ooc import OocEngine
from .comm import announce, broadcast_wheel, collective, world
from .shares import rank_starts

if TYPE_CHECKING:
    from ...model.decomposition import XHistogram
    from ooc_dem.storage.store import Store


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
    writes_frame_parts = False  # frames stream the committed epoch's groups on rank 0

    def __init__(
        self,
        sc,
        model: Model,
        wheel_state: np.ndarray,
        block: int,
        bounds,
        *,
        store=None,
        io_overlap: bool = False,
        redecompositions=(),
        comm=None,
        path=None,
    ):
        super().__init__(
            sc, model, wheel_state, block, bounds, store=store, io_overlap=io_overlap, redecompositions=redecompositions
        )
        self.comm = comm if comm is not None else world()
        self.rank, self.R = self.comm.Get_rank(), self.comm.Get_size()
        self.path = str(path if path is not None else store.path)
        self._ro_store: Store | None = None  # ranks > 0: the store opened read-only
        self.starts = np.zeros(self.R + 1, np.int64)
        self._epoch_hist: tuple[int, XHistogram] | None = None  # (step, x histogram) of the epoch the sweeps read

    def _announce(self) -> None:
        """Rank 0: the other ranks make their engine like this one (same geometry)."""
        announce(
            self,
            (self.sc.to_toml(), self.model.hist_cap, self.K, [float(v) for v in self.bounds], self.fixed, self.path),
        )

    @classmethod
    def on_worker(cls, comm, toml: str, hist_cap: int, block: int, bounds, fixed: bool, path: str) -> "MpiOocEngine":
        """A rank other than 0: the engine rank 0 announced (``_announce``), serving its
        operations."""
        from ...model.scenario import scenario_from_toml

        sc = scenario_from_toml(toml)
        model = Model.from_scenario(sc)
        model.hist_cap = hist_cap
        eng = cls(sc, model, np.zeros(WS_SIZE), block, np.array(bounds), comm=comm, path=path)
        eng.fixed = fixed
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
        eng = super().reopen(
            sc,
            model,
            reader,
            wheel_state,
            engine_attrs,
            store=store,
            io_overlap=io_overlap,
            redecompositions=redecompositions,
        )
        eng._announce()
        return eng

    def commit(self, step: int, arrays: dict, attrs: dict, durable: bool = False) -> None:
        first = self.committed_step is None
        super().commit(step, arrays, attrs, durable)
        if first:  # the initial epoch (written by rank 0 alone) is in: the ranks join
            self._announce()

    def sweep(self, step0: int, k: int, frame=None) -> np.ndarray:
        """Rank 0: every rank sweeps its slabs of the committed epoch into the next one
        (left open for ``commit``; frames are written from the committed epoch)."""
        writer = self._begin_epoch(step0 + k)
        # the initial epoch is committed when the engine is made: a sweep reads the last one
        assert self.committed_step is not None, "a sweep before the initial epoch's commit"
        try:
            return collective(
                self, "sweep_ranks", (int(step0), int(k), int(self.committed_step), writer.basename, self.ws.copy())
            )
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
        if self._ro_store is not None:  # reopened to see the epochs rank 0 committed since
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
        done: dict[str, Any] = {"owned": 0, "resident": [], "rec": np.zeros((0, N_REC)), "ws": None}

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
                self._write_group(d, rec, attrs)
        elif hi_d > lo_d:
            from ooc_dem.storage import StoreError, write_part

            owners = [r for r in range(1, self.R) if self.starts[r + 1] > self.starts[r]]
            try:
                part = write_part(self.path, step0 + k, basename, owners.index(self.rank) + 1, groups())
            except StoreError as e:
                failure = f"rank {self.rank}: {e}"
        got = (
            self.comm.gather((part, failure, done["owned"], done["resident"]), root=0)
            if self.R > 1
            else [(part, failure, done["owned"], done["resident"])]
        )
        rec_wheel = self._share_sweep_wheel(wslab, done, k)
        if self.rank != 0:
            return None
        writer = self._writer
        assert writer is not None, "rank 0 opened the epoch (sweep) before the ranks swept"
        for p, _f, _o, _r in got:
            if p is not None:
                writer.add_part(p)
        failed = [f for _p, f, _o, _r in got if f]
        if failed:
            from ooc_dem.storage import StoreError

            raise StoreError(failed[0])
        owned_total = sum(o for _p, _f, o, _r in got)
        if self._n is not None and owned_total != self._n:
            raise EngineError(
                f"sweep at step {step0} kept {owned_total} of {self._n} discs "
                f"(bounds {self.bounds.tolist()}): decomposition error"
            )
        self._note_resident([x for _p, _f, _o, r in got for x in r])
        return rec_wheel

    #: the collective operations by the name rank 0 sends (``comm.collective``)
    OPS: ClassVar[dict[str, Callable[..., Any]]] = {"sweep_ranks": _op_sweep_ranks}

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
