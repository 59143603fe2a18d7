"""Simulation: a scenario advanced in one of the execution modes, with epochs,
time series, summary and figures written into its output directory (a store).
"""
from __future__ import annotations

import dataclasses
import math
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import __version__
from .bed import settled_bed, surface_height, wheel_footprint
from ..model.checkpoint import FORMAT_VERSION, SUPPORTED_VERSIONS, open_epoch, read_all_particles
from ..physics.layout import REC_X, WS_SIZE, WS_X, WS_Y
from ..model.scenario import (MAX_DOMAINS, MAX_STEPS, Scenario, big, critical_time_step, show,
                        steps_for_duration)
from .metrics import N_SERIES
from .outputs import complete_outputs, run_summary, write_outputs
from ..physics.layout import AX_X, AX_Y, AX_Z
from ..model.state import Particles
from ..engine import budget
from ..engine.interface import Engine
from ..engine.monolithic import MonolithicEngine
from ..engine.stepper import EngineError, Model

MODES = ("monolithic", "ddm", "ooc", "mpi", "mpi-ooc")
# the out-of-core modes: one slab and its halo resident (mpi-ooc: on each rank)
OOC_MODES = ("ooc", "mpi-ooc")
BACKENDS = ("hdf5", "zarr", "memory")


class RunError(RuntimeError):
    """A run cannot start or continue (message is one line)."""


@dataclass
class RunOptions:
    mode: str = "monolithic"
    backend: str = "hdf5"
    domains: int | None = None
    block: int | None = None
    steps: int | None = None            # total steps to run (from step 0)
    duration: float | None = None       # or: total simulated time to run, s (from t = 0)
    checkpoint_every: int | None = None  # steps between committed epochs
    durable: bool = False
    progress: bool = True
    figures: bool = True
    memory: int | None = None           # bytes the run may hold at its peak (--memory): chooses D, K
    compression: str | None = None      # the store's (storage.COMPRESSIONS[backend]); None: off
    io_overlap: bool = False            # out-of-core: read ahead, write behind in threads (--io-overlap)


def place_wheel(sc: Scenario, bed: Particles) -> np.ndarray:
    """Wheel centre above the bed under x0, lug tips drop_gap above the highest disc (3D:
    the highest sphere under the wheel's footprint, across its width too)."""
    w = sc.wheel
    ws = np.zeros(WS_SIZE)
    x, y = bed.pos[:, AX_X], bed.pos[:, AX_Y]
    under = np.abs(x - w.x0) < w.lug_tip_radius + sc.soil.r_max
    if sc.dim == 3:
        from ..engine.stepper import wheel_z0
        under &= np.abs(bed.pos[:, AX_Z] - wheel_z0(sc)) < 0.5 * w.width + sc.soil.r_max
    top = float((y[under] + bed.r[under]).max()) if under.any() else float((y + bed.r).max())
    ws[WS_X] = w.x0
    ws[WS_Y] = top + w.lug_tip_radius + w.drop_gap
    return ws


def total_steps(sc: Scenario, opts: RunOptions) -> int:
    if opts.steps is not None:
        if not 0 <= opts.steps <= MAX_STEPS:
            raise RunError(f"--steps {show(opts.steps)}: must be in [0, {big(MAX_STEPS)}]")
        return int(opts.steps)
    if opts.duration is not None:
        return steps_for_duration(opts.duration, sc.physics.dt, f"--duration {show(opts.duration)}")
    if sc.wheel.enabled:
        return steps_for_duration(sc.wheel.settle_time + sc.wheel.travel_time, sc.physics.dt,
                                  "wheel.settle_time + wheel.travel_time")
    return int(sc.output.run_steps)


# ---- memory plan: the measured bytes per particle of each mode and dimension, and the
# budget that chooses D and K, live in engine/budget.py
SERIES_ROW_BYTES = N_SERIES * 8    # one series.csv row (float64 columns)
MIN_DISCS_PER_DOMAIN = 20           # a sub-domain of fewer discs is all halo and overhead


@dataclass(frozen=True)
class RunPlan:
    """What a run will do, resolved and checked before anything is allocated or written
    (``ooc-dem check`` prints it)."""
    scenario: str
    mode: str
    backend: str
    n_discs: int
    steps: int
    simulated_time_s: float
    dt_s: float
    dt_critical_s: float
    checkpoint_every: int
    domains: int
    block: int
    streamed_bed: bool
    memory_bytes: int
    memory_available_bytes: int
    memory_budget_bytes: int | None = None

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


_fmt_bytes = budget.fmt_bytes
_hop = budget.hop


