"""Numba kernels only, no I/O.

The step machinery is written once for every dimension: ``step`` (``run_steps``, and
``instantiate``, which compiles the machinery for a dimension), ``produce`` (phase 1:
one row per contact), ``gather`` (phase 2: each particle sums its rows and is
advanced), ``history`` (the pairs' springs between the particles' histories and the
pair rows), ``neighbors`` (cell lists, the half pair list and its CSR index), ``chunks``,
``wheel`` (the rigid wheel: lugs, reaction, motion), ``layout`` (the records every
dimension shares) and ``twins`` (``specialise``: one source compiled with a dimension's
kernels, and one-thread twins). What a template leaves to the dimension is a
``twins.Slot``.

Each dimension's package (``d2``, ``d3``) holds only what is its own -- its records,
contact law, contact rows, the walls' and the wheel's contact geometry and its cell
geometry -- and is a ``KernelModule``: the same names in every dimension, checked when
the package is imported. ``kernels(dim)`` picks it.
"""

from __future__ import annotations

import importlib
from typing import Callable, Protocol

import llvmlite.binding as _llvm
import numpy as np

# The 3D pair law runs on blocks of pairs (d3.forces.law_block), one loop that reads ~40
# arrays and writes 15. LLVM vectorizes such a loop only after checking at run time that
# the arrays do not overlap, and by default gives up beyond 8 such checks (two options:
# loops without and with a vectorize hint); this budget lets it. It changes no result:
# LLVM vectorizes without reordering or fusing any floating-point operation (no fast-math).
_llvm.set_option("", "--runtime-memory-check-threshold=4096")
_llvm.set_option("", "--vectorize-memory-check-threshold=4096")


class KernelModule(Protocol):
    """What every dimension's kernel module (``physics.d2``, ``physics.d3``) exports."""

    DIM: int  # axes D
    N_CHUNKS: int  # body-row buffers a Bodies holds (chunks.N_CHUNKS)
    N_ERR: int  # error flags (layout.ERRORS)
    CONTACT_PARAMS: np.dtype  # one material pair's record (table cp[type_a, type_b])
    WALLS: np.dtype  # the walls' record
    PAIR_ROW: np.dtype  # the general pair-row layout
    BODY_ROW: np.dtype  # one particle-body contact of a step
    pair_row_layout: Callable  # pair_row_layout(cp) -> the pair-row layout of table cp
    # the step (physics.step.run_steps) and its one-thread twin, with the twin's write-back
    # of the rows' springs (serial DDM's compiled sweeps, engine.live)
    run_steps: Callable
    run_steps_serial: Callable
    sync_history_serial: Callable
    spatial_order: Callable  # spatial_order(pos, n, cell) -> memory-order permutation
    # the phases of a step (tools/kernel_bench.py times them)
    produce: Callable
    gather_integrate: Callable
    load_history: Callable
    sync_history: Callable
    build_pairs: Callable


KERNEL_NAMES = tuple(KernelModule.__annotations__)


def check_kernel_module(module) -> None:
    """Raise ImportError unless ``module`` exports every KernelModule name."""
    missing = [k for k in KERNEL_NAMES if not hasattr(module, k)]
    if missing:
        raise ImportError(f"{module.__name__} is not a physics.KernelModule: no {', '.join(missing)}")


def kernels(dim: int) -> KernelModule:
    """The step-kernel module of a dim-dimensional model (physics.d2, physics.d3)."""
    if dim not in (2, 3):
        raise ValueError(f"dimension {dim!r} not supported (expected 2 or 3)")
    return importlib.import_module(f"{__name__}.d{int(dim)}")
