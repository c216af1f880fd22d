"""Triangle soups for ray casting: instanced boxes, cylinders and spheres with per-triangle labels."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class TriangleSoup:
    """Triangles in world coordinates with a class label and an owner index (-1: none) per triangle."""

    vertices: np.ndarray  # (V, 3) float32
    triangles: np.ndarray  # (T, 3) uint32
    labels: np.ndarray  # (T,) uint8
    owners: np.ndarray  # (T,) int32

    @staticmethod
    def empty() -> TriangleSoup:
        """A soup with no triangles."""
        return TriangleSoup(
            np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint32), np.zeros(0, np.uint8), np.zeros(0, np.int32)
        )

    @staticmethod
    def merge(parts: list[TriangleSoup]) -> TriangleSoup:
        """Concatenate soups into one."""
        parts = [part for part in parts if len(part.triangles)]
        if not parts:
            return TriangleSoup.empty()
        offsets = np.cumsum([0] + [len(part.vertices) for part in parts[:-1]])
        return TriangleSoup(
            np.concatenate([part.vertices for part in parts]).astype(np.float32),
            np.concatenate([part.triangles + off for part, off in zip(parts, offsets)]).astype(np.uint32),
            np.concatenate([part.labels for part in parts]),
            np.concatenate([part.owners for part in parts]),
        )


@dataclass(frozen=True)
class Template:
    """A unit mesh instanced by scaling, yawing and translating."""

    vertices: np.ndarray
    triangles: np.ndarray


def _box_template() -> Template:
    """Unit cube centred on x, y with its bottom at z = 0."""
    corners = np.array([[x, y, z] for z in (0.0, 1.0) for y in (-0.5, 0.5) for x in (-0.5, 0.5)], dtype=np.float64)
    faces = np.array(
        [
            [0, 2, 1],
            [1, 2, 3],
            [4, 5, 6],
            [5, 7, 6],
            [0, 1, 4],
            [1, 5, 4],
            [2, 6, 3],
            [3, 6, 7],
            [0, 4, 2],
            [2, 4, 6],
            [1, 3, 5],
            [3, 7, 5],
        ],
        dtype=np.int64,
    )
    return Template(corners, faces)


def _cylinder_template(sides: int = 8) -> Template:
    """Unit-radius prism of height 1 with its bottom at z = 0."""
    angles = 2.0 * np.pi * np.arange(sides) / sides
    ring = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    vertices = np.concatenate([np.c_[ring, np.zeros(sides)], np.c_[ring, np.ones(sides)], [[0, 0, 0], [0, 0, 1]]])
    i = np.arange(sides)
    j = (i + 1) % sides
    bottom_centre, top_centre = 2 * sides, 2 * sides + 1
    faces = np.concatenate(
        [
            np.stack([i, j, i + sides], axis=1),
            np.stack([j, j + sides, i + sides], axis=1),
            np.stack([np.full(sides, bottom_centre), j, i], axis=1),
            np.stack([np.full(sides, top_centre), i + sides, j + sides], axis=1),
        ]
    )
    return Template(vertices, faces)


def _sphere_template(rings: int = 4, segments: int = 8) -> Template:
    """Unit sphere centred at the origin."""
    theta = np.linspace(0.0, np.pi, rings + 1)[1:-1]
    phi = 2.0 * np.pi * np.arange(segments) / segments
    body = np.stack(
        [
            np.outer(np.sin(theta), np.cos(phi)),
            np.outer(np.sin(theta), np.sin(phi)),
            np.outer(np.cos(theta), np.ones(segments)),
        ],
        axis=-1,
    ).reshape(-1, 3)
    vertices = np.concatenate([[[0, 0, 1]], body, [[0, 0, -1]]])
    faces = []
    south = len(vertices) - 1
    for k in range(segments):
        n = (k + 1) % segments
        faces.append([0, 1 + k, 1 + n])
        last = 1 + (rings - 2) * segments
        faces.append([south, last + n, last + k])
        for r in range(rings - 2):
            a, b = 1 + r * segments + k, 1 + r * segments + n
            c, d = a + segments, b + segments
            faces += [[a, c, b], [b, c, d]]
    return Template(vertices, np.array(faces))


BOX = _box_template()
CYLINDER = _cylinder_template()
SPHERE = _sphere_template()


def instances(
    template: Template,
    scales: np.ndarray,
    yaws: np.ndarray,
    translations: np.ndarray,
    label: int | np.ndarray,
    owners: np.ndarray | None = None,
) -> TriangleSoup:
    """Place copies of a template: scale (M,3), yaw (M,), translation (M,3); triangles keep label and owner."""
    count = len(scales)
    if count == 0:
        return TriangleSoup.empty()
    local = template.vertices[None, :, :] * scales[:, None, :]
    cos, sin = np.cos(yaws)[:, None], np.sin(yaws)[:, None]
    world = np.empty_like(local)
    world[..., 0] = cos * local[..., 0] - sin * local[..., 1] + translations[:, None, 0]
    world[..., 1] = sin * local[..., 0] + cos * local[..., 1] + translations[:, None, 1]
    world[..., 2] = local[..., 2] + translations[:, None, 2]
    per = len(template.triangles)
    offsets = (np.arange(count) * len(template.vertices))[:, None, None]
    triangles = (template.triangles[None] + offsets).reshape(-1, 3)
    labels = np.broadcast_to(np.asarray(label, np.uint8), (count,)).repeat(per)
    owner = np.full(count, -1, np.int32) if owners is None else owners.astype(np.int32)
    return TriangleSoup(world.reshape(-1, 3).astype(np.float32), triangles.astype(np.uint32), labels, owner.repeat(per))


def import_open3d():
    """Open3D, imported on first use (it takes a while to load)."""
    import open3d as o3d

    return o3d


def raycasting_scene(soup: TriangleSoup):
    """An Open3D RaycastingScene holding one triangle soup (one geometry)."""
    o3d = import_open3d()
    scene = o3d.t.geometry.RaycastingScene(nthreads=0)
    if len(soup.triangles):
        scene.add_triangles(
            o3d.core.Tensor(np.ascontiguousarray(soup.vertices, np.float32)),
            o3d.core.Tensor(np.ascontiguousarray(soup.triangles, np.uint32)),
        )
    return scene
