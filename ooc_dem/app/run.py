"""Simulation: a scenario advanced in one of the execution modes, with epochs,
time series, summary and figures written into its output directory (a store).

``plan.py`` resolves and checks the run's options first; the mode's engine comes from
the registry (``engine.modes``) and is driven through ``engine.interface.Engine`` only:
the run loop hands it a number of steps, gets back what they computed, folds it into
the metrics and commits the epochs. ``resume.py`` reads what a resume continues from.
"""

from __future__ import annotations

import dataclasses
import json
import os
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from .. import __version__
from ..engine.interface import Engine
from ..engine.modes import MODES, Mode
from ..engine.stepper import EngineError, Model
from ..model.checkpoint import FORMAT_VERSION, OpenEpoch, open_epoch
from ..model.scenario import Scenario
from ..model.state import Particles
from ..physics.layout import AX_X, AX_Y, AX_Z, REC_X, WS_SIZE
from .bed import bed_info, settled_bed, surface_height, wheel_footprint
from .outputs import complete_outputs, run_summary, write_outputs
from .plan import RunError, RunOptions, plan_run, streamable
from .progress import COMPILING, Progress, kernels_cached, settling_progress
from .resume import ResumeEpoch, check_engine_attrs, open_resume_epoch, stored_run
from .run_setup import StreamedBed, place_wheel, stopped_before_first_commit
from .runfiles import read_bed_info

if TYPE_CHECKING:
    from ooc_dem.storage.store import Store

    from .metrics import WheelMetrics
    from .trajectory import FrameParts, TrajectoryWriter

__all__ = [
    "RunError",
    "RunOptions",
    "Simulation",
    "plan_run",
    "resume_simulation",
    "run_to_end",
]


