"""Analytic shapes with exact answers for the comparison tests."""

from __future__ import annotations

import numpy as np

from treesim.geometry import sample_surface

UTM = (500000.0, 5500000.0, 300.0)


def sphere_mesh(radius: float = 1.0, subdivisions: int = 4, centre=(0.0, 0.0, 0.0)):
    """An icosphere inscribed in the sphere of ``radius``: float64 (vertices, faces)."""
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    v = np.asarray(m.vertices, dtype=np.float64)
    v = v / np.linalg.norm(v, axis=1, keepdims=True) * radius  # exactly on the sphere
    return v + np.asarray(centre, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)


def open_cylinder(
    radius: float = 0.2, height: float = 1.0, sections: int = 512, base=(0.0, 0.0, 0.0)
):
    """The side wall of a vertical cylinder (no caps), vertices at angles 2πk/sections, so
    that angles 0 and π (the plane x = 0 splits it) fall on vertices when sections is even."""
    a = 2 * np.pi * np.arange(sections) / sections
    ring = np.column_stack([radius * np.cos(a), radius * np.sin(a), np.zeros(sections)])
    v = np.concatenate([ring, ring + [0.0, 0.0, height]]) + np.asarray(base, dtype=np.float64)
    i = np.arange(sections)
    j = (i + 1) % sections
    f = np.concatenate(
        [np.column_stack([i, j, j + sections]), np.column_stack([i, j + sections, i + sections])]
    )
    return v, f.astype(np.int64)


def sample_faces(v, f, mask, n, seed=1):
    """``n`` points exactly on the triangles selected by ``mask`` (uniform by area)."""
    pts, _ = sample_surface(v, f[mask], n, seed=seed)
    return pts


def centroids(v, f):
    return v[f].mean(axis=1)
