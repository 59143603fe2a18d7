"""Soil bed generation: random loose fill of the bin, deposited under gravity.

Discs with radii drawn from ``soil.grading`` between r_min and r_max (uniform by
default; model/grading.py) are placed on a loose jittered grid and settle under
gravity until the mean speed falls below ``bed.settle_speed``.
Large beds (``bed.tile`` > 0) are made of side-by-side copies of one settled
tile: every disc of a tile stays clear of the tile's walls, so copies never
overlap, and a tile can be produced per sub-domain without holding the bed.

3D (``physics.dim = 3``): spheres on a jittered cubic grid of the same pitch filling
the box (length x width) bottom up; tiled beds repeat the tile along x and
``bed.tiles_across`` times across the width (z), mirrored in x and in z every other
tile.

A settled bed reports itself (``bed_info``; ``TiledBedMeasure`` for a tiled bed streamed
part by part): surface height, bulk density, porosity, coordination number and grading
(model/bedreport.py).

The angle-of-repose test (``repose.enabled``, docs/reference/repose3d.md) starts from a
column: a square box of side 2 ``repose.column_radius`` filled and settled like any bed,
cut to the cylinder of that radius, its ``soil.n`` lowest spheres kept and set down at
the centre of the bin's floor (``settled_column``); in 2D a box of width 2
``column_radius`` holding the column's ``soil.n`` discs.
"""

from __future__ import annotations

import dataclasses

import math
import os
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeAlias

import numpy as np
from numpy.typing import NDArray

from ..engine.stepper import DomainStepper, Model
from ..errors import OocDemError
from ..physics.layout import AX_X, AX_Y, HM_R, HS_T, SP_Z
from ..model.bedreport import BedMeasure, bed_report, top_layer_height
from ..model.bedreport import surface_height as surface_height  # its home: the bed's measures
from ..model.grading import draw_radii, grading_of_soil
from ..model.scenario_check import scenario_from_dict, tile_grid, tile_scenario, tile_size
from ..model.schema import MAX_STEPS, Scenario, ScenarioError
from ..model.state import Particles

if TYPE_CHECKING:
    from ..storage.npzfile import RowShape

# called as the bed settles: (simulated time in s, mean speed in m/s)
SettleProgress: TypeAlias = "Callable[[float, float], object]"


class BedError(OocDemError, RuntimeError):
    pass


