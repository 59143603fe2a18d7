"""THE per-domain step, shared by every execution mode.

The step itself is the dimension's kernel module (``physics.kernels(model.dim)``, a
``physics.KernelModule``), entry point ``run_steps`` (``physics.step``, written once and
compiled per dimension): wheel controls, ``produce`` (one row per contact),
``gather_integrate`` (each disc sums its rows in ascending partner-id order and is
advanced), the wheel's reaction summed in ascending disc id, the wheel's leapfrog, and a
rebuild of the half pair list when some disc has moved half the skin.

``DomainStepper`` holds one set of discs (the whole bin in monolithic mode; a
sub-domain plus its halo in DDM and out-of-core) and advances all of them K
steps in place. Monolithic, DDM and out-of-core only differ in which discs they
hand it and where the results go, so they cannot drift apart. It never looks inside
the kernel module: it hands it the named records of physics.layout.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numba
import numpy as np

from ..physics import kernels
from ..physics import layout as L
from ..model.contacts import contact_params_2d
from ..physics.d2.layout import CONTACT_PARAMS, N_FIELDS, WALLS
from ..physics.layout import (
    ERR_BODY_CAPACITY,
    ERR_HIST_OVERFLOW,  # noqa: F401
    ERR_PAIR_CAPACITY,
    N_ERR,  # noqa: F401
    N_REC,
    REC_COLUMNS,  # noqa: F401
    REC_DB,  # noqa: F401
    REC_FX,  # noqa: F401
    REC_FY,  # noqa: F401
    REC_NC,  # noqa: F401
    REC_T,  # noqa: F401
    REC_THETA,  # noqa: F401
    REC_TQ,  # noqa: F401
    REC_VX,  # noqa: F401
    REC_VY,  # noqa: F401
    REC_WZ,  # noqa: F401
    REC_X,  # noqa: F401
    REC_Y,  # noqa: F401
    WC_DRAWBAR,  # noqa: F401
    WC_OMEGA,  # noqa: F401
    WC_RAMP,  # noqa: F401
    WC_SETTLE,  # noqa: F401
    WC_SIZE,
    WC_SLIP,  # noqa: F401
    WC_SLIPMODE,  # noqa: F401
    WG_CAP,  # noqa: F401
    WG_ENABLED,  # noqa: F401
    WG_LUG_IN,  # noqa: F401
    WG_LUG_OUT,  # noqa: F401
    WG_MASS,  # noqa: F401
    WG_NLUGS,  # noqa: F401
    WG_R,  # noqa: F401
    WG_SIZE,
    WHEEL_CONTROLS,
    WHEEL_GEOMETRY,
    WHEEL_RECORD,
    WHEEL_STATE,
    WS_SIZE,
    Bodies,
    Forces,
    KernelParams,
    MeshWheel,
    WheelOutline,
    Pairs,
    discs_of,
    no_mesh,
    field_names,
    record,
    spin_width,
)
from ..model.state import Particles, default_hist_cap
from ..physics.outline import wheel_outline
from ..errors import OocDemError

SERIAL_BELOW = 3000  # discs; below this a domain runs on one thread
PAIR_HEADROOM = 1.05  # pair list capacity = pairs counted at a build x this (+64)


class EngineError(OocDemError, RuntimeError):
    """A run cannot continue (capacity overflow, unstable state)."""


@dataclass
class Model:
    """Everything the kernels need from a scenario: flat float arrays whose layouts are
    the records of physics.layout (``records()`` gives the record views)."""

    dt: float
    gravity: np.ndarray  # (dim,) acceleration of gravity
    skin: float
    cp: np.ndarray  # CONTACT_PARAMS table [type_a, type_b, field]; types T_SOIL, T_WALL, T_WHEEL
    walls: np.ndarray  # WALLS
    wg: np.ndarray  # WHEEL_GEOMETRY
    wc: np.ndarray  # WHEEL_CONTROLS
    wheel_enabled: bool
    r_max: float
    dim: int = 2  # 2 for every current scenario; picks the kernel module
    hist_cap: int = 0  # contact-history capacity C per particle (0: the dimension's default)
    mesh: MeshWheel | None = None  # 3D: the wheel's triangles (None: the built-in rim and lugs)
    outline: WheelOutline | None = None  # 2D: the wheel as a closed polyline (None: the built-in rim and lugs)

    def __post_init__(self):
        if not self.hist_cap:
            self.hist_cap = default_hist_cap(self.dim)
        self.gravity = np.ascontiguousarray(self.gravity, np.float64)
        if self.gravity.shape != (self.dim,):
            raise ValueError(f"Model: gravity {self.gravity.shape} must be a {self.dim}-vector")

    @classmethod
    def from_scenario(cls, sc) -> "Model":
        if sc.dim == 3:
            return cls._from_scenario_3d(sc)
        cp = np.zeros((L.N_TYPES, L.N_TYPES, N_FIELDS))
        table = record(cp, CONTACT_PARAMS)

        thickness = sc.physics.thickness

        def put(a, b, pair):
            vals = contact_params_2d(pair, thickness)
            table[a, b] = vals
            table[b, a] = vals

        put(L.T_SOIL, L.T_SOIL, sc.contact.soil_soil)
        put(L.T_WALL, L.T_SOIL, sc.contact.soil_wall)
        put(L.T_WHEEL, L.T_SOIL, sc.contact.soil_wheel)
        walls = np.zeros(len(WALLS.names))
        record(walls, WALLS)[0] = (sc.bin.length, 1.0, 1.0, 1.0)
        wg, wc = wheel_records(sc)
        w = sc.wheel
        outline = None
        if w.enabled and w.outline:
            from ..model.wheel_outline import outline_points

            outline = wheel_outline(outline_points(sc), 2.0 * sc.soil.r_max)
        return cls(
            dt=sc.physics.dt,
            gravity=np.array(sc.gravity_vector, np.float64),
            skin=sc.bed.skin,
            cp=cp,
            walls=walls,
            wg=wg,
            wc=wc,
            wheel_enabled=w.enabled,
            r_max=sc.soil.r_max,
            dim=sc.dim,
            hist_cap=sc.hist_cap,
            outline=outline,
        )

    @classmethod
    def _from_scenario_3d(cls, sc) -> "Model":
        """The 3D model (physics.d3.layout records): contact table with the law per material
        pair, the box of floor, end walls and side walls (z = 0, bin.width), and the wheel
        (the 2D records; its width and lateral centre z0 span the rim and the lugs)."""
        from ..physics.d3 import layout as L3
        from ..model.contacts import contact_table_3d

        table = contact_table_3d(sc)
        cp = np.ascontiguousarray(table).view(np.float64).reshape(L3.N_TYPES, L3.N_TYPES, L3.N_FIELDS).copy()
        walls = L3.walls_record(sc.bin.length, sc.bin.width).view(np.float64).copy()
        wg, wc = wheel_records(sc)
        mesh = None
        if sc.wheel.enabled and sc.wheel.mesh:
            from ..model.mesh_wheel import body_frame_triangles, load_wheel_mesh, wheel_axle_inertia

            tri = body_frame_triangles(sc)
            mesh = load_wheel_mesh(sc, tri)
            if sc.wheel.control in FREE_SPIN_CONTROLS and sc.wheel.inertia == 0.0:  # else wheel_inertia's
                record(wc, WHEEL_CONTROLS)["inertia"] = wheel_axle_inertia(sc, tri)
        return cls(
            dt=sc.physics.dt,
            gravity=np.array(sc.gravity_vector, np.float64),
            skin=sc.bed.skin,
            cp=cp,
            walls=walls,
            wg=wg,
            wc=wc,
            wheel_enabled=sc.wheel.enabled,
            r_max=sc.soil.r_max,
            dim=3,
            hist_cap=sc.hist_cap,
            mesh=mesh,
        )

    @property
    def order_cell(self) -> float:
        """The cell of the particles' memory order (one contact hop: 2 r_max + skin), as the
        neighbour grid's: epoch groups are stored in this order (decomposition.group_order)."""
        return 2.0 * self.r_max + self.skin

    def layouts(self):
        """(CONTACT_PARAMS, WALLS) record dtypes of this model's dimension."""
        kern = self.kernels()
        return kern.CONTACT_PARAMS, kern.WALLS

    def records(self):
        """(cp, walls, wg, wc) as record views (no copies) for the kernels."""
        cpt, wallt = self.layouts()
        return (
            record(np.ascontiguousarray(self.cp, np.float64), cpt),
            record(np.ascontiguousarray(self.walls, np.float64), wallt),
            record(np.ascontiguousarray(self.wg, np.float64), WHEEL_GEOMETRY),
            record(np.ascontiguousarray(self.wc, np.float64), WHEEL_CONTROLS),
        )

    def kernel_params(self) -> KernelParams:
        """The kernels' parameters (layout.KernelParams; records are views, no copies)."""
        cp, walls, wg, wc = self.records()
        mesh = self.mesh if self.mesh is not None else no_mesh()
        params = (float(self.dt), self.gravity, float(self.skin), cp, walls, wg, wc, mesh)
        return KernelParams(*params) if self.outline is None else KernelParams(*params, self.outline)

    def kernels(self):
        """The step-kernel module of this model's dimension (run_steps, spatial_order)."""
        return kernels(self.dim)

    def with_walls(self, **on: bool) -> "Model":
        """A copy with the named fixed walls switched on (True) or off (False): ``left``
        (x = 0), ``right`` (x = length), ``bottom`` (y = 0), 3D also ``front`` (z = 0) and
        ``back`` (z = width); so that a box can be built of plates (``physics.plates``)."""
        _, wallt = self.layouts()
        flags = tuple(n for n in field_names(wallt) if n not in ("length", "width"))
        walls = np.array(self.walls, np.float64)
        rec = record(walls, wallt)
        for name, flag in on.items():
            if name not in flags:
                raise ValueError(f"with_walls: no wall {name!r} in {self.dim}D (walls: {', '.join(flags)})")
            rec[name] = 1.0 if flag else 0.0
        return dataclasses.replace(self, walls=walls)

    def without_wheel(self) -> "Model":
        wg = self.wg.copy()
        record(wg, WHEEL_GEOMETRY)["enabled"] = 0.0
        return Model(
            self.dt,
            self.gravity.copy(),
            self.skin,
            self.cp,
            self.walls,
            wg,
            self.wc,
            False,
            self.r_max,
            self.dim,
            self.hist_cap,
        )  # no wheel: no mesh