class Simulation:
    """A scenario run in one mode, writing its store, series, summary and figures into ``out``."""

    def __init__(self, sc: Scenario, out: str | Path, opts: RunOptions | None = None):
        self.sc = sc
        self.out = Path(out)
        self.opts = opts or RunOptions()
        # everything checked and sized before a byte is allocated or a file written
        self.plan = plan_run(sc, self.opts)
        self.mode: Mode = MODES[self.opts.mode]
        if self.opts.memory is not None and self.mode.decomposes:
            # the budget's D and K become the run's own (stored with it: a resume keeps them)
            self.opts = dataclasses.replace(self.opts, domains=self.plan.domains, block=self.plan.block)
        self.model = Model.from_scenario(sc)
        self.steps = self.plan.steps
        self.checkpoint_every = self.plan.checkpoint_every
        self.store: Store | None = None
        self.engine: Engine | None = None
        self.metrics: WheelMetrics | None = None
        self.step = 0
        self.surface = 0.0
        self.bed_info: dict[str, Any] | None = None  # bed.json: the bed's report (summary.json's "bed")
        self.wall_time = 0.0
        # trajectory frames (trajectory.py): every frame_every steps, 0 = none
        from .trajectory_format import frame_every

        self.frame_every = frame_every(sc)
        self.frames: TrajectoryWriter | None = None

    @property
    def redecompositions(self) -> list[dict[str, Any]]:
        """Every decomposition the engine has chosen ({"step", "bounds"}), stored with each epoch."""
        return self.engine.redecompositions if self.engine is not None else []

    def _engine(self) -> Engine:
        """The engine, which start or a resume has made before anything else uses it."""
        assert self.engine is not None, "the run is started or resumed first"
        return self.engine

    # ------------------------------------------------------------------ setup
    def _meta(self) -> dict[str, Any]:
        o = self.opts
        return {
            "engine": "ooc-dem",
            "engine_version": __version__,
            "format_version": FORMAT_VERSION,
            "dim": self.model.dim,
            "hist_cap": self.model.hist_cap,
            "scenario_toml": self.sc.to_toml(),
            "scenario_hash": self.sc.hash(),
            "scenario_name": self.sc.name,
            "run": {
                "mode": o.mode,
                "backend": o.backend,
                "domains": o.domains,
                "block": o.block,
                "steps": self.steps,
                "checkpoint_every": self.checkpoint_every,
                "io_overlap": o.io_overlap,
            },
        }

    def _store_backend(self) -> str:
        # monolithic and DDM checkpoint to a file store too; the backend is the user's choice
        return self.opts.backend

    def start(self, bed: Particles | None = None, streamed: bool = False) -> None:
        """Create the store and the initial epoch. ``streamed``: an out-of-core run of a
        tiled bare bed writes its bed into the store tile by tile (never the whole bed in RAM)."""
        from ooc_dem.storage import StoreError, create_store

        if self.out.exists() and any(self.out.iterdir()) and not stopped_before_first_commit(self.out):
            raise RunError(
                f"--out {self.out}: directory exists and is not empty (use a new directory, "
                f"or `ooc-dem resume {self.out}` to continue a run)"
            )
        sc = self.sc
        if streamed and bed is None and streamable(sc, self.opts):
            return self._start_streamed()
        if self.plan.streamed_bed:  # planned for a streamed bed, but the whole bed will be in RAM
            self.plan = plan_run(sc, self.opts, streamed=False)
        if bed is None:
            bed = settled_bed(self.sc, progress=settling_progress(self.sc) if self.opts.progress else None)
        ws = place_wheel(self.sc, bed) if self.sc.wheel.enabled else np.zeros(WS_SIZE)
        self.surface = surface_height(bed, self.sc.bin.length, self.sc.soil.r_max, across=wheel_footprint(self.sc))
        self.bed_info = bed_info(sc, bed, self.surface)
        try:
            self.store = create_store(self.out, self._store_backend(), self._meta(), compression=self.opts.compression)
        except StoreError as e:
            raise RunError(str(e)) from None
        # a memory store lives in this process only; the run's other outputs still go to --out
        self.out.mkdir(parents=True, exist_ok=True)
        # initial.npz keeps the 2D users' column names (x, y: layout.AXIS_NAMES)
        extra: dict[str, Any] = {"z": bed.pos[:, AX_Z]} if bed.dim == 3 else {}  # 3D: the slice and rut views
        np.savez(
            self.out / "initial.npz",
            id=bed.id,
            x=bed.pos[:, AX_X],
            y=bed.pos[:, AX_Y],
            r=bed.r,
            surface=np.float64(self.surface),
            **extra,
        )
        (self.out / "scenario.toml").write_text(self.sc.to_toml(), encoding="utf-8")
        (self.out / "bed.json").write_text(json.dumps(self.bed_info, indent=2), encoding="utf-8")
        self.engine = self._make_engine(bed, ws)
        if self.sc.wheel.enabled:
            from .metrics import WheelMetrics

            self.metrics = WheelMetrics(self.sc, self.surface, self.steps)
        self.step = 0
        self.commit()
        self._start_trajectory()

    def _start_streamed(self) -> None:
        from ooc_dem.storage import StoreError, create_store

        bed = StreamedBed(self.sc)
        try:
            self.store = create_store(self.out, self._store_backend(), self._meta(), compression=self.opts.compression)
        except StoreError as e:
            raise RunError(str(e)) from None
        self.out.mkdir(parents=True, exist_ok=True)
        (self.out / "scenario.toml").write_text(self.sc.to_toml(), encoding="utf-8")
        self.engine = self.mode.engine.create_streamed(
            self.sc,
            self.model,
            bed,
            np.zeros(WS_SIZE),
            domains=self.plan.domains,
            block=self.plan.block,
            store=self.store,
            **self._engine_options(),
        )
        # create_streamed passed over the bed once: its surfaces are measured
        assert bed.surfaces is not None, "the streamed bed was not passed over"
        self.surface = float(np.mean(bed.surfaces))
        self.bed_info = bed.measure.info(self.surface)
        (self.out / "bed.json").write_text(json.dumps(self.bed_info, indent=2), encoding="utf-8")
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
            self.frames = TrajectoryWriter.reopen(
                self.out, self.sc, self.model.dim, self.n_discs(), self.step, durable=self.opts.durable
            )
        else:
            self.frames = TrajectoryWriter.create(
                self.out, self.sc, self.model.dim, self.n_discs(), durable=self.opts.durable
            )
        if self.frames is not None and self.frames.due(self.step):
            self._write_frame(parts_written=False)

    def _frame_parts(self, step: int) -> FrameParts | None:
        """Where an engine that writes frame parts puts the discs of the frame due at
        ``step`` (None: no frame is due then, or the engine writes none)."""
        from .trajectory import FrameParts

        if self.frames is None or not self._engine().writes_frame_parts or not self.frames.due(step):
            return None
        return FrameParts(self.frames, step)

    def _write_frame(self, parts_written: bool) -> None:
        """Commit the frame of the current step; ``parts_written``: the engine wrote its parts
        during the advance (out-of-core, into ``_frame_parts``)."""
        from .trajectory_format import ROW_FIELDS

        # only called for a due frame, so the trajectory is open
        assert self.frames is not None, "no trajectory open"
        t = self.step * self.sc.physics.dt
        ws = np.asarray(self._engine().wheel_state, np.float64)
        if parts_written:
            self.frames.end(self.step, t, ws)
        else:
            # one part at a time (out-of-core: each group of the committed epoch; never the whole bed)
            self.frames.write_frame(self.step, t, ws, self._engine().state_parts(ROW_FIELDS))

    def _engine_options(self) -> dict[str, bool]:
        """The run's options the mode's engine takes besides its geometry (out-of-core:
        --io-overlap)."""
        return {"io_overlap": self.opts.io_overlap} if self.mode.out_of_core else {}

    def _make_engine(self, particles: Particles, ws: NDArray[np.float64]) -> Engine:
        engine: Engine = self.mode.engine.create(
            self.sc,
            self.model,
            particles,
            ws,
            domains=self.plan.domains,
            block=self.plan.block,
            store=self.store,
            **self._engine_options(),
        )
        return engine

    def _reopen_engine(self, reader: OpenEpoch, arrays: dict[str, NDArray[Any]], attrs: dict[str, Any]) -> Engine:
        """The engine continuing from the committed epoch ``reader`` reads (checked)."""
        engine: Engine = self.mode.engine.reopen(
            self.sc,
            self.model,
            reader,
            arrays["wheel_state"],
            attrs.get("engine"),
            store=self.store,
            redecompositions=list(attrs.get("redecompositions", [])),
            **self._engine_options(),
        )
        return engine

    def _continue_from(self, store: Store, epoch: ResumeEpoch, where: Path) -> None:
        """Take up the committed epoch a resume reads (``resume.open_resume_epoch``): its
        step, surface, wall time, wheel metrics and the engine continuing from it."""
        attrs = epoch.attrs
        self.model.hist_cap = epoch.hist_cap
        self.store = store
        self.step = attrs["step"]
        self.surface = float(attrs.get("surface", 0.0))
        self.wall_time = float(attrs.get("wall_time", 0.0))
        at = f"{where}: epoch {epoch.reader.step}"
        if self.sc.wheel.enabled:
            from .metrics import WheelMetrics

            metrics = self.metrics = WheelMetrics(self.sc, self.surface, max(self.steps, self.step))
            try:
                metrics.load_state(epoch.arrays)
            except (KeyError, ValueError) as e:  # missing or mis-shaped accumulators
                raise RunError(
                    f"{at}: stored wheel metrics unusable ({type(e).__name__}: {' '.join(str(e).split())})"
                ) from None
        if self.mode.decomposes:
            check_engine_attrs(attrs.get("engine"), len(epoch.reader.domains()), at)
        self.engine = self._reopen_engine(epoch.reader, epoch.arrays, attrs)

    # ------------------------------------------------------------ checkpoint
    def commit(self) -> None:
        from ooc_dem.storage import StoreError

        attrs = {
            "step": self.step,
            "time": self.step * self.sc.physics.dt,
            "surface": self.surface,
            "scenario_hash": self.sc.hash(),
            "mode": self.opts.mode,
            "wall_time": self.wall_time,
            "redecompositions": self.redecompositions,
            "format_version": FORMAT_VERSION,
            "engine_version": __version__,
        }
        engine = self._engine()
        attrs["engine"] = engine.info()
        arrays = {"wheel_state": np.asarray(engine.wheel_state, np.float64).copy()}
        if self.metrics is not None:
            arrays.update(self.metrics.state_arrays())
        try:
            engine.commit(self.step, arrays, attrs, self.opts.durable)
        except StoreError as e:
            raise RunError(str(e)) from None

    def fold(self, rec: NDArray[np.float64], step0: int) -> None:
        """Fold per-step wheel records into the metrics (sequential: block-size independent)."""
        if self.metrics is not None:
            self.metrics.add(rec, step0)

    # ------------------------------------------------------------------- run
    def run(self) -> dict[str, Any]:
        if self.engine is None:
            self.start()
        engine = self._engine()
        dt = self.sc.physics.dt
        if self.opts.progress and self.step < self.steps and not kernels_cached(self.sc.dim):
            print(f"ooc-dem: {COMPILING}", file=sys.stderr, flush=True)
        bar = Progress(self.opts.progress, self.steps - self.step, dt, f"{self.sc.name} [{self.opts.mode}]")
        chunk_pref = engine.preferred_chunk
        t_start = time.time() - self.wall_time
        try:
            while self.step < self.steps:
                next_ckpt = (self.step // self.checkpoint_every + 1) * self.checkpoint_every
                # frame steps end an advance too (out-of-core: a sweep), like epochs: where an
                # advance is cut never changes a bit (docs/design.md section 3)
                next_frame = (
                    (self.step // self.frame_every + 1) * self.frame_every if self.frames is not None else self.steps
                )
                n = min(self.steps, next_ckpt, next_frame, self.step + chunk_pref) - self.step
                step0 = self.step
                frame = self._frame_parts(step0 + n)
                rec = engine.advance(step0, n, frame)
                self.fold(rec, step0)
                self.step = step0 + n
                self.wall_time = time.time() - t_start
                post: dict[str, str] = {}
                if self.sc.wheel.enabled and len(rec):
                    post["x"] = f"{rec[-1, REC_X]:.4f}"
                bar.update(self.step, n, **post)
                # out-of-core: the advance wrote this step's epoch; committed first (the next
                # sweep reads it, and a frame is published only after its epoch)
                committed = engine.epoch_each_advance
                if committed:
                    self.commit()
                if self.frames is not None and self.frames.due(self.step):
                    self._write_frame(parts_written=frame is not None)
                if not committed and (self.step % self.checkpoint_every == 0 or self.step == self.steps):
                    self.commit()
        except EngineError as e:
            raise RunError(f"{e} (last committed epoch kept in {self.out})") from None
        except KeyboardInterrupt:
            # still a KeyboardInterrupt (every handler of Ctrl-C sees one), now saying where it stopped
            raise KeyboardInterrupt(self.interrupted_message()) from None
        finally:
            bar.close()
        summary = self.finish()
        self.close()
        return summary

    def interrupted_message(self) -> str:
        """What an interrupted run tells: its directory and the step `resume` continues from."""
        # read back from the store: a Ctrl-C can land after a commit reached the disk and before
        # anything in this process recorded it
        at: int | None = None
        if self.store is not None:
            try:
                cur = self.store.manifest(fresh=True)["current"]
                at = None if cur is None else int(cur["step"])
            except Exception:  # noqa: BLE001 - the message falls back to what this process saw
                at = self.store.current()
        if at is None:
            return f"interrupted before the first epoch was committed: {self.out} holds no run yet (run it again)"
        return (
            f"interrupted at step {self.step}: `ooc-dem resume {self.out}` continues from step {at} "
            f"(t = {at * self.sc.physics.dt:.6g} s, the last committed epoch)"
        )

    def close(self) -> None:
        """Release the store (and its write lock); the outputs stay in the run directory."""
        if self.frames is not None:
            self.frames.close()
            self.frames = None
        if self.store is not None:
            self.store.close()

    def finish(self) -> dict[str, Any]:
        """Write series.csv, summary.json and the figures from the committed final state
        (``outputs.py``: each under a temporary name, renamed when complete)."""
        results: dict[str, Any] = {"bed": self.bed_info} if self.bed_info is not None else {}
        results.update(self.metrics.summary() if self.metrics is not None else {})
        if self.sc.repose.enabled:  # the angle-of-repose test (docs/reference/repose3d.md)
            from .repose import heap_outputs

            # in id order: every mode (and the state read back) gives the same bits; the
            # figure is written before summary.json, so a summary means both are there
            p = self._engine().particles().sorted_by_id()
            results["repose"] = heap_outputs(self.out, self.sc, p.pos, p.r, p.vel, self.opts.figures)
        summary = run_summary(
            scenario=self.sc.name,
            scenario_hash=self.sc.hash(),
            mode=self.opts.mode,
            backend=self.opts.backend,
            steps=self.step,
            dt=self.sc.physics.dt,
            wall_time=self.wall_time,
            n_discs=self.n_discs(),
            engine=self._engine().info(),
            results=results,
            state_hash=self.state_hash(),
        )
        write_outputs(
            self.out,
            summary,
            self.metrics.series() if self.metrics is not None else None,
            figures=self.opts.figures and self.metrics is not None,
        )
        return summary

    def complete_outputs(self) -> list[str]:
        """After the last commit: write whichever outputs a kill left unwritten; return their names."""
        from .plots import figure_files
        from .repose import REPOSE_FIGURE

        repose = (REPOSE_FIGURE,) if self.opts.figures and self.sc.repose.enabled else ()
        figures = figure_files(self.sc) if self.opts.figures and self.metrics is not None else ()
        return complete_outputs(
            self.out, self.step, self.finish, series=self.metrics is not None, figures=figures, summary_figures=repose
        )

    def n_discs(self) -> int:
        return self._engine().n_discs()

    def state_hash(self) -> str:
        from ..model.checkpoint import hash_epoch
        from ..model.state_check import state_bounds
        from ooc_dem.storage import open_store

        store = open_store(self.out, repair=False)  # read-only: this run holds the write lock
        reader = open_epoch(store)
        # streamed and validated as read: never the whole state in RAM
        h = hash_epoch(reader, str(self.out), self.model.dim, self.model.hist_cap, state_bounds(self.sc))
        reader.close()
        store.close()
        return h


def resume_simulation(
    path: str | os.PathLike[str],
    steps: int | None = None,
    until: float | None = None,
    progress: bool = True,
    figures: bool = True,
    mode: str | None = None,
) -> Simulation | None:
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
        store.close()  # releases the write lock: a refused resume leaves the store free
        raise
    if sim is None:
        store.close()
    return sim


def finished_summary(out: Path, sc: Scenario, opts: RunOptions) -> dict[str, Any] | None:
    """The summary of the run in ``out`` if it ran to its planned end, else None."""
    from .plan import total_steps
    from .runfiles import read_summary

    summary = read_summary(out, complete=False)
    if summary is None or summary.get("steps") != total_steps(sc, opts):
        return None
    return summary


def run_to_end(sc: Scenario, out: Path, opts: RunOptions) -> str:
    """Run ``sc`` in ``out`` to its planned end: reuse it when finished, resume it when
    stopped after a commit, start it otherwise (the caller has checked that ``out`` holds
    a run of ``sc``). Returns what was done: "reused", "resumed" or "ran"."""
    from .plan import total_steps

    if out.exists():
        if finished_summary(out, sc, opts) is not None:
            return "reused"
        if any(out.iterdir()) and not stopped_before_first_commit(out):
            sim = resume_simulation(out, steps=total_steps(sc, opts), progress=opts.progress, figures=opts.figures)
            if sim is not None:
                sim.run()
            return "resumed"
    Simulation(sc, out, opts).run()
    return "ran"


def _reopen(
    store: Store,
    path: Path,
    steps: int | None,
    until: float | None,
    progress: bool,
    figures: bool,
    mode: str | None = None,
) -> Simulation | None:
    """resume_simulation's work on an open store (None: the run was already finished)."""
    sc, opts = stored_run(store, path, steps, until, progress, figures, mode)
    sim = Simulation(sc, path, opts)  # the stored options planned and checked as a run's
    sim.bed_info = read_bed_info(path)  # the bed's report, for summary.json (None: an older run)
    epoch = open_resume_epoch(store, path, sc)
    try:
        sim._continue_from(store, epoch, path)
    finally:
        epoch.reader.close()
    for w in store.warnings:  # only once the epoch is accepted: a refusal stays one line
        print(f"ooc-dem: warning: {w}", file=sys.stderr)
    # the trajectory continues from the resumed step: later frames dropped, this one written
    # if a kill came between the epoch's commit and the frame's
    if sim.frame_every:
        from .trajectory_format import TrajectoryError

        try:
            sim._start_trajectory(resumed=True)
        except TrajectoryError as e:
            raise RunError(str(e)) from None
    if sim.step >= sim.steps:
        if sim.frames is not None:
            sim.frames.close()
            sim.frames = None
        done = sim.complete_outputs()
        print(
            f"{path}: run already finished at step {sim.step}"
            + (f" (wrote its missing outputs: {', '.join(done)})" if done else " (nothing to do)")
        )
        return None
    return sim
