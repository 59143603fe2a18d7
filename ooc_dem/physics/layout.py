"""Named layouts of every kernel-side record (the ONE definition; numba compiles them).

Each packed vector the engine stores or passes around has a structured dtype here;
kernels read and write it by field name through a record view of the flat float64
array (``record(flat, DTYPE)``), so the stored form (a flat vector, e.g. the epoch's
``wheel_state``, or the (steps, 12) wheel records) and the canonical hash never
change, and no kernel indexes a column by number. The ``*_X``-style integer
constants are the same layouts as column positions, for code that handles the flat
arrays outside the kernels (stores, metrics, plots).

The records every dimension shares live here; a dimension's own (its contact parameters,
walls, contact rows and law-block columns) live in its package (``d2.layout``,
``d3.layout``).

Records:
- ``WHEEL_GEOMETRY``  rigid wheel with capsule lugs
- ``WHEEL_STATE``     wheel kinematics (``wz`` is the spin about the axle z, clockwise
                      negative; export.py writes these names)
- ``WHEEL_CONTROLS``  prescribed motion, drawbar load, driving torque
- ``WHEEL_RECORD``    one row per step of a wheel run
- ``LUG_DIRECTION``   unit vector of one lug at the current wheel angle
- ``ERRORS``          kernel error flags
- ``PLATE``           one rigid plate of the plates' table (``physics.plates``)
- ``PLATE_RECORD``    one plate's row of one step
- the kernels' argument records (named tuples of arrays): ``Discs``, ``Pairs``,
  ``Bodies``, ``Forces``, ``KernelParams``
"""

from __future__ import annotations

from collections import namedtuple
from enum import IntEnum
from typing import Any

import numpy as np

F8 = "<f8"

# ------------------------------------------------------- run_steps' arguments
# role: every particle is owned, every pair row reloaded; spans: no light cone, every step
# advances every particle. Every caller passes these (not None): the same argument types,
# so one compiled run_steps serves the engine and the test drivers (with None, numba
# compiles the step again for literal values)
EVERY_PARTICLE = np.zeros(0, np.int8)
NO_CONE = np.zeros((0, 2), np.int64)


def index_dtype(n: int):
    """The pair lists' and CSR offsets' index type for a domain of n particles: int32 while
    the pair count (~8 n) stays far below 2**31, else int64."""
    return np.int32 if n < 2**28 else np.int64


# ------------------------------------------------------------------- axes
# columns of the per-particle vectors pos / vel (N, D) and of forces (N, D):
# x = travel (slabs run along x), y = vertical (gravity in -y), z = across the bin (3D)
AX_X, AX_Y, AX_Z = 0, 1, 2
AXIS_NAMES = ("x", "y", "z")
DIMS = (2, 3)


def axes(dim: int) -> tuple[int, ...]:
    """The axes of a dim-dimensional run, in column order."""
    if dim not in DIMS:
        raise ValueError(f"dimension {dim!r} not supported (expected one of {DIMS})")
    return tuple(range(dim))


def spin_width(dim: int) -> int:
    """R: angular velocity components (2D: about z only)."""
    axes(dim)
    return 1 if dim == 2 else 3


# components of the spin (N, R): 2D has the one about z in column SP_Z; 3D has all three
SP_Z = 0  # 2D
SP_X3, SP_Y3, SP_Z3 = 0, 1, 2  # 3D


def hist_widths(dim: int) -> tuple[int, int]:
    """(S, M): components of a contact's tangential and rolling springs (from the contact
    law: 2D scalar springs; 3D springs as 3-vectors)."""
    axes(dim)
    return (1, 1) if dim == 2 else (3, 3)


# the one component of a 2D spring in hist_s / hist_m (N, C, 1)
HS_T = 0
HM_R = 0


def field_indices(name: str, names: tuple[str, ...]) -> Any:
    """An IntEnum of the given names numbered from 0: the columns of a block of law rows.
    (The names are computed, so a type checker cannot list the members: typed Any.)"""
    return IntEnum(name, names, start=0)


def field_tuple(name: str, names: tuple[str, ...]) -> Any:
    """A namedtuple type of the given (computed) field names."""
    return namedtuple(name, names)