FREE_SPIN_CONTROLS = ("torque", "towed")  # omega free: the wheel's inertia matters


def wheel_records(sc) -> tuple[np.ndarray, np.ndarray]:
    """(WHEEL_GEOMETRY, WHEEL_CONTROLS) flat vectors of a scenario's wheel (zeros without
    one); the same in 2D and 3D (3D reads width and z0 too)."""
    wg = np.zeros(WG_SIZE)
    wc = np.zeros(WC_SIZE)
    w = sc.wheel
    if w.enabled:
        g = record(wg, WHEEL_GEOMETRY)
        g["enabled"] = 1.0
        g["radius"] = w.radius
        g["cap"] = 0.5 * w.lug_thickness
        g["lug_in"] = w.radius
        g["lug_out"] = max(w.radius, w.lug_tip_radius - 0.5 * w.lug_thickness)
        g["nlugs"] = w.n_lugs
        g["mass"] = w.load / sc.physics.gravity
        g["width"] = w.width
        g["z0"] = wheel_z0(sc)
        c = record(wc, WHEEL_CONTROLS)
        c["settle"] = w.settle_time
        c["omega"] = w.omega
        c["slipmode"] = 1.0 if w.control == "slip" else 0.0
        c["drawbar"] = w.drawbar_load
        c["ramp"] = w.drawbar_ramp
        c["slip"] = w.slip
        free_spin = w.control in FREE_SPIN_CONTROLS
        c["spinmode"] = 1.0 if free_spin else 0.0
        c["torque"] = w.torque if w.control == "torque" else 0.0
        c["torque_ramp"] = w.torque_ramp
        c["inertia"] = wheel_inertia(sc)
        c["speedmode"] = 1.0 if w.control == "towed" or (w.control == "torque" and w.carriage == "speed") else 0.0
        c["speed"] = w.speed
        c["yfixed"] = 1.0 if w.vertical == "fixed" else 0.0
    return wg, wc


