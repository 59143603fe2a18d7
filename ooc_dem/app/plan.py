"""A run's plan: its options resolved and checked against its scenario and this machine
before anything is allocated or written (the mode, steps, checkpoints, sub-domains D and
block K, the memory it needs). ``run``, ``check`` and ``resume`` share it; the modes and
what they can do come from the registry (``engine.modes``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from ..engine import budget
from ..errors import OocDemError
from ..engine.modes import MODES, mode_names
from ..model.scenario import Scenario
from ..model.scenario_check import critical_time_step
from ..model.schema import MAX_DOMAINS, MAX_STEPS, big, did_you_mean, show, steps_for_duration
from ..storage import BACKENDS
from .metrics import N_SERIES


class RunError(OocDemError, RuntimeError):
    """A run cannot start or continue (message is one line)."""


@dataclass
class RunOptions:
    mode: str = "monolithic"
    backend: str = "hdf5"
    domains: int | None = None
    block: int | None = None
    steps: int | None = None  # total steps to run (from step 0)
    duration: float | None = None  # or: total simulated time to run, s (from t = 0)
    checkpoint_every: int | None = None  # steps between committed epochs
    durable: bool = False
    progress: bool = True
    figures: bool = True
    memory: int | None = None  # bytes the run may hold at its peak (--memory): chooses D, K
    compression: str | None = None  # the store's (storage.COMPRESSIONS[backend]); None: off
    io_overlap: bool = False  # out-of-core: read ahead, write behind in threads (--io-overlap)


def total_steps(sc: Scenario, opts: RunOptions) -> int:
    if opts.steps is not None:
        if not 0 <= opts.steps <= MAX_STEPS:
            raise RunError(f"--steps {show(opts.steps)}: must be in [0, {big(MAX_STEPS)}]")
        return int(opts.steps)
    if opts.duration is not None:
        return steps_for_duration(opts.duration, sc.physics.dt, f"--duration {show(opts.duration)}")
    if sc.wheel.enabled:
        return steps_for_duration(
            sc.wheel.settle_time + sc.wheel.travel_time, sc.physics.dt, "wheel.settle_time + wheel.travel_time"
        )
    return int(sc.output.run_steps)


# ---- memory plan: the measured bytes per particle of each mode and dimension, and the
# budget that chooses D and K, live in engine/budget.py
SERIES_ROW_BYTES = N_SERIES * 8  # one series.csv row (float64 columns)
MIN_DISCS_PER_DOMAIN = 20  # a sub-domain of fewer discs is all halo and overhead


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

    def as_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


# ns per particle-step of a whole run (kernels compiled, the machine's threads), fitted on the
# 2-core machine of docs/benchmarks.md: quick (2D, 1500 discs, 220 000 steps, 32 s) and the
# Ding 2011 wheels (3D Hertz, 49 350 spheres, one thread); 3D linear not fitted apart
# (docs/benchmarks.md). A rough guide, not a promise.
COST_NS = {(2, "linear"): 97.0, (3, "linear"): 400.0, (3, "hertz"): 400.0}
COST_BASIS = (
    "fitted cost model: particles x steps x {ns:g} ns (this dimension and law on the 2-core machine of "
    "docs/benchmarks.md, kernels compiled; first run: + a few minutes of compiling); rough, +-50 %"
)


def estimate_wall_time(sc: Scenario, steps: int) -> dict[str, Any]:
    """The run's wall time by the fitted cost model (``COST_NS``): seconds and the basis."""
    law = sc.contact.soil_soil.law if sc.dim == 3 else "linear"
    ns = COST_NS.get((sc.dim, law), COST_NS[(3, "hertz")])
    return {"seconds": round(sc.soil.n * steps * ns * 1e-9, 1), "basis": COST_BASIS.format(ns=ns)}


_fmt_bytes = budget.fmt_bytes
_hop = budget.hop


