"""The sweep: serial domain decomposition over a store of epochs.

A sweep reads epoch e and writes epoch e+1 (Jacobi: every sub-domain sees its
neighbours' time-n state). For each slab in turn it loads the discs the slab owns
plus a halo K contact-hops wide from the other groups, advances all of them K
steps with THE per-domain step (``DomainStepper``), and writes only the owned
discs. Ownership is by position: a disc belongs to the slab holding its x at the
start of the sweep, so migration needs no bookkeeping, and its contact history
travels with it.

Out-of-core runs this sweep over an HDF5 or zarr store, committing every epoch.
Serial DDM runs the same sweep over epochs held in RAM, with its sub-domains kept
alive between sweeps (``live.LiveDomains``: same bits, no per-sweep rebuilding).
"""
from __future__ import annotations


import numba
import numpy as np

from ..checkpoint import open_epoch, particles_to_record, record_to_particles
from ..decomposition import (XHistogram, equal_bounds, owner, summary_ok, wheel_bounds, wheel_slab_index,
                             wheel_slab_ok, x_summary)
from ..physics.layout import AX_X, WS_X
from ..state import DISC_FIELDS, HIST_FIELDS
from ..state import Particles
from .live import SWEEPS_REBUILD, LiveDomains, sweeps_kernel
from .stepper import N_REC, DomainStepper, EngineError, Model


def _block(sim) -> int:
    """K: the run's --block, else for out-of-core chosen from the geometry, else the scenario's."""
    if sim.opts.block:
        return sim.opts.block
    sc = sim.sc
    if sim.opts.mode == "ooc":
        D = sim.opts.domains or sc.decomposition.domains
        return max(sc.decomposition.block, auto_block(sc, D, sc.bin.length))
    return sc.decomposition.block


class RamEpochs:
    """Serial DDM's epoch in RAM: per-domain disc sets sorted by x, with their attrs.

    Between sweeps the live sub-domains (live.py) hold the newest states; this view is
    made from them only when a commit, a re-decomposition or a rebuild needs it. The
    discs stay ``Particles``; the store-record view is made only for commits."""

    def __init__(self):
        self.current: dict[int, tuple[Particles, dict]] = {}

    # reader side
    def domains(self):
        return sorted(self.current)

    def domain_attrs(self, d):
        return self.current[d][1]

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
        self.current[d] = (record_to_particles(arrays), attrs)


def _read_rows(src, d, lo: float, hi: float, hist_cap: int | None = None) -> Particles | None:
    """Discs of group d with lo <= x < hi (groups are sorted by x: one contiguous slice)."""
    attrs = src.domain_attrs(d)
    n = int(attrs.get("n", 0))
    if n == 0 or attrs["xmax"] < lo or attrs["xmin"] >= hi:
        return None
    x = src.read_domain(d, ["pos"])["pos"][:, AX_X]
    a, b = int(np.searchsorted(x, lo, "left")), int(np.searchsorted(x, hi, "left"))
    if b <= a:
        return None
    if a == 0 and b == n:
        return record_to_particles(src.read_domain(d), hist_cap)
    # scalar arrays by row; the CSR history by the matching entry range
    hn = src.read_domain(d, ["hist_n"])["hist_n"]
    off = np.concatenate([[0], np.cumsum(hn, dtype=np.int64)])
    rec = src.read_domain(d, list(DISC_FIELDS), slice(a, b))
    rec.update(src.read_domain(d, list(HIST_FIELDS), slice(int(off[a]), int(off[b]))))
    return record_to_particles(rec, hist_cap)