def wheel_inertia(sc) -> float:
    """The wheel's moment of inertia about its axle (kg m^2): wheel.inertia, or that of a
    uniform disc of its mass and rim radius (m R^2 / 2) when it is 0 (a mesh wheel's:
    ``mesh_wheel.wheel_axle_inertia``)."""
    w = sc.wheel
    return w.inertia if w.inertia > 0.0 else 0.5 * (w.load / sc.physics.gravity) * w.radius * w.radius


def wheel_z0(sc) -> float:
    """The wheel's lateral centre (3D): wheel.z0, or the bin's mid-width when it is 0."""
    return sc.wheel.z0 if sc.wheel.z0 > 0.0 else 0.5 * sc.bin.width


class DomainStepper:
    """Advances one set of discs (and optionally the wheel) in place, K steps at a time.

    Besides the discs it holds only what a step needs, sized from the bed: per disc the
    neighbour-list build positions and two CSR offsets (8 + 16 bytes); per candidate
    pair (within r_i + r_j + skin, each pair once, ~2.2 a disc in a settled bed) its two
    disc indices, its slot in the partner's CSR index, a contact flag and one
    ``layout.PAIR_ROW`` (61 bytes, 5 % headroom); the wall/wheel rows of one step.
    Optionally (keep_forces) the last step's forces and torques."""

    # the candidate pairs' arrays, made (and grown) by _grow_pairs
    pair_b: np.ndarray
    pair_a: np.ndarray
    inc_k: np.ndarray
    on: np.ndarray
    rows: np.ndarray

    def __init__(
        self,
        particles: Particles,
        model: Model,
        wheel_state: np.ndarray | None = None,
        reorder: bool = True,
        keep_forces: bool = False,
        pairs_hint: int = 0,
        plates: np.ndarray | None = None,
    ):
        """plates: a ``layout.PLATE`` table (``physics.plates``: at most layout.MAX_PLATES
        rigid plates), copied; ``self.plates`` is the live table (the step moves the plates;
        a caller may change a plate's velocity, mode or load between advances), and each
        advance leaves its plates' rows in ``plate_records`` (steps, P). keep_forces: keep each step's contact forces and torques in ``force`` (N, D) and
        ``torque`` (N, R) (diagnostics and tests; 24 bytes a disc in 2D). pairs_hint: the
        candidate pairs expected (e.g. from a like slab), so that the first build fills the
        list at once instead of counting, growing it and building again; a wrong hint
        costs that second build, never a result."""
        if particles.dim != model.dim:
            raise EngineError(f"{particles.dim}D particles handed to a {model.dim}D model")
        if particles.hist_cap != model.hist_cap:
            raise EngineError(
                f"particles with a contact-history capacity of {particles.hist_cap} "
                f"handed to a model of capacity {model.hist_cap}"
            )
        self.kern = model.kernels()
        # row layouts of this dimension's kernels (physics.KernelModule): the pair row of
        # this contact table (3D leaves the rolling parts out without rolling resistance)
        self._pair_row = self.kern.pair_row_layout(model.records()[0])
        self._body_row = self.kern.BODY_ROW
        if reorder and len(particles) > 1:
            perm = self.kern.spatial_order(particles.pos, len(particles), 2 * model.r_max + model.skin)
            particles.permute_inplace(perm)  # the caller's discs, reordered: no second copy
        self.p = particles
        self.model = model
        self.n = len(particles)
        n = self.n
        self.ws = np.zeros(WS_SIZE) if wheel_state is None else np.array(wheel_state, dtype=np.float64)
        self.plates = np.zeros(0, L.PLATE) if plates is None else np.array(plates, dtype=L.PLATE).reshape(-1)
        if len(self.plates) > L.MAX_PLATES:
            raise EngineError(f"{len(self.plates)} plates: at most {L.MAX_PLATES}")
        self.plate_records = np.zeros((0, len(self.plates)), L.PLATE_RECORD)
        self._idx = L.index_dtype(n)
        self.half_off = np.zeros(n + 1, self._idx)
        self.inc_off = np.zeros(n + 1, self._idx)
        self._grow_pairs(max(0, int(pairs_hint)))
        self.ref = np.zeros((n, model.dim))  # positions at the last neighbour-list build
        nf = n if keep_forces else 0
        self._forces = Forces(np.zeros((nf, model.dim)), np.zeros((nf, spin_width(model.dim))))
        self.keep_forces = keep_forces
        chunks = self.kern.N_CHUNKS
        self.bodies = Bodies(np.zeros(chunks * 8, self._body_row), np.zeros(chunks, np.int64))
        self.err = np.zeros(self.kern.N_ERR, np.int64)
        self._built = False
        self._pairs_done = False
        self.rebuilds = 0

    def _grow_pairs(self, npairs: int) -> None:
        """Room for npairs candidate pairs (+ headroom). The old list is let go first: a
        rebuild follows, and the springs are in the discs' histories (written back before
        the build that overflowed), so old and new never need to coexist."""
        cap = int(npairs * PAIR_HEADROOM) + 64
        released = np.zeros(0)
        self.pair_b = self.pair_a = self.inc_k = self.on = self.rows = released
        self.pair_b = np.zeros(cap, self._idx)
        self.pair_a = np.zeros(cap, self._idx)
        self.inc_k = np.zeros(cap, self._idx)
        self.on = np.zeros(cap, np.uint8)
        self.rows = np.zeros(cap, self._pair_row)

    def _force(self, k):
        if not self.keep_forces:
            raise AttributeError("contact forces are kept only by DomainStepper(..., keep_forces=True)")
        return self._forces[k]

    force = property(lambda self: self._force(0), doc="contact force (N, D) of the last step (keep_forces)")
    torque = property(lambda self: self._force(1), doc="contact torque (N, R) of the last step (keep_forces)")

    @property
    def pairs(self) -> int:
        """Candidate pairs in the current list (each once)."""
        return int(self.half_off[-1])

    def nbytes(self) -> int:
        """Bytes the stepper holds besides the discs."""
        arrs = (
            self.half_off,
            self.inc_off,
            self.pair_b,
            self.pair_a,
            self.inc_k,
            self.on,
            self.rows,
            self.ref,
            *self._forces,
            self.bodies.rows,
        )
        return sum(a.nbytes for a in arrs)

    def advance(self, step0: int, nsteps: int, spans: np.ndarray | None = None) -> np.ndarray:
        """Advance nsteps from global step step0; returns the per-step wheel records
        (nsteps x N_REC, columns REC_COLUMNS). spans: (nsteps, 2) index ranges [first, end)
        of the discs each step advances (an out-of-core slab's light cone,
        ``engine.sweep.cone_spans``: only the discs whose state can still reach the owned
        ones by the block's end; the rest are left as they are); None: all, every step."""
        m = self.model
        rec = np.zeros((nsteps if m.wheel_enabled else 0, N_REC))
        self.plate_records = np.zeros((nsteps if len(self.plates) else 0, len(self.plates)), L.PLATE_RECORD)
        # small domains run on one thread: a parallel launch costs more than it saves
        # there, and the result is the same whatever the thread count (docs/design.md §3)
        threads = numba.get_num_threads()
        serial = self.n < SERIAL_BELOW and threads > 1
        if serial:
            numba.set_num_threads(1)
        try:
            done = self._run(nsteps, step0, rec, L.NO_CONE if spans is None else spans)
        finally:
            if serial:
                numba.set_num_threads(threads)
        self._check(step0 + done, nsteps)
        return rec

    def kernel_args(self) -> tuple:
        """(kernel params, Discs, Pairs, Bodies, Forces, wheel state record, errors): what
        the step kernels take of this stepper (views, no copies)."""
        pl = Pairs(self.half_off, self.pair_b, self.pair_a, self.inc_off, self.inc_k, self.ref, self.on, self.rows)
        return (
            self.model.kernel_params(),
            discs_of(self.p),
            pl,
            self.bodies,
            self._forces,
            record(self.ws, WHEEL_STATE),
            self.err,
        )

    def _grow_bodies(self) -> None:
        """A chunk's wall/wheel rows did not fit: twice the room."""
        self.bodies = Bodies(np.zeros(2 * self.bodies.rows.shape[0], self._body_row), self.bodies.count)

    def _run(self, nsteps, step0, rec, spans=L.NO_CONE) -> int:
        recv = record(rec, WHEEL_RECORD) if len(rec) else np.zeros(1, WHEEL_RECORD)  # unused
        n_plates = len(self.plates)
        prec = self.plate_records.reshape(-1)  # step s's plate k at row s P + k
        done = 0
        while True:
            kp, d, pl, bd, forces, ws, err = self.kernel_args()
            k, rb = self.kern.run_steps(
                nsteps - done,
                step0 + done,
                kp,
                d,
                pl,
                bd,
                forces,
                ws,
                L.Plates(self.plates, prec[done * n_plates :]),
                err,
                recv[done:] if len(rec) else recv,
                not self._built,
                self._pairs_done,
                L.EVERY_PARTICLE,
                spans[done:],
            )
            del kp, d, pl, bd, forces, ws, err  # no view may keep a list that is regrown
            self._pairs_done = False
            done += k
            self.rebuilds += rb
            self._built = True
            if self.err[ERR_PAIR_CAPACITY]:
                # the list just counted does not fit: grow it, rebuild before the next step
                self._grow_pairs(int(self.err[ERR_PAIR_CAPACITY]))
                self.err[ERR_PAIR_CAPACITY] = 0
                self._built = False
            elif self.err[ERR_BODY_CAPACITY]:
                self._grow_bodies()
                self.err[ERR_BODY_CAPACITY] = 0
                # the step's pair rows are made (and hold its new springs): redo its bodies only
                self._pairs_done = True
            else:
                return done
            if done >= nsteps:
                return done  # a rebuild is pending: the next advance starts with it

    def _check(self, at, nsteps):
        p = self.p
        if self.err[ERR_HIST_OVERFLOW]:
            raise EngineError(
                f"contact history overflow at step {at}: a particle has more than "
                f"{p.hist_id.shape[1]} contacts (a wide grading's large grains touch more small ones: "
                f"raise physics.history_capacity; or overlaps too large: check dt, kn, or the bed)"
            )
        if not np.isfinite(p.pos).all():
            raise EngineError(f"non-finite position at step {at}: the run is unstable")
