"""Pictures of 3D frames for ``ooc-dem animate``: spheres splatted into an image with numpy.

An orthographic view along -z (x to the right, y up, the viewer on the +z side): every sphere
is a shaded disc of its projected radius in whole pixels, drawn from a small sprite made once
per radius (the pixel offsets inside the disc, their shading and how far each is in front of
the sphere's centre). Hidden surfaces are removed exactly with a z-buffer of 64-bit keys: a
fragment's key is its quantised depth, then the sphere's index, then the sprite pixel's, so
one ``np.minimum.at`` over all fragments leaves in each pixel the nearest fragment and says
which sphere and which shade it is. The cost is linear in the covered pixels (no sorting,
no per-sphere Python), in bounded memory (the fragments go through in chunks).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

MAX_RADIUS_PX = 64  # a sphere larger than this on screen is drawn at this radius
CHUNK_FRAGMENTS = 1 << 22  # fragments generated at a time (memory: ~20 bytes each)
LIGHT = np.array([-0.45, 0.55, 0.70])  # from the upper left, towards the viewer
AMBIENT, DIFFUSE = 0.35, 0.65
EMPTY = np.iinfo(np.uint64).max
# depth slabs drawn nearest first, the hidden spheres of each skipped: the first is 1/2^SLABS
# of the depth (a few grains, enough to cover most of a bed's face), each next one twice as deep
SLABS = 7
SLAB_MIN_SPHERES = 20000


def _bits(n: int) -> int:
    return max(1, int(n).bit_length())


@dataclass(frozen=True)
class _Sprites:
    """The discs of the radii in use, one table: per entry its pixel offset (dy, dx), its
    shade and its height above the disc's plane as a fraction of the radius."""

    start: dict[int, int]  # radius -> first entry
    count: dict[int, int]
    dy: NDArray[np.int64]
    dx: NDArray[np.int64]
    shade: NDArray[np.float32]
    lift: NDArray[np.float64]


def _sprites(radii: NDArray[np.int64]) -> _Sprites:
    light = LIGHT / np.linalg.norm(LIGHT)
    start: dict[int, int] = {}
    count: dict[int, int] = {}
    parts: list[tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float32], NDArray[np.float64]]] = []
    at = 0
    for rho in map(int, radii):
        oy, ox = np.mgrid[-rho : rho + 1, -rho : rho + 1]
        edge = rho + 0.5
        d2 = (ox * ox + oy * oy).astype(np.float64)
        inside = d2 <= (rho + 0.35) ** 2
        oy, ox, d2 = oy[inside], ox[inside], d2[inside]
        nz = np.sqrt(np.maximum(0.0, 1.0 - d2 / (edge * edge)))
        normal = np.column_stack([ox / edge, -oy / edge, nz])  # image rows grow downwards
        shade = AMBIENT + DIFFUSE * np.maximum(0.0, normal @ light)
        if rho >= 2:
            shade = np.where(d2 > (rho - 0.5) ** 2, 0.7 * shade, shade)  # a darker rim
        start[rho], count[rho] = at, len(ox)
        at += len(ox)
        parts.append((oy.astype(np.int64), ox.astype(np.int64), shade.astype(np.float32), nz))
    dy, dx, sh, lift = (np.concatenate([p[i] for p in parts]) for i in range(4))
    return _Sprites(start, count, dy, dx, sh, lift)


