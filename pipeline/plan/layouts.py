"""Where a scanner may stand: the candidate grid and the classic layouts (baselines).

**Candidates** (:func:`candidate_grid`): the nodes of a square grid of ``spacing_m`` centred
on the plot centre, within the plot's radius, at ``height_m`` above the terrain there
(``terrain.height_at + height_m``), and at least ``clearance_m`` from every tree's
surface (an exact point-to-triangle distance, Open3D, in the plot's local frame).

**Classic layouts** (:func:`classic_layouts`), as field teams use them:

* ``ring-3``: three stations 120° apart around the plot centre, at ``ring_distance_m``
  (default half the plot radius; one tree: the station rule, :func:`treesim.scan.
  stations.station_distance_m`), the first on +x;
* ``centre+3``: the centre and a ring of three at the same distance;
* ``cross-5``: the "5-scan cross", the centre and four stations on +x, +y, -x, -y;
* ``grid-S``: square grids of spacing ``S`` centred on the plot centre, nodes within the
  plot radius.

A layout's station that falls within ``clearance_m`` of a tree is moved to the nearest
free spot (rings of ``0.25`` m steps up to 2 m), as a field team steps aside; the move is
recorded.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..errors import EmptyInputError
from ..frame import LocalFrame
from ..scan.stations import station_distance_m
from ..scene import MeshPart

__all__ = [
    "Layout",
    "TreeClearance",
    "candidate_grid",
    "classic_layouts",
    "rule_distance_m",
    "square_grid_xy",
]


class TreeClearance:
    """Distance from points to the trees' surfaces (the terrain is not counted)."""

    def __init__(self, parts: Sequence[MeshPart], *, nthreads: int = 0) -> None:
        import open3d as o3d

        v = np.concatenate([np.asarray(p.vertices, np.float64) for p in parts])
        off = np.cumsum([0] + [len(p.vertices) for p in parts[:-1]])
        f = np.concatenate(
            [np.asarray(p.faces, np.int64) + o for p, o in zip(parts, off, strict=True)]
        )
        self.frame = LocalFrame.around(v)
        self.rc = o3d.t.geometry.RaycastingScene(nthreads=int(nthreads))
        self.rc.add_triangles(
            o3d.core.Tensor(self.frame.to_local(v).astype(np.float32)),
            o3d.core.Tensor(f.astype(np.uint32)),
        )
        self._o3d = o3d

    def distance_m(self, points: np.ndarray) -> np.ndarray:
        pts = self.frame.to_local(np.asarray(points, np.float64).reshape(-1, 3))
        if not len(pts):
            return np.zeros(0)
        d = self.rc.compute_distance(self._o3d.core.Tensor(pts.astype(np.float32)))
        return d.numpy().astype(np.float64)


def rule_distance_m(vertices: np.ndarray) -> float:
    """The station rule's distance (:func:`treesim.scan.stations.station_distance_m`) for
    a tree of these vertices (n, 3): crown diameter the mean of its x and y extents,
    height its z extent."""
    ext = vertices.max(axis=0) - vertices.min(axis=0)
    return station_distance_m(0.5 * (ext[0] + ext[1]), ext[2])


def square_grid_xy(centre_xy: Sequence[float], radius_m: float, spacing_m: float) -> np.ndarray:
    """(k, 2) nodes of a square grid of ``spacing_m`` through ``centre_xy`` within
    ``radius_m`` of it, row by row."""
    n = int(math.floor(radius_m / spacing_m + 1e-9))
    ij = np.arange(-n, n + 1) * spacing_m
    gx, gy = np.meshgrid(ij, ij, indexing="xy")
    xy = np.stack([gx.ravel(), gy.ravel()], axis=1)
    xy = xy[np.hypot(xy[:, 0], xy[:, 1]) <= radius_m + 1e-9]
    return xy + np.asarray(centre_xy, np.float64)


