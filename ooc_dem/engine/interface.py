"""The one interface of the three engines (monolithic, serial DDM, out-of-core).

The run loop (``app/run.py``, ``Simulation``) drives an engine through these members
only; it never asks which class it holds. An engine is given what it needs when it is
made (scenario, model, options, the store, callbacks) and never reaches back into the
simulation that made it.
"""
from __future__ import annotations

from typing import Callable, Iterable, Iterator, Protocol, runtime_checkable

import numpy as np

from ..model.state import Particles


@runtime_checkable
class Engine(Protocol):
    """What the run loop needs of an engine."""

    #: the execution mode this engine implements ("monolithic", "ddm", "ooc")
    name: str
    #: the most steps the run loop hands to one ``advance`` (a whole number of blocks)
    preferred_chunk: int
    #: True if ``advance`` folds its wheel records into the metrics itself (out-of-core
    #: commits every sweep, so the records are folded before each commit)
    folds_records: bool
    #: True if a frame due at the end of an ``advance`` has had its discs written already
    #: (out-of-core writes each slab's part as the sweep passes it)
    writes_frame_parts: bool
    #: every decomposition chosen so far: {"step", "bounds"} (stored with each epoch)
    redecompositions: list

    @property
    def wheel_state(self) -> np.ndarray:
        """The wheel state (``layout.WHEEL_STATE``) after the last advance."""
        ...

    def advance(self, step0: int, nsteps: int) -> np.ndarray:
        """Advance every disc nsteps steps from global step step0; the wheel's per-step
        records (``layout.WHEEL_RECORD``), one row per step (none without a wheel)."""
        ...

    def particles(self) -> Particles:
        """The whole current state in RAM (for callers that hold it anyway)."""
        ...

    def n_discs(self) -> int:
        ...

    def state_parts(self, names: Iterable[str]) -> Iterator:
        """The current state one part at a time (``Particles`` or record dicts holding at
        least ``names``); out-of-core reads each group of the committed epoch in turn."""
        ...

    def commit(self, step: int, arrays: dict, attrs: dict, durable: bool = False) -> None:
        """Commit the state of ``step`` as an epoch of the store, with the globals
        ``arrays`` and ``attrs`` (raises ``storage.StoreError``)."""
        ...

    def info(self) -> dict:
        """What the run reports of the engine (summary.json and every epoch's attrs)."""
        ...


def write_epoch(store, step: int, write_domains: Callable, arrays: dict, attrs: dict,
                durable: bool = False) -> None:
    """Write one epoch into ``store``: the domain groups (``write_domains(writer)``), the
    globals, then the commit; the partial epoch is removed on any failure."""
    writer = store.begin_epoch(step)
    try:
        write_domains(writer)
        writer.write_globals(arrays, attrs)
        writer.commit(durable=durable)
    except BaseException:
        writer.abort()
        raise
