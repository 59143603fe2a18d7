"""The sweep: serial domain decomposition over epochs, as two engines.

A sweep reads epoch e and writes epoch e+1 (Jacobi: every sub-domain sees its
neighbours' time-n state). Every slab advances its owned discs plus a halo K
contact-hops wide K steps with THE per-domain step (``DomainStepper``), and only the
owned discs are kept. Ownership is by position: a disc belongs to the slab holding its
x at the start of the sweep, so migration needs no bookkeeping, and its contact
history travels with it.

``OocEngine`` (out-of-core, ``ooc.py``) runs the sweep over an HDF5 or zarr store: for
each slab in turn it loads the slab and its halo from epoch e, advances them, writes the
owned discs into epoch e+1 and drops everything; every sweep writes an epoch. ``DdmEngine``
(serial DDM) runs the same sweep over epochs held in RAM, with its sub-domains kept
alive between sweeps (``live.LiveDomains``: same bits, no per-sweep rebuilding), and
copies its state into the store only when the run commits. ``SlabSweep`` holds what the
two share: the slabs, the block K and halo, the wheel's slab and re-decomposition.
"""

from __future__ import annotations

import numpy as np

from ..model.checkpoint import particles_to_record, record_rows, record_to_particles
from ..model.decomposition import (
    XHistogram,
    equal_bounds,
    group_order,
    owner,
    summary_ok,
    wheel_bounds,
    wheel_slab_index,
    wheel_slab_ok,
    x_summary,
)
from ..physics.layout import AX_X, WS_X
from ..model.state import DISC_FIELDS, HIST_FIELDS
from ..model.state import Particles
from .interface import write_epoch
from .live import LiveDomains
from .live_kernels import SWEEPS_REBUILD, sweeps_kernel
from .stepper import N_REC, Model


class RamEpochs:
    """Serial DDM's epoch in RAM: per-domain disc sets in cell order (groups), with their attrs.

    Between sweeps the live sub-domains (live.py) hold the newest states; this view is
    made from them only when a commit, a re-decomposition or a rebuild needs it. The
    discs stay ``Particles``; the store-record view is made only for commits."""

    def __init__(self, hist_cap: int | None = None):
        self.current: dict[int, tuple[Particles, dict]] = {}
        self.hist_cap = hist_cap  # the model's: records are read into states of this capacity

    # reader side
    def domains(self):
        return sorted(self.current)

    def domain_attrs(self, d):
        return self.current[d][1]

    def domain_len(self, d) -> int:
        return len(self.current[d][0])

    def domain_particles(self, d) -> Particles:
        return self.current[d][0]

    def read_domain(self, d, names=None, rows=None):
        rec = particles_to_record(self.current[d][0])
        names = names or list(rec)
        if rows is None:
            return {k: rec[k] for k in names}
        return {k: rec[k][rows] for k in names}

    # writer side
    def write_particles(self, d, p: Particles, attrs):
        self.current[d] = (p, attrs)

    def write_domain(self, d, arrays, attrs):
        self.current[d] = (record_to_particles(arrays, self.hist_cap), attrs)


def read_strip(src, d, lo: float, hi: float) -> dict | None:
    """The store record of group d's discs with lo <= x < hi. Groups are written in cell
    order (``group_order``: x sorted up to one cell column), so these rows lie in one short
    candidate range: after the last row whose running maximum of x is below lo, before the
    first whose running minimum of the rest is at or above hi. The range is read and
    filtered exactly, so any row order is read correctly (x-sorted groups of older stores
    give the exact slice)."""
    # the count the store checked against the group's arrays, not an attribute (an edited
    # attribute would drop the group's discs)
    n = src.domain_len(d)
    attrs = src.domain_attrs(d)
    if n == 0 or attrs["xmax"] < lo or attrs["xmin"] >= hi:
        return None
    x = src.read_domain(d, ["pos"])["pos"][:, AX_X]
    a = int(np.searchsorted(np.maximum.accumulate(x), lo, "left"))
    b = int(np.searchsorted(np.minimum.accumulate(x[::-1])[::-1], hi, "left"))
    if b <= a:
        return None
    inside = (x[a:b] >= lo) & (x[a:b] < hi)
    del x
    if not inside.any():
        return None
    if a == 0 and b == n:
        rec = src.read_domain(d)
    else:
        # scalar arrays by row; the CSR history by the matching entry range
        hn = src.read_domain(d, ["hist_n"])["hist_n"]
        start, stop = int(hn[:a].sum(dtype=np.int64)), int(hn[:b].sum(dtype=np.int64))
        del hn
        rec = src.read_domain(d, list(DISC_FIELDS), slice(a, b))
        rec.update(src.read_domain(d, list(HIST_FIELDS), slice(start, stop)))
    return rec if inside.all() else record_rows(rec, np.flatnonzero(inside))


