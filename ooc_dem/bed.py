"""Soil bed generation: random loose fill of the bin, deposited under gravity.

Discs with radii uniform in [r_min, r_max] are placed on a loose jittered grid
and settle under gravity until the mean speed falls below ``bed.settle_speed``.
Large beds (``bed.tile`` > 0) are made of side-by-side copies of one settled
tile: every disc of a tile stays clear of the tile's walls, so copies never
overlap, and a tile can be produced per sub-domain without holding the bed.
"""
from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from .engine.stepper import DomainStepper, Model
from .physics.layout import AX_X, AX_Y, HM_R, HS_T, SP_Z
from .scenario import MAX_STEPS, Scenario, ScenarioError, scenario_from_dict
from .state import Particles


class BedError(RuntimeError):
    pass


def initial_fill(sc: Scenario) -> Particles:
    """Loose random fill: a jittered square grid of pitch 2.2 r_max, bottom up."""
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
            f"bin.height = {sc.bin.height}: the loose fill of {s.n} discs needs {top:.3f} m; raise bin.height")
    r = rng.uniform(s.r_min, s.r_max, s.n)
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
    p = Particles.new(pos, r, s.density, sc.physics.thickness)
    # a little random motion so the fill does not stack as a crystal
    p.vel[:, AX_X] = rng.normal(0.0, 0.01, s.n)
    return p


def surface_height(p: Particles, length: float, r_max: float) -> float:
    """Mean height of the top of the bed (column-wise max of y + r), walls excluded."""
    width = 4 * r_max
    ncol = max(1, int(length / width))
    col = np.clip((p.pos[:, AX_X] / width).astype(np.int64), 0, ncol - 1)
    top = np.full(ncol, -np.inf)
    np.maximum.at(top, col, p.pos[:, AX_Y] + p.r)
    inner = top[1:-1] if ncol > 4 else top
    inner = inner[np.isfinite(inner)]
    return float(np.mean(inner)) if len(inner) else 0.0


def settle(sc: Scenario, p: Particles, progress=None) -> tuple[Particles, int]:
    """Deposit under gravity until the mean speed < settle_speed. Returns (bed, steps)."""
    model = Model.from_scenario(sc).without_wheel()
    stepper = DomainStepper(p, model)
    dt = sc.physics.dt
    # bed.max_settle_time / dt is at most MAX_STEPS (scenario validation); the fixed
    # intervals below are capped so that a tiny dt cannot make them overflow
    max_steps = int(math.ceil(sc.bed.max_settle_time / dt))
    chunk = max(1, min(max_steps, int(round(min(0.005 / dt, MAX_STEPS)))))  # check every 5 ms of simulated time
    step = 0
    min_steps = int(round(min(0.05 / dt, MAX_STEPS + 1)))
    while True:
        stepper.advance(step, chunk)
        step += chunk
        q = stepper.p
        speed = float(np.mean(np.hypot(q.vel[:, AX_X], q.vel[:, AX_Y])))
        if progress is not None:
            progress(step * dt, speed)
        if step >= min_steps and speed < sc.bed.settle_speed:
            break
        if step >= max_steps:
            raise BedError(f"bed did not settle within bed.max_settle_time = {sc.bed.max_settle_time} s "
                           f"(mean speed {speed:.2e} m/s > bed.settle_speed = {sc.bed.settle_speed})")
    return stepper.p, step


def _zero_motion(p: Particles) -> Particles:
    """A settled bed starts at rest with its contact springs kept (the history is the bed's memory)."""
    p.vel[:] = 0.0
    p.spin[:] = 0.0
    return p


def tile_scenario(sc: Scenario) -> Scenario:
    d = sc.to_dict()
    tile_len = sc.bin.length / (-(-sc.soil.n // sc.bed.tile))
    d["soil"]["n"] = sc.bed.tile
    d["bin"]["length"] = tile_len
    d["bed"]["tile"] = 0
    d["wheel"]["enabled"] = False
    return scenario_from_dict(d)


def cache_dir() -> Path:
    root = os.environ.get("OOC_DEM_CACHE") or os.path.join(
        os.environ.get("XDG_CACHE_HOME", os.path.expanduser("~/.cache")), "ooc-dem")
    return Path(root)


def _cached(sc: Scenario, build, progress=None) -> Particles:
    # format-2 beds (pos, vel, ...) under their own name, so that an engine of format 1
    # sharing the cache never sees (and deletes) them; a format-1 cache (x, y, ...) still
    # loads: Particles converts it (state.upgrade_v1)
    beds = cache_dir() / "beds"
    path = beds / f"{sc.bed_hash()}.v2.npz"
    for f in (path, beds / f"{sc.bed_hash()}.npz"):
        if f.is_file():
            try:
                with np.load(f) as z:
                    return Particles(**{k: z[k] for k in z.files})
            except Exception:
                if f == path:
                    path.unlink(missing_ok=True)
    p = build(progress)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".tmp{os.getpid()}.npz")
    np.savez(tmp, **p.arrays())
    os.replace(tmp, path)
    return p


def settled_bed(sc: Scenario, progress=None, use_cache: bool = True) -> Particles:
    """The settled bed of a scenario (sorted by id), cached on disk by its bed hash."""
    if sc.bed.tile > 0 and sc.soil.n > sc.bed.tile:
        # filled part by part into one allocation (no list of parts plus a concatenated copy)
        bed = Particles.empty(sc.soil.n, sc.dim)
        at = 0
        for part in tiled_bed_parts(sc, progress=progress, use_cache=use_cache, tiles_per_part=8):
            for k in bed.arrays():
                getattr(bed, k)[at:at + len(part)] = getattr(part, k)
            at += len(part)
        return bed

    def build(progress):
        bed, _ = settle(sc, initial_fill(sc), progress)
        return _zero_motion(bed).sorted_by_id()

    return _cached(sc, build, progress) if use_cache else build(progress)


def tiled_bed_parts(sc: Scenario, progress=None, use_cache: bool = True, tiles_per_part: int = 1):
    """Yield the bed in x order, a few tiles at a time (never the whole bed in RAM).

    Every other tile is mirrored, so that across each seam a disc that touched the
    tile's side wall faces its own mirror image at exactly contact distance: the
    wall's normal support is replaced by a disc instead of a gap. The discs that
    make N exact are taken off the top of the tiles (the loosest, least loaded).
    Disc ids are tile * n_tile + the tile's own id.
    """
    tsc = tile_scenario(sc)
    tile = settled_bed(tsc, progress, use_cache).sorted_by_id()
    n_tile = len(tile)
    tile_len = tsc.bin.length
    n_total = sc.soil.n
    ntiles = -(-n_total // n_tile)
    extra = ntiles * n_tile - n_total
    top_first = np.argsort(-(tile.pos[:, AX_Y] + tile.r), kind="stable")
    templates: dict = {}
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


def _tile_template(tile: Particles, keep, mirrored: bool, left_inner: bool, right_inner: bool,
                   tile_len: float) -> Particles:
    """One tile copy at offset 0 with tile-local ids (shifted per copy by the caller)."""
    from .physics.forces import ID_WALL_LEFT, ID_WALL_RIGHT
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
