"""Writes the example wheel meshes (binary STL, metres, the wheel's body frame: axle along
z through the origin, z = 0 at the wheel's mid-width) into examples/meshes/:

- grousered.stl: paper2008-3d's built-in wheel as a mesh: the rim cylinder (R = 0.1 m,
  0.1 m wide) and 18 straight lugs, each a plate 4 mm thick with a rounded tip at
  R = 0.110 m, across the whole width and rounded beyond it, as the built-in lugs
  (capsules swept over a rectangle) are;
- chevron.stl: the same rim with 18 chevron lugs, each a V whose arms sweep back by
  15 degrees from the mid-width to the rim's edges.

The rim is tessellated so that its facets deviate less than 0.2 mm from the circle
(``SEGMENTS``); its end faces in rings, so that no triangle is long and thin (the contact
grid lists a triangle in every cell its bounding box overlaps). Each part is a closed
surface; the parts overlap (the lugs' roots lie inside the rim), which the contact (the
closest triangle) does not mind.

    python tools/make_wheel_meshes.py [OUT_DIR]
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import trimesh

SEGMENTS = 144  # sagitta R (1 - cos(pi / n)) = 24 um at R = 0.1 m (< 0.2 mm)
RINGS = 8  # rings of each end face
TIP_SEGMENTS = 8  # facets of a lug's rounded tip (and of its root)
END_SLICES, END_ANGLE = 4, 80.0  # a straight lug's rounded ends beyond the width: slices, degrees


def rim(radius: float, width: float, segments: int = SEGMENTS, rings: int = RINGS) -> trimesh.Trimesh:
    """A closed cylinder about z, z in -width/2 .. width/2, its end faces in rings."""
    phi = 2.0 * math.pi * np.arange(segments) / segments
    verts: list[tuple[float, float, float]] = []
    faces: list[tuple[int, int, int]] = []
    for side, z in ((-1, -0.5 * width), (1, 0.5 * width)):
        base = len(verts)
        verts.append((0.0, 0.0, z))
        for k in range(1, rings + 1):
            rk = radius * k / rings
            verts += [(rk * math.cos(p), rk * math.sin(p), z) for p in phi]
        ring = lambda k, j: base + 1 + (k - 1) * segments + (j % segments)  # noqa: E731
        for j in range(segments):
            tri = (base, ring(1, j), ring(1, j + 1))
            faces.append(tri if side > 0 else tri[::-1])
            for k in range(1, rings):
                a, b, c, d = ring(k, j), ring(k, j + 1), ring(k + 1, j + 1), ring(k + 1, j)
                for t in ((a, d, c), (a, c, b)):
                    faces.append(t if side > 0 else t[::-1])
    lo = 1 + (rings - 1) * segments
    hi = len(verts) // 2 + lo
    for j in range(segments):
        a, b = lo + j, lo + (j + 1) % segments
        c, d = hi + (j + 1) % segments, hi + j
        faces += [(a, b, c), (a, c, d)]
    return trimesh.Trimesh(np.array(verts), np.array(faces), process=False)


def lug_section(root: float, tip: float, rho: float, tip_segments: int = TIP_SEGMENTS) -> np.ndarray:
    """A straight lug's cross-section (s along the lug, t across it), counter-clockwise:
    the points within rho of the segment s = root .. tip (both ends half-round)."""
    out = [
        (tip + rho * math.cos(a), rho * math.sin(a))
        for a in np.linspace(-0.5 * math.pi, 0.5 * math.pi, tip_segments + 1)
    ]
    out += [
        (root + rho * math.cos(a), rho * math.sin(a))
        for a in np.linspace(0.5 * math.pi, 1.5 * math.pi, tip_segments + 1)
    ]
    return np.array(out)


def loft(sections: list[np.ndarray], zs: list[float]) -> trimesh.Trimesh:
    """A closed solid through convex polygons (each (m, 3), counter-clockwise seen from +z)
    stacked at increasing z, its ends closed by fans from their centroids."""
    m = len(sections[0])
    verts = np.concatenate([np.column_stack([s[:, :2], np.full(m, z)]) for s, z in zip(sections, zs)])
    faces = []
    for k in range(len(zs) - 1):
        for j in range(m):
            a, b = k * m + j, k * m + (j + 1) % m
            c, d = b + m, a + m
            faces += [(a, b, c), (a, c, d)]
    ends: list[np.ndarray] = []
    for k, flip in ((0, True), (len(zs) - 1, False)):
        centre = len(verts) + len(ends)
        ends.append(np.append(sections[k][:, :2].mean(axis=0), zs[k]))
        for j in range(m):
            t = (centre, k * m + j, k * m + (j + 1) % m)
            faces.append(t[::-1] if flip else t)
    return trimesh.Trimesh(np.vstack([verts, np.array(ends)]), np.array(faces), process=False)


def turned(section: np.ndarray, phi: float) -> np.ndarray:
    """A cross-section (s, t) turned to the lug direction phi: points (x, y)."""
    c, s = math.cos(phi), math.sin(phi)
    return np.column_stack([c * section[:, 0] - s * section[:, 1], s * section[:, 0] + c * section[:, 1]])


def grousered_wheel(
    radius=0.1,
    width=0.1,
    n_lugs=18,
    lug_tip_radius=0.110,
    lug_thickness=0.004,
    segments=SEGMENTS,
    rings=RINGS,
    tip_segments=TIP_SEGMENTS,
) -> trimesh.Trimesh:
    """The built-in wheel (engine.stepper.wheel_records) as one mesh: the rim, and each lug
    the points within cap = lug_thickness / 2 of the rectangle from the rim to
    lug_tip_radius - cap across the width (its ends beyond the width rounded in
    END_SLICES steps); lug k at angle 2 pi k / n_lugs."""
    cap = 0.5 * lug_thickness
    tip = max(radius, lug_tip_radius - cap)
    # the rounded ends: the section within cap cos(b) of the lug's axis at cap sin(b)
    # beyond the rim's face, b from END_ANGLE down to 0 (the last sliver left flat)
    betas = np.linspace(math.radians(END_ANGLE), 0.0, END_SLICES + 1)
    zs = [-0.5 * width - cap * math.sin(b) for b in betas] + [0.5 * width + cap * math.sin(b) for b in betas[::-1]]
    rhos = [cap * math.cos(b) for b in betas] + [cap * math.cos(b) for b in betas[::-1]]
    parts = [rim(radius, width, segments, rings)]
    for k in range(n_lugs):
        phi = 2.0 * math.pi * k / n_lugs
        parts.append(loft([turned(lug_section(radius, tip, rho, tip_segments), phi) for rho in rhos], zs))
    return _joined(parts)


def chevron_wheel(
    radius=0.1,
    width=0.1,
    n_lugs=18,
    lug_tip_radius=0.110,
    lug_thickness=0.004,
    sweep_deg=15.0,
    slices=4,
    segments=SEGMENTS,
    rings=RINGS,
) -> trimesh.Trimesh:
    """The rim with chevron lugs: lug k at angle 2 pi k / n_lugs at the mid-width, its arms
    turned back by sweep_deg at the edges (linearly in |z|, ``slices`` steps each half)."""
    cap = 0.5 * lug_thickness
    sec = lug_section(radius, max(radius, lug_tip_radius - cap), cap)
    zs = list(np.linspace(-0.5 * width, 0.5 * width, 2 * slices + 1))
    parts = [rim(radius, width, segments, rings)]
    for k in range(n_lugs):
        phi = 2.0 * math.pi * k / n_lugs
        secs = [turned(sec, phi + math.radians(sweep_deg) * abs(z) / (0.5 * width)) for z in zs]
        parts.append(loft(secs, zs))
    return _joined(parts)


def _joined(parts: list[trimesh.Trimesh]) -> trimesh.Trimesh:
    """The parts as one mesh (their triangles one after another, in order)."""
    mesh = trimesh.util.concatenate(parts)
    assert isinstance(mesh, trimesh.Trimesh)
    return mesh


def main(argv: list[str]) -> int:
    out = Path(argv[0]) if argv else Path(__file__).resolve().parents[1] / "examples" / "meshes"
    out.mkdir(parents=True, exist_ok=True)
    for name, mesh in (("grousered", grousered_wheel()), ("chevron", chevron_wheel())):
        path = out / f"{name}.stl"
        mesh.export(path, file_type="stl")
        print(f"{path}: {len(mesh.faces)} triangles, {path.stat().st_size} bytes")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
