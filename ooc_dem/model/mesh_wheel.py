"""A 3D wheel's surface read from a triangle mesh file (``wheel.mesh``: STL or OBJ, read
with trimesh), placed in the wheel's body frame (scaled by ``wheel.mesh_scale``, turned by
``wheel.mesh_rotate``, moved by ``wheel.mesh_offset``; the axle along z through the
origin) and indexed for the contact kernel (``physics.mesh.mesh_wheel``).

A file that cannot serve is refused with one line (``ScenarioError``): missing,
unreadable, not a triangle mesh, no triangle, more than MAX_TRIANGLES, a non-finite
vertex, or a surface that does not enclose the axle."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..physics.detmath import det_cos, det_sin
from ..physics.layout import MAX_MESH_PARTS, MeshWheel
from ..physics.mesh import mesh_wheel, surface_parts
from .schema import ScenarioError, show

MAX_TRIANGLES = 2_000_000
MAX_MESH_FILE = 512 * 1024 * 1024  # bytes (a binary STL of MAX_TRIANGLES is 100 MB)
MESH_TYPES = (".stl", ".obj")


def read_mesh_triangles(path: str | Path) -> np.ndarray:
    """The triangles (T, 3, 3) of a mesh file, as the file gives them (no merging, no
    reordering: the triangle index is the file's)."""
    import trimesh

    p = Path(path)
    what = f"wheel.mesh = {show(str(path), 300)}"
    try:
        is_file = p.is_file()
        size = p.stat().st_size if is_file else 0
    except (OSError, ValueError):
        is_file, size = False, 0
    if not is_file:
        raise ScenarioError(f"{what}: no such file")
    if p.suffix.lower() not in MESH_TYPES:
        raise ScenarioError(f"{what}: not an STL or OBJ file (the name must end in .stl or .obj)")
    if size > MAX_MESH_FILE:
        raise ScenarioError(f"{what}: {size} bytes; a mesh file is at most {MAX_MESH_FILE} bytes")
    try:
        mesh = trimesh.load(str(p), file_type=p.suffix.lower()[1:], force="mesh", process=False)
    except Exception as e:  # trimesh's readers raise many kinds on a damaged file
        first = (str(e).splitlines() or [type(e).__name__])[0][:160]
        raise ScenarioError(f"{what}: unreadable ({first})") from None
    if not isinstance(mesh, trimesh.Trimesh):
        raise ScenarioError(f"{what}: not a triangle mesh")
    faces = np.asarray(mesh.faces)
    verts = np.asarray(mesh.vertices, np.float64)
    if faces.ndim != 2 or faces.shape[0] == 0:
        raise ScenarioError(f"{what}: no triangle")
    if faces.shape[1] != 3:
        raise ScenarioError(f"{what}: not a triangle mesh")
    if faces.shape[0] > MAX_TRIANGLES:
        raise ScenarioError(f"{what}: {faces.shape[0]} triangles; at most {MAX_TRIANGLES}")
    if not np.isfinite(verts).all():
        raise ScenarioError(f"{what}: a vertex is not finite")
    return np.ascontiguousarray(verts[faces])


def rotation(angles_deg) -> np.ndarray:
    """The rotation matrix of angles (degrees) about x, then y, then z (fixed axes). Made
    with the kernels' deterministic cos/sin and products written out in a fixed order (no
    libm, no BLAS), so the wheel's vertices are the same bits on every machine."""
    if len(angles_deg) == 0:
        return np.eye(3)
    ax, ay, az = (math.radians(a) for a in angles_deg)
    rx = [[1.0, 0.0, 0.0], [0.0, det_cos(ax), -det_sin(ax)], [0.0, det_sin(ax), det_cos(ax)]]
    ry = [[det_cos(ay), 0.0, det_sin(ay)], [0.0, 1.0, 0.0], [-det_sin(ay), 0.0, det_cos(ay)]]
    rz = [[det_cos(az), -det_sin(az), 0.0], [det_sin(az), det_cos(az), 0.0], [0.0, 0.0, 1.0]]
    return np.array(_product(rz, _product(ry, rx)))


def _product(a: list[list[float]], b: list[list[float]]) -> list[list[float]]:
    return [[a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j] for j in range(3)] for i in range(3)]


def rotate(tri: np.ndarray, rot: np.ndarray) -> np.ndarray:
    """tri (..., 3) turned by rot, each component summed in a fixed order (not matmul)."""
    x, y, z = tri[..., 0], tri[..., 1], tri[..., 2]
    return np.stack([rot[i, 0] * x + rot[i, 1] * y + rot[i, 2] * z for i in range(3)], axis=-1)