def record_dtype(names, kind=F8):
    """A record of the named fields, all of one kind (float64 by default)."""
    return np.dtype([(n, kind) for n in names])


def field_names(dt: np.dtype) -> tuple[str, ...]:
    """The fields of a record dtype (ValueError for a plain dtype)."""
    if dt.names is None:
        raise ValueError(f"{dt} is not a record dtype")
    return dt.names


def _index(dt: np.dtype) -> dict[str, int]:
    return {n: k for k, n in enumerate(field_names(dt))}


def record(flat: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """Record view of a C-contiguous float64 array whose last axis is ``dtype``'s fields
    (no copy: writes through the view change ``flat``). A vector gives shape (1,)."""
    a = np.ascontiguousarray(flat)
    if a is not flat and flat.size:
        raise ValueError("record(): the flat array must be C-contiguous (a view would be lost)")
    n_fields = len(field_names(dtype))
    if a.shape[-1] != n_fields:
        raise ValueError(f"record(): last axis {a.shape[-1]} != {n_fields} fields of {dtype}")
    v = a.view(dtype)
    return v.reshape(v.shape[:-1]) if a.ndim > 1 else v


# ----------------------------------------------------------- material types
# material types of the contact table cp[type_a, type_b] (each dimension's CONTACT_PARAMS):
# soil particles, walls, wheel
T_SOIL, T_WALL, T_WHEEL = 0, 1, 2
N_TYPES = 3

# -------------------------------------------------------------------- wheel
# width, z0: the wheel's extent across the bin, centred on z = z0 (3D only; 2D ignores them)
WHEEL_GEOMETRY = record_dtype(("enabled", "radius", "lug_in", "lug_out", "cap", "nlugs", "mass", "width", "z0"))
WG_ENABLED, WG_R, WG_LUG_IN, WG_LUG_OUT, WG_CAP, WG_NLUGS, WG_MASS, WG_WIDTH, WG_Z0 = range(9)
WG_SIZE = len(WHEEL_GEOMETRY.names)

WHEEL_STATE = record_dtype(("x", "y", "vx", "vy", "theta", "wz"))
WS_NAMES = WHEEL_STATE.names
WS_X, WS_Y, WS_VX, WS_VY, WS_THETA, WS_WZ = range(6)
WS_SIZE = len(WS_NAMES)

# the first six fields are the prescribed-spin controls (drawbar, slip); the rest came
# with the free-spin controls (torque, towed) and the fixed carriage height:
# spinmode 1: omega free, the wheel a rigid body of the given inertia about its axle,
# driven by torque (N m, clockwise positive: drives in +x) ramped in over torque_ramp;
# speedmode 1: the carriage at the prescribed forward speed (no drawbar load);
# yfixed 1: the axle's height held while travelling (vy = 0)
WHEEL_CONTROLS = record_dtype(
    (
        "settle",
        "omega",
        "slipmode",
        "drawbar",
        "ramp",
        "slip",
        "spinmode",
        "torque",
        "torque_ramp",
        "inertia",
        "speedmode",
        "speed",
        "yfixed",
    )
)
(
    WC_SETTLE,
    WC_OMEGA,
    WC_SLIPMODE,
    WC_DRAWBAR,
    WC_RAMP,
    WC_SLIP,
    WC_SPINMODE,
    WC_TORQUE,
    WC_TORQUE_RAMP,
    WC_INERTIA,
    WC_SPEEDMODE,
    WC_SPEED,
    WC_YFIXED,
) = range(13)
WC_SIZE = len(WHEEL_CONTROLS.names)

WHEEL_RECORD = record_dtype(("t", "x", "y", "vx", "vy", "wz", "theta", "fx", "fy", "torque", "drawbar", "contacts"))
REC_COLUMNS = WHEEL_RECORD.names
(REC_T, REC_X, REC_Y, REC_VX, REC_VY, REC_WZ, REC_THETA, REC_FX, REC_FY, REC_TQ, REC_DB, REC_NC) = range(12)
N_REC = len(REC_COLUMNS)

# unit vector of each lug at the current wheel angle (wheel.lug_directions)
LUG_DIRECTION = record_dtype(("ux", "uy"))

# ------------------------------------------------------------------- plates
# A plate (physics.plates) is a finite, axis-aligned rigid rectangle (2D: a segment) with
# one active face: its normal is +-e_axis (side = +1 or -1: the particles are on that side
# of pos along the axis); it spans lo1..hi1 along the first other axis and lo2..hi2 along
# the second (in ascending axis order; 2D: lo2, hi2 are unused), and moves with (vx, vy,
# vz) (2D: vz unused). mode PLATE_PRESCRIBED: that velocity as given; PLATE_FORCE: along
# its normal it is a rigid body of the given mass pushed onto the particles by a constant
# load (N), its normal speed at most vmax (0: no limit); its other components as given.
PLATE = record_dtype(
    ("axis", "side", "pos", "lo1", "hi1", "lo2", "hi2", "vx", "vy", "vz", "mode", "load", "mass", "vmax")
)
PLATE_PRESCRIBED, PLATE_FORCE = 0, 1
MAX_PLATES = 16  # a table holds at most this many (ids -90 .. -75)
# one plate's row of one step: its state at the step's start (pos, the low ends of its
# extents), the velocity it moved with, the particles' force on it (fx, fy, fz; 2D: fz = 0),
# the normal force N they press on it with (= -f . normal) and how many touch it
PLATE_RECORD = record_dtype(("t", "pos", "lo1", "lo2", "vx", "vy", "vz", "fx", "fy", "fz", "load", "contacts"))

# ------------------------------------------------------------------- errors
ERRORS = record_dtype(("hist_overflow", "pair_capacity", "body_capacity"), "<i8")
ERR_HIST_OVERFLOW, ERR_PAIR_CAPACITY, ERR_BODY_CAPACITY = range(3)
N_ERR = len(ERRORS.names)
# kept for importers of the old name (the neighbour list has no fixed cap any more)
ERR_NBR_OVERFLOW = ERR_PAIR_CAPACITY

# ------------------------------------------------------------- partner ids
# partner ids of the bodies (negative, so they sort before every particle): the wheel's
# parts, the plates and the walls both dimensions have (3D adds its side walls, d3.layout).
# A particle's body rows are summed in ascending id: lugs, rim, plates, walls
ID_LUG0 = -1000  # lug k has id ID_LUG0 + k
ID_RIM = -100
MAX_MESH_PARTS = ID_RIM - ID_LUG0  # a mesh wheel's part k has id ID_LUG0 + k, below the rim's
ID_PLATE0 = -90  # plate k of the table has id ID_PLATE0 + k (above the rim, below every wall)
ID_WALL_RIGHT = -3
ID_WALL_LEFT = -2
ID_WALL_BOTTOM = -1

# ------------------------------------------------------------ law blocks
# The touching pairs are evaluated in blocks (physics.produce): a block's law inputs and
# results are rows of two (fields, LAW_ROW) arrays (structure of arrays, each dimension's
# LawIn / LawOut), so the compiler runs the law on several pairs at once (SIMD), each
# pair's arithmetic that of the pair evaluated alone. LAW_BLOCK: pairs a block holds (a
# thread's block columns stay in its core's L2; 128 measured no different at 100k); its
# rows are padded by a cache line (rows 2 KiB apart would put a pair's fields in two sets
# of the L1 cache, evicting each other)
LAW_BLOCK = 256
LAW_ROW = LAW_BLOCK + 8


# ------------------------------------------------------- kernel argument records
# (named tuples of arrays: numba compiles them; every field is a view, never a copy)

# the discs of one domain (views of a state.Particles): pos/vel (N, D), spin (N, R),
# hist_id (N, C), hist_s (N, C, S), hist_m (N, C, M)
Discs = namedtuple(
    "Discs", ["pos", "vel", "spin", "r", "mass", "inertia", "mat", "gid", "hist_n", "hist_id", "hist_s", "hist_m"]
)
# a 3D wheel's surface as triangles in its body frame (axle along z through the origin,
# z = 0 at the wheel's z0; physics.mesh): tri (T, 3, 3) vertex coordinates; a uniform grid
# over their bounding box, grid = (x, y, z of its low corner, cell size), dims (3,) cells
# along x, y, z, and each cell's triangles in CSR form (cell_start (cells + 1), cell_tri,
# ascending within a cell); bounds = (the farthest point from the axle, lowest z, highest z);
# part (T,) each triangle's connected piece of the surface (its contacts' partner id:
# ID_LUG0 + part, so at most MAX_MESH_PARTS pieces)
MeshWheel = namedtuple("MeshWheel", ["tri", "grid", "dims", "cell_start", "cell_tri", "bounds", "part"])


# a 2D wheel's outline as a closed polyline in its body frame (physics.outline; axle at the
# origin, counter-clockwise): vert (V, 2) its vertices (segment k from vertex k to k + 1,
# the last back to 0), turn (V,) at each vertex +1 convex, -1 reflex, 0 straight; a uniform
# grid over its bounding box, grid = (x, y of its low corner, cell size), dims (2,) cells
# along x and y, each cell's segments in CSR form (cell_start (cells + 1), cell_seg,
# ascending within a cell); reach (1,) its farthest point from the axle. No vertex: none.
WheelOutline = namedtuple("WheelOutline", ["vert", "turn", "grid", "dims", "cell_start", "cell_seg", "reach"])


def no_outline() -> WheelOutline:
    """An empty wheel outline (no vertex: the wheel is the built-in rim and lugs)."""
    return WheelOutline(
        np.zeros((0, 2)),
        np.zeros(0),
        np.zeros(3),
        np.zeros(2, np.int64),
        np.zeros(1, np.int64),
        np.zeros(0, np.int64),
        np.zeros(1),
    )


# the model's kernel parameters: dt, gravity (D,), skin, the records CONTACT_PARAMS
# table, WALLS, WHEEL_GEOMETRY, WHEEL_CONTROLS (engine.stepper.Model.kernel_params), the
# wheel's triangle mesh (MeshWheel; no triangle: the built-in rim and lugs) and the 2D
# wheel's outline (WheelOutline; none by default)
KernelParams = namedtuple(
    "KernelParams", ["dt", "gravity", "skin", "cp", "walls", "wg", "wc", "mesh", "outline"], defaults=(no_outline(),)
)
# per-particle contact force (N, D) and torque (N, R) of the last step; length 0 when not kept
Forces = namedtuple("Forces", ["force", "torque"])
# the plates' table (PLATE, (P,): their state, moved by the step) and their records of the
# steps (PLATE_RECORD, step s's plate k at row s P + k); P = 0: no plates (NO_PLATES)
Plates = namedtuple("Plates", ["table", "rec"])
# half pair list + CSR index (physics.neighbors: build_pairs), the build positions, and the
# pairs' rows of the current step (slot = position in pair_b; on[k] = in contact)
# (ref: the positions (N, D) at the last build)
Pairs = namedtuple("Pairs", ["half_off", "pair_b", "pair_a", "inc_off", "inc_k", "ref", "on", "rows"])
# body rows of the current step: chunks.N_CHUNKS buffers of equal capacity, count[c] used
Bodies = namedtuple("Bodies", ["rows", "count"])


def no_plates() -> Plates:
    """An empty plates argument (no plate: the step is that of a run without plates)."""
    return Plates(np.zeros(0, PLATE), np.zeros(0, PLATE_RECORD))


def no_mesh() -> MeshWheel:
    """An empty wheel mesh (no triangle: the wheel is the built-in rim and lugs)."""
    return MeshWheel(
        np.zeros((0, 3, 3)),
        np.zeros(4),
        np.zeros(3, np.int64),
        np.zeros(1, np.int64),
        np.zeros(0, np.int64),
        np.zeros(3),
        np.zeros(0, np.int64),
    )


def discs_of(p) -> Discs:
    """The kernel view of a state.Particles (no copy)."""
    return Discs(p.pos, p.vel, p.spin, p.r, p.mass, p.inertia, p.mat, p.id, p.hist_n, p.hist_id, p.hist_s, p.hist_m)