def _on_terrain(terrain, xy: np.ndarray, height_m: float) -> np.ndarray:
    z = np.asarray(terrain.height_at(xy[:, 0], xy[:, 1]), np.float64) + height_m
    return np.column_stack([xy, z])


def candidate_grid(
    terrain,
    centre_xy: Sequence[float],
    radius_m: float,
    *,
    spacing_m: float,
    height_m: float,
    clearance: TreeClearance,
    clearance_m: float,
) -> tuple[np.ndarray, dict[str, int]]:
    """Candidate positions (k, 3) on the grid (module notes) and how many were left out."""
    xy = square_grid_xy(centre_xy, radius_m, spacing_m)
    pos = _on_terrain(terrain, xy, height_m)
    free = clearance.distance_m(pos) >= clearance_m
    if not free.any():
        raise EmptyInputError(
            f"no candidate station: all {len(pos)} grid nodes ({spacing_m:g} m apart) lie "
            f"within {clearance_m:g} m of a tree; use a finer --candidate-spacing-m or a "
            "smaller clearance"
        )
    return pos[free], {"grid_nodes": int(len(pos)), "too_close_to_a_tree": int((~free).sum())}


@dataclass
class Layout:
    """A named set of stations (positions (k, 3)) and the moves made to free them."""

    name: str
    description: str
    positions: np.ndarray
    moved_m: list[float] = field(default_factory=list)


def _free(
    pos: np.ndarray, clearance: TreeClearance, clearance_m: float, terrain, height_m: float
) -> tuple[np.ndarray, float] | None:
    if clearance.distance_m(pos[None])[0] >= clearance_m:
        return pos, 0.0
    for r in np.arange(0.25, 2.0001, 0.25):
        n = max(8, int(math.ceil(2 * math.pi * r / 0.25)))
        a = np.linspace(0, 2 * math.pi, n, endpoint=False)
        xy = pos[None, :2] + r * np.column_stack([np.cos(a), np.sin(a)])
        cand = _on_terrain(terrain, xy, height_m)
        d = clearance.distance_m(cand)
        ok = np.flatnonzero(d >= clearance_m)
        if len(ok):
            return cand[ok[0]], float(r)
    return None


def classic_layouts(
    terrain,
    centre_xy: Sequence[float],
    radius_m: float,
    *,
    ring_distance_m: float,
    grid_spacings_m: Sequence[float],
    height_m: float,
    clearance: TreeClearance,
    clearance_m: float,
) -> list[Layout]:
    """The classic layouts (module notes), stations freed from the trees."""
    c = np.asarray(centre_xy, np.float64)
    d = float(ring_distance_m)

    def ring(n: int, start_deg: float = 0.0) -> np.ndarray:
        a = np.radians(start_deg + 360.0 * np.arange(n) / n)
        return c + d * np.column_stack([np.cos(a), np.sin(a)])

    specs: list[tuple[str, str, np.ndarray]] = [
        ("ring-3", f"3 stations 120° apart, {d:.3g} m from the centre", ring(3)),
        ("centre+3", f"the centre and 3 stations 120° apart at {d:.3g} m", np.vstack([c, ring(3)])),
        (
            "cross-5",
            f"5-scan cross: the centre and 4 stations at {d:.3g} m",
            np.vstack([c, ring(4)]),
        ),
    ]
    for s in grid_spacings_m:
        xy = square_grid_xy(c, radius_m, float(s))
        specs.append((f"grid-{float(s):g}m", f"square grid {float(s):g} m, {len(xy)} nodes", xy))
    out = []
    for name, desc, xy in specs:
        pos, moved = [], []
        for p in _on_terrain(terrain, xy, height_m):
            got = _free(p, clearance, clearance_m, terrain, height_m)
            if got is None:
                continue  # no free spot within 2 m: the station is left out
            pos.append(got[0])
            moved.append(got[1])
        if pos:
            out.append(Layout(name, desc, np.array(pos), moved))
    return out
