"""Particle state (structure of arrays) and wheel state: one dtype layout for all modes.

Per particle: global id, position (D,), velocity (D,) at the half step, spin (R,),
radius, mass, inertia, material, and its contact history: up to C (the model's
``hist_cap``) entries (partner id, tangential spring (S,), rolling spring (M,)) sorted
by partner id. Overflowing the capacity is an error, never a silent drop. The shapes
come from one function, ``fields(dim, cap)``; columns are the named axes of
physics.layout (AX_X, AX_Y, AX_Z).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..physics.layout import (
    AX_X,  # noqa: F401
    AX_Y,  # noqa: F401
    HM_R,  # noqa: F401
    HS_T,  # noqa: F401
    SP_Z,  # noqa: F401
    WS_NAMES,
    WS_SIZE,  # noqa: F401
    axes,  # noqa: F401
    hist_widths,
    spin_width,
)

# default contact-history capacity C per dimension (the model's ``hist_cap``; scenario key
# physics.history_capacity overrides it). A 2D disc in a settled polydisperse bed touches at
# most 6 others (hexagonal packing; the largest count seen in paper2008 with the wheel is 6),
# so 8 leaves room without paying for 12 (24 B a slot); a sphere touches up to 12 in a
# monodisperse packing. Overflow is an error (EngineError), never a silent drop, and the
# capacity never enters a result bit or the state hash.
HIST_CAP_BY_DIM = {2: 8, 3: 12}
HIST_CAP = HIST_CAP_BY_DIM[2]  # the 2D default

# name -> dtype of every per-particle array, in canonical order; the shapes are
# (N,) + field_tails(dim, cap)[name]
FIELD_DTYPES: dict[str, np.dtype] = {
    "id": np.dtype("<i8"),
    "pos": np.dtype("<f8"),
    "vel": np.dtype("<f8"),
    "spin": np.dtype("<f8"),
    "r": np.dtype("<f8"),
    "mass": np.dtype("<f8"),
    "inertia": np.dtype("<f8"),
    "mat": np.dtype("<i4"),
    "hist_n": np.dtype("<i4"),
    "hist_id": np.dtype("<i8"),
    "hist_s": np.dtype("<f8"),
    "hist_m": np.dtype("<f8"),
}
ALL_FIELDS = tuple(FIELD_DTYPES)
# the per-disc fields (one row a disc in the store record too) and the history fields
# (one row a contact in the store record: CSR)
DISC_FIELDS = ("id", "pos", "vel", "spin", "r", "mass", "inertia", "mat", "hist_n")
HIST_FIELDS = ("hist_id", "hist_s", "hist_m")
WHEEL_FIELDS = WS_NAMES  # layout.WHEEL_STATE: the one definition


def field_tails(dim: int, cap: int) -> dict[str, tuple[int, ...]]:
    """Per-particle shape (after the leading N) of every field of a dim-dimensional state
    with history capacity cap: the ONE definition of the state's layout."""
    D = len(axes(dim))
    R = spin_width(dim)
    S, M = hist_widths(dim)
    if type(cap) is not int or cap < 0:
        raise ValueError(f"history capacity {cap!r}: must be an integer >= 0")
    return {
        "id": (),
        "pos": (D,),
        "vel": (D,),
        "spin": (R,),
        "r": (),
        "mass": (),
        "inertia": (),
        "mat": (),
        "hist_n": (),
        "hist_id": (cap,),
        "hist_s": (cap, S),
        "hist_m": (cap, M),
    }


def fields(dim: int, cap: int) -> dict[str, tuple[np.dtype, tuple[int, ...]]]:
    """name -> (dtype, per-particle shape) of a state (canonical order)."""
    tails = field_tails(dim, cap)
    return {k: (FIELD_DTYPES[k], tails[k]) for k in ALL_FIELDS}


def record_fields(dim: int) -> dict[str, tuple[np.dtype, tuple[int, ...]]]:
    """name -> (dtype, per-row shape) of a store record (format 2): the disc fields one row a
    disc, the history fields one row a contact (CSR, rows of disc after disc)."""
    tails = field_tails(dim, 0)
    out = {}
    for k in ALL_FIELDS:
        t = tails[k]
        out[k] = (FIELD_DTYPES[k], t[1:] if k in HIST_FIELDS else t)
    return out


