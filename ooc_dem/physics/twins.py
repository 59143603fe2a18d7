"""Compiled variants of one Python source (numba, no I/O).

The step machinery is written once (``physics.step``, ``produce``, ``gather``, ``history``,
``neighbors``) and compiled once per dimension: the names a template leaves to the
dimension (its contact law, rows, bodies and cell geometry) are ``Slot``s, and
``specialise`` compiles the template's Python source again under a new name with those
names bound to the dimension's kernels. Serial twins use the same mechanism: serial DDM
runs its sub-domains side by side, one per thread, inside one compiled call; each
sub-domain's step must then run on its own thread, not launch a parallel region of its
own, so it is compiled again without ``parallel`` (``prange`` becomes ``range``) and with
the kernels it calls replaced by their own serial twins. Every variant is the same
source, so the arithmetic and the bits are the same.
"""

from __future__ import annotations

import types
from typing import Any
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
NO_PARFORS = {
    "comprehension": False,
    "prange": False,
    "numpy": False,
    "reduction": False,
    "inplace_binop": False,
    "setitem": False,
    "stencil": False,
    "fusion": False,
}


def no_parfors() -> ParallelOptions:
    """numba's parallel pipeline with every transformation off (a fresh copy)."""
    return ParallelOptions(dict(NO_PARFORS))


class Slot:
    """A name a template leaves to each dimension, bound by ``specialise``; ``doc`` says
    what the dimension puts there. A template that still holds one is never compiled."""

    def __init__(self, doc: str):
        self.doc = doc

    def __repr__(self) -> str:
        return f"Slot({self.doc!r})"


def slot(doc: str) -> Any:
    """A template's open name: a Slot, typed Any because each dimension binds there a kernel,
    a constant or a record type of its own."""
    return Slot(doc)


def slots_of(module) -> dict[str, Slot]:
    """The Slots a template module leaves open, by name."""
    return {k: v for k, v in vars(module).items() if isinstance(v, Slot)}


def bindings(names, *modules) -> dict:
    """Each of ``names`` from the first of ``modules`` that has it (a dimension's kernels
    and constants, for ``specialise``); raises TypeError when one is missing or two of
    the modules give it different objects."""
    bind = {}
    for name in names:
        found = {id(getattr(m, name)): getattr(m, name) for m in modules if hasattr(m, name)}
        if len(found) != 1:
            where = ", ".join(m.__name__ for m in modules)
            raise TypeError(f"{name}: {'missing from' if not found else 'ambiguous in'} {where}")
        bind[name] = next(iter(found.values()))
    return bind


def specialise(kernel, name: str, bind: dict | None = None, **options):
    """njit(cache=True, **options) of ``kernel``'s Python function under ``name``, the global
    names it uses that ``bind`` holds rebound to them. ``kernel`` is a plain function (a
    template) or a numba dispatcher; the variant caches under its own name. Raises
    TypeError when a Slot the function uses is left unbound."""
    py = getattr(kernel, "py_func", kernel)
    used = set(py.__code__.co_names)
    g = dict(py.__globals__)
    g.update({k: v for k, v in (bind or {}).items() if k in used})
    open_ = sorted(k for k in used if isinstance(g.get(k), Slot))
    if open_:
        raise TypeError(f"specialise({py.__name__} as {name}): unbound {', '.join(open_)}")
    f = types.FunctionType(py.__code__, g, name, py.__defaults__, py.__closure__)
    f.__qualname__ = name
    f.__module__ = py.__module__
    f.__doc__ = py.__doc__
    return njit(cache=True, **options)(f)


def serial_twin(kernel, name: str, parallel: bool = False, **callees):
    """``specialise`` of ``kernel`` under ``name`` with its global names in ``callees``
    (kernel name -> serial twin) rebound, compiled without a parallel region
    (``no_parfors``). ``parallel``: compile the twin itself with prange (a driver whose
    callees are serial twins)."""
    py = getattr(kernel, "py_func", kernel)
    for k in callees:
        if k not in py.__code__.co_names:
            raise KeyError(f"serial_twin({py.__name__}): it does not call {k!r}")
    return specialise(kernel, name, callees, parallel=True if parallel else no_parfors())
