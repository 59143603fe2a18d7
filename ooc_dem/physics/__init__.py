"""Numba kernels only, no I/O. One module of step kernels per dimension (``d2``, ``d3``),
each exposing ``run_steps(nsteps, step0, kp, d, pl, bd, forces, ws, err, rec, rebuild_now, pairs_done,
role, spans)`` and ``spatial_order(pos, n, cell)``; ``kernels(dim)`` picks it."""
import importlib


def kernels(dim: int):
    """The step-kernel module of a dim-dimensional model (physics.d2, physics.d3)."""
    if dim not in (2, 3):
        raise ValueError(f"dimension {dim!r} not supported (expected 2 or 3)")
    return importlib.import_module(f"{__name__}.d{int(dim)}")