def winding_number(tri: np.ndarray, point=(0.0, 0.0, 0.0)) -> float:
    """The winding number of the closed surface tri (T, 3, 3) about a point (the signed
    solid angles of the triangles, Van Oosterom and Strackee, over 4 pi): +-1 inside, 0
    outside."""
    a = tri - np.asarray(point, np.float64)
    la = np.linalg.norm(a, axis=2)
    x, y, z = a[:, 0], a[:, 1], a[:, 2]
    lx, ly, lz = la[:, 0], la[:, 1], la[:, 2]
    num = np.einsum("ij,ij->i", x, np.cross(y, z))
    den = lx * ly * lz + np.einsum("ij,ij->i", x, y) * lz + np.einsum("ij,ij->i", y, z) * lx
    den += np.einsum("ij,ij->i", z, x) * ly
    return float(np.sum(2.0 * np.arctan2(num, den)) / (4.0 * math.pi))


def body_frame_triangles(sc) -> np.ndarray:
    """The scenario's wheel mesh in the wheel's body frame (T, 3, 3), checked."""
    w = sc.wheel
    tri = read_mesh_triangles(w.mesh) * w.mesh_scale
    if len(w.mesh_rotate):
        tri = rotate(tri, rotation(w.mesh_rotate))
    if len(w.mesh_offset):
        tri = tri + np.asarray(w.mesh_offset, np.float64)
    tri = np.ascontiguousarray(tri)
    if not np.isfinite(tri).all():
        raise ScenarioError(f"wheel.mesh = {show(w.mesh, 300)}: a vertex is not finite once scaled")
    if abs(winding_number(tri)) < 0.5:
        raise ScenarioError(
            f"wheel.mesh = {show(w.mesh, 300)}: the surface does not enclose the axle "
            f"(the origin of the wheel's frame; wheel.mesh_offset, wheel.mesh_rotate place it)"
        )
    return tri


def is_closed_surface(tri: np.ndarray) -> bool:
    """Whether the triangles form a closed surface (every edge shared by exactly two
    triangles, the vertices merged where they coincide), by trimesh."""
    import trimesh

    faces = np.arange(3 * len(tri), dtype=np.int64).reshape(-1, 3)
    return bool(trimesh.Trimesh(vertices=tri.reshape(-1, 3), faces=faces, process=True).is_watertight)


def solid_axle_inertia(tri: np.ndarray, mass: float) -> float:
    """The moment of inertia about the axle (z through the origin) of the solid that the
    closed surface ``tri`` bounds, holding ``mass`` uniformly: mass * (integral of x^2 + y^2
    over the solid) / its volume. Both integrals are sums over the signed tetrahedra
    (origin, triangle): V = a.(b x c)/6 and the integral of x^2 = V/10 (xa^2 + xb^2 + xc^2 +
    xa xb + xb xc + xc xa). Elementwise IEEE operations and math.fsum's exactly rounded
    sums: the same bits on every machine, whatever the summation order of numpy's."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    vol6 = (
        a[:, 0] * (b[:, 1] * c[:, 2] - b[:, 2] * c[:, 1])
        + a[:, 1] * (b[:, 2] * c[:, 0] - b[:, 0] * c[:, 2])
        + a[:, 2] * (b[:, 0] * c[:, 1] - b[:, 1] * c[:, 0])
    )

    def second_moment(k: int) -> np.ndarray:
        xa, xb, xc = a[:, k], b[:, k], c[:, k]
        return xa * xa + xb * xb + xc * xc + xa * xb + xb * xc + xc * xa

    volume6 = math.fsum(vol6.tolist())
    # sum of V/10 (...) over tetrahedra = (1/60) sum of vol6 (...)
    radial60 = math.fsum((vol6 * (second_moment(0) + second_moment(1))).tolist())
    return mass * (radial60 / 10.0) / volume6


def wheel_axle_inertia(sc, tri: np.ndarray) -> float:
    """A free-spinning mesh wheel's moment of inertia about its axle when wheel.inertia is
    not given: the mesh's solid holding the wheel's mass (wheel.load / gravity) uniformly;
    an open surface bounds no solid and needs wheel.inertia."""
    if not is_closed_surface(tri):
        raise ScenarioError(
            f"wheel.mesh = {show(sc.wheel.mesh, 300)}: not a closed surface, so it bounds no solid whose "
            f"moment of inertia a free-spinning wheel (wheel.control = {sc.wheel.control}) could take: "
            f"give wheel.inertia"
        )
    return solid_axle_inertia(tri, sc.wheel_mass)


def load_wheel_mesh(sc, tri: np.ndarray) -> MeshWheel:
    """The kernel's mesh of the scenario's wheel from its triangles in the body frame
    (``body_frame_triangles``): their parts (at most MAX_MESH_PARTS: each part is a
    partner id of its own) and their grid (cells of the largest sphere's diameter)."""
    part = surface_parts(tri)
    n_parts = int(part.max()) + 1
    if n_parts > MAX_MESH_PARTS:
        raise ScenarioError(
            f"wheel.mesh = {show(sc.wheel.mesh, 300)}: {n_parts} separate parts (pieces not joined by a "
            f"shared vertex); at most {MAX_MESH_PARTS}"
        )
    return mesh_wheel(tri, 2.0 * sc.soil.r_max, part)
