"""Faceted shapes with answers derivable in float64, for the extremes tests.

* :func:`sheet`: a crumpled sheet, a height field over a regular grid whose every shared
  edge bends (seeded random heights), and :func:`sheet_offset_m`, how far a point lies
  from it along its normal axis (an upper bound of its distance to the sheet);
* :func:`prism`: a closed regular prism (a low-facet cylinder), and
  :func:`prism_distance_m`, the exact distance of points to its surface.

Both oracles are written from the construction, not with the library's geometry kernels.
"""

from __future__ import annotations

import numpy as np


def rotation_z(deg: float) -> np.ndarray:
    """(3, 3) rotation about the vertical axis by ``deg``."""
    a = np.radians(deg)
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rotation_x(deg: float) -> np.ndarray:
    """(3, 3) rotation about the x axis by ``deg``."""
    a = np.radians(deg)
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def sheet(
    n: int, size_m: float, amp_m: float, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A sheet facing +x: vertex ``(i, j)`` at ``(h[i, j], y_i, z_j)``, ``y_i`` and ``z_j``
    on an ``n`` × ``n`` cell grid of side ``size_m`` centred on the origin, heights
    ``h`` ~ N(0, ``amp_m``). Each cell is split along its ``(i, j)``-``(i+1, j+1)``
    diagonal. Returns (vertices, faces, h)."""
    rng = np.random.default_rng(seed)
    g = np.linspace(-size_m / 2, size_m / 2, n + 1)
    y, z = np.meshgrid(g, g, indexing="ij")
    h = amp_m * rng.standard_normal(y.shape)
    v = np.stack([h.ravel(), y.ravel(), z.ravel()], axis=1)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return v, faces, h


def sheet_offset_m(p: np.ndarray, n: int, size_m: float, h: np.ndarray) -> np.ndarray:
    """|x - h(y, z)| of points ``p`` (sheet coordinates) over the sheet's grid: the
    offset along x from the piecewise-linear height at (y, z), an upper bound of the
    distance to the sheet (inf outside the grid)."""
    step = size_m / n
    fi = (p[:, 1] + size_m / 2) / step
    fj = (p[:, 2] + size_m / 2) / step
    i = np.clip(np.floor(fi).astype(int), 0, n - 1)
    j = np.clip(np.floor(fj).astype(int), 0, n - 1)
    s, t = fi - i, fj - j
    ha, hb, hc, hd = h[i, j], h[i + 1, j], h[i + 1, j + 1], h[i, j + 1]
    # triangle (a, b, c) where s >= t, (a, c, d) where t >= s: both agree on the diagonal
    x = np.where(s >= t, ha + s * (hb - ha) + t * (hc - hb), ha + t * (hd - ha) + s * (hc - hd))
    inside = (s >= -1e-9) & (s <= 1 + 1e-9) & (t >= -1e-9) & (t <= 1 + 1e-9)
    return np.where(inside, np.abs(p[:, 0] - x), np.inf)


def prism(facets: int, radius_m: float, height_m: float) -> tuple[np.ndarray, np.ndarray]:
    """A closed regular prism standing on z = 0: corner ``k`` of a ring at angle
    ``2πk / facets`` and radius ``radius_m``; each side a rectangle of two triangles,
    the caps fans around their centres; outward triangles."""
    ang = 2 * np.pi * np.arange(facets) / facets
    ring = np.stack([radius_m * np.cos(ang), radius_m * np.sin(ang)], axis=1)
    lo = np.column_stack([ring, np.zeros(facets)])
    hi = np.column_stack([ring, np.full(facets, height_m)])
    v = np.vstack([lo, hi, [[0.0, 0.0, 0.0], [0.0, 0.0, height_m]]])
    k = np.arange(facets)
    k1 = (k + 1) % facets
    side = np.concatenate(
        [np.stack([k, k1, facets + k1], 1), np.stack([k, facets + k1, facets + k], 1)]
    )
    bottom = np.stack([np.full(facets, 2 * facets), k1, k], 1)
    top = np.stack([np.full(facets, 2 * facets + 1), facets + k, facets + k1], 1)
    return v, np.concatenate([side, bottom, top]).astype(np.int64)


def prism_distance_m(p: np.ndarray, v: np.ndarray, facets: int, height_m: float) -> np.ndarray:
    """Exact distance (m) of points ``p`` (prism coordinates) to the prism's surface: its
    side walls (each a vertical rectangle: a segment between two ring corners times
    [0, ``height_m``]) and its caps (the ring polygon at z = 0 and z = ``height_m``,
    whose borders the walls already hold)."""
    best = np.full(len(p), np.inf)
    inside = np.ones(len(p), dtype=bool)
    for k in range(facets):
        a, b = v[k, :2], v[(k + 1) % facets, :2]
        e = b - a
        s = np.clip((p[:, :2] - a) @ e / (e @ e), 0.0, 1.0)
        dxy = p[:, :2] - (a + s[:, None] * e)
        dz = p[:, 2] - np.clip(p[:, 2], 0.0, height_m)
        best = np.minimum(best, np.sqrt(np.einsum("ij,ij->i", dxy, dxy) + dz * dz))
        rel = p[:, :2] - a
        inside &= e[0] * rel[:, 1] - e[1] * rel[:, 0] >= 0.0  # left of every edge (CCW)
    cap = np.minimum(np.abs(p[:, 2]), np.abs(p[:, 2] - height_m))
    return np.where(inside, np.minimum(best, cap), best)


def prism_pulses(
    spec,
    station: np.ndarray,
    corners_xy: np.ndarray,
    height_m: float,
    eps_m: float,
) -> tuple[np.ndarray, np.ndarray]:
    """The grid pulses of a level station (heading 0) that hit a vertical convex prism's
    side walls: ``corners_xy`` (k, 2) counter-clockwise, walls from z = 0 to
    ``height_m``; the station's height within (0, ``height_m``), so no cap is visible.

    Computed in float64 from the grid angles (``h0 + column × hres``, ``v0 + line ×
    vres``): a pulse hits where its azimuth lies between the outermost corners' and its
    ray, at the wall it enters, lies between the wall's foot and top. Returns the keys
    (``line × n_azimuth + column``) of the pulses that hit with a margin of ``eps_m`` to
    spare (sure) and of those within ``eps_m`` of hitting (possible)."""
    rel = corners_xy - station[:2]
    centre = np.arctan2(rel[:, 1].mean(), rel[:, 0].mean())
    ang = np.arctan2(rel[:, 1], rel[:, 0]) - centre
    ang = (ang + np.pi) % (2 * np.pi) - np.pi
    reach = np.hypot(rel[:, 0], rel[:, 1])
    hres, vres = spec.horizontal_resolution_deg, spec.vertical_resolution_deg
    h0, v0 = spec.horizontal_fov_deg[0], spec.vertical_fov_deg[0]
    lo = np.degrees(centre + ang.min()) - h0
    hi = np.degrees(centre + ang.max()) - h0
    cols = np.arange(int(np.floor(lo / hres)) - 2, int(np.ceil(hi / hres)) + 3)
    cols = cols % spec.n_azimuth  # (n_azimuth x hres need not be 360 degrees exactly)
    alpha = np.radians(h0 + cols * hres)  # the scanner's column azimuths (float64)
    rel_a = (alpha - centre + np.pi) % (2 * np.pi) - np.pi
    # lateral margin: how far the ray passes inside (> 0) or outside the outermost corners
    lat = np.minimum(
        (rel_a - ang.min()) * reach[ang.argmin()], (ang.max() - rel_a) * reach[ang.argmax()]
    )
    # horizontal distance to the wall the ray enters (Cyrus-Beck on the convex polygon)
    u = np.stack([np.cos(alpha), np.sin(alpha)], axis=1)
    s_in = np.zeros(len(cols))
    for k in range(len(corners_xy)):
        e = corners_xy[(k + 1) % len(corners_xy)] - corners_xy[k]
        n = np.array([e[1], -e[0]])  # outward
        nu = u @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            s = -((station[:2] - corners_xy[k]) @ n) / nu
        s_in = np.where(nu < 0, np.maximum(s_in, s), s_in)
    z0 = station[2]
    el_lo = np.degrees(np.arctan2(-z0, s_in))
    el_hi = np.degrees(np.arctan2(height_m - z0, s_in))
    first = np.floor((el_lo - v0) / vres).astype(int) - 2
    last = np.ceil((el_hi - v0) / vres).astype(int) + 2
    n_lines = last - first + 1
    col = np.repeat(cols, n_lines)
    line = np.repeat(first, n_lines) + (
        np.arange(n_lines.sum()) - np.repeat(np.cumsum(n_lines) - n_lines, n_lines)
    )
    el = np.radians(v0 + line * vres)
    s_c = np.repeat(s_in, n_lines)
    z = z0 + s_c * np.tan(el)
    vert = np.minimum(z, height_m - z) * np.cos(el)
    margin = np.minimum(np.repeat(lat, n_lines), vert)
    keep = (line >= 0) & (line < spec.n_elevation)
    key = line * spec.n_azimuth + col
    return np.unique(key[keep & (margin > eps_m)]), np.unique(key[keep & (margin > -eps_m)])


def float32_ray_error_m(station_m: float, reach_m: float, scene_m: float) -> float:
    """How far a float32 ray can pass from its float64 grid ray, and float32 vertices
    lie from theirs: 16 float32 ulps (2**-24 each) of the station's distance from the
    scanner's local frame's origin, of the distance travelled and of the scene's size
    (origin, direction and vertex rounding, and Embree's own arithmetic on them)."""
    return 16 * 2.0**-24 * (station_m + reach_m + scene_m)


def rectangle(
    centre: np.ndarray, rot: np.ndarray, half: tuple[float, float], cells: tuple[int, int]
) -> tuple[np.ndarray, np.ndarray]:
    """A flat rectangle ``centre + u e1 + v e2`` (``e1``, ``e2`` the first two columns of
    ``rot``; |u| <= half[0], |v| <= half[1]) triangulated on a ``cells`` grid (coplanar
    triangles, many shared edges). Returns (vertices, faces)."""
    u = np.linspace(-half[0], half[0], cells[0] + 1)
    v = np.linspace(-half[1], half[1], cells[1] + 1)
    uu, vv = np.meshgrid(u, v, indexing="ij")
    verts = centre + uu.reshape(-1, 1) * rot[:, 0] + vv.reshape(-1, 1) * rot[:, 1]
    idx = np.arange(uu.size).reshape(uu.shape)
    a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return verts, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def rectangle_pulses(
    spec,
    station: np.ndarray,
    centre: np.ndarray,
    rot: np.ndarray,
    half: tuple[float, float],
    eps_m: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The grid pulses of a level station (heading 0) that hit the rectangle of
    :func:`rectangle`, in float64: each pulse's ray meets the rectangle's plane at a
    point whose signed in-plane distance Δ to the rectangle's border (> 0 inside) is
    exact, and every point of the border lies at least |Δ| · cos(incidence) from the
    ray (an in-plane vector makes an angle of at least 90° - incidence with the ray).
    Returns the keys (``line × n_azimuth + column``) of the pulses that surely hit
    (margin > ``eps_m``), of those that may (margin > -``eps_m``), and the incidence
    (deg) of the sure ones."""
    n = rot[:, 2]
    # the angular box of the border, sampled densely (edges bow in azimuth/elevation)
    s = np.linspace(-1.0, 1.0, 2001)
    border = np.concatenate(
        [
            centre + half[0] * np.outer(s, rot[:, 0]) + sgn * half[1] * rot[:, 1]
            for sgn in (-1.0, 1.0)
        ]
        + [
            centre + sgn * half[0] * rot[:, 0] + half[1] * np.outer(s, rot[:, 1])
            for sgn in (-1.0, 1.0)
        ]
    )
    rel = border - station
    az0 = np.arctan2(rel[:, 1].mean(), rel[:, 0].mean())
    az = (np.arctan2(rel[:, 1], rel[:, 0]) - az0 + np.pi) % (2 * np.pi) - np.pi
    el = np.degrees(np.arctan2(rel[:, 2], np.hypot(rel[:, 0], rel[:, 1])))
    hres, vres = spec.horizontal_resolution_deg, spec.vertical_resolution_deg
    h0, v0 = spec.horizontal_fov_deg[0], spec.vertical_fov_deg[0]
    c_lo = int(np.floor((np.degrees(az0 + az.min()) - h0) / hres)) - 3
    c_hi = int(np.ceil((np.degrees(az0 + az.max()) - h0) / hres)) + 3
    l_lo = max(0, int(np.floor((el.min() - v0) / vres)) - 3)
    l_hi = min(spec.n_elevation - 1, int(np.ceil((el.max() - v0) / vres)) + 3)
    cols = np.arange(c_lo, c_hi + 1) % spec.n_azimuth
    lines = np.arange(l_lo, l_hi + 1)
    col, line = (a.ravel() for a in np.meshgrid(cols, lines, indexing="ij"))
    alpha = np.radians(h0 + col * hres)
    elev = np.radians(v0 + line * vres)
    d = np.stack([np.cos(elev) * np.cos(alpha), np.cos(elev) * np.sin(alpha), np.sin(elev)], 1)
    dn = d @ n
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        t = ((centre - station) @ n) / dn
        p = station + t[:, None] * d - centre
        u, v = p @ rot[:, 0], p @ rot[:, 1]
        delta = np.minimum(half[0] - np.abs(u), half[1] - np.abs(v))
        ok = (t > spec.min_range_m) & (t < spec.max_range_m)
        margin = np.where(ok, delta * np.abs(dn), -np.inf)
    margin = np.nan_to_num(margin, nan=-np.inf)
    key = line * spec.n_azimuth + col
    sure = margin > eps_m
    inc = np.degrees(np.arccos(np.clip(np.abs(dn[sure]), 0.0, 1.0)))
    return key[sure], key[margin > -eps_m], inc