def x_histogram(src, length: float) -> XHistogram:
    """The discs' x histogram of an epoch (a store reader or RamEpochs) from its groups'
    stored x summaries; a group without a valid one (a store written before groups kept x summaries, DDM's
    groups in RAM) is counted from its x, one group at a time. Never one value per disc of
    the whole bed, and the same counts (so bounds) whichever way the discs are grouped."""
    hist = XHistogram(length)
    for d in src.domains():
        attrs = src.domain_attrs(d)
        s = attrs.get("x_summary")
        if summary_ok(s, length, attrs.get("n")):
            hist.add_summary(s)
        elif isinstance(src, RamEpochs):
            hist.add_x(src.domain_particles(d).pos[:, AX_X])
        else:
            hist.add_x(src.read_domain(d, ["pos"])["pos"][:, AX_X])
    return hist


def slab_bounds(sc, hist: XHistogram, domains: int, wheel_x: float, reach: float, margin_required: float) -> np.ndarray:
    """The D + 1 slab bounds of the scenario's policy from the discs' x histogram: around
    the wheel (its reach plus the margins inside one slab) or equal counts. Every engine
    that decomposes (serial DDM, out-of-core, MPI) takes its bounds from here."""
    if sc.wheel.enabled and sc.decomposition.policy == "wheel":
        half = reach + margin_required + sc.decomposition.margin
        return wheel_bounds(hist, domains, wheel_x, half)
    return equal_bounds(hist, domains)


def group_rows(p: Particles, rows, cell: float) -> np.ndarray:
    """Rows `rows` of p (all if None) in a group's cell order (``group_order`` with cells
    of side `cell`)."""
    rows = np.arange(len(p)) if rows is None else np.asarray(rows)
    return rows[group_order(p.pos[rows], cell)]


def group_attrs(x: np.ndarray) -> dict:
    """A group's count and x extent, from its discs' x."""
    return {"n": len(x), "xmin": float(x.min()) if len(x) else 0.0, "xmax": float(x.max()) if len(x) else 0.0}


def group_record(p: Particles, rows, cell: float, length: float) -> tuple[dict, dict]:
    """A domain group as the store writes it: discs `rows` of p (all if None) gathered in
    cell order straight into a store record, and its attrs (count, x extent, x summary
    over a bin of `length`)."""
    rec = particles_to_record(p, group_rows(p, rows, cell))
    x = rec["pos"][:, AX_X]
    return rec, {**group_attrs(x), "x_summary": x_summary(x, length)}


def group_of(p: Particles, rows, cell: float) -> tuple[Particles, dict]:
    """A domain group: discs `rows` of p (all if None) in cell order (``group_rows``), with
    its x extent. One gather, whatever `rows` is."""
    q = p.take(group_rows(p, rows, cell))
    return q, group_attrs(q.pos[:, AX_X])


