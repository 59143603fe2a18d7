"""Serial twins of parallel kernels (numba, no I/O).

Serial DDM runs its sub-domains side by side, one per thread, inside one compiled call;
each sub-domain's step must then run on its own thread, not launch a parallel region of
its own. ``serial_twin`` compiles the same Python source a second time, without
``parallel`` (``prange`` becomes ``range``) and with the kernels it calls replaced by
their own serial twins. The arithmetic is the same source, so the bits are the same.
"""
from __future__ import annotations

import sys
import types
import warnings

from numba import njit
from numba.core.cpu_options import ParallelOptions
from numba.core.errors import NumbaPerformanceWarning

# the twins ask for the parallel pipeline on purpose without a parallel loop (numba may put
# terminal colour codes and a newline before the text: the pattern allows any prefix; pytest,
# which restores the filters after each test, has the same filter in pyproject.toml)
TWIN_WARNING = r"(?s).*The keyword argument 'parallel=True' was specified but no transformation"
warnings.filterwarnings("ignore", message=TWIN_WARNING, category=NumbaPerformanceWarning)

# numba's parallel pipeline with every transformation off: no parallel region is made
# (prange is a plain range), yet the loops compile to code several times faster than
# plain njit's (measured on the history lookup loop: 15 us against 120 us for 1500
# discs); same source, same arithmetic, same bits. Given to numba as a ParallelOptions,
# never as a dict: numba builds its options from a dict by popping the keys, so one
# shared dict is empty after the first compilation and every later twin would get the
# default (every transformation on: a parallel region inside each "serial" step)
NO_PARFORS = {"comprehension": False, "prange": False, "numpy": False, "reduction": False,
              "inplace_binop": False, "setitem": False, "stencil": False, "fusion": False}


def no_parfors() -> ParallelOptions:
    """numba's parallel pipeline with every transformation off (a fresh copy)."""
    return ParallelOptions(dict(NO_PARFORS))


def serial_twin(kernel, name: str, parallel: bool = False, **callees):
    """njit(cache=True) of ``kernel``'s Python function under ``name``, its global names
    in ``callees`` (kernel name -> serial twin) rebound. ``kernel`` is a numba dispatcher
    or a plain function; the twin caches under its own name. ``parallel``: compile the
    twin itself with prange (a driver whose callees are serial twins)."""
    py = getattr(kernel, "py_func", kernel)
    g = dict(py.__globals__)
    for k in callees:
        if k not in py.__code__.co_names:
            raise KeyError(f"serial_twin({py.__name__}): it does not call {k!r}")
    g.update(callees)
    f = types.FunctionType(py.__code__, g, name, py.__defaults__, py.__closure__)
    f.__qualname__ = name
    f.__module__ = py.__module__
    f.__doc__ = f"Serial twin of {py.__name__} (physics.twins)."
    return njit(cache=True, parallel=True if parallel else no_parfors())(f)


def step_twin(run_steps):
    """The one-thread twin ``run_steps_serial`` of a dimension's step: ``run_steps`` with the
    phases it calls (produce, gather_integrate, build_pairs, sync_history, load_history)
    replaced by their serial twins, each found beside its phase as ``<phase>_serial`` (the
    same convention in 2D and 3D). Serial DDM's compiled sweeps run it on each sub-domain
    (engine.live)."""
    g = getattr(run_steps, "py_func", run_steps).__globals__
    callees = {}
    for phase in STEP_PHASES:
        kernel = g[phase]
        home = sys.modules[getattr(kernel, "py_func", kernel).__module__]
        callees[phase] = getattr(home, phase + "_serial")
    return serial_twin(run_steps, "run_steps_serial", **callees)


# what a step calls that runs in parallel (step_twin)
STEP_PHASES = ("produce", "gather_integrate", "build_pairs", "sync_history", "load_history")
