"""Sampled analytic shapes with exact answers, for the reconstruction tests."""

from __future__ import annotations

import numpy as np

#: A georeferenced offset (UTM-like easting, northing, elevation).
GEO = np.array([500000.0, 5500000.0, 300.0])


def tube(
    radius: float = 0.15,
    height: float = 1.0,
    n: int = 8000,
    *,
    noise_m: float = 0.0,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Points on an open vertical tube (z from 0 to height), and outward radial unit vectors."""
    rng = np.random.default_rng(seed)
    th = rng.uniform(0.0, 2.0 * np.pi, n)
    z = rng.uniform(0.0, height, n)
    radial = np.c_[np.cos(th), np.sin(th), np.zeros(n)]
    pts = np.c_[radius * radial[:, :2], z]
    if noise_m:
        pts = pts + rng.normal(scale=noise_m, size=pts.shape)
    return pts, radial


def stem_on_ground(seed: int = 0) -> tuple[np.ndarray, int]:
    """A noisy 15 cm stem 2 m tall standing on a noisy 3 m x 3 m ground plane: the points
    (stem first) and the number of stem points."""
    stem, _ = tube(radius=0.15, height=2.0, n=12000, noise_m=0.001, seed=seed)
    rng = np.random.default_rng(seed + 1)
    g = np.c_[rng.uniform(-1.5, 1.5, 20000), rng.uniform(-1.5, 1.5, 20000)]
    g = g[np.hypot(g[:, 0], g[:, 1]) > 0.15]
    ground = np.c_[g, 0.003 * rng.normal(size=len(g))]
    return np.vstack([stem, ground]), len(stem)


def sphere(radius: float = 0.3, n: int = 6000, *, seed: int = 0) -> np.ndarray:
    """Points on a sphere centred at the origin (uniform by area)."""
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(n, 3))
    return radius * v / np.linalg.norm(v, axis=1, keepdims=True)


def closed_cylinder(
    radius: float = 0.15, height: float = 0.6, n: int = 8000, *, seed: int = 0
) -> np.ndarray:
    """Points on a closed cylinder (side and both caps, uniform by area), base at z = 0."""
    rng = np.random.default_rng(seed)
    side_area = 2.0 * np.pi * radius * height
    cap_area = np.pi * radius * radius
    n_side = int(round(n * side_area / (side_area + 2.0 * cap_area)))
    n_cap = (n - n_side) // 2
    th = rng.uniform(0.0, 2.0 * np.pi, n_side)
    side = np.c_[radius * np.cos(th), radius * np.sin(th), rng.uniform(0.0, height, n_side)]
    caps = []
    for z in (0.0, height):
        r = radius * np.sqrt(rng.uniform(0.0, 1.0, n_cap))
        t = rng.uniform(0.0, 2.0 * np.pi, n_cap)
        caps.append(np.c_[r * np.cos(t), r * np.sin(t), np.full(n_cap, z)])
    return np.vstack([side, *caps])


def leaves(
    n_leaves: int = 150,
    points_per_leaf: int = 40,
    *,
    centre: tuple[float, float, float] = (0.0, 0.0, 1.6),
    crown_radius: float = 0.6,
    leaf_radius: float = 0.03,
    seed: int = 0,
) -> np.ndarray:
    """Small flat discs with random orientations scattered in a spherical crown."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n_leaves):
        c = np.asarray(centre) + crown_radius * rng.uniform(-1.0, 1.0, 3)
        normal = rng.normal(size=3)
        normal /= np.linalg.norm(normal)
        a = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
        a /= np.linalg.norm(a)
        b = np.cross(normal, a)
        r = leaf_radius * np.sqrt(rng.uniform(0.0, 1.0, points_per_leaf))
        t = rng.uniform(0.0, 2.0 * np.pi, points_per_leaf)
        out.append(c + (r * np.cos(t))[:, None] * a + (r * np.sin(t))[:, None] * b)
    return np.vstack(out)