def default_hist_cap(dim: int) -> int:
    """The contact-history capacity of a dim-dimensional state unless a scenario sets one."""
    try:
        return HIST_CAP_BY_DIM[dim]
    except KeyError:
        raise ValueError(f"dimension {dim!r}: must be 2 or 3") from None


def bytes_per_disc(dim: int = 2, cap: int | None = None) -> int:
    """Bytes of one particle's state (capacity cap, else the dimension's default)."""
    cap = default_hist_cap(dim) if cap is None else cap
    return sum(dt.itemsize * int(np.prod(shape, dtype=np.int64)) for dt, shape in fields(dim, cap).values())


BYTES_PER_DISC = bytes_per_disc(2, HIST_CAP)


# format 1 (2D only) stored each component as its own array: a format-2 array is the
# stack of these along a new last axis (the ONE conversion table of the old format)
V1_ARRAYS: dict[str, tuple[str, ...]] = {
    "pos": ("x", "y"),
    "vel": ("vx", "vy"),
    "spin": ("w",),
    "hist_s": ("hist_ft",),
    "hist_m": ("hist_mr",),
}


def is_v1(names: Iterable[str]) -> bool:
    """Whether a set of array names is a format-1 state/record (and not format 2)."""
    names = set(names)
    return "pos" not in names and "x" in names


def upgrade_v1(arrays: dict[str, Any]) -> dict[str, Any]:
    """Arrays named as in format 1 (x, y, vx, vy, w, hist_ft, hist_mr) -> format-2 arrays
    (pos, vel, spin, hist_s, hist_m); format-2 arrays pass unchanged. Works for a state's
    arrays ((N,) -> (N, k); (N, C) -> (N, C, k)) and a store record's ((E,) -> (E, k))."""
    if not is_v1(arrays):
        return arrays
    out = {k: v for k, v in arrays.items() if not any(k in c for c in V1_ARRAYS.values())}
    for new, comps in V1_ARRAYS.items():
        if all(c in arrays for c in comps):
            out[new] = stack_v1(new, [arrays[c] for c in comps])
    return out


def stack_v1(name: str, parts: Iterable[ArrayLike]) -> NDArray[Any]:
    """The format-2 array ``name`` from its format-1 component arrays (V1_ARRAYS[name])."""
    arrays = [np.asarray(a) for a in parts]
    if len({(a.shape, a.dtype.str) for a in arrays}) != 1:
        raise ValueError(f"format-1 arrays {', '.join(V1_ARRAYS[name])} differ in shape or dtype")
    return np.stack(arrays, axis=-1)


