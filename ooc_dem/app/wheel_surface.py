"""The wheel's surface as a triangle mesh, at a pose (x, y, angle) of a trajectory frame.

``wheel_surface(geometry, x, y, angle) -> (vertices (V, 3), triangles (T, 3))`` is the one
place the exports and films get the wheel's shape from: the built-in wheel's rim cylinder
(tessellated, with its two end caps) and one closed box per lug plate. A wheel of another
shape (a mesh wheel) gives its own triangles through the same signature, moved to the pose.
``wheel_outline_triangles`` is the 2D wheel (the outline polygon of ``trajectory.wheel_outline``)
as a fan of triangles in the x-y plane.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from ..model.scenario import Scenario

RIM_SEGMENTS = 72

# the 12 triangles of a box whose corners are numbered as in _lug_boxes (outward normals)
_BOX_TRIANGLES = np.array(
    [
        [0, 2, 1],
        [0, 3, 2],  # the face at the wheel's -z side
        [4, 5, 6],
        [4, 6, 7],  # +z side
        [0, 1, 5],
        [0, 5, 4],
        [1, 2, 6],
        [1, 6, 5],
        [2, 3, 7],
        [2, 7, 6],
        [3, 0, 4],
        [3, 4, 7],
    ],
    np.int64,
)


@dataclass(frozen=True, eq=False)
class WheelGeometry:
    """The wheel: rim radius, width and lateral centre (z), its lugs, and, for a mesh wheel,
    its triangles in the wheel's body frame (T, 3, 3), which then replace rim and lugs."""

    radius: float
    width: float
    z_centre: float
    n_lugs: int
    lug_tip_radius: float
    lug_thickness: float
    mesh: NDArray[np.float64] | None = None

    @classmethod
    def of_scenario(cls, sc: Scenario) -> WheelGeometry:
        from ..engine.stepper import wheel_z0
        from ..model.mesh_wheel import body_frame_triangles

        w = sc.wheel
        z = wheel_z0(sc) if sc.dim == 3 else 0.0
        mesh = body_frame_triangles(sc) if sc.dim == 3 and w.mesh else None
        return cls(
            float(w.radius),
            float(w.width),
            float(z),
            int(w.n_lugs),
            float(w.lug_tip_radius),
            float(w.lug_thickness),
            mesh,
        )


def mesh_at_pose(geometry: WheelGeometry, x: float, y: float, angle: float) -> NDArray[np.float64]:
    """A mesh wheel's triangles (T, 3, 3) at centre (x, y) turned by ``angle`` about the
    axle (the kernel's body frame: world = centre + R(angle) body)."""
    assert geometry.mesh is not None
    b = geometry.mesh
    c, s = np.cos(angle), np.sin(angle)
    out = np.empty_like(b)
    out[..., 0] = x + c * b[..., 0] - s * b[..., 1]
    out[..., 1] = y + s * b[..., 0] + c * b[..., 1]
    out[..., 2] = geometry.z_centre + b[..., 2]
    return out


def _rim(
    g: WheelGeometry, x: float, y: float, angle: float, segments: int
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """The rim cylinder: two rings of points and the two cap centres, quads split in two."""
    phi = angle + 2.0 * np.pi * np.arange(segments) / segments
    za, zb = g.z_centre - 0.5 * g.width, g.z_centre + 0.5 * g.width
    ring = np.column_stack([x + g.radius * np.cos(phi), y + g.radius * np.sin(phi)])
    pts = np.vstack(
        [
            np.column_stack([ring, np.full(segments, za)]),
            np.column_stack([ring, np.full(segments, zb)]),
            [[x, y, za], [x, y, zb]],
        ]
    )
    k = np.arange(segments)
    k1 = (k + 1) % segments
    side = np.concatenate([np.column_stack([k, k1, segments + k1]), np.column_stack([k, segments + k1, segments + k])])
    ca, cb = 2 * segments, 2 * segments + 1
    caps = np.concatenate(
        [
            np.column_stack([np.full(segments, ca), k1, k]),
            np.column_stack([np.full(segments, cb), segments + k, segments + k1]),
        ]
    )
    return pts, np.concatenate([side, caps]).astype(np.int64)


def _lug_boxes(g: WheelGeometry, x: float, y: float, angle: float) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """One box a lug: from the rim to the lug tip, lug_thickness thick, across the width."""
    n = g.n_lugs
    if n <= 0 or g.lug_tip_radius <= g.radius:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    a = angle + 2.0 * np.pi * np.arange(n) / n
    u = np.column_stack([np.cos(a), np.sin(a)])  # outward along the lug
    v = np.column_stack([-u[:, 1], u[:, 0]])  # across it
    half = 0.5 * g.lug_thickness
    corners = [(g.radius, -half), (g.lug_tip_radius, -half), (g.lug_tip_radius, half), (g.radius, half)]
    za, zb = g.z_centre - 0.5 * g.width, g.z_centre + 0.5 * g.width
    pts = np.empty((n, 8, 3))
    for j, z in enumerate((za, zb)):
        for c, (s, t) in enumerate(corners):
            xy = np.array([x, y]) + s * u + t * v
            pts[:, 4 * j + c, :2] = xy
            pts[:, 4 * j + c, 2] = z
    tris = (_BOX_TRIANGLES[None, :, :] + 8 * np.arange(n)[:, None, None]).reshape(-1, 3)
    return pts.reshape(-1, 3), tris


def wheel_surface(
    geometry: WheelGeometry, x: float, y: float, angle: float, segments: int = RIM_SEGMENTS
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """(vertices (V, 3), triangles (T, 3) of vertex indices) of the wheel at centre (x, y)
    turned by ``angle`` (the trajectory's wheel state): the rim cylinder in ``segments``
    facets with its end caps (4 segments triangles), then 12 triangles per lug box; a mesh
    wheel's own triangles instead."""
    if geometry.mesh is not None:
        tri = mesh_at_pose(geometry, float(x), float(y), float(angle))
        return tri.reshape(-1, 3), np.arange(3 * len(tri), dtype=np.int64).reshape(-1, 3)
    rp, rt = _rim(geometry, float(x), float(y), float(angle), segments)
    lp, lt = _lug_boxes(geometry, float(x), float(y), float(angle))
    return np.vstack([rp, lp]).astype(np.float64), np.vstack([rt, lt + len(rp)]).astype(np.int64)


def wheel_outline_triangles(
    outline: NDArray[np.float64], x: float, y: float
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """The 2D wheel's outline polygon (P x 2, star-shaped about its centre: the rim and the
    lug notches) as P triangles fanned from the centre (x, y); vertices (P + 1, 2)."""
    p = len(outline)
    pts = np.vstack([[[float(x), float(y)]], np.asarray(outline, np.float64)])
    k = np.arange(p)
    return pts, np.column_stack([np.zeros(p, np.int64), 1 + k, 1 + (k + 1) % p]).astype(np.int64)
