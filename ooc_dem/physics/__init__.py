"""Numba kernels only, no I/O. One module of step kernels per dimension (``d2``, ``d3``),
each exposing ``run_steps(nsteps, step0, kp, d, pl, bd, forces, ws, err, rec, rebuild_now, pairs_done,
role, spans)`` and ``spatial_order(pos, n, cell)``; ``kernels(dim)`` picks it."""
import importlib

import llvmlite.binding as _llvm

# The 3D pair law runs on blocks of pairs (d3.forces.law_block), one loop that reads ~40
# arrays and writes 15. LLVM vectorizes such a loop only after checking at run time that
# the arrays do not overlap, and by default gives up beyond 8 such checks (two options:
# loops without and with a vectorize hint); this budget lets it. It changes no result:
# LLVM vectorizes without reordering or fusing any floating-point operation (no fast-math).
_llvm.set_option("", "--runtime-memory-check-threshold=4096")
_llvm.set_option("", "--vectorize-memory-check-threshold=4096")


def kernels(dim: int):
    """The step-kernel module of a dim-dimensional model (physics.d2, physics.d3)."""
    if dim not in (2, 3):
        raise ValueError(f"dimension {dim!r} not supported (expected 2 or 3)")
    return importlib.import_module(f"{__name__}.d{int(dim)}")