def max_domains(sc: Scenario) -> int:
    """The most sub-domains that make sense for the bed: each slab at least one contact hop
    wide and holding at least MIN_DISCS_PER_DOMAIN discs (and at most MAX_DOMAINS)."""
    by_width = int(sc.bin.length // _hop(sc))
    by_discs = sc.soil.n // MIN_DISCS_PER_DOMAIN
    return max(1, min(MAX_DOMAINS, by_width, by_discs))


def _domains_and_block(sc: Scenario, opts: RunOptions) -> tuple[int, int]:
    if not MODES[opts.mode].decomposes:
        return 1, 1
    D = opts.domains or sc.decomposition.domains
    if opts.domains is not None and not 1 <= opts.domains <= MAX_DOMAINS:
        raise RunError(f"--domains {show(opts.domains)}: must be in [1, {MAX_DOMAINS}]")
    limit = max_domains(sc)
    if D > limit:
        what = f"--domains {D}" if opts.domains else f"decomposition.domains = {D}"
        raise RunError(
            f"{what}: at most {limit} sub-domain{'s' if limit > 1 else ''} for this bed ({sc.soil.n} discs, "
            f"bin.length {sc.bin.length:g} m: each slab needs >= {MIN_DISCS_PER_DOMAIN} discs "
            f"and >= one contact hop {_hop(sc):.3g} m)"
        )
    return D, _block_for(sc, opts, D)


def _block_for(sc: Scenario, opts: RunOptions, domains: int) -> int:
    """K exactly as the mode's engine will choose it for D sub-domains (its own rule, not a copy)."""
    return opts.block or MODES[opts.mode].engine.default_block(sc, domains)


def streamable(sc: Scenario, opts: RunOptions) -> bool:
    """An out-of-core run of a tiled bare bed writes its bed into the store tile by tile."""
    return MODES[opts.mode].out_of_core and not sc.wheel.enabled and 0 < sc.bed.tile < sc.soil.n


def _series_bytes(sc: Scenario, steps: int) -> float:
    """A wheel run's series: the grown buffer (up to twice the rows) plus the copy each commit writes."""
    if not sc.wheel.enabled:
        return 0.0
    per_row = max(1, int(round(sc.output.series_interval / sc.physics.dt)))
    return 3.0 * (steps // per_row + 1) * SERIES_ROW_BYTES


def _slabs(opts: RunOptions) -> int:
    """Out-of-core slabs resident at once: one, or three with --io-overlap."""
    return 3 if opts.io_overlap and MODES[opts.mode].out_of_core else 1


def estimate_memory(sc: Scenario, opts: RunOptions, steps: int, domains: int, block: int, streamed: bool) -> int:
    """Bytes the run needs at its peak (engine/budget.py: measured bytes per particle)."""
    return budget.estimate_peak(
        sc, opts.mode, opts.backend, domains, block, streamed, _series_bytes(sc, steps), _slabs(opts)
    )


def _budgeted(sc: Scenario, opts: RunOptions, steps: int, streamed: bool) -> tuple[int, int]:
    """--memory: out-of-core takes the fewest sub-domains (the largest slab) whose slab, halo
    and I/O buffers fit, and K as the sweep chooses it for them; a --domains or --block given
    too is kept. Other modes only check the budget."""
    memory = opts.memory
    assert memory is not None, "only a run given --memory is budgeted"
    if not memory >= 1:
        raise RunError(f"--memory {show(memory)}: must be a positive size such as 2GB")
    if not MODES[opts.mode].out_of_core or opts.domains is not None:
        return _domains_and_block(sc, opts)
    block_of = lambda D: _block_for(sc, opts, D)
    got = budget.choose_decomposition(
        sc, memory, block_of, max_domains(sc), opts.backend, streamed, _series_bytes(sc, steps), _slabs(opts)
    )
    if got is None:
        raise RunError(
            budget.smallest_fit_message(
                sc, memory, block_of, max_domains(sc), opts.backend, streamed, _series_bytes(sc, steps), _slabs(opts)
            )
        )
    return got[0], got[1]


def machine_memory() -> int:
    import psutil

    return int(psutil.virtual_memory().total)


def _check_compression(opts: RunOptions) -> None:
    from ooc_dem.storage import COMPRESSIONS

    have = COMPRESSIONS.get(opts.backend, ())
    if opts.compression is not None and opts.compression not in have:
        raise RunError(
            f"--compression {show(opts.compression)}: the {opts.backend} backend has "
            f"{', '.join(have) or 'no compression'}"
        )


def plan_run(sc: Scenario, opts: RunOptions, streamed: bool | None = None) -> RunPlan:
    """Resolve and check a run's options against its scenario and this machine (no allocation,
    no file, no bed): the shared planning of `run`, `check` and `resume`."""
    if opts.mode not in MODES:
        raise RunError(
            f"--mode {show(opts.mode)}: must be one of {', '.join(mode_names())}" + did_you_mean(opts.mode, MODES)
        )
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
        raise RunError(
            f"--memory {_fmt_bytes(opts.memory)}: the {opts.mode} run needs about "
            f"{_fmt_bytes(need)} (D = {D}, K = {K})"
            + ("" if MODES[opts.mode].out_of_core else "; --mode ooc chooses sub-domains that fit")
        )
    return RunPlan(
        scenario=sc.name,
        mode=opts.mode,
        backend=opts.backend,
        n_discs=sc.soil.n,
        steps=steps,
        simulated_time_s=steps * sc.physics.dt,
        dt_s=sc.physics.dt,
        dt_critical_s=critical_time_step(sc),
        checkpoint_every=every,
        domains=D,
        block=K,
        streamed_bed=streamed,
        memory_bytes=need,
        memory_available_bytes=have,
        memory_budget_bytes=opts.memory,
    )


def check_bed_memory(sc: Scenario) -> int:
    """`ooc-dem prepare`: the whole settled bed is held (an untiled bed is settled as one domain).
    Returns the estimated bytes; refuses what cannot fit, naming soil.n."""
    m = budget.byte_model(sc.dim)
    tiled = 0 < sc.bed.tile < sc.soil.n
    per_disc = 2 * m.state if tiled else m.monolithic
    need = m.baseline + sc.soil.n * per_disc
    have = machine_memory()
    if need > have:
        raise RunError(
            f"soil.n = {sc.soil.n}: preparing the bed needs about {_fmt_bytes(need)} of memory, "
            f"this machine has {_fmt_bytes(have)} (`ooc-dem run --mode ooc` streams a tiled bed "
            f"instead)"
        )
    return need


def _memory_message(sc: Scenario, opts: RunOptions, steps: int, need: int, have: int, streamed: bool) -> str:
    series_rows = steps // max(1, int(round(sc.output.series_interval / sc.physics.dt))) + 1
    series = _series_bytes(sc, steps)
    if series > need / 2:
        what = f"output.series_interval = {sc.output.series_interval!r}: {steps} steps keep {series_rows} series rows"
    else:
        what = f"soil.n = {sc.soil.n}"
    msg = f"{what}: the run needs about {_fmt_bytes(need)} of memory ({opts.mode}), this machine has {_fmt_bytes(have)}"
    out_of_core = MODES[opts.mode].out_of_core
    if not out_of_core and series <= need / 2:
        ooc = RunOptions(**{**dataclasses.asdict(opts), "mode": "ooc", "domains": None, "block": None})
        D = max_domains(sc)
        alt = estimate_memory(sc, ooc, steps, D, 1, streamable(sc, ooc))
        if alt <= have:
            msg += f"; --mode ooc --domains {D} would need about {_fmt_bytes(alt)}"
    elif out_of_core and series <= need / 2 and not streamed and not sc.wheel.enabled:
        msg += " (out-of-core set-up holds the bed unless it is tiled: bed.tile)"
    return msg


def default_checkpoint_every(sc: Scenario, steps: int) -> int:
    """One epoch per simulated second of a wheel run (at most ~100 per run), else only at the end."""
    if sc.wheel.enabled:
        every = int(round(min(1.0 / sc.physics.dt, MAX_STEPS)))  # a tiny dt: 1/dt overflows
        return max(every, -(-steps // 100)) if steps else every
    return max(1, steps)
