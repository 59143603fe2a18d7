"""What a resume continues from: a run's store read and checked as untrusted input (its
meta, the stored run options, the last intact epoch and its globals). ``run.py``'s
``resume_simulation`` makes the Simulation that continues from it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from numpy.typing import NDArray

from ..engine.modes import MODES, switching_families
from ..model.checkpoint import SUPPORTED_VERSIONS, open_epoch
from ..model.scenario import Scenario
from ..model.schema import show, steps_for_duration
from ..storage import BACKENDS
from .plan import RunError, RunOptions, total_steps

if TYPE_CHECKING:
    from ooc_dem.storage import Store


# the run options a store's meta must hold, with the types a resume accepts
_RUN_OPTION_TYPES = {
    "mode": (str,),
    "backend": (str,),
    "domains": (int, type(None)),
    "block": (int, type(None)),
    "steps": (int,),
    "checkpoint_every": (int,),
    "io_overlap": (bool, type(None)),
}  # None: a store written before it existed


def _stored_run_options(meta: dict[str, Any], path: Path) -> dict[str, Any]:
    """The run options recorded in a store's meta, checked (a store is untrusted input)."""
    stored = meta.get("run")
    if not isinstance(stored, dict):
        raise RunError(f"{path}: store meta has no run options (not written by `ooc-dem run`)")
    # each value's type is checked just below
    run: dict[str, Any] = {key: stored.get(key) for key in _RUN_OPTION_TYPES}
    for key, types in _RUN_OPTION_TYPES.items():
        if type(run[key]) not in types:
            raise RunError(
                f"{path}: stored run option {key!r} = {show(run[key])} has the wrong type (store damaged or edited)"
            )
    if run["mode"] not in MODES or run["backend"] not in BACKENDS:
        raise RunError(f"{path}: stored run mode/backend {show(run['mode'])}/{show(run['backend'])} unknown")
    for key in ("domains", "block"):
        if run[key] is not None and not 1 <= run[key] <= 100_000:
            raise RunError(f"{path}: stored run option {key!r} = {show(run[key])} out of range")
    if run["steps"] < 0 or run["checkpoint_every"] < 1:
        raise RunError(f"{path}: stored run options steps/checkpoint_every out of range")
    return run


def check_engine_attrs(engine: object, n_domains: int, where: str) -> None:
    """The decomposition a sweep engine resumes from: block K and the slab bounds."""
    if not isinstance(engine, dict):
        raise RunError(f"{where}: globals attribute 'engine' missing")
    block, bounds = engine.get("block"), engine.get("bounds")
    if type(block) is not int or not 1 <= block <= 100_000:
        raise RunError(f"{where}: stored block K = {show(block)}: must be an integer in [1, 100000]")
    if (
        not isinstance(bounds, list)
        or len(bounds) != n_domains - 1
        or not all(type(b) in (int, float) and math.isfinite(b) for b in bounds)
        or any(b1 < b0 for b0, b1 in zip(bounds, bounds[1:]))
    ):
        raise RunError(f"{where}: stored slab bounds must be {n_domains - 1} finite ascending numbers")


def stored_run(
    store: Store,
    path: Path,
    steps: int | None,
    until: float | None,
    progress: bool,
    figures: bool,
    mode: str | None = None,
) -> tuple[Scenario, RunOptions]:
    """The scenario and run options a store's meta holds (checked), with the new total
    steps (``steps`` or ``until``) and mode (``mode``: one of the stored mode's family)."""
    from ..model.checkpoint import stored_scenario
    from ..model.state_check import StateError

    meta = store.meta or {}
    if meta.get("engine") != "ooc-dem":
        raise RunError(f"{path}: not an ooc-dem run store")
    v = meta.get("format_version")
    if type(v) is not int or v not in SUPPORTED_VERSIONS:
        raise RunError(
            f"{path}: store format version {show(v)} is not supported "
            f"(this engine reads versions {', '.join(map(str, SUPPORTED_VERSIONS))})"
        )
    try:
        sc = stored_scenario(meta, str(path))
    except StateError as e:
        raise RunError(str(e)) from None
    run = _stored_run_options(meta, path)
    if store.current() is None:
        raise RunError(
            f"{path}: no committed epoch: the run stopped before its first checkpoint; "
            f"start it again with `ooc-dem run {sc.name} --out {path}` (it replaces "
            f"this empty store)"
        )
    total = run["steps"]
    if until is not None:
        total = steps_for_duration(until, sc.physics.dt, f"--until {show(until)}")
    elif steps is not None:
        total = total_steps(sc, RunOptions(steps=steps))
    if mode is not None and mode != run["mode"]:
        if mode not in MODES or not MODES[run["mode"]].switches_to(MODES[mode]):
            families = " and ".join(" and ".join(f) for f in switching_families())
            raise RunError(
                f"--mode {show(mode)}: a {run['mode']} run resumes in its own mode "
                f"(only {families} runs switch between each other)"
            )
        run["mode"] = mode
    opts = RunOptions(
        mode=run["mode"],
        backend=run["backend"],
        domains=run["domains"],
        block=run["block"],
        steps=total,
        checkpoint_every=run["checkpoint_every"],
        progress=progress,
        figures=figures,
        io_overlap=bool(run["io_overlap"]),
    )
    return sc, opts


@dataclass
class ResumeEpoch:
    """The store's last intact epoch, validated: its reader (open: the caller closes it),
    the history capacity its states were written with, and its globals."""

    reader: Any  # a store's epoch reader, or a format-1 one seen through V1Epoch (open_epoch)
    hist_cap: int
    arrays: dict[str, NDArray[Any]]
    attrs: dict[str, Any]


def open_resume_epoch(store: Store, path: Path, sc: Scenario) -> ResumeEpoch:
    """The last intact epoch of the store, validated against the stored layout and written
    by scenario ``sc``."""
    from ooc_dem.storage import StoreError
    from ..model.checkpoint import stored_layout
    from ..model.state_check import StateError, validate_epoch

    reader = None
    try:
        try:
            dim, hist_cap, bounds = stored_layout(store.meta or {}, str(path), sc)
            reader = open_epoch(store)
            validate_epoch(reader, str(path), dim, hist_cap, bounds)
        except (StoreError, StateError) as e:
            raise RunError(str(e)) from None
        arrays, attrs = reader.read_globals()
        if attrs.get("scenario_hash") != sc.hash():
            raise RunError(f"{path}: epoch {reader.step} was written by a different scenario")
    except BaseException:
        if reader is not None:
            reader.close()
        raise
    return ResumeEpoch(reader, hist_cap, arrays, attrs)