def max_domains(sc: Scenario) -> int:
    """The most sub-domains that make sense for the bed: each slab at least one contact hop
    wide and holding at least MIN_DISCS_PER_DOMAIN discs (and at most MAX_DOMAINS)."""
    by_width = int(sc.bin.length // _hop(sc))
    by_discs = sc.soil.n // MIN_DISCS_PER_DOMAIN
    return max(1, min(MAX_DOMAINS, by_width, by_discs))


def _domains_and_block(sc: Scenario, opts: RunOptions) -> tuple[int, int]:
    if opts.mode == "monolithic":
        return 1, 1
    D = opts.domains or sc.decomposition.domains
    if opts.domains is not None and not 1 <= opts.domains <= MAX_DOMAINS:
        raise RunError(f"--domains {show(opts.domains)}: must be in [1, {MAX_DOMAINS}]")
    limit = max_domains(sc)
    if D > limit:
        what = f"--domains {D}" if opts.domains else f"decomposition.domains = {D}"
        raise RunError(f"{what}: at most {limit} sub-domain{'s' if limit > 1 else ''} for this bed ({sc.soil.n} discs, "
                       f"bin.length {sc.bin.length:g} m: each slab needs >= {MIN_DISCS_PER_DOMAIN} discs "
                       f"and >= one contact hop {_hop(sc):.3g} m)")
    return D, _block_for(sc, opts, D)


def _block_for(sc: Scenario, opts: RunOptions, domains: int) -> int:
    """K exactly as the sweep will choose it for D sub-domains (its own rule, not a copy)."""
    from ..engine.sweep import DdmEngine, OocEngine
    engine = OocEngine if opts.mode in OOC_MODES else DdmEngine
    return opts.block or engine.default_block(sc, domains)


def streamable(sc: Scenario, opts: RunOptions) -> bool:
    """An out-of-core run of a tiled bare bed writes its bed into the store tile by tile."""
    return opts.mode in OOC_MODES and not sc.wheel.enabled and 0 < sc.bed.tile < sc.soil.n


def _series_bytes(sc: Scenario, steps: int) -> float:
    """A wheel run's series: the grown buffer (up to twice the rows) plus the copy each commit writes."""
    if not sc.wheel.enabled:
        return 0.0
    per_row = max(1, int(round(sc.output.series_interval / sc.physics.dt)))
    return 3.0 * (steps // per_row + 1) * SERIES_ROW_BYTES


def _slabs(opts: RunOptions) -> int:
    """Out-of-core slabs resident at once: one, or three with --io-overlap."""
    return 3 if opts.io_overlap and opts.mode in OOC_MODES else 1


def estimate_memory(sc: Scenario, opts: RunOptions, steps: int, domains: int, block: int,
                    streamed: bool) -> int:
    """Bytes the run needs at its peak (engine/budget.py: measured bytes per particle)."""
    return budget.estimate_peak(sc, opts.mode, opts.backend, domains, block, streamed,
                                _series_bytes(sc, steps), _slabs(opts))


def _budgeted(sc: Scenario, opts: RunOptions, steps: int, streamed: bool) -> tuple[int, int]:
    """--memory: out-of-core takes the fewest sub-domains (the largest slab) whose slab, halo
    and I/O buffers fit, and K as the sweep chooses it for them; a --domains or --block given
    too is kept. Other modes only check the budget."""
    if opts.memory is not None and not opts.memory >= 1:
        raise RunError(f"--memory {show(opts.memory)}: must be a positive size such as 2GB")
    if opts.mode not in OOC_MODES or opts.domains is not None:
        return _domains_and_block(sc, opts)
    block_of = lambda D: _block_for(sc, opts, D)
    got = budget.choose_decomposition(sc, opts.memory, block_of, max_domains(sc), opts.backend, streamed,
                                      _series_bytes(sc, steps), _slabs(opts))
    if got is None:
        raise RunError(budget.smallest_fit_message(sc, opts.memory, block_of, max_domains(sc), opts.backend,
                                                   streamed, _series_bytes(sc, steps), _slabs(opts)))
    return got[0], got[1]


def machine_memory() -> int:
    import psutil
    return int(psutil.virtual_memory().total)


def _check_compression(opts: RunOptions) -> None:
    from ooc_dem.storage import COMPRESSIONS
    have = COMPRESSIONS.get(opts.backend, ())
    if opts.compression is not None and opts.compression not in have:
        raise RunError(f"--compression {show(opts.compression)}: the {opts.backend} backend has "
                       f"{', '.join(have) or 'no compression'}")


def plan_run(sc: Scenario, opts: RunOptions, streamed: bool | None = None) -> RunPlan:
    """Resolve and check a run's options against its scenario and this machine (no allocation,
    no file, no bed): the shared planning of `run`, `check` and `resume`."""
    if opts.mode not in MODES:
        raise RunError(f"--mode {show(opts.mode)}: must be one of {', '.join(MODES)}")
    if opts.backend not in BACKENDS:
        raise RunError(f"--backend {show(opts.backend)}: must be one of {', '.join(BACKENDS)}")
    _check_compression(opts)
    steps = total_steps(sc, opts)
    if opts.checkpoint_every is not None and not 1 <= opts.checkpoint_every <= MAX_STEPS:
        raise RunError(f"--checkpoint-every {show(opts.checkpoint_every)}: must be in [1, {big(MAX_STEPS)}] steps")
    every = opts.checkpoint_every or default_checkpoint_every(sc, steps)
    streamed = streamable(sc, opts) if streamed is None else streamed
    D, K = _domains_and_block(sc, opts) if opts.memory is None else _budgeted(sc, opts, steps, streamed)
    need = estimate_memory(sc, opts, steps, D, K, streamed)
    have = machine_memory()
    if need > have:
        raise RunError(_memory_message(sc, opts, steps, need, have, streamed))
    if opts.memory is not None and need > opts.memory:
        raise RunError(f"--memory {_fmt_bytes(opts.memory)}: the {opts.mode} run needs about "
                       f"{_fmt_bytes(need)} (D = {D}, K = {K})"
                       + ("" if opts.mode in OOC_MODES else "; --mode ooc chooses sub-domains that fit"))
    return RunPlan(scenario=sc.name, mode=opts.mode, backend=opts.backend, n_discs=sc.soil.n, steps=steps,
                   simulated_time_s=steps * sc.physics.dt, dt_s=sc.physics.dt,
                   dt_critical_s=critical_time_step(sc), checkpoint_every=every, domains=D, block=K,
                   streamed_bed=streamed, memory_bytes=need, memory_available_bytes=have,
                   memory_budget_bytes=opts.memory)


def check_bed_memory(sc: Scenario) -> int:
    """`ooc-dem prepare`: the whole settled bed is held (an untiled bed is settled as one domain).
    Returns the estimated bytes; refuses what cannot fit, naming soil.n."""
    m = budget.byte_model(sc.dim)
    tiled = 0 < sc.bed.tile < sc.soil.n
    per_disc = 2 * m.state if tiled else m.monolithic
    need = m.baseline + sc.soil.n * per_disc
    have = machine_memory()
    if need > have:
        raise RunError(f"soil.n = {sc.soil.n}: preparing the bed needs about {_fmt_bytes(need)} of memory, "
                       f"this machine has {_fmt_bytes(have)} (`ooc-dem run --mode ooc` streams a tiled bed "
                       f"instead)")
    return need


def _memory_message(sc, opts, steps, need, have, streamed) -> str:
    series_rows = steps // max(1, int(round(sc.output.series_interval / sc.physics.dt))) + 1
    series = _series_bytes(sc, steps)
    if series > need / 2:
        what = (f"output.series_interval = {sc.output.series_interval!r}: {steps} steps keep "
                f"{series_rows} series rows")
    else:
        what = f"soil.n = {sc.soil.n}"
    msg = (f"{what}: the run needs about {_fmt_bytes(need)} of memory ({opts.mode}), this machine "
           f"has {_fmt_bytes(have)}")
    if opts.mode not in OOC_MODES and series <= need / 2:
        ooc = RunOptions(**{**dataclasses.asdict(opts), "mode": "ooc", "domains": None, "block": None})
        D = max_domains(sc)
        alt = estimate_memory(sc, ooc, steps, D, 1, streamable(sc, ooc))
        if alt <= have:
            msg += f"; --mode ooc --domains {D} would need about {_fmt_bytes(alt)}"
    elif opts.mode in OOC_MODES and series <= need / 2 and not streamed and not sc.wheel.enabled:
        msg += " (out-of-core set-up holds the bed unless it is tiled: bed.tile)"
    return msg


class Progress:
    """tqdm bar over simulated time, with steps/s; silent when disabled."""

    def __init__(self, enabled: bool, total_steps: int, dt: float, label: str):
        self.bar = None
        self.dt = dt
        if enabled and total_steps > 0:
            from tqdm import tqdm
            self.bar = tqdm(total=total_steps, desc=label, unit="step", unit_scale=True,
                            mininterval=1.0, file=sys.stderr, dynamic_ncols=True,
                            bar_format="{desc}: {percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} steps "
                                       "[{elapsed}<{remaining}, {rate_fmt}] {postfix}")

    def update(self, step: int, n: int, **post):
        if self.bar is not None:
            self.bar.set_postfix_str(f"t={step * self.dt:.4f} s " + " ".join(f"{k}={v}" for k, v in post.items()),
                                     refresh=False)
            self.bar.update(n)

    def close(self):
        if self.bar is not None:
            self.bar.close()


# what `run` puts into its output directory before the first commit
_RUN_SETUP_FILES = ("initial.npz", "scenario.toml")


def _stopped_before_first_commit(out: Path) -> bool:
    """Whether `out` is a run that was stopped (killed, disk full) before its first commit.

    Such a directory holds nothing to lose: a store with no committed epoch and the run's own
    set-up files. `run --out` may start afresh there (create_store replaces the store and
    refuses if a live writer holds it); anything else in the directory makes it a user's.
    """
    from ooc_dem.storage import StoreError, open_store, store_owns
    try:
        store = open_store(out, repair=False)
    except StoreError:
        return False
    try:
        if store.current() is not None or store.meta.get("engine") != "ooc-dem":
            return False
    finally:
        store.close()
    own = set(_RUN_SETUP_FILES) | {n + ".tmp" for n in _RUN_SETUP_FILES}
    return all(n in own or store_owns(out, n) for n in os.listdir(out))


def default_checkpoint_every(sc: Scenario, steps: int) -> int:
    """One epoch per simulated second of a wheel run (at most ~100 per run), else only at the end."""
    if sc.wheel.enabled:
        every = int(round(min(1.0 / sc.physics.dt, MAX_STEPS)))   # a tiny dt: 1/dt overflows
        return max(every, -(-steps // 100)) if steps else every
    return max(1, steps)


class FrameParts:
    """The parts of the trajectory frame at ``step``, as an engine writes them during an
    advance (``engine.interface.FrameParts``)."""

    def __init__(self, frames, step: int):
        self.frames = frames
        self.step = step

    def write_part(self, part: dict) -> None:
        self.frames.write_part(self.step, part)


class Simulation:
    """A scenario run in one mode, writing its store, series, summary and figures into ``out``."""

    def __init__(self, sc: Scenario, out: str | Path, opts: RunOptions | None = None):
        self.sc = sc
        self.out = Path(out)
        self.opts = opts or RunOptions()
        # everything checked and sized before a byte is allocated or a file written
        self.plan = plan_run(sc, self.opts)
        if self.opts.memory is not None and self.opts.mode != "monolithic":
            # the budget's D and K become the run's own (stored with it: a resume keeps them)
            self.opts = dataclasses.replace(self.opts, domains=self.plan.domains, block=self.plan.block)
        self.model = Model.from_scenario(sc)
        self.steps = self.plan.steps
        self.checkpoint_every = self.plan.checkpoint_every
        self.store = None
        self.engine: Engine | None = None
        self.metrics = None
        self.step = 0
        self.surface = 0.0
        self.wall_time = 0.0
        # trajectory frames (trajectory.py): every frame_every steps, 0 = none
        from .trajectory import frame_every
        self.frame_every = frame_every(sc)
        self.frames = None

    @property
    def redecompositions(self) -> list:
        """Every decomposition the engine has chosen ({"step", "bounds"}), stored with each epoch."""
        return self.engine.redecompositions if self.engine is not None else []

    # ------------------------------------------------------------------ setup
    def _meta(self) -> dict:
        o = self.opts
        return {"engine": "ooc-dem", "engine_version": __version__, "format_version": FORMAT_VERSION,
                "dim": self.model.dim, "hist_cap": self.model.hist_cap,
                "scenario_toml": self.sc.to_toml(), "scenario_hash": self.sc.hash(),
                "scenario_name": self.sc.name,
                "run": {"mode": o.mode, "backend": o.backend, "domains": o.domains, "block": o.block,
                        "steps": self.steps, "checkpoint_every": self.checkpoint_every,
                        "io_overlap": o.io_overlap}}

    def _store_backend(self) -> str:
        # monolithic and DDM checkpoint to a file store too; the backend is the user's choice
        return self.opts.backend

    def start(self, bed: Particles | None = None, streamed: bool = False) -> None:
        """Create the store and the initial epoch. ``streamed``: an out-of-core run of a
        tiled bare bed writes its bed into the store tile by tile (never the whole bed in RAM)."""
        from ooc_dem.storage import StoreError, create_store
        if self.out.exists() and any(self.out.iterdir()) and not _stopped_before_first_commit(self.out):
            raise RunError(f"--out {self.out}: directory exists and is not empty (use a new directory, "
                           f"or `ooc-dem resume {self.out}` to continue a run)")
        sc = self.sc
        if streamed and bed is None and streamable(sc, self.opts):
            return self._start_streamed()
        if self.plan.streamed_bed:   # planned for a streamed bed, but the whole bed will be in RAM
            self.plan = plan_run(sc, self.opts, streamed=False)
        if bed is None:
            bed = settled_bed(self.sc, progress=self._bed_progress())
        ws = place_wheel(self.sc, bed) if self.sc.wheel.enabled else np.zeros(WS_SIZE)
        self.surface = surface_height(bed, self.sc.bin.length, self.sc.soil.r_max,
                                      across=wheel_footprint(self.sc))
        try:
            self.store = create_store(self.out, self._store_backend(), self._meta(),
                                      compression=self.opts.compression)
        except StoreError as e:
            raise RunError(str(e)) from None
        # a memory store lives in this process only; the run's other outputs still go to --out
        self.out.mkdir(parents=True, exist_ok=True)
        # initial.npz keeps the 2D users' column names (x, y: layout.AXIS_NAMES)
        extra = {"z": bed.pos[:, AX_Z]} if bed.dim == 3 else {}   # 3D: the slice and rut views
        np.savez(self.out / "initial.npz", id=bed.id, x=bed.pos[:, AX_X], y=bed.pos[:, AX_Y],
                 r=bed.r, surface=np.float64(self.surface), **extra)
        (self.out / "scenario.toml").write_text(self.sc.to_toml(), encoding="utf-8")
        self.engine = self._make_engine(bed, ws)
        if self.sc.wheel.enabled:
            from .metrics import WheelMetrics
            self.metrics = WheelMetrics(self.sc, self.surface, self.steps)
        self.step = 0
        self.commit()
        self._start_trajectory()

    def _start_streamed(self) -> None:
        from ooc_dem.storage import StoreError, create_store
        from .bed import tiled_bed_parts
        parts = lambda: tiled_bed_parts(self.sc, tiles_per_part=8)
        band = wheel_footprint(self.sc)
        surf = []

        def part_surface(p):   # each part's own columns (its own x origin)
            x0 = p.pos[:, AX_X].min()
            surf.append(surface_height(p, p.pos[:, AX_X].max() - x0, self.sc.soil.r_max,
                                       x_origin=x0, across=band))

        try:
            self.store = create_store(self.out, self._store_backend(), self._meta(),
                                      compression=self.opts.compression)
        except StoreError as e:
            raise RunError(str(e)) from None
        self.out.mkdir(parents=True, exist_ok=True)
        (self.out / "scenario.toml").write_text(self.sc.to_toml(), encoding="utf-8")
        self.engine = self._with_io_options(self._ooc_engine_class().create_streamed(
            self.sc, self.model, parts, np.zeros(WS_SIZE), domains=self.plan.domains, block=self.plan.block,
            store=self.store, observe=part_surface))
        self.surface = float(np.mean(surf))
        self.step = 0
        self.commit()
        self._start_trajectory()

    # ------------------------------------------------------------ trajectory
    def _start_trajectory(self, resumed: bool = False) -> None:
        """Open the trajectory (new, or continued after the resumed step) and write the
        frame of the current step if one belongs there."""
        from .trajectory import TrajectoryWriter
        if not self.frame_every:
            return
        if resumed:
            self.frames = TrajectoryWriter.reopen(self.out, self.sc, self.model.dim, self.n_discs(), self.step,
                                                 durable=self.opts.durable)
        else:
            self.frames = TrajectoryWriter.create(self.out, self.sc, self.model.dim, self.n_discs(),
                                                 durable=self.opts.durable)
        if self.frames.due(self.step):
            self._write_frame(parts_written=False)

    def _frame_parts(self, step: int) -> "FrameParts | None":
        """Where an engine that writes frame parts puts the discs of the frame due at
        ``step`` (None: no frame is due then, or the engine writes none)."""
        if self.frames is None or not self.engine.writes_frame_parts or not self.frames.due(step):
            return None
        return FrameParts(self.frames, step)

    def _write_frame(self, parts_written: bool) -> None:
        """Commit the frame of the current step; ``parts_written``: the engine wrote its parts
        during the advance (out-of-core, into ``_frame_parts``)."""
        from .trajectory import ROW_FIELDS
        t = self.step * self.sc.physics.dt
        ws = np.asarray(self.engine.wheel_state, np.float64)
        if parts_written:
            self.frames.end(self.step, t, ws)
        else:
            # one part at a time (out-of-core: each group of the committed epoch; never the whole bed)
            self.frames.write_frame(self.step, t, ws, self.engine.state_parts(ROW_FIELDS))

    def _ooc_engine_class(self):
        """Out-of-core in one process, or on MPI ranks (each streaming its own slabs)."""
        if self.opts.mode == "mpi-ooc":
            from ..engine.mpi import MpiOocEngine
            return MpiOocEngine
        from ..engine.sweep import OocEngine
        return OocEngine

    def _with_io_options(self, engine):
        """An out-of-core engine with the run's I/O options."""
        engine.io_overlap = self.opts.io_overlap
        return engine

    def _make_engine(self, particles: Particles, ws: np.ndarray) -> Engine:
        if self.opts.mode == "monolithic":
            return MonolithicEngine(particles, ws, self.model, store=self.store)
        if self.opts.mode == "mpi":   # ranks own slab ranges (engine/mpi.py)
            from ..engine.mpi import MpiEngine
            return MpiEngine.create(self.sc, self.model, particles, ws, domains=self.plan.domains,
                                    block=self.plan.block, store=self.store)
        from ..engine.sweep import DdmEngine
        if self.opts.mode == "ddm":
            return DdmEngine.create(self.sc, self.model, particles, ws, domains=self.plan.domains,
                                    block=self.plan.block, store=self.store)
        return self._with_io_options(self._ooc_engine_class().create(
            self.sc, self.model, particles, ws, domains=self.plan.domains, block=self.plan.block, store=self.store))

    def _reopen_engine(self, reader, arrays: dict, attrs: dict) -> Engine:
        """The engine continuing from the committed epoch ``reader`` reads (checked)."""
        ws = arrays["wheel_state"]
        redecompositions = list(attrs.get("redecompositions", []))
        if self.opts.mode == "monolithic":
            particles = read_all_particles(reader, self.model.dim, self.model.hist_cap)
            return MonolithicEngine(particles, ws, self.model, store=self.store,
                                    redecompositions=redecompositions)
        if self.opts.mode == "mpi":
            from ..engine.mpi import MpiEngine
            return MpiEngine.reopen(self.sc, self.model, reader, ws, attrs["engine"], store=self.store,
                                    redecompositions=redecompositions)
        from ..engine.sweep import DdmEngine
        if self.opts.mode == "ddm":
            return DdmEngine.reopen(self.sc, self.model, reader, ws, attrs["engine"], store=self.store,
                                    redecompositions=redecompositions)
        return self._with_io_options(self._ooc_engine_class().reopen(
            self.sc, self.model, reader, ws, attrs["engine"], store=self.store,
            redecompositions=redecompositions))

    def _bed_progress(self):
        if not self.opts.progress:
            return None
        state = {"last": 0.0}

        def cb(t, speed):
            if time.time() - state["last"] > 1.0:
                state["last"] = time.time()
                print(f"\rsettling bed: t = {t:.3f} s, mean speed {speed:.2e} m/s "
                      f"(target {self.sc.bed.settle_speed:.1e})", end="", file=sys.stderr, flush=True)
        return cb

    # ------------------------------------------------------------ checkpoint
    def commit(self) -> None:
        from ooc_dem.storage import StoreError
        attrs = {"step": self.step, "time": self.step * self.sc.physics.dt, "surface": self.surface,
                 "scenario_hash": self.sc.hash(), "mode": self.opts.mode,
                 "wall_time": self.wall_time, "redecompositions": self.redecompositions,
                 "format_version": FORMAT_VERSION, "engine_version": __version__}
        attrs["engine"] = self.engine.info()
        arrays = {"wheel_state": np.asarray(self.engine.wheel_state, np.float64).copy()}
        if self.metrics is not None:
            arrays.update(self.metrics.state_arrays())
        try:
            self.engine.commit(self.step, arrays, attrs, self.opts.durable)
        except StoreError as e:
            raise RunError(str(e)) from None

    def fold(self, rec, step0: int) -> None:
        """Fold per-step wheel records into the metrics (sequential: block-size independent)."""
        if self.metrics is not None:
            self.metrics.add(rec, step0)

    # ------------------------------------------------------------------- run
    def run(self) -> dict:
        if self.engine is None:
            self.start()
        dt = self.sc.physics.dt
        bar = Progress(self.opts.progress, self.steps - self.step, dt, f"{self.sc.name} [{self.opts.mode}]")
        chunk_pref = self.engine.preferred_chunk
        t_start = time.time() - self.wall_time
        try:
            while self.step < self.steps:
                next_ckpt = (self.step // self.checkpoint_every + 1) * self.checkpoint_every
                # frame steps end an advance too (out-of-core: a sweep), like epochs: where an
                # advance is cut never changes a bit (docs/design.md section 3)
                next_frame = ((self.step // self.frame_every + 1) * self.frame_every
                              if self.frames is not None else self.steps)
                n = min(self.steps, next_ckpt, next_frame, self.step + chunk_pref) - self.step
                step0 = self.step
                frame = self._frame_parts(step0 + n)
                rec = self.engine.advance(step0, n, frame)
                self.fold(rec, step0)
                self.step = step0 + n
                self.wall_time = time.time() - t_start
                post = {}
                if self.sc.wheel.enabled and len(rec):
                    post["x"] = f"{rec[-1, REC_X]:.4f}"
                bar.update(self.step, n, **post)
                # out-of-core: the advance wrote this step's epoch; committed first (the next
                # sweep reads it, and a frame is published only after its epoch)
                committed = self.engine.epoch_each_advance
                if committed:
                    self.commit()
                if self.frames is not None and self.frames.due(self.step):
                    self._write_frame(parts_written=frame is not None)
                if not committed and (self.step % self.checkpoint_every == 0 or self.step == self.steps):
                    self.commit()
        except EngineError as e:
            raise RunError(f"{e} (last committed epoch kept in {self.out})") from None
        finally:
            bar.close()
        summary = self.finish()
        self.close()
        return summary

    def close(self) -> None:
        """Release the store (and its write lock); the outputs stay in the run directory."""
        if self.frames is not None:
            self.frames.close()
            self.frames = None
        if self.store is not None:
            self.store.close()

    def finish(self) -> dict:
        """Write series.csv, summary.json and the figures from the committed final state
        (``outputs.py``: each under a temporary name, renamed when complete)."""
        results = dict(self.metrics.summary()) if self.metrics is not None else {}
        if self.sc.repose.enabled:   # the angle-of-repose test (docs/reference/repose3d.md)
            from .repose import heap_outputs
            # in id order: every mode (and the state read back) gives the same bits; the
            # figure is written before summary.json, so a summary means both are there
            p = self.engine.particles().sorted_by_id()
            results["repose"] = heap_outputs(self.out, self.sc, p.pos, p.r, p.vel, self.opts.figures)
        summary = run_summary(scenario=self.sc.name, scenario_hash=self.sc.hash(), mode=self.opts.mode,
                              backend=self.opts.backend, steps=self.step, dt=self.sc.physics.dt,
                              wall_time=self.wall_time, n_discs=self.n_discs(), engine=self.engine.info(),
                              results=results, state_hash=self.state_hash())
        write_outputs(self.out, summary, self.metrics.series() if self.metrics is not None else None,
                      figures=self.opts.figures and self.metrics is not None)
        return summary

    def complete_outputs(self) -> list[str]:
        """After the last commit: write whichever outputs a kill left unwritten; return their names."""
        from .plots import figure_files
        from .repose import REPOSE_FIGURE
        repose = (REPOSE_FIGURE,) if self.opts.figures and self.sc.repose.enabled else ()
        figures = figure_files(self.sc) if self.opts.figures and self.metrics is not None else ()
        return complete_outputs(self.out, self.step, self.finish, series=self.metrics is not None,
                                figures=figures, summary_figures=repose)

    def n_discs(self) -> int:
        return self.engine.n_discs()

    def state_hash(self) -> str:
        from ..model.checkpoint import hash_epoch, state_bounds
        from ooc_dem.storage import open_store
        store = open_store(self.out, repair=False)   # read-only: this run holds the write lock
        reader = open_epoch(store)
        # streamed and validated as read: never the whole state in RAM
        h = hash_epoch(reader, str(self.out), self.model.dim, self.model.hist_cap, state_bounds(self.sc))
        reader.close()
        store.close()
        return h


# the run options a store's meta must hold, with the types a resume accepts
_RUN_OPTION_TYPES = {"mode": (str,), "backend": (str,), "domains": (int, type(None)),
                     "block": (int, type(None)), "steps": (int,), "checkpoint_every": (int,),
                     "io_overlap": (bool, type(None))}   # None: a store written before it existed


def _stored_run_options(meta: dict, path) -> dict:
    """The run options recorded in a store's meta, checked (a store is untrusted input)."""
    stored = meta.get("run")
    if not isinstance(stored, dict):
        raise RunError(f"{path}: store meta has no run options (not written by `ooc-dem run`)")
    run = {key: stored.get(key) for key in _RUN_OPTION_TYPES}
    for key, types in _RUN_OPTION_TYPES.items():
        if type(run[key]) not in types:
            raise RunError(f"{path}: stored run option {key!r} = {show(run[key])} has the wrong type "
                           f"(store damaged or edited)")
    if run["mode"] not in MODES or run["backend"] not in BACKENDS:
        raise RunError(f"{path}: stored run mode/backend {show(run['mode'])}/{show(run['backend'])} "
                       f"unknown")
    for key in ("domains", "block"):
        if run[key] is not None and not 1 <= run[key] <= 100_000:
            raise RunError(f"{path}: stored run option {key!r} = {show(run[key])} out of range")
    if run["steps"] < 0 or run["checkpoint_every"] < 1:
        raise RunError(f"{path}: stored run options steps/checkpoint_every out of range")
    return run


def _check_engine_attrs(engine, n_domains: int, where: str) -> None:
    """The decomposition a sweep engine resumes from: block K and the slab bounds."""
    if not isinstance(engine, dict):
        raise RunError(f"{where}: globals attribute 'engine' missing")
    block, bounds = engine.get("block"), engine.get("bounds")
    if type(block) is not int or not 1 <= block <= 100_000:
        raise RunError(f"{where}: stored block K = {show(block)}: must be an integer in [1, 100000]")
    if (not isinstance(bounds, list) or len(bounds) != n_domains - 1
            or not all(type(b) in (int, float) and math.isfinite(b) for b in bounds)
            or any(b1 < b0 for b0, b1 in zip(bounds, bounds[1:]))):
        raise RunError(f"{where}: stored slab bounds must be {n_domains - 1} finite ascending numbers")


def resume_simulation(path, steps: int | None = None, until: float | None = None,
                      progress: bool = True, figures: bool = True,
                      mode: str | None = None) -> "Simulation | None":
    """Reopen a run's store at its last intact epoch and return a Simulation ready to run.

    Returns None (after a message) when the run is already finished; if its outputs
    (summary, series, figures) were not all written - a kill after the last commit -
    they are written first, from the committed state.
    """
    from ooc_dem.storage import StoreError, open_store
    path = Path(path)
    try:
        store = open_store(path)
    except StoreError as e:
        raise RunError(str(e)) from None
    try:
        sim = _reopen(store, path, steps, until, progress, figures, mode)
    except BaseException:
        store.close()           # releases the write lock: a refused resume leaves the store free
        raise
    if sim is None:
        store.close()
    return sim


# modes whose epochs are one another's (serial DDM's groups and bounds; out-of-core's): a
# resume may switch within a family
SWITCHABLE_MODES = (("ddm", "mpi"), ("ooc", "mpi-ooc"))


def _reopen(store, path: Path, steps, until, progress: bool, figures: bool,
            mode: str | None = None) -> "Simulation | None":
    """resume_simulation's work on an open store (None: the run was already finished)."""
    from ooc_dem.storage import StoreError
    from ..model.checkpoint import StateError, stored_layout, stored_scenario, validate_epoch
    meta = store.meta or {}
    if meta.get("engine") != "ooc-dem":
        raise RunError(f"{path}: not an ooc-dem run store")
    v = meta.get("format_version")
    if type(v) is not int or v not in SUPPORTED_VERSIONS:
        raise RunError(f"{path}: store format version {show(v)} is not supported "
                       f"(this engine reads versions {', '.join(map(str, SUPPORTED_VERSIONS))})")
    try:
        sc = stored_scenario(meta, str(path))
    except StateError as e:
        raise RunError(str(e)) from None
    run = _stored_run_options(meta, path)
    if store.current() is None:
        raise RunError(f"{path}: no committed epoch: the run stopped before its first checkpoint; "
                       f"start it again with `ooc-dem run {sc.name} --out {path}` (it replaces "
                       f"this empty store)")
    total = run["steps"]
    if until is not None:
        total = steps_for_duration(until, sc.physics.dt, f"--until {show(until)}")
    elif steps is not None:
        total = total_steps(sc, RunOptions(steps=steps))
    if mode is not None and mode != run["mode"]:
        if not any(mode in f and run["mode"] in f for f in SWITCHABLE_MODES):
            raise RunError(f"--mode {show(mode)}: a {run['mode']} run resumes in its own mode "
                           f"(only {' and '.join(f'{a} and {b}' for a, b in SWITCHABLE_MODES)} runs "
                           f"switch between each other)")
        run["mode"] = mode
    opts = RunOptions(mode=run["mode"], backend=run["backend"], domains=run["domains"], block=run["block"],
                      steps=total, checkpoint_every=run["checkpoint_every"], progress=progress,
                      figures=figures, io_overlap=bool(run["io_overlap"]))
    sim = Simulation(sc, path, opts)
    try:
        dim, sim.model.hist_cap, bounds = stored_layout(meta, str(path), sc)
        reader = open_epoch(store)
        validate_epoch(reader, str(path), dim, sim.model.hist_cap, bounds)
    except (StoreError, StateError) as e:
        raise RunError(str(e)) from None
    arrays, attrs = reader.read_globals()
    if attrs.get("scenario_hash") != sc.hash():
        raise RunError(f"{path}: epoch {reader.step} was written by a different scenario")
    step = attrs["step"]
    sim.store = store
    sim.step = step
    sim.surface = float(attrs.get("surface", 0.0))
    sim.wall_time = float(attrs.get("wall_time", 0.0))
    try:
        if sc.wheel.enabled:
            from .metrics import WheelMetrics
            sim.metrics = WheelMetrics(sc, sim.surface, max(total, step))
            try:
                sim.metrics.load_state(arrays)
            except (KeyError, ValueError) as e:   # missing or mis-shaped accumulators
                raise RunError(f"{path}: epoch {reader.step}: stored wheel metrics unusable "
                               f"({type(e).__name__}: {' '.join(str(e).split())})") from None
        if sim.opts.mode != "monolithic":
            _check_engine_attrs(attrs.get("engine"), len(reader.domains()), f"{path}: epoch {reader.step}")
        sim.engine = sim._reopen_engine(reader, arrays, attrs)
    finally:
        reader.close()
    for w in store.warnings:   # only once the epoch is accepted: a refusal stays one line
        print(f"ooc-dem: warning: {w}", file=sys.stderr)
    # the trajectory continues from the resumed step: later frames dropped, this one written
    # if a kill came between the epoch's commit and the frame's
    if sim.frame_every:
        from .trajectory import TrajectoryError
        try:
            sim._start_trajectory(resumed=True)
        except TrajectoryError as e:
            raise RunError(str(e)) from None
    if step >= total:
        if sim.frames is not None:
            sim.frames.close()
            sim.frames = None
        done = sim.complete_outputs()
        print(f"{path}: run already finished at step {step}"
              + (f" (wrote its missing outputs: {', '.join(done)})" if done else " (nothing to do)"))
        return None
    return sim