def x_histogram(src, length: float) -> XHistogram:
    """The discs' x histogram of an epoch (a store reader or RamEpochs) from its groups'
    stored x summaries; a group without a valid one (a store written before issue 17, DDM's
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


def group_of(p: Particles, rows=None) -> tuple[Particles, dict]:
    """A domain group: discs `rows` of p (all if None) sorted by x (strips are then
    contiguous), with its x extent. One gather, whatever `rows` is."""
    rows = np.arange(len(p)) if rows is None else np.asarray(rows)
    q = p.take(rows[np.argsort(p.pos[rows, AX_X], kind="stable")])
    attrs = {"n": len(q), "xmin": float(q.pos[0, AX_X]) if len(q) else 0.0,
             "xmax": float(q.pos[-1, AX_X]) if len(q) else 0.0}
    return q, attrs


def auto_block(sc, domains: int, length: float) -> int:
    """K for out-of-core: the largest block whose redundant halo work (2 K hop / slab width)
    stays at or below 10 % of a slab, capped at 200 steps; at least 1."""
    hop = 2.0 * sc.soil.r_max + sc.bed.skin
    width = length / max(1, domains)
    return int(max(1, min(200, (0.05 * width) // hop)))


class SweepEngine:
    """Serial DDM (epochs in RAM) or out-of-core (epochs in a store) with blocks of K steps."""

    folds_records = property(lambda self: self.src is None)

    def __init__(self, sim, bounds: np.ndarray, wheel_state: np.ndarray, block: int, src):
        self.sim = sim
        self.sc = sim.sc
        self.model: Model = sim.model
        self.model_nowheel = self.model.without_wheel()
        self.K = block
        self.bounds = np.asarray(bounds, np.float64)
        self.D = len(self.bounds) - 1
        self.ws = np.asarray(wheel_state, np.float64).copy()
        self.src = src
        self.fixed = False  # True: bounds given by the caller, never redefined
        self._writer = None         # out-of-core: epoch being written
        self._store_reader = None   # out-of-core: current committed epoch
        self.committed_step = None
        self.resident_max = 0
        self.resident_last: list[int] = []
        self.resident_first: list[int] | None = None
        self._n = None
        sc = self.sc
        hop = 2.0 * sc.soil.r_max + sc.bed.skin
        # halo: K contact hops (a hop is at most 2 r_max plus the motion the skin allows)
        self.halo = self.K * hop
        w = sc.wheel
        self.reach = max(w.radius, w.lug_tip_radius) + sc.soil.r_max if w.enabled else 0.0
        # no owned disc of another slab may feel the wheel within a block
        self.margin_required = self.halo + 2.0 * sc.soil.r_max + self.K * sc.physics.dt * 1.0
        # serial DDM: persistent sub-domains (None until the first sweep or after a
        # rebuild), and whether they hold newer states than self.src
        self._live: LiveDomains | None = None
        self._live_newer = False
        self._live_stale = False    # the compiled sweeps stopped for a rebuild of the local sets
        self._step = 0
        self.live_builds = 0
        # serial DDM runs whole sweeps in compiled calls (live.run_sweeps) on one thread;
        # with more threads, one call per sub-domain and block (the lanes' barrier per
        # sweep measured ~6x slower than that on 2 threads, paper2008 D = 6, K = 1)
        self.compiled_sweeps = (sweeps_kernel(self.model.kernels()) is not None
                                and numba.get_num_threads() == 1)
        # x motion a live local set tolerates before it is rebuilt (one contact hop)
        self.membership_skin = hop
        self.preferred_chunk = max(self.K, (2000 // self.K) * self.K)

    # ---------------------------------------------------------------- setup
    @classmethod
    def create(cls, sim, particles: Particles, ws: np.ndarray, bounds=None) -> "SweepEngine":
        """Split the discs into slabs (by the scenario's policy, or the given bounds)."""
        sc = sim.sc
        D = sim.opts.domains or sc.decomposition.domains
        K = _block(sim)
        src = RamEpochs() if sim.opts.mode == "ddm" else None
        eng = cls(sim, np.array([-np.inf, np.inf]), ws, K, src)
        if src is None:
            eng._writer = sim.store.begin_epoch(0)
        if bounds is None:
            eng.D = D
            eng.bounds = eng.decompose(XHistogram.of(particles.pos[:, AX_X], sc.bin.length), step=0)
        else:
            eng.bounds = np.asarray(bounds, np.float64)
            eng.D = len(eng.bounds) - 1
            eng.fixed = True
        groups = owner(eng.bounds, particles.pos[:, AX_X])
        for d in range(eng.D):
            eng._stage(d, *group_of(particles, np.flatnonzero(groups == d)))
        eng._n = len(particles)
        return eng

    @classmethod
    def create_streamed(cls, sim, parts, ws: np.ndarray) -> "SweepEngine":
        """Out-of-core start from a bed produced in x-ordered parts (``parts()`` yields them),
        never holding the whole bed: pass 1 counts the discs in x bins (for the bounds),
        pass 2 writes each sub-domain's group as soon as no later part can add to it."""
        sc = sim.sc
        eng = cls(sim, np.array([-np.inf, np.inf]), ws, _block(sim), None)
        eng.D = sim.opts.domains or sc.decomposition.domains
        hist = XHistogram(sc.bin.length)
        for part in parts():
            hist.add_x(part.pos[:, AX_X])
        eng._n = hist.n
        eng.bounds = eng.decompose(hist, step=0)
        eng._writer = sim.store.begin_epoch(0)
        pending: dict[int, list] = {d: [] for d in range(eng.D)}
        written = set()

        def flush(upto: float):
            for d in range(eng.D):
                if d not in written and eng.bounds[d + 1] <= upto:
                    eng._stage(d, *group_of(Particles.concat(pending.pop(d))))
                    written.add(d)

        for part in parts():
            flush(float(part.pos[:, AX_X].min()))
            g = owner(eng.bounds, part.pos[:, AX_X])
            for d in np.unique(g):
                if int(d) in written:
                    raise RuntimeError("bed parts are not in x order")
                pending[int(d)].append(part.take(np.flatnonzero(g == d)))
        flush(np.inf)
        return eng

    def _stage(self, d, q: Particles, attrs):
        # the group's x summary, so that a re-decomposition reads no disc (see x_histogram)
        attrs = {**attrs, "x_summary": x_summary(q.pos[:, AX_X], self.sc.bin.length)}
        if self.src is not None:
            self.src.write_particles(d, q, attrs)
        else:
            if self._writer is None:
                raise RuntimeError("out-of-core sweep without an open epoch writer")
            self._writer.write_domain(d, particles_to_record(q), attrs)

    def decompose(self, hist: XHistogram, step: int) -> np.ndarray:
        sc = self.sc
        if sc.wheel.enabled and sc.decomposition.policy == "wheel":
            half = self.reach + self.margin_required + sc.decomposition.margin
            b = wheel_bounds(hist, self.D, float(self.ws[WS_X]), half)
        else:
            b = equal_bounds(hist, self.D)
        self.sim.redecompositions.append({"step": int(step), "bounds": [float(v) for v in b[1:-1]]})
        return b

    # -------------------------------------------------------------- the sweep
    def _reader(self):
        if self.src is None:
            return self._store_reader
        if self._live is not None and self._live_newer:
            # the live sub-domains hold the newest states: the epoch's groups are
            # each slab's owned discs (ownership at the start of the last sweep)
            live = self._live
            self.src.current = {d: group_of(live.p, live.owned_rows(d)) for d in range(live.D)}
            self._live_newer = False
        return self.src

    def commit_epoch(self, step, arrays, attrs, durable=False) -> None:
        """Out-of-core: finish the epoch being written (globals + manifest commit).
        DDM: copy the RAM epoch into the run's store."""
        if self.src is not None:
            writer = self.sim.store.begin_epoch(step)
            try:
                self.write_domains(writer)
                writer.write_globals(arrays, attrs)
                writer.commit(durable=durable)
            except BaseException:
                writer.abort()
                raise
            return
        if self.committed_step == step:
            return  # the sweep that reached this step committed it already
        writer, self._writer = self._writer, None
        try:
            writer.write_globals(arrays, attrs)
            writer.commit(durable=durable)
        except BaseException:
            writer.abort()
            raise
        self.committed_step = step
        if self._store_reader is not None:
            self._store_reader.close()
        self._store_reader = open_epoch(self.sim.store)

    def sweep(self, step0: int, k: int) -> np.ndarray:
        """Advance every slab k <= K steps (the halo is sized for K)."""
        self._step = step0
        wslab = self._wheel_check()
        if self.src is not None:
            return self._sweep_live(step0, k, wslab)
        src = self._reader()
        self._writer = self.sim.store.begin_epoch(step0 + k)
        try:
            return self._sweep_domains(src, step0, k, wslab)
        except BaseException:
            if self._writer is not None:
                self._writer.abort()
                self._writer = None
            raise

    def _sweep_live(self, step0: int, k: int, wslab: int) -> np.ndarray:
        """Serial DDM: the sweep over persistent in-RAM sub-domains (see live.py)."""
        live = self._live
        if live is not None and (live.wslab != wslab or self._live_stale or not live.refresh()):
            live = None  # rebuilt below from the epoch's groups (_reader folds the live states in)
        if live is None:
            live = self._build_live(wslab)
        self._live_stale = False
        self._live_newer = True
        rec_wheel, ws = live.advance(step0, k)
        if ws is not None:
            self.ws = ws
        self._note_resident(live.resident())
        return rec_wheel

    def _note_resident(self, resident: list[int]) -> None:
        self.resident_last = resident
        if self.resident_first is None:
            self.resident_first = list(resident)
        self.resident_max = max(self.resident_max, max(resident) if resident else 0)

    def _sweep_domains(self, src, step0: int, k: int, wslab: int) -> np.ndarray:
        """Out-of-core: each slab rebuilt from epoch e, advanced, its owned discs written to e+1."""
        rec_wheel = np.zeros((0, N_REC))
        new_ws = self.ws
        resident = []
        owned_total = 0
        # trajectory hook: a frame at the sweep's end gets each slab's owned discs as it passes
        frames = getattr(self.sim, "frames", None)
        frame_step = step0 + k if frames is not None and frames.due(step0 + k) else None
        for d in range(self.D):
            lo, hi = self.bounds[d], self.bounds[d + 1]
            pieces = [q for g in src.domains()
                      if (q := _read_rows(src, g, lo - self.halo, hi + self.halo,
                                               self.model.hist_cap)) is not None]
            # the pieces are x-sorted strips: already in a cache-friendly order, and memory
            # order never changes a result (docs/design.md §3), so no spatial re-sort here
            local = Particles.concat(pieces, self.model.dim, self.model.hist_cap)
            resident.append(len(local))
            if d == wslab:
                st = DomainStepper(local, self.model, self.ws, reorder=False)
            else:
                st = DomainStepper(local, self.model_nowheel, None, reorder=False)
            owned = np.flatnonzero((st.p.pos[:, AX_X] >= lo) & (st.p.pos[:, AX_X] < hi))
            if len(local):
                rec = st.advance(step0, k)
            else:
                rec = np.zeros((0, N_REC))
            if d == wslab:
                rec_wheel = rec
                new_ws = st.ws.copy()
            owned_total += len(owned)
            q, attrs = group_of(st.p, owned)
            self._stage(d, q, attrs)
            if frame_step is not None:
                frames.write_part(frame_step, q)
            del st, local, pieces, q
        if self._n is not None and owned_total != self._n:
            raise EngineError(f"sweep at step {step0} kept {owned_total} of {self._n} discs "
                              f"(bounds {self.bounds.tolist()}): decomposition error")
        self.ws = new_ws
        self._note_resident(resident)
        # the epoch is complete: fold the wheel records, then commit it (every sweep)
        self.sim.fold(rec_wheel, step0)
        self.sim.step = step0 + k
        self.sim.commit()
        return rec_wheel

    def advance(self, step0: int, nsteps: int) -> np.ndarray:
        recs = []
        s = step0
        end = step0 + nsteps
        while s < end:
            whole = (end - s) // self.K
            if self.src is not None and whole and self.compiled_sweeps:
                rec, done = self._sweeps_live(s, whole)
                recs.append(rec)
                s += done * self.K
                continue
            k = min(self.K, end - s)
            recs.append(self.sweep(s, k))
            s += k
        return np.concatenate(recs) if recs else np.zeros((0, N_REC))

    def _wheel_check(self):
        """Before a sweep, as ``sweep`` does: re-decompose when the wheel's reach plus the
        margin leaves its slab; the wheel's slab (-1 without a wheel)."""
        sc = self.sc
        if self._redecomposes():
            if not wheel_slab_ok(self.bounds, float(self.ws[WS_X]), self.reach, self.margin_required):
                self.bounds = self.decompose(x_histogram(self._reader(), self.sc.bin.length), self._step)
                self._live = None
        return wheel_slab_index(self.bounds, float(self.ws[WS_X])) if sc.wheel.enabled else -1

    def _redecomposes(self) -> bool:
        sc = self.sc
        return sc.wheel.enabled and sc.decomposition.policy == "wheel" and self.D > 1 and not self.fixed

    def _sweeps_live(self, step0: int, nsweeps: int):
        """Serial DDM: up to nsweeps whole sweeps in compiled calls (live.run_sweeps), until
        the local sets must be rebuilt or the wheel leaves its slab. Same bits as one
        ``sweep`` call per block. Returns (wheel records, sweeps done)."""
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
            self._live_stale = True   # a disc moved beyond the membership skin
        return rec, done

    def _build_live(self, wslab: int) -> LiveDomains:
        src = self._reader()
        discs = Particles.concat([src.domain_particles(d) for d in src.domains()],
                                 self.model.dim, self.model.hist_cap)
        live = LiveDomains(discs, self.bounds, self.halo, self.membership_skin, self.model,
                           self.model_nowheel, self.ws, wslab)
        self._live = live
        self.live_builds += 1
        # the live sub-domains are now the only copy kept (the groups are made
        # from them again when a commit or a rebuild needs them)
        src.current = {}
        return live

    # ------------------------------------------------------------ interface
    @property
    def wheel_state(self):
        return self.ws

    def n_discs(self) -> int:
        src = self._reader()
        return sum(int(src.domain_attrs(d).get("n", 0)) for d in src.domains())

    def particles(self) -> Particles:
        src = self._reader()
        if isinstance(src, RamEpochs):
            return Particles.concat([src.domain_particles(d) for d in src.domains()],
                                    self.model.dim, self.model.hist_cap)
        m = self.model
        return Particles.concat([record_to_particles(src.read_domain(d), m.hist_cap)
                                 for d in src.domains()], m.dim, m.hist_cap)

    def write_domains(self, writer) -> None:
        src = self._reader()
        for d in src.domains():
            writer.write_domain(d, src.read_domain(d), src.domain_attrs(d))

    def info(self) -> dict:
        return {"domains": self.D, "block": self.K, "halo_m": self.halo,
                "resident_max": self.resident_max, "resident_last_sweep": self.resident_last,
                "bounds": [float(v) for v in self.bounds[1:-1]],
                "redecompositions": len(self.sim.redecompositions),
                **({"local_set_builds": self.live_builds} if self.src is not None else {})}

    @classmethod
    def reopen(cls, sim, reader, arrays, attrs) -> "SweepEngine":
        K = int(attrs["engine"]["block"])
        if sim.opts.mode == "ooc":
            bounds = np.array([-np.inf, *attrs["engine"]["bounds"], np.inf])
            eng = cls(sim, bounds, arrays["wheel_state"], K, None)
            eng._store_reader = open_epoch(sim.store, reader.step)
            eng.committed_step = int(attrs["step"])
            eng._n = sum(int(reader.domain_attrs(d).get("n", 0)) for d in reader.domains())
            return eng
        src = RamEpochs()
        bounds = np.array([-np.inf, *attrs["engine"]["bounds"], np.inf])
        eng = cls(sim, bounds, arrays["wheel_state"], K, src)
        for d in reader.domains():
            src.write_domain(d, reader.read_domain(d), reader.domain_attrs(d))
        eng._n = eng.n_discs()
        return eng


class _Run:
    """The few attributes of a Simulation that the sweep needs (for direct use)."""

    def __init__(self, sc, mode="ddm", block=1):
        from types import SimpleNamespace
        self.sc = sc
        self.model = Model.from_scenario(sc)
        self.opts = SimpleNamespace(mode=mode, domains=None, block=block)
        self.redecompositions = []


def sweep_run(sc, particles: Particles, wheel_state, steps: int, bounds=None, domains=None, block=1,
              membership_skin=None):
    """Advance discs `steps` steps with the serial-DDM sweep; returns (particles, wheel_state, records, engine).

    `bounds` fixes the slab bounds (D+1 ascending values, -inf and +inf at the ends);
    otherwise the scenario's policy with `domains` sub-domains is used. `membership_skin`
    overrides how far (m) discs may move before the local sets are rebuilt.
    """
    run = _Run(sc, "ddm", block)
    run.opts.domains = domains
    eng = SweepEngine.create(run, particles, np.asarray(wheel_state, np.float64), bounds=bounds)
    if membership_skin is not None:
        eng.membership_skin = membership_skin
    rec = eng.advance(0, steps)
    return eng.particles(), eng.wheel_state, rec, eng