def initial_fill(sc: Scenario) -> Particles:
    """Loose random fill: a jittered square grid of pitch 2.2 r_max, bottom up."""
    if sc.dim == 3:
        return initial_fill_3d(sc)
    s = sc.soil
    rng = np.random.default_rng(s.seed)
    pitch = 2.2 * s.r_max
    ncol = int((sc.bin.length - 2 * s.r_max) / pitch)
    if ncol < 1:
        raise ScenarioError(f"bin.length = {sc.bin.length}: too short for one disc column")
    nrow = -(-s.n // ncol)
    top = s.r_max + (nrow - 1) * pitch + s.r_max
    if top > sc.bin.height:
        raise ScenarioError(
            f"bin.height = {sc.bin.height}: the loose fill of {s.n} discs needs {top:.3f} m; raise bin.height"
        )
    r = draw_radii(grading_of_soil(s), s.n, rng, sc.dim)  # uniform: rng.uniform(r_min, r_max, n)
    k = np.arange(s.n)
    col = k % ncol
    row = k // ncol
    slack = 0.5 * (pitch - 2 * s.r_max)
    x0 = 0.5 * (sc.bin.length - (ncol - 1) * pitch)
    x = x0 + col * pitch + rng.uniform(-slack, slack, s.n)
    y = s.r_max + row * pitch + rng.uniform(0, slack, s.n)
    pos = np.zeros((s.n, sc.dim))
    pos[:, AX_X] = x
    pos[:, AX_Y] = y
    p = Particles.new(pos, r, s.density, sc.physics.thickness, hist_cap=sc.hist_cap)
    # a little random motion so the fill does not stack as a crystal
    p.vel[:, AX_X] = rng.normal(0.0, 0.01, s.n)
    return p


def initial_fill_3d(sc: Scenario) -> Particles:
    """Loose random fill of the 3D box: a jittered cubic grid of pitch 2.2 r_max, layer by
    layer bottom up (x fastest, then z), with a little random horizontal motion."""
    from ..physics.layout import AX_Z

    s = sc.soil
    rng = np.random.default_rng(s.seed)
    pitch = 2.2 * s.r_max
    nx = int((sc.bin.length - 2 * s.r_max) / pitch)
    nz = int((sc.bin.width - 2 * s.r_max) / pitch)
    if nx < 1 or nz < 1:
        raise ScenarioError(
            f"bin.length = {sc.bin.length}, bin.width = {sc.bin.width}: too small for one sphere column"
        )
    per = nx * nz
    nrow = -(-s.n // per)
    top = s.r_max + (nrow - 1) * pitch + s.r_max
    if top > sc.bin.height:
        raise ScenarioError(
            f"bin.height = {sc.bin.height}: the loose fill of {s.n} spheres needs {top:.3f} m; raise bin.height"
        )
    r = draw_radii(grading_of_soil(s), s.n, rng, sc.dim)  # uniform: rng.uniform(r_min, r_max, n)
    k = np.arange(s.n)
    layer, inlayer = k // per, k % per
    ix, iz = inlayer % nx, inlayer // nx
    slack = 0.5 * (pitch - 2 * s.r_max)
    x0 = 0.5 * (sc.bin.length - (nx - 1) * pitch)
    z0 = 0.5 * (sc.bin.width - (nz - 1) * pitch)
    pos = np.zeros((s.n, 3))
    pos[:, AX_X] = x0 + ix * pitch + rng.uniform(-slack, slack, s.n)
    pos[:, AX_Y] = s.r_max + layer * pitch + rng.uniform(0, slack, s.n)
    pos[:, AX_Z] = z0 + iz * pitch + rng.uniform(-slack, slack, s.n)
    p = Particles.new(pos, r, s.density, sc.physics.thickness, hist_cap=sc.hist_cap)
    p.vel[:, AX_X] = rng.normal(0.0, 0.01, s.n)
    p.vel[:, AX_Z] = rng.normal(0.0, 0.01, s.n)
    return p


def mean_speed(p: Particles) -> float:
    """Mean particle speed; each speed the square root of its components' squares summed in
    axis order (exact operations: libm's hypot and einsum's vectorised sums may round
    otherwise on another machine, and the speed decides when settling stops)."""
    v = p.vel
    sq = v[:, 0] * v[:, 0]
    for k in range(1, p.dim):
        sq = sq + v[:, k] * v[:, k]
    return float(np.mean(np.sqrt(sq)))


def wheel_footprint(sc: Scenario) -> tuple[float, float] | None:
    """The band across the bin (z) the 3D wheel rolls over, for ``surface_height``; None
    in 2D or without a wheel (the whole bed is under the wheel's width)."""
    if sc.dim != 3 or not sc.wheel.enabled:
        return None
    from ..engine.stepper import wheel_z0

    z0, half = wheel_z0(sc), 0.5 * sc.wheel.width
    return (z0 - half, z0 + half)


def bed_info(sc: Scenario, bed: Particles, surface: float) -> dict[str, Any]:
    """bed.json of a settled bed whole in memory: its scenario, size, surface height (the
    wheel's reference: ``surface_height`` under the wheel), bed hash and report (bulk
    density, porosity, coordination number, grading: model/bedreport.py)."""
    report = bed_report(bed, sc.bin.length, sc.soil.r_max, sc.physics.thickness, sc.bin.width)
    if sc.repose.enabled:  # a column standing in a wide bin: no bed filling the bin to measure
        report.update(bulk_density_kg_m3=None, porosity=None)
    return _info(sc, len(bed), surface, report)


def _info(sc: Scenario, n: int, surface: float, report: dict[str, Any]) -> dict[str, Any]:
    return {"scenario": sc.name, "n_discs": n, "surface_height_m": surface, "bed_hash": sc.bed_hash(), **report}


class TiledBedMeasure:
    """The report of a tiled bed measured part by part as ``tiled_bed_parts`` yields them
    (never whole in memory): each part below its own top layer, over the tile columns it
    spans (model/bedreport.BedMeasure)."""

    def __init__(self, sc: Scenario) -> None:
        self.sc = sc
        self.measure = BedMeasure(sc.dim, sc.physics.thickness, sc.bin.width)
        self.tile_length = tile_size(sc)[0]
        self.across = tile_grid(sc)[1]

    def add(self, part: Particles) -> None:
        sc = self.sc
        x0 = float(part.pos[:, AX_X].min())
        band = (0.0, sc.bin.width) if sc.dim == 3 else None
        plane = top_layer_height(part, float(part.pos[:, AX_X].max()) - x0, sc.soil.r_max, x_origin=x0, across=band)
        # grain ids are tile * bed.tile + the tile's own id, tiles numbered across z first
        columns = len(np.unique(part.id // sc.bed.tile // self.across))
        self.measure.add(part, plane, columns * self.tile_length)

    def info(self, surface: float) -> dict[str, Any]:
        """bed.json of the bed measured (``surface``: its surface height as the run took it)."""
        return _info(self.sc, self.measure.n, surface, self.measure.report())


def pour_scenario(sc: Scenario) -> Scenario:
    """The scenario a bed is poured with: its own, or with bed.fill_friction as the soil-soil
    friction (grains that slide past each other while they fall pack denser: the usual way
    to reach a measured bulk density; the run then steps the contact's own friction)."""
    if sc.bed.fill_friction < 0.0:
        return sc
    pair = dataclasses.replace(sc.contact.soil_soil, friction=sc.bed.fill_friction)
    return dataclasses.replace(sc, contact=dataclasses.replace(sc.contact, soil_soil=pair))


def settle_schedule(sc: Scenario) -> tuple[int, int, int]:
    """(chunk, min_steps, max_steps) of ``settle``: the speed is checked every chunk steps (5 ms
    of simulated time), from min_steps (50 ms) on, up to max_steps (bed.max_settle_time)."""
    dt = sc.physics.dt
    # bed.max_settle_time / dt is at most MAX_STEPS (scenario validation); the fixed
    # intervals below are capped so that a tiny dt cannot make them overflow
    max_steps = int(math.ceil(sc.bed.max_settle_time / dt))
    chunk = max(1, min(max_steps, int(round(min(0.005 / dt, MAX_STEPS)))))
    min_steps = int(round(min(0.05 / dt, MAX_STEPS + 1)))
    return chunk, min_steps, max_steps


def settle(sc: Scenario, p: Particles, progress: SettleProgress | None = None) -> tuple[Particles, int]:
    """Deposit under gravity until the mean speed < settle_speed (with bed.fill_friction, if
    set). Returns (bed, steps)."""
    model = Model.from_scenario(pour_scenario(sc)).without_wheel()
    stepper = DomainStepper(p, model)
    dt = sc.physics.dt
    chunk, min_steps, max_steps = settle_schedule(sc)
    step = 0
    while True:
        stepper.advance(step, chunk)
        step += chunk
        q = stepper.p
        speed = mean_speed(q)
        if progress is not None:
            progress(step * dt, speed)
        if step >= min_steps and speed < sc.bed.settle_speed:
            break
        if step >= max_steps:
            raise BedError(
                f"bed did not settle within bed.max_settle_time = {sc.bed.max_settle_time} s "
                f"(mean speed {speed:.2e} m/s > bed.settle_speed = {sc.bed.settle_speed})"
            )
    return stepper.p, step


def column_scenario(sc: Scenario) -> Scenario:
    """The scenario the repose column is settled in: the square box of side 2 column_radius
    around the column, filled with scenario.repose_fill's count of spheres."""
    from ..model.scenario_check import repose_fill

    d = sc.to_dict()
    side = 2.0 * sc.repose.column_radius
    d["bin"]["length"] = d["bin"]["width"] = side
    d["soil"]["n"] = repose_fill(sc)[0]
    d["repose"]["enabled"] = False
    return scenario_from_dict(d)


def settled_column(sc: Scenario, progress: SettleProgress | None = None) -> Particles:
    """The repose test's column at rest on the floor of sc's bin, centred (module doc).

    Settled in ``column_scenario``'s box, the spheres whose centres lie within
    column_radius - r_max of the box's axis are kept (the cylinder holds them whole; in 2D
    the box of width 2 column_radius is the column and every disc is kept), of those the
    soil.n lowest, ids renumbered 0..n-1 in their old order (so every history
    stays sorted by partner id). Contacts with the box's four side walls are dropped (those
    walls are gone), as are contacts with cut spheres; the floor's are kept (it stays)."""
    from ..physics.layout import AX_Z, ID_WALL_BOTTOM

    csc = column_scenario(sc)
    col, _ = settle(csc, initial_fill(csc), progress)
    col = _zero_motion(col).sorted_by_id()
    R = sc.repose.column_radius
    if sc.dim == 3:
        dx, dz = col.pos[:, AX_X] - R, col.pos[:, AX_Z] - R
        radial = np.sqrt(dx * dx + dz * dz)  # exact operations, not libm's hypot
        inside = np.flatnonzero(radial <= R - sc.soil.r_max)
    else:  # the box of width 2R is the column: every disc is inside
        inside = np.flatnonzero(np.abs(col.pos[:, AX_X] - R) <= R)
    if len(inside) < sc.soil.n:
        raise BedError(
            f"soil.n = {sc.soil.n}: the settled repose column holds only {len(inside)} spheres "
            f"inside repose.column_radius = {R!r}; lower soil.n or widen the column"
        )
    lowest = inside[np.argsort(col.pos[inside, AX_Y], kind="stable")[: sc.soil.n]]
    q = col.take(np.sort(lowest))
    new_id = np.full(len(col), -1, np.int64)
    new_id[q.id] = np.arange(len(q))  # sorted_by_id: col.id is 0..n_fill-1
    hid, hs, hm, hn = q.hist_id.copy(), q.hist_s.copy(), q.hist_m.copy(), q.hist_n.copy()
    q.hist_id[:] = 0
    q.hist_s[:] = 0.0
    q.hist_m[:] = 0.0
    for i in range(len(q)):
        k = 0
        for e in range(hn[i]):
            pid = int(hid[i, e])
            if pid >= 0:
                pid = int(new_id[pid])
                if pid < 0:
                    continue
            elif pid != ID_WALL_BOTTOM:
                continue
            q.hist_id[i, k], q.hist_s[i, k], q.hist_m[i, k] = pid, hs[i, e], hm[i, e]
            k += 1
        q.hist_n[i] = k
    q.id[:] = np.arange(len(q))
    q.pos[:, AX_X] += 0.5 * sc.bin.length - R
    if sc.dim == 3:
        q.pos[:, AX_Z] += 0.5 * sc.bin.width - R
    return q


def _zero_motion(p: Particles) -> Particles:
    """A settled bed starts at rest with its contact springs kept (the history is the bed's memory)."""
    p.vel[:] = 0.0
    p.spin[:] = 0.0
    return p


def cache_dir() -> Path:
    root = os.environ.get("OOC_DEM_CACHE") or os.path.join(
        os.environ.get("XDG_CACHE_HOME", os.path.expanduser("~/.cache")), "ooc-dem"
    )
    return Path(root)


def read_bed(path: str | os.PathLike[str], sc: Scenario, label: str) -> Particles:
    """A bed file (``prepare``'s bed.npz, a bed-cache entry) read as untrusted input: every
    member's size is read from its header and held against the scenario's soil.n (and a
    history capacity of at most MAX_HIST_CAP) before anything is inflated, its dtype must
    convert to the state's without loss, and the bed must pass ``check_bed``. A format-1 bed
    (x, y, vx, vy, w, hist_ft, hist_mr) is read as such and converted. Anything else raises
    StateError, one line starting with ``label`` and the file."""
    from ..model.checkpoint import check_bed
    from ..model.state_check import StateError
    from ..storage.npzfile import npz_member_names, read_npz_members
    from ..model.schema import MAX_HIST_CAP
    from ..model.state import FIELD_DTYPES, HIST_FIELDS, V1_ARRAYS, field_tails, is_v1

    where = f"{label} {path}"
    dtypes = dict(FIELD_DTYPES)
    want: dict[str, tuple[RowShape, str]] = {}
    for k, shape in field_tails(sc.dim, 0).items():
        tail: RowShape = shape
        if k in HIST_FIELDS:  # a bed's capacity is its own, not the scenario's
            tail = (range(MAX_HIST_CAP + 1),) + shape[1:]
        want[k] = (tail, "iu" if FIELD_DTYPES[k].kind in "iu" else "iuf")
    try:
        if is_v1(npz_member_names(path, StateError)):
            for new, comps in V1_ARRAYS.items():
                tail, kinds = want.pop(new)
                for c in comps:  # one component of the format-2 array: its last axis dropped
                    want[c], dtypes[c] = (tail[:-1], kinds), FIELD_DTYPES[new]
        arrays = read_npz_members(path, want, sc.soil.n, StateError, n_from=f"soil.n = {sc.soil.n}")
    except StateError as e:
        raise StateError(f"{label} {e}") from None
    for k, a in arrays.items():
        t = dtypes[k]
        if not (
            np.can_cast(a.dtype, t)
            or (t.kind == "i" and (a.size == 0 or (np.iinfo(t).min <= a.min() and a.max() <= np.iinfo(t).max)))
        ):
            raise StateError(f"{where}: {k!r} holds {a.dtype} values beyond {t}")
    try:
        p = Particles(**arrays)
    except ValueError as e:
        raise StateError(f"{where}: {' '.join(str(e).split())}") from None
    check_bed(p, where, sc)
    return p


# The bed cache's version: a bed is cached under <bed hash>.v<N>.npz, N raised whenever the
# code that generates or settles a bed gives other bits, so that no older bed is reused
# (and an older engine sharing the cache never sees, nor deletes, the new ones).
# 3: masses as r * r * r, restitution logs and grading radii correctly rounded (the same
# bits on every machine); 2: the state's format 2 (pos, vel, ...).
BED_CACHE_VERSION = 3


def bed_cache_path(sc: Scenario) -> Path:
    """The bed cache's file of a scenario's settled bed."""
    return cache_dir() / "beds" / f"{sc.bed_hash()}.v{BED_CACHE_VERSION}.npz"


def _cached(
    sc: Scenario, build: Callable[[SettleProgress | None], Particles], progress: SettleProgress | None = None
) -> Particles:
    path = bed_cache_path(sc)
    from ..model.state_check import StateError

    if path.is_file():
        try:
            p = read_bed(path, sc, "cached bed")  # the cache is a file like any other
            # the capacity is no part of the bed's bits (nor of its hash): a bed cached
            # at another capacity is refitted to this scenario's
            return p if p.hist_cap == sc.hist_cap else p.with_hist_cap(sc.hist_cap)
        except Exception as e:
            if isinstance(e, StateError):
                print(f"ooc-dem: warning: {e}; rebuilding it", file=sys.stderr, flush=True)
            path.unlink(missing_ok=True)
    p = build(progress)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".tmp{os.getpid()}.npz")
    np.savez(tmp, allow_pickle=False, **p.arrays())  # numeric arrays: nothing to pickle
    os.replace(tmp, path)
    return p


def settled_bed(sc: Scenario, progress: SettleProgress | None = None, use_cache: bool = True) -> Particles:
    """The settled bed of a scenario (sorted by id), cached on disk by its bed hash."""
    if sc.bed.tile > 0 and sc.soil.n > sc.bed.tile:
        # filled part by part into one allocation (no list of parts plus a concatenated copy)
        bed = Particles.empty(sc.soil.n, sc.dim, sc.hist_cap)
        at = 0
        for part in tiled_bed_parts(sc, progress=progress, use_cache=use_cache, tiles_per_part=8):
            for k in bed.arrays():
                getattr(bed, k)[at : at + len(part)] = getattr(part, k)
            at += len(part)
        return bed

    def build(progress: SettleProgress | None) -> Particles:
        if sc.repose.enabled:
            return settled_column(sc, progress)
        bed, _ = settle(sc, initial_fill(sc), progress)
        return _zero_motion(bed).sorted_by_id()

    return _cached(sc, build, progress) if use_cache else build(progress)


def tiled_bed_parts(
    sc: Scenario, progress: SettleProgress | None = None, use_cache: bool = True, tiles_per_part: int = 1
) -> Iterator[Particles]:
    """Yield the bed in x order, a few tiles at a time (never the whole bed in RAM).

    Every other tile is mirrored, so that across each seam a disc that touched the
    tile's side wall faces its own mirror image at exactly contact distance: the
    wall's normal support is replaced by a disc instead of a gap. The discs that
    make N exact are taken off the top of the tiles (the loosest, least loaded).
    Disc ids are tile * n_tile + the tile's own id.
    """
    if sc.dim == 3:
        yield from _tiled_bed_parts_3d(sc, progress, use_cache, tiles_per_part)
        return
    tsc = tile_scenario(sc)
    tile = settled_bed(tsc, progress, use_cache).sorted_by_id()
    n_tile = len(tile)
    tile_len = tsc.bin.length
    n_total = sc.soil.n
    ntiles = -(-n_total // n_tile)
    extra = ntiles * n_tile - n_total
    top_first = np.argsort(-(tile.pos[:, AX_Y] + tile.r), kind="stable")
    templates: dict[tuple[int, bool, bool, bool], Particles] = {}
    for start in range(0, ntiles, tiles_per_part):
        parts = []
        for k in range(start, min(ntiles, start + tiles_per_part)):
            drop = extra // ntiles + (1 if k < extra % ntiles else 0)
            key = (drop, k % 2 == 1, k > 0, k < ntiles - 1)
            if key not in templates:
                keep = np.ones(n_tile, bool)
                keep[top_first[:drop]] = False
                templates[key] = _tile_template(tile, keep, *key[1:], tile_len)
            q = templates[key].take(np.arange(len(templates[key])))  # a copy
            q.pos[:, AX_X] += k * tile_len
            q.id += k * n_tile
            used = np.arange(q.hist_id.shape[1])[None, :] < q.hist_n[:, None]
            q.hist_id[used & (q.hist_id >= 0)] += k * n_tile
            parts.append(q)
        yield Particles.concat(parts)


def _tile_template(
    tile: Particles, keep: NDArray[np.bool_], mirrored: bool, left_inner: bool, right_inner: bool, tile_len: float
) -> Particles:
    """One tile copy at offset 0 with tile-local ids (shifted per copy by the caller)."""
    from ..physics.layout import ID_WALL_LEFT, ID_WALL_RIGHT

    q = tile.take(np.flatnonzero(keep))
    if mirrored:
        # a reflection in x: x -> L - x, vx -> -vx, and (2D) the spin about z reverses
        q.pos[:, AX_X] = tile_len - q.pos[:, AX_X]
        q.vel[:, AX_X] = -q.vel[:, AX_X]
        q.spin[:, SP_Z] = -q.spin[:, SP_Z]
    hid, hs, hm, hn = q.hist_id.copy(), q.hist_s.copy(), q.hist_m.copy(), q.hist_n.copy()
    q.hist_id[:] = 0
    q.hist_s[:] = 0.0
    q.hist_m[:] = 0.0
    for i in range(len(q)):
        entries = []
        for s in range(hn[i]):
            pid = int(hid[i, s])
            ft, mr = hs[i, s, HS_T], hm[i, s, HM_R]
            if mirrored:
                # a reflection reverses the tangential direction and the sense of rotation
                ft, mr = -ft, -mr
            if pid >= 0:
                if not keep[pid]:
                    continue
            else:
                if mirrored and pid in (ID_WALL_LEFT, ID_WALL_RIGHT):
                    pid = ID_WALL_LEFT if pid == ID_WALL_RIGHT else ID_WALL_RIGHT
                if (pid == ID_WALL_LEFT and left_inner) or (pid == ID_WALL_RIGHT and right_inner):
                    continue
            entries.append((pid, ft, mr))
        entries.sort(key=lambda e: e[0])
        for s, (pid, ft, mr) in enumerate(entries):
            q.hist_id[i, s], q.hist_s[i, s, HS_T], q.hist_m[i, s, HM_R] = pid, ft, mr
        q.hist_n[i] = len(entries)
    return q


def _tiled_bed_parts_3d(
    sc: Scenario, progress: SettleProgress | None, use_cache: bool, tiles_per_part: int
) -> Iterator[Particles]:
    """tiled_bed_parts in 3D: tile columns along x (each ``bed.tiles_across`` tiles across z),
    a few columns at a time, in x order. Tile (kx, kz) is number k = kx * nz + kz, mirrored
    in x when kx is odd and in z when kz is odd; sphere ids are k * n_tile + the tile's id."""
    from ..physics.d3.layout import ID_WALL_BACK, ID_WALL_FRONT, ID_WALL_LEFT, ID_WALL_RIGHT
    from ..physics.layout import AX_Z

    tsc = tile_scenario(sc)
    tile = settled_bed(tsc, progress, use_cache).sorted_by_id()
    n_tile = len(tile)
    tl, tw = tsc.bin.length, tsc.bin.width
    nx, nz = tile_grid(sc)
    ntiles = nx * nz
    extra = ntiles * n_tile - sc.soil.n
    top_first = np.argsort(-(tile.pos[:, AX_Y] + tile.r), kind="stable")
    swap = {
        ID_WALL_LEFT: ID_WALL_RIGHT,
        ID_WALL_RIGHT: ID_WALL_LEFT,
        ID_WALL_FRONT: ID_WALL_BACK,
        ID_WALL_BACK: ID_WALL_FRONT,
    }
    templates: dict[tuple[int, bool, bool, bool, bool, bool, bool], Particles] = {}
    for start in range(0, nx, max(1, tiles_per_part // nz)):
        parts = []
        for kx in range(start, min(nx, start + max(1, tiles_per_part // nz))):
            for kz in range(nz):
                k = kx * nz + kz
                drop = extra // ntiles + (1 if k < extra % ntiles else 0)
                key = (drop, kx % 2 == 1, kz % 2 == 1, kx > 0, kx < nx - 1, kz > 0, kz < nz - 1)
                if key not in templates:
                    keep = np.ones(n_tile, bool)
                    keep[top_first[:drop]] = False
                    mx, mz, inner_l, inner_r, inner_f, inner_b = key[1:]
                    q = tile.take(np.flatnonzero(keep))
                    # reflections: a true vector (position, velocity, tangential spring)
                    # flips the mirrored component, a pseudovector (spin, rolling moment)
                    # the other two
                    for on, ax, length in ((mx, AX_X, tl), (mz, AX_Z, tw)):
                        if not on:
                            continue
                        q.pos[:, ax] = length - q.pos[:, ax]
                        q.vel[:, ax] = -q.vel[:, ax]
                        q.hist_s[:, :, ax] = -q.hist_s[:, :, ax]
                        for other in range(3):
                            if other != ax:
                                q.spin[:, other] = -q.spin[:, other]
                                q.hist_m[:, :, other] = -q.hist_m[:, :, other]
                    drop_walls = set()
                    for inner, wid in (
                        (inner_l, ID_WALL_LEFT),
                        (inner_r, ID_WALL_RIGHT),
                        (inner_f, ID_WALL_FRONT),
                        (inner_b, ID_WALL_BACK),
                    ):
                        if inner:
                            drop_walls.add(wid)
                    hid, hs, hm, hn = (q.hist_id.copy(), q.hist_s.copy(), q.hist_m.copy(), q.hist_n.copy())
                    q.hist_id[:] = 0
                    q.hist_s[:] = 0.0
                    q.hist_m[:] = 0.0
                    for i in range(len(q)):
                        entries = []
                        for e in range(hn[i]):
                            pid = int(hid[i, e])
                            if pid >= 0:
                                if not keep[pid]:
                                    continue
                            else:
                                if mx and pid in (ID_WALL_LEFT, ID_WALL_RIGHT):
                                    pid = swap[pid]
                                if mz and pid in (ID_WALL_FRONT, ID_WALL_BACK):
                                    pid = swap[pid]
                                if pid in drop_walls:
                                    continue
                            entries.append((pid, hs[i, e], hm[i, e]))
                        entries.sort(key=lambda t: t[0])
                        for e, (pid, a, b) in enumerate(entries):
                            q.hist_id[i, e], q.hist_s[i, e], q.hist_m[i, e] = pid, a, b
                        q.hist_n[i] = len(entries)
                    templates[key] = q
                q = templates[key].take(np.arange(len(templates[key])))  # a copy
                q.pos[:, AX_X] += kx * tl
                q.pos[:, AX_Z] += kz * tw
                q.id += k * n_tile
                used = np.arange(q.hist_id.shape[1])[None, :] < q.hist_n[:, None]
                q.hist_id[used & (q.hist_id >= 0)] += k * n_tile
                parts.append(q)
        yield Particles.concat(parts, 3, tile.hist_cap)