class SphereSplatter:
    """Draws spheres into a ``height`` x ``width`` picture of the x-y window
    [xa, xb] x [ya, yb] (equal scale: the window's aspect should be the picture's)."""

    def __init__(self, width: int, height: int, xa: float, xb: float, ya: float, yb: float) -> None:
        self.width, self.height = int(width), int(height)
        self.xa, self.yb = float(xa), float(yb)
        self.scale = self.width / (float(xb) - float(xa))  # pixels per metre
        self._sprites: dict[tuple[int, ...], _Sprites] = {}

    def render(
        self,
        pos: NDArray[np.float64],
        r: NDArray[np.float64],
        colour: NDArray[np.float32],
        background: tuple[int, int, int] = (255, 255, 255),
    ) -> NDArray[np.uint8]:
        """The picture (height x width x 3, uint8) of spheres at ``pos`` (N x 3) of radii ``r``,
        each in its ``colour`` (N x 3 in [0, 1]) shaded as a lit ball."""
        W, H = self.width, self.height
        img = np.empty((H * W, 3), np.uint8)
        img[:] = np.asarray(background, np.uint8)
        if len(r) == 0:
            return img.reshape(H, W, 3)
        s = self.scale
        cx = np.floor((pos[:, 0] - self.xa) * s).astype(np.int64)
        cy = np.floor((self.yb - pos[:, 1]) * s).astype(np.int64)
        rad = np.clip(np.rint(r * s), 1, MAX_RADIUS_PX).astype(np.int64)
        seen = (cx + rad >= 0) & (cx - rad < W) & (cy + rad >= 0) & (cy - rad < H)
        if not seen.any():
            return img.reshape(H, W, 3)
        if seen.all():
            sel = np.arange(len(r))
            depth, rr = -pos[:, 2], np.asarray(r)
        else:
            sel = np.flatnonzero(seen)
            cx, cy, rad = cx[sel], cy[sel], rad[sel]
            depth, rr = -pos[sel, 2], r[sel]  # the viewer is on the +z side: a larger z is nearer
        radii = np.flatnonzero(np.bincount(rad))
        key = tuple(radii.tolist())
        sp = self._sprites.get(key)
        if sp is None:
            sp = self._sprites[key] = _sprites(radii)
        # the key's fields, high to low: depth, sphere, sprite entry
        tb, sb = _bits(len(sp.dx)), _bits(len(sel))
        db = 64 - tb - sb
        if db < 12:
            raise ValueError(f"{len(sel)} spheres: too many to draw in one picture")
        front = depth - rr  # each sphere's nearest point
        near, far = float(np.min(front)), float(np.max(depth))
        dscale = ((1 << db) - 1) / max(far - near, 1e-300)
        zbuf = np.full(H * W, EMPTY, np.uint64)
        slabs = SLABS if len(sel) > SLAB_MIN_SPHERES else 1
        if slabs == 1:
            self._draw(zbuf, np.arange(len(sel)), rad, cx, cy, depth, rr, sp, near, dscale, db, sb, tb)
        else:
            # nearest depth slabs first; a sphere of a later slab whose nearest point lies
            # behind every surface already drawn around it (the farthest one over a window of
            # the largest sprite about its centre, every pixel in it covered) cannot show
            shift = np.uint64(sb + tb)
            front -= near
            front *= dscale
            q_near = np.minimum(front, (1 << db) - 1).astype(np.uint64)
            inside = (cx >= 0) & (cx < W) & (cy >= 0) & (cy < H)
            centre = np.where(inside, cy * W + cx, 0)
            reach = int(radii[-1])
            # slab j: the depths in [2^(j - slabs), 2^(j + 1 - slabs)) of the range (j > 0)
            frac = np.maximum((depth - near) / max(far - near, 1e-300), 1e-300)
            slab = np.clip(np.frexp(frac)[1] + (slabs - 1), 0, slabs - 1).astype(np.int8)
            by_slab = np.argsort(slab, kind="stable")  # a radix sort of small integers
            bounds = np.concatenate([[0], np.cumsum(np.bincount(slab, minlength=slabs))])
            for j in range(slabs):
                members = by_slab[bounds[j] : bounds[j + 1]]
                if j and len(members):
                    behind = _window_max((zbuf >> shift).reshape(H, W), reach).ravel()
                    shows = (q_near[members] <= behind[centre[members]]) | ~inside[members]
                    members = members[shows]
                self._draw(zbuf, members, rad, cx, cy, depth, rr, sp, near, dscale, db, sb, tb)
        hit = np.flatnonzero(zbuf != EMPTY)
        k = zbuf[hit]
        ent = (k & np.uint64((1 << tb) - 1)).astype(np.int64)
        sph = ((k >> np.uint64(tb)) & np.uint64((1 << sb) - 1)).astype(np.int64)
        rgb = np.asarray(colour, np.float32)[sel[sph]] * sp.shade[ent, None]
        img[hit] = np.clip(rgb * 255.0 + 0.5, 0, 255).astype(np.uint8)
        return img.reshape(H, W, 3)

    def _draw(
        self,
        zbuf: NDArray[np.uint64],
        members: NDArray[np.int64],
        rad: NDArray[np.int64],
        cx: NDArray[np.int64],
        cy: NDArray[np.int64],
        depth: NDArray[np.float64],
        rr: NDArray[np.float64],
        sp: _Sprites,
        near: float,
        dscale: float,
        db: int,
        sb: int,
        tb: int,
    ) -> None:
        """Put the fragments of spheres ``members`` into the z-buffer, radius by radius."""
        W, H = self.width, self.height
        of = rad[members]
        for rho in map(int, np.flatnonzero(np.bincount(of))):
            group = members[of == rho]
            a, m = sp.start[rho], sp.count[rho]
            dy, dx, lift = sp.dy[a : a + m], sp.dx[a : a + m], sp.lift[a : a + m]
            entry = np.arange(a, a + m, dtype=np.uint64)
            per = max(1, CHUNK_FRAGMENTS // m)
            for c in range(0, len(group), per):
                idx = group[c : c + per]
                x, y = cx[idx], cy[idx]
                at = (y * W + x)[:, None] + (dy * W + dx)  # the fragments' pixels
                d = depth[idx, None] - rr[idx, None] * lift
                d -= near
                d *= dscale
                q = np.minimum(d, (1 << db) - 1).astype(np.uint64)  # d >= 0: near is the front
                q <<= np.uint64(sb + tb)
                q |= idx.astype(np.uint64)[:, None] << np.uint64(tb)
                q |= entry
                if x.min() >= rho and x.max() < W - rho and y.min() >= rho and y.max() < H - rho:
                    np.minimum.at(zbuf, at.ravel(), q.ravel())
                else:  # fragments off the picture are dropped
                    px = x[:, None] + dx
                    py = y[:, None] + dy
                    ok = (px >= 0) & (px < W) & (py >= 0) & (py < H)
                    np.minimum.at(zbuf, at[ok], q[ok])


def _window_max(q: NDArray[np.uint64], reach: int) -> NDArray[np.uint64]:
    """The largest value of q over the (2 reach + 1)^2 window about each pixel; outside the
    picture counts as 0 (nothing is drawn there, so nothing there can show a sphere)."""
    out = q.copy()
    for axis in (0, 1):
        src = out.copy()
        n = src.shape[axis]
        for k in range(1, reach + 1):
            if k >= n:
                break
            lo = [slice(None)] * 2
            hi = [slice(None)] * 2
            lo[axis], hi[axis] = slice(0, n - k), slice(k, n)
            np.maximum(out[tuple(lo)], src[tuple(hi)], out=out[tuple(lo)])
            np.maximum(out[tuple(hi)], src[tuple(lo)], out=out[tuple(hi)])
    return out


def colour_map(
    values: NDArray[np.float64], lo: float, hi: float, name: str = "viridis", start: float = 0.0
) -> NDArray[np.float32]:
    """RGB (N x 3 in [0, 1]) of ``values`` over [lo, hi] on the part [start, 1] of the
    matplotlib colour map ``name``."""
    from matplotlib import colormaps

    lut = colormaps[name](np.linspace(start, 1.0, 256))[:, :3].astype(np.float32)
    t = (np.asarray(values, np.float64) - lo) / max(hi - lo, 1e-300)
    return lut[np.clip((t * 255.0 + 0.5).astype(np.int64), 0, 255)]