class Particles:
    """A set of particles as contiguous arrays (any order; ids are global).

    pos, vel (N, D); spin (N, R); hist_id (N, C); hist_s (N, C, S); hist_m (N, C, M)
    (``fields(dim, cap)``); D and C are read from the arrays given."""

    __slots__ = ALL_FIELDS
    # the fields, declared for readers and type checkers (the slots above make them)
    id: np.ndarray
    pos: np.ndarray
    vel: np.ndarray
    spin: np.ndarray
    r: np.ndarray
    mass: np.ndarray
    inertia: np.ndarray
    mat: np.ndarray
    hist_n: np.ndarray
    hist_id: np.ndarray
    hist_s: np.ndarray
    hist_m: np.ndarray

    def __init__(self, **arrays: ArrayLike) -> None:
        arrays = upgrade_v1(arrays)
        pos = np.asarray(arrays["pos"])
        hid = np.asarray(arrays["hist_id"])
        if pos.ndim != 2 or hid.ndim != 2:
            raise ValueError(f"Particles: pos must be (N, D) and hist_id (N, C), got {pos.shape} and {hid.shape}")
        spec = fields(int(pos.shape[1]), int(hid.shape[1]))
        n = pos.shape[0]
        for name, (dt, tail) in spec.items():
            a = np.ascontiguousarray(arrays[name], dtype=dt)
            if a.shape != (n,) + tail:
                raise ValueError(f"Particles: {name} has shape {a.shape}, expected {(n,) + tail}")
            setattr(self, name, a)

    @classmethod
    def empty(cls, n: int, dim: int = 2, hist_cap: int | None = None) -> "Particles":
        hist_cap = default_hist_cap(dim) if hist_cap is None else hist_cap
        return cls(**{k: np.zeros((n,) + tail, dt) for k, (dt, tail) in fields(dim, hist_cap).items()})

    @classmethod
    def new(
        cls,
        pos: ArrayLike,
        r: ArrayLike,
        density: float,
        thickness: float,
        mat: ArrayLike | None = None,
        ids: ArrayLike | None = None,
        hist_cap: int | None = None,
    ) -> "Particles":
        """Particles at rest at pos (N, D) with radii r; mass from the density (2D: discs are
        cylinders of length ``thickness``; 3D: spheres)."""
        pos = np.asarray(pos, np.float64)
        n, dim = pos.shape
        p = cls.empty(n, dim, hist_cap)
        p.id[:] = np.arange(n) if ids is None else ids
        p.pos[:] = pos
        p.r[:] = r
        if dim == 2:
            p.mass[:] = density * np.pi * p.r * p.r * thickness
            p.inertia[:] = 0.5 * p.mass * p.r * p.r
        else:
            # r * r * r, not r**3: numpy's pow rounds per CPU (its AVX-512 pow is not libm's)
            p.mass[:] = density * (4.0 / 3.0) * np.pi * (p.r * p.r * p.r)
            p.inertia[:] = 0.4 * p.mass * p.r * p.r
        if mat is not None:
            p.mat[:] = mat
        return p

    @property
    def dim(self) -> int:
        return int(self.pos.shape[1])

    @property
    def hist_cap(self) -> int:
        return int(self.hist_id.shape[1])

    def __len__(self) -> int:
        return len(self.id)

    def arrays(self) -> dict[str, np.ndarray]:
        return {k: getattr(self, k) for k in ALL_FIELDS}

    def take(self, idx: NDArray[np.integer[Any]] | NDArray[np.bool_] | slice) -> "Particles":
        return Particles(**{k: v[idx] for k, v in self.arrays().items()})

    def permute_inplace(self, perm: NDArray[np.integer[Any]]) -> "Particles":
        """Reorder every array in place (one array-sized temporary at a time, never a second state)."""
        for k in ALL_FIELDS:
            a = getattr(self, k)
            a[...] = a[perm]
        return self

    def sorted_by_id(self) -> "Particles":
        return self.take(np.argsort(self.id, kind="stable"))

    @staticmethod
    def concat(parts: list["Particles"], dim: int = 2, hist_cap: int | None = None) -> "Particles":
        """All parts in one (dim and hist_cap only give the shape of an empty result)."""
        if not parts:
            return Particles.empty(0, dim, hist_cap)
        return Particles(**{k: np.concatenate([getattr(p, k) for p in parts]) for k in ALL_FIELDS})

    def nbytes(self) -> int:
        return sum(v.nbytes for v in self.arrays().values())

    def with_hist_cap(self, cap: int) -> "Particles":
        """A copy with contact-history capacity cap (ValueError if a particle holds more)."""
        if len(self) and int(self.hist_n.max()) > cap:
            raise ValueError(f"a particle holds {int(self.hist_n.max())} contacts, more than {cap}")
        q = Particles.empty(len(self), self.dim, cap)
        k = min(cap, self.hist_cap)
        for name in ALL_FIELDS:
            a, b = getattr(q, name), getattr(self, name)
            if name in HIST_FIELDS:
                a[:, :k] = b[:, :k]
            else:
                a[...] = b
        return q


def state_hash(p: Particles, wheel: np.ndarray | None, step: int) -> str:
    """The canonical state hash (``ooc_dem.model.statehash``: a multiset hash of per-disc digests)."""
    from .statehash import hash_records

    used = np.arange(p.hist_cap)[None, :] < p.hist_n[:, None]
    rec = {k: getattr(p, k) for k in DISC_FIELDS}
    rec.update({k: getattr(p, k)[used] for k in HIST_FIELDS})
    return hash_records([rec], wheel, step)


def clean_history(p: Particles) -> None:
    """Zero unused history slots in place (canonical content)."""
    used = np.arange(p.hist_cap)[None, :] < p.hist_n[:, None]
    for name in HIST_FIELDS:
        a = getattr(p, name)
        a[~used] = 0