def auto_block(sc, domains: int, length: float) -> int:
    """K for out-of-core: the largest block whose halo (2 K hop / slab width) stays at or
    below 10 % of a slab (its redundant work, with the light cone, about half that), capped
    at 200 steps; at least 1."""
    hop = 2.0 * sc.soil.r_max + sc.bed.skin
    width = length / max(1, domains)
    return int(max(1, min(200, (0.05 * width) // hop)))


def cone_spans(x: np.ndarray, lo: float, hi: float, hop: float, k: int) -> np.ndarray:
    """The light cone of slab [lo, hi) over a block of k steps: (k, 2) index ranges
    [first, end) of the discs step s (0-based) advances (``DomainStepper.advance``).

    A disc's state reaches at most one contact hop further per step (the halo's own
    premise), so for the owned discs to be exact after k steps, step s needs exact only
    the discs within k - s - 1 hops of the slab, and for them the rows of their partners
    one hop further out: it advances the discs within k - s hops (x from the start of the
    block). Those farther out are left as they are: nothing they hold can reach the
    owned discs any more. The slab's halo work halves. The discs come in x-column order
    (group_order), so each range is tight; in any other order the smallest range holding
    them is a superset, so the owned discs are still exact."""
    spans = np.zeros((k, 2), np.int64)
    n = len(x)
    if n == 0 or k <= 0:
        return spans
    dist = np.maximum(np.maximum(lo - x, x - hi), 0.0)
    hops = np.minimum(np.ceil(dist / hop), k + 1).astype(np.int64)  # 0: inside the slab
    rows = np.arange(n, dtype=np.int64)
    first = np.full(k + 2, n, np.int64)
    last = np.full(k + 2, -1, np.int64)
    np.minimum.at(first, hops, rows)
    np.maximum.at(last, hops, rows)
    # the rows of discs within m hops: from the least first to the greatest last of hops <= m
    first = np.minimum.accumulate(first)
    last = np.maximum.accumulate(last)
    reach = k - np.arange(k)  # step s advances the discs within k - s hops
    spans[:, 0] = first[reach]
    spans[:, 1] = np.maximum(last[reach] + 1, first[reach])
    return spans


class SlabSweep:
    """What serial DDM and out-of-core share: D slabs (bounds), K steps per sweep, the
    halo, the wheel's slab and the re-decomposition when the wheel nears its slab's edge,
    the resident counts. A subclass says where the epochs live (``_stage``, ``_source``,
    ``_x_histogram``) and how a sweep runs."""

    name = ""
    epoch_each_advance = False
    writes_frame_parts = False

    def __init__(self, sc, model: Model, wheel_state: np.ndarray, block: int, bounds, redecompositions=()):
        self.sc = sc
        self.model = model
        self.model_nowheel = model.without_wheel()
        self.K = block
        self.bounds = np.asarray(bounds, np.float64)
        self.D = len(self.bounds) - 1
        self.ws = np.asarray(wheel_state, np.float64).copy()
        self.fixed = False  # True: bounds given by the caller, never redefined
        self.redecompositions = list(redecompositions)
        self.resident_max = 0
        self.resident_last: list[int] = []
        self.resident_first: list[int] | None = None
        self._n: int | None = None
        self._step = 0
        # a contact hop: at most 2 r_max plus the motion the skin allows
        self.hop = 2.0 * sc.soil.r_max + sc.bed.skin
        # halo: K contact hops
        self.halo = self.K * self.hop
        w = sc.wheel
        self.reach = max(w.radius, w.lug_tip_radius) + sc.soil.r_max if w.enabled else 0.0
        # no owned disc of another slab may feel the wheel within a block
        self.margin_required = self.halo + 2.0 * sc.soil.r_max + self.K * sc.physics.dt * 1.0
        self.preferred_chunk = max(self.K, (2000 // self.K) * self.K)

    # ---------------------------------------------------------------- setup
    def _populate(self, particles: Particles, domains: int, bounds=None) -> None:
        """Split the discs into slabs (by the scenario's policy, or the given bounds) and
        stage each slab's group."""
        if bounds is None:
            self.D = domains
            self.bounds = self.decompose(XHistogram.of(particles.pos[:, AX_X], self.sc.bin.length), step=0)
        else:
            self.bounds = np.asarray(bounds, np.float64)
            self.D = len(self.bounds) - 1
            self.fixed = True
        groups = owner(self.bounds, particles.pos[:, AX_X])
        for d in range(self.D):
            self._stage(d, *group_of(particles, np.flatnonzero(groups == d), self.model.order_cell))
        self._n = len(particles)

    def _stage(self, d: int, q: Particles, attrs: dict) -> None:
        """Put group d of the epoch being made."""
        raise NotImplementedError

    def _source(self):
        """The epoch the next sweep reads (a RamEpochs or a store's EpochReader)."""
        raise NotImplementedError

    def _x_histogram(self) -> XHistogram:
        """The x histogram of the epoch the next sweep reads (for a re-decomposition)."""
        return x_histogram(self._source(), self.sc.bin.length)

    def _summarised(self, q: Particles, attrs: dict) -> dict:
        """A group's attrs with its x summary, so that a re-decomposition reads no disc
        (see x_histogram)."""
        return {**attrs, "x_summary": x_summary(q.pos[:, AX_X], self.sc.bin.length)}

    def _bounds_changed(self) -> None:
        """Called when a re-decomposition has moved the bounds."""

    def decompose(self, hist: XHistogram, step: int) -> np.ndarray:
        b = slab_bounds(self.sc, hist, self.D, float(self.ws[WS_X]), self.reach, self.margin_required)
        self.redecompositions.append({"step": int(step), "bounds": [float(v) for v in b[1:-1]]})
        return b

    # -------------------------------------------------------------- the sweep
    def _wheel_check(self):
        """Before a sweep: re-decompose when the wheel's reach plus the margin leaves its
        slab; the wheel's slab (-1 without a wheel)."""
        if self._redecomposes():
            if not wheel_slab_ok(self.bounds, float(self.ws[WS_X]), self.reach, self.margin_required):
                self.bounds = self.decompose(self._x_histogram(), self._step)
                self._bounds_changed()
        return wheel_slab_index(self.bounds, float(self.ws[WS_X])) if self.sc.wheel.enabled else -1

    def _redecomposes(self) -> bool:
        sc = self.sc
        return sc.wheel.enabled and sc.decomposition.policy == "wheel" and self.D > 1 and not self.fixed

    def _note_resident(self, resident: list[int]) -> None:
        self.resident_last = resident
        if self.resident_first is None:
            self.resident_first = list(resident)
        self.resident_max = max(self.resident_max, max(resident) if resident else 0)

    # ------------------------------------------------------------ interface
    @property
    def wheel_state(self):
        return self.ws

    def n_discs(self) -> int:
        src = self._source()
        return sum(src.domain_len(d) for d in src.domains())

    def write_domains(self, writer) -> None:
        src = self._source()
        for d in src.domains():
            writer.write_domain(d, src.read_domain(d), src.domain_attrs(d))

    def info(self) -> dict:
        return {
            "domains": self.D,
            "block": self.K,
            "halo_m": self.halo,
            "resident_max": self.resident_max,
            "resident_last_sweep": self.resident_last,
            "bounds": [float(v) for v in self.bounds[1:-1]],
            "redecompositions": len(self.redecompositions),
        }

    @staticmethod
    def _stored_geometry(engine_attrs: dict) -> tuple[int, np.ndarray]:
        """(K, bounds) of a committed epoch's engine attrs (checked by the caller)."""
        return (int(engine_attrs["block"]), np.array([-np.inf, *engine_attrs["bounds"], np.inf]))


class DdmEngine(SlabSweep):
    """Serial DDM: the slabs live in RAM between sweeps (``live.LiveDomains``); a commit
    copies them into the store."""

    name = "ddm"

    def __init__(self, sc, model: Model, wheel_state: np.ndarray, block: int, bounds, store=None, redecompositions=()):
        super().__init__(sc, model, wheel_state, block, bounds, redecompositions)
        self.store = store  # where `commit` writes (None: a sweep without commits)
        self.epoch = RamEpochs(model.hist_cap)
        # persistent sub-domains (None until the first sweep or after a rebuild), and
        # whether they hold newer states than self.epoch
        self._live: LiveDomains | None = None
        self._live_newer = False
        self._live_stale = False  # the compiled sweeps stopped for a rebuild of the local sets
        self.live_builds = 0
        # whole sweeps in compiled calls (live.run_sweeps), the sub-domains side by side
        # on the threads (paper2008, D = 6, K = 1, 6000 steps, 2 threads: 4.9 s against
        # 8.2 s for one call per sub-domain and block)
        self.compiled_sweeps = sweeps_kernel(self.model.kernels()) is not None
        # x motion a live local set tolerates before it is rebuilt (one contact hop)
        self.membership_skin = 2.0 * sc.soil.r_max + sc.bed.skin

    @classmethod
    def default_block(cls, sc, domains: int) -> int:
        """K without --block: the scenario's (the paper's loop is K = 1)."""
        return sc.decomposition.block

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
        store=None,
        bounds=None,
    ) -> "DdmEngine":
        """Split the discs into `domains` slabs by the scenario's policy (or at `bounds`)."""
        eng = cls(sc, model, wheel_state, block, [-np.inf, np.inf], store)
        eng._populate(particles, domains, bounds)
        return eng

    @classmethod
    def reopen(
        cls, sc, model: Model, reader, wheel_state: np.ndarray, engine_attrs: dict, *, store, redecompositions=()
    ) -> "DdmEngine":
        """Continue from a committed epoch (its groups copied into RAM)."""
        K, bounds = cls._stored_geometry(engine_attrs)
        eng = cls(sc, model, wheel_state, K, bounds, store, redecompositions)
        for d in reader.domains():
            eng.epoch.write_domain(d, reader.read_domain(d), reader.domain_attrs(d))
        eng._n = eng.n_discs()
        return eng

    def _stage(self, d, q: Particles, attrs):
        self.epoch.write_particles(d, q, self._summarised(q, attrs))

    def _source(self) -> RamEpochs:
        if self._live is not None and self._live_newer:
            # the live sub-domains hold the newest states: the epoch's groups are
            # each slab's owned discs (ownership at the start of the last sweep)
            live = self._live
            cell = self.model.order_cell
            self.epoch.current = {d: group_of(live.p, live.owned_rows(d), cell) for d in range(live.D)}
            self._live_newer = False
        return self.epoch

    def _bounds_changed(self) -> None:
        self._live = None

    def advance(self, step0: int, nsteps: int, frame=None) -> np.ndarray:
        recs = []
        s = step0
        end = step0 + nsteps
        while s < end:
            whole = (end - s) // self.K
            if whole and self.compiled_sweeps:
                rec, done = self._sweeps_live(s, whole)
                recs.append(rec)
                s += done * self.K
                continue
            k = min(self.K, end - s)
            recs.append(self.sweep(s, k))
            s += k
        return np.concatenate(recs) if recs else np.zeros((0, N_REC))

    def sweep(self, step0: int, k: int) -> np.ndarray:
        """Advance every slab k <= K steps (the halo is sized for K) over the persistent
        in-RAM sub-domains (see live.py)."""
        self._step = step0
        wslab = self._wheel_check()
        live = self._live
        if live is not None and (live.wslab != wslab or self._live_stale or not live.refresh()):
            live = None  # rebuilt below from the epoch's groups (_source folds the live states in)
        if live is None:
            live = self._build_live(wslab)
        self._live_stale = False
        self._live_newer = True
        rec_wheel, ws = live.advance(step0, k)
        if ws is not None:
            self.ws = ws
        self._note_resident(live.resident())
        return rec_wheel

    def _sweeps_live(self, step0: int, nsweeps: int):
        """Up to nsweeps whole sweeps in compiled calls (live.run_sweeps), until the local
        sets must be rebuilt or the wheel leaves its slab. Same bits as one ``sweep``
        call per block. Returns (wheel records, sweeps done)."""
        self._step = step0
        wslab = self._wheel_check()
        live = self._live
        fresh = False
        if live is not None and (live.wslab != wslab or self._live_stale):
            live = None
        if live is None:
            live = self._build_live(wslab)
            fresh = True
        self._live_stale = False
        if not self.sc.wheel.enabled:
            reach = -1.0
        elif self._redecomposes():
            reach = self.reach + self.margin_required
        else:
            reach = 0.0
        rec, done, status = live.run_sweeps(step0, nsweeps, self.K, not fresh, reach)
        self._live_newer = True
        if live.wslab >= 0:
            self.ws = live.steppers[live.wslab].ws.copy()
        self._note_resident(live.resident())
        if status == SWEEPS_REBUILD:
            self._live_stale = True  # a disc moved beyond the membership skin
        return rec, done

    def _build_live(self, wslab: int) -> LiveDomains:
        src = self._source()
        discs = Particles.concat([src.domain_particles(d) for d in src.domains()], self.model.dim, self.model.hist_cap)
        live = LiveDomains(
            discs, self.bounds, self.halo, self.membership_skin, self.model, self.model_nowheel, self.ws, wslab
        )
        self._live = live
        self.live_builds += 1
        # the live sub-domains are now the only copy kept (the groups are made
        # from them again when a commit or a rebuild needs them)
        src.current = {}
        return live

    def particles(self) -> Particles:
        src = self._source()
        return Particles.concat([src.domain_particles(d) for d in src.domains()], self.model.dim, self.model.hist_cap)

    def state_parts(self, names=()):
        yield self.particles()

    def commit(self, step: int, arrays: dict, attrs: dict, durable: bool = False) -> None:
        """Copy the RAM epoch into the run's store."""
        if self.store is None:
            raise RuntimeError("serial-DDM sweep without a store to commit to")
        write_epoch(self.store, step, self.write_domains, arrays, attrs, durable)

    def info(self) -> dict:
        return {**super().info(), "local_set_builds": self.live_builds}


def sweep_run(
    sc, particles: Particles, wheel_state, steps: int, bounds=None, domains=None, block=1, membership_skin=None
):
    """Advance discs `steps` steps with the serial-DDM sweep; returns (particles, wheel_state, records, engine).

    `bounds` fixes the slab bounds (D+1 ascending values, -inf and +inf at the ends);
    otherwise the scenario's policy with `domains` sub-domains is used. `membership_skin`
    overrides how far (m) discs may move before the local sets are rebuilt.
    """
    model = Model.from_scenario(sc)
    eng = DdmEngine.create(
        sc,
        model,
        particles,
        np.asarray(wheel_state, np.float64),
        domains=domains or sc.decomposition.domains,
        block=block or DdmEngine.default_block(sc, domains),
        bounds=bounds,
    )
    if membership_skin is not None:
        eng.membership_skin = membership_skin
    rec = eng.advance(0, steps)
    return eng.particles(), eng.wheel_state, rec, eng
