"""Particle state (structure of arrays) and wheel state: one dtype layout for all modes.

Per disc: global id, position, velocity (at the half step), spin, radius, mass,
inertia, material, and its contact history: up to ``HIST_CAP`` entries
(partner id, tangential spring force, rolling spring moment) sorted by partner
id. Overflowing the capacity is an error, never a silent drop.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np

from .physics.layout import WS_NAMES, WS_SIZE

HIST_CAP = 12
FORMAT_VERSION = 1

# name -> dtype of the per-disc scalar arrays, in canonical order
SCALAR_FIELDS: dict[str, np.dtype] = {
    "id": np.dtype("<i8"),
    "x": np.dtype("<f8"),
    "y": np.dtype("<f8"),
    "vx": np.dtype("<f8"),
    "vy": np.dtype("<f8"),
    "w": np.dtype("<f8"),
    "r": np.dtype("<f8"),
    "mass": np.dtype("<f8"),
    "inertia": np.dtype("<f8"),
    "mat": np.dtype("<i4"),
    "hist_n": np.dtype("<i4"),
}
# per-disc history rows (N, HIST_CAP)
HIST_FIELDS: dict[str, np.dtype] = {
    "hist_id": np.dtype("<i8"),
    "hist_ft": np.dtype("<f8"),
    "hist_mr": np.dtype("<f8"),
}
ALL_FIELDS = {**SCALAR_FIELDS, **HIST_FIELDS}
WHEEL_FIELDS = WS_NAMES   # layout.WHEEL_STATE: the one definition
BYTES_PER_DISC = sum(d.itemsize for d in SCALAR_FIELDS.values()) + HIST_CAP * sum(
    d.itemsize for d in HIST_FIELDS.values())


class Particles:
    """A set of discs as contiguous arrays (any order; ids are global)."""

    __slots__ = tuple(ALL_FIELDS)

    def __init__(self, **arrays):
        for name, dt in ALL_FIELDS.items():
            a = arrays[name]
            setattr(self, name, np.ascontiguousarray(a, dtype=dt))

    @classmethod
    def empty(cls, n: int) -> "Particles":
        arrs = {k: np.zeros(n, d) for k, d in SCALAR_FIELDS.items()}
        arrs.update({k: np.zeros((n, HIST_CAP), d) for k, d in HIST_FIELDS.items()})
        return cls(**arrs)

    @classmethod
    def new(cls, x, y, r, density, thickness, mat=None, ids=None) -> "Particles":
        n = len(x)
        p = cls.empty(n)
        p.id[:] = np.arange(n) if ids is None else ids
        p.x[:] = x
        p.y[:] = y
        p.r[:] = r
        p.mass[:] = density * np.pi * p.r * p.r * thickness
        p.inertia[:] = 0.5 * p.mass * p.r * p.r
        if mat is not None:
            p.mat[:] = mat
        return p

    def __len__(self) -> int:
        return len(self.id)

    def arrays(self) -> dict[str, np.ndarray]:
        return {k: getattr(self, k) for k in ALL_FIELDS}

    def take(self, idx) -> "Particles":
        return Particles(**{k: v[idx] for k, v in self.arrays().items()})

    def permute_inplace(self, perm) -> "Particles":
        """Reorder every array in place (one array-sized temporary at a time, never a second state)."""
        for k in ALL_FIELDS:
            a = getattr(self, k)
            a[...] = a[perm]
        return self

    def sorted_by_id(self) -> "Particles":
        return self.take(np.argsort(self.id, kind="stable"))

    @staticmethod
    def concat(parts: list["Particles"]) -> "Particles":
        if not parts:
            return Particles.empty(0)
        return Particles(**{k: np.concatenate([getattr(p, k) for p in parts]) for k in ALL_FIELDS})

    def nbytes(self) -> int:
        return sum(v.nbytes for v in self.arrays().values())


@dataclass
class WheelState:
    """Kinematic state of the rigid wheel (centre, half-step velocity, angle, spin)."""
    x: float = 0.0
    y: float = 0.0
    vx: float = 0.0
    vy: float = 0.0
    theta: float = 0.0
    wz: float = 0.0

    def to_array(self) -> np.ndarray:
        a = np.zeros(WS_SIZE)
        a[:] = [self.x, self.y, self.vx, self.vy, self.theta, self.wz]
        return a

    @classmethod
    def from_array(cls, a) -> "WheelState":
        return cls(*[float(v) for v in a[:WS_SIZE]])


def canonical_bytes(p: Particles, wheel: np.ndarray | None, step: int):
    """Yield the state serialised in canonical order (sorted by id, fixed dtypes).

    History slots beyond a disc's count are zeroed so that stale leftovers in
    unused slots never change the hash.
    """
    q = p.sorted_by_id()
    yield np.int64(step).tobytes()
    yield np.int64(len(q)).tobytes()
    for name, dt in SCALAR_FIELDS.items():
        yield np.ascontiguousarray(getattr(q, name), dt).tobytes()
    used = np.arange(HIST_CAP)[None, :] < q.hist_n[:, None]
    for name, dt in HIST_FIELDS.items():
        a = np.where(used, getattr(q, name), 0).astype(dt)
        yield np.ascontiguousarray(a).tobytes()
    if wheel is not None:
        yield np.ascontiguousarray(wheel, "<f8").tobytes()


def state_hash(p: Particles, wheel: np.ndarray | None, step: int) -> str:
    h = hashlib.sha256()
    for chunk in canonical_bytes(p, wheel, step):
        h.update(chunk)
    return h.hexdigest()


def clean_history(p: Particles) -> None:
    """Zero unused history slots in place (canonical content)."""
    used = np.arange(HIST_CAP)[None, :] < p.hist_n[:, None]
    for name in HIST_FIELDS:
        a = getattr(p, name)
        a[~used] = 0
