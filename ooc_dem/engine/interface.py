"""The one interface of the engines (monolithic, serial DDM, out-of-core, and both on MPI ranks).

The run loop (``app/run.py``, ``Simulation``) drives an engine through these members
only; it never asks which class it holds. An engine is given what it needs when it is
made (scenario, model, options, the store) and never calls back into the application:
an ``advance`` returns what it computed (the wheel's records; out-of-core also leaves
the epoch it wrote open) and the run loop folds and commits it.

The one thing an engine hands over while it advances is a trajectory frame's parts
(``FrameParts``), and only out-of-core does: its slabs are in RAM one at a time, so a
frame due at the end of a sweep gets each slab's owned discs as the sweep passes them.
Returning them instead would hold one value per disc of the whole bed; yielding them to
the run loop would hand control back mid-sweep, and with ``--io-overlap`` the parts are
written by the write-behind thread while the next slab computes. So the loop passes a
sink for that one advance: a plain data destination whose type is defined here, which
the application implements (its trajectory writer) and the engine does not keep.
"""

from __future__ import annotations

from typing import Callable, Iterable, Iterator, Protocol, runtime_checkable

import numpy as np

from ..model.state import Particles


@runtime_checkable
class Engine(Protocol):
    """What the run loop needs of an engine."""

    #: the execution mode this engine implements (``engine.modes``)
    name: str
    #: the most steps the run loop hands to one ``advance`` (a whole number of blocks;
    #: out-of-core: one block)
    preferred_chunk: int
    #: True if every ``advance`` writes the epoch of its end step and leaves it open
    #: (out-of-core: a sweep reads the committed epoch e and writes e + 1): the run loop
    #: commits it before anything else, since the next advance reads it
    epoch_each_advance: bool
    #: True if ``advance`` writes the discs of its end state into the ``frame`` it is
    #: given (out-of-core: each slab's owned discs as the sweep passes them); the run loop
    #: writes the other engines' frames from ``state_parts``
    writes_frame_parts: bool
    #: every decomposition chosen so far: {"step", "bounds"} (stored with each epoch)
    redecompositions: list

    @property
    def wheel_state(self) -> np.ndarray:
        """The wheel state (``layout.WHEEL_STATE``) after the last advance."""
        ...

    def advance(self, step0: int, nsteps: int, frame: "FrameParts | None" = None) -> np.ndarray:
        """Advance every disc nsteps steps from global step step0; the wheel's per-step
        records (``layout.WHEEL_RECORD``), one row per step (none without a wheel).
        ``frame``: where the discs at step0 + nsteps go if the engine writes frame parts
        (``writes_frame_parts``; the others leave it alone)."""
        ...

    def particles(self) -> Particles:
        """The whole current state in RAM (for callers that hold it anyway)."""
        ...

    def n_discs(self) -> int: ...

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


class FrameParts(Protocol):
    """Where an engine that writes frame parts puts the discs of the state at the end of
    an advance, one part at a time (a store record holding at least id, pos, vel, spin, r
    and mat); every disc goes into exactly one part. The run loop hands one to
    ``Engine.advance`` when a trajectory frame is due at its end, and publishes the frame
    after the advance."""

    def write_part(self, part: dict) -> None: ...


def write_epoch(store, step: int, write_domains: Callable, arrays: dict, attrs: dict, durable: bool = False) -> None:
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
