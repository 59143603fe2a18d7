"""The execution modes: one registry of name -> engine class and what the mode can do.

The application (planning, the run loop, resume), the command line and the profiler read
the modes from here and decide on their capabilities, never on their names. The engine
classes are imported on first use (``Mode.engine``): the command line's parser lists the
modes without loading the kernels.

Every engine class has the same constructors: ``create(sc, model, particles,
wheel_state, *, domains, block, store, **options)`` and ``reopen(sc, model, reader,
wheel_state, engine_attrs, *, store, redecompositions, **options)``, and
``default_block(sc, domains)``; out-of-core ones take ``io_overlap`` among the options
and also ``create_streamed`` (a bed that never is whole in RAM).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable


@dataclass(frozen=True)
class Mode:
    name: str
    #: one line for the command line's help
    summary: str
    #: split into D sub-domains advanced K steps a sweep (all but monolithic)
    decomposes: bool
    #: one slab and its halo resident at a time (on each rank for mpi-ooc), the epochs
    #: in the store: a memory budget chooses D and K
    out_of_core: bool
    #: runs on MPI ranks (under mpiexec)
    mpi: bool
    #: modes whose epochs are one another's (the same groups and bounds): a resume may
    #: switch between the modes of one family
    family: str
    _load: Callable[[], Any] = field(repr=False, compare=False)

    @property
    def engine(self) -> Any:
        """The engine class (``engine.interface.Engine``); typed Any: its factories
        (create, reopen, create_streamed) are classmethods whose options differ by mode."""
        return self._load()

    def switches_to(self, other: "Mode") -> bool:
        """Whether a run of this mode may be resumed in ``other``."""
        return other.family == self.family


def _monolithic() -> type:
    from .monolithic import MonolithicEngine

    return MonolithicEngine


def _ddm() -> type:
    from .sweep import DdmEngine

    return DdmEngine


def _ooc() -> type:
    from .ooc import OocEngine

    return OocEngine


def _mpi() -> type:
    from .mpi import MpiEngine

    return MpiEngine


def _mpi_ooc() -> type:
    from .mpi import MpiOocEngine

    return MpiOocEngine


MODES: dict[str, Mode] = {
    m.name: m
    for m in (
        Mode(
            "monolithic",
            "the whole bin as one domain",
            decomposes=False,
            out_of_core=False,
            mpi=False,
            family="monolithic",
            _load=_monolithic,
        ),
        Mode(
            "ddm",
            "serial domain decomposition, the sub-domains in RAM",
            decomposes=True,
            out_of_core=False,
            mpi=False,
            family="ddm",
            _load=_ddm,
        ),
        Mode(
            "ooc",
            "out-of-core: one slab and its halo in RAM, the epochs in the store",
            decomposes=True,
            out_of_core=True,
            mpi=False,
            family="ooc",
            _load=_ooc,
        ),
        Mode(
            "mpi",
            "serial DDM's sub-domains spread over MPI ranks",
            decomposes=True,
            out_of_core=False,
            mpi=True,
            family="ddm",
            _load=_mpi,
        ),
        Mode(
            "mpi-ooc",
            "out-of-core with each MPI rank streaming its own slabs",
            decomposes=True,
            out_of_core=True,
            mpi=True,
            family="ooc",
            _load=_mpi_ooc,
        ),
    )
}


def mode_names(where: Callable[[Mode], bool] = lambda m: True) -> tuple[str, ...]:
    """The modes' names (those for which ``where`` holds), in the registry's order."""
    return tuple(name for name, m in MODES.items() if where(m))


def switching_families() -> list[tuple[str, ...]]:
    """The families of more than one mode (a resume switches within one)."""
    families: dict[str, list[str]] = {}
    for m in MODES.values():
        families.setdefault(m.family, []).append(m.name)
    return [tuple(names) for names in families.values() if len(names) > 1]
