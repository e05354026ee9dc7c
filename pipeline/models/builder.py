"""The builder of a procedural tree: grows :class:`~treesim.models.species.TreeParams`
into an exact cylinder table and, on request, its leaves.

Stems wait in a queue, the trunk first; each is grown segment by segment (curvature,
wobble, upward attraction and splits at Weber & Penn's joints, the trunk's flared base
subdivided), and its children are placed along it (counts, lengths, down angles and
rotation by W&P's rules) and queued in turn. Every random number comes from one
generator in that fixed order, so a seed gives the same tree bit for bit; the leaves
draw from a generator of their own, so a tree with and without leaves has the same wood.
:func:`treesim.models.procedural.generate_tree` runs it.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .cylinders import CylinderTable
from .species import CHILD_RADIUS_LIMIT, LEAF_SHAPES, StemLevel, TreeParams, shape_ratio

__all__ = ["MIN_JUNCTION_FACETS", "TreeBuilder"]

#: Junctions are crack-free in meshes with at least this many facets per ring (a child's
#: base disc lies inside the parent's inscribed polygon, radius r cos(pi / facets)).
MIN_JUNCTION_FACETS: int = 8

#: Sub-segments of the trunk's lowest eighth, where the flare changes the radius fastest.
_FLARE_SUBSEGMENTS = 4

_UP = np.array([0.0, 0.0, 1.0])


# ---------------------------------------------------------------------- vector helpers


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.cross`` of two 3-vectors, the same products and differences (so the same
    float64 bits) without its general-shape overhead: 2.6x faster tree generation."""
    a0, a1, a2 = float(a[0]), float(a[1]), float(a[2])
    b0, b1, b2 = float(b[0]), float(b[1]), float(b[2])
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


def _rotate(v: np.ndarray, axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotate ``v`` about the unit ``axis`` by ``angle`` radians (Rodrigues)."""
    c, s = math.cos(angle), math.sin(angle)
    return v * c + _cross(axis, v) * s + axis * (float(axis @ v) * (1.0 - c))


def _droop(radial: np.ndarray, axis: np.ndarray, droop: float) -> np.ndarray:
    """``radial`` (unit, square to ``axis``) turned by the fraction ``droop`` toward the
    ground's direction square to ``axis`` (unchanged where the axis is vertical)."""
    g = np.array([0.0, 0.0, -1.0])[None, :] - axis * (-axis[:, 2:3])
    g_norm = np.linalg.norm(g, axis=1, keepdims=True)
    g = np.where(g_norm > 1e-9, g / np.maximum(g_norm, 1e-300), radial)
    out = (1.0 - droop) * radial + droop * g
    n = np.linalg.norm(out, axis=1, keepdims=True)
    return np.where(n > 1e-9, out / np.maximum(n, 1e-300), radial)


def _perpendicular(d: np.ndarray) -> np.ndarray:
    """A unit vector perpendicular to the unit ``d``."""
    world = np.zeros(3)
    world[int(np.argmin(np.abs(d)))] = 1.0
    return _unit(_cross(d, world))


def _tilt_toward(d: np.ndarray, target: np.ndarray, angle: float) -> np.ndarray:
    """Turn the unit ``d`` toward the unit ``target`` by ``angle`` (never past it)."""
    axis = _cross(d, target)
    s = float(np.linalg.norm(axis))
    if s < 1e-12:
        return d
    between = math.atan2(s, float(d @ target))
    return _unit(_rotate(d, axis / s, min(angle, between)))


@dataclass
class _Stem:
    """A stem waiting to be grown."""

    level: int  # index into params.levels
    order: int  # branch order in the table (topological)
    start: np.ndarray
    direction: np.ndarray
    right: np.ndarray  # unit, perpendicular to direction: the plane of the systematic curve
    length: float
    radius: Callable[[float], float]  # radius at a fraction of the stem's length
    parent_row: int  # -1 for the trunk
    parent_length: float  # length of the parent stem (0 for the trunk)
    offset: float  # where on the parent it starts, metres from the parent's base
    split_error: float = 0.0
    segments: int = 0  # W&P segments; 0: the level's (a clone gets its stem's remaining ones)


@dataclass
class _Grown:
    """A grown stem's centre line, for placing its children and leaves."""

    stem: _Stem
    nodes: np.ndarray  # (m + 1, 3)
    radii: np.ndarray  # (m + 1,)
    arc: np.ndarray  # (m + 1,) cumulative length
    rows: np.ndarray  # (m,) table rows
    right: np.ndarray  # its curve plane's normal at the base


class TreeBuilder:
    """Grows one tree: :meth:`build` the wood (a validated :class:`CylinderTable`), then
    :meth:`leaves` on the stems of the last level, from a generator of their own.

    Parameters
    ----------
    params : TreeParams
        The species.
    rng : numpy.random.Generator
        The wood's random numbers, drawn in a fixed order.
    """

    def __init__(self, params: TreeParams, rng: np.random.Generator) -> None:
        self.p = params
        self.rng = rng
        self.start: list[np.ndarray] = []
        self.end: list[np.ndarray] = []
        self.r0: list[float] = []
        self.r1: list[float] = []
        self.parent: list[int] = []
        self.branch: list[int] = []
        self.order: list[int] = []
        self.position: list[int] = []
        self.n_stems = 0
        self.trunk_length = params.trunk_length_m  # drawn in build()
        self.leaf_stems: list[_Grown] = []
        self.queue: deque[_Stem] = deque()

    def u(self) -> float:
        """Uniform in [-1, 1)."""
        return 2.0 * float(self.rng.random()) - 1.0

    def profile(self, base_radius: float, taper: float, flare: float) -> Callable[[float], float]:
        tip = min(base_radius, self.p.tip_radius_m)

        def radius(z: float) -> float:
            r = base_radius - (base_radius - tip) * taper * z
            if flare > 0.0:
                y = max(0.0, 1.0 - 8.0 * z)
                r *= 1.0 + flare * (100.0**y - 1.0) / 100.0
            return r

        return radius

    # ------------------------------------------------------------------ growing

    def grow(self, stem: _Stem) -> _Grown:
        p, lev = self.p, self.p.levels[stem.level]
        segs = stem.segments or lev.segments
        trunk = stem.parent_row < 0
        # Node fractions: W&P's segments, the trunk's lowest eighth subdivided.
        fracs = [k / segs for k in range(segs + 1)]
        if trunk and p.flare > 0.0:
            extra = [j / (8.0 * _FLARE_SUBSEGMENTS) for j in range(1, _FLARE_SUBSEGMENTS + 1)]
            # (none within a fifth of a segment of a W&P joint: no sliver segments)
            extra = [z for z in extra if min(abs(z - f) for f in fracs) > 0.2 / segs]
            fracs = sorted(set(fracs) | set(extra))
        bends = {k / segs for k in range(1, segs)}

        d = stem.direction.copy()
        right = stem.right.copy()
        pos = stem.start.copy()
        nodes = [pos.copy()]
        rows: list[int] = []
        self.n_stems += 1
        branch = self.n_stems
        parent_row = stem.parent_row
        split_error = stem.split_error
        for j in range(len(fracs) - 1):
            z0, z1 = fracs[j], fracs[j + 1]
            nxt = pos + d * (stem.length * (z1 - z0))
            row = len(self.start)
            self.start.append(pos)
            self.end.append(nxt)
            self.r0.append(stem.radius(z0))
            self.r1.append(stem.radius(z1))
            self.parent.append(parent_row)
            self.branch.append(branch)
            self.order.append(stem.order)
            self.position.append(j + 1)
            rows.append(row)
            parent_row = row
            pos = nxt
            nodes.append(pos.copy())
            if z1 not in bends:
                continue
            # Curvature at a W&P joint.
            k = round(z1 * segs) - 1  # the segment that just ended
            if lev.curve_back_deg == 0.0:
                bend = lev.curve_deg / segs
            else:
                half = max(segs / 2.0, 1.0)
                bend = (lev.curve_deg if k < segs / 2.0 else lev.curve_back_deg) / half
            d = _unit(_rotate(d, right, math.radians(bend)))
            if lev.curve_var_deg > 0.0:
                wobble_axis = _rotate(right, d, math.pi * self.u())
                angle = math.radians(lev.curve_var_deg / segs * self.u())
                d = _unit(_rotate(d, wobble_axis, angle))
                right = _rotate(right, wobble_axis, angle)
            if stem.level >= 2 and p.attraction_up != 0.0:
                declination = math.acos(max(-1.0, min(1.0, float(d[2]))))
                pull = p.attraction_up * declination / segs
                d = _tilt_toward(d, _UP if pull > 0 else -_UP, abs(pull))
            right = _unit(right - d * float(right @ d))
            # Splits (W&P's error diffusion), never in the trunk's bare base.
            if lev.seg_splits > 0.0 and not (trunk and z1 < p.base_size):
                want = lev.seg_splits + split_error
                clones = int(want)
                split_error = want - clones
                for _ in range(clones):
                    d = self.split(stem, d, right, z1, row, segs - k - 1)
                    right = _unit(right - d * float(right @ d))
        grown = _Grown(
            stem=stem,
            nodes=np.array(nodes),
            radii=np.array([stem.radius(z) for z in fracs]),
            arc=np.array(fracs) * stem.length,
            rows=np.array(rows, dtype=np.int64),
            right=stem.right,
        )
        return grown

    def split(
        self, stem: _Stem, d: np.ndarray, right: np.ndarray, z: float, row: int, segments: int
    ) -> np.ndarray:
        """Queue a clone forking off at fraction ``z``; return the stem's new direction.

        The clone grows the stem's remaining ``segments`` (so splitting always ends).
        """
        p, lev = self.p, self.p.levels[stem.level]
        angle = math.radians(lev.split_angle_deg + lev.split_angle_var_deg * self.u())
        plane = _rotate(right, d, 2.0 * math.pi * float(self.rng.random()))  # fork axis
        clone_dir = _unit(_rotate(d, plane, 2.0 * angle / 3.0))
        stem_dir = _unit(_rotate(d, plane, -angle / 3.0))
        ratio = p.split_radius_ratio
        mother = stem.radius

        def radius(zc: float, z=z) -> float:
            return ratio * mother(z + zc * (1.0 - z))

        # Start on the incoming segment's axis, back far enough that the clone's base
        # disc (radius ratio * r, tilted by 2/3 of the angle) stays inside the stem.
        seg_axis = _unit(self.end[row] - self.start[row])
        seg_len = float(np.linalg.norm(self.end[row] - self.start[row]))
        r_clone = radius(0.0)
        tilt = math.sqrt(max(0.0, 1.0 - float(clone_dir @ seg_axis) ** 2))
        back = min(1.05 * r_clone * tilt + 1e-6, 0.5 * seg_len)
        self.queue.append(
            _Stem(
                level=stem.level,
                order=stem.order + 1,
                start=self.end[row] - back * seg_axis,
                direction=clone_dir,
                right=_unit(_cross(plane, clone_dir)),
                length=stem.length * (1.0 - z) + back,
                radius=radius,
                parent_row=row,
                parent_length=stem.parent_length,  # a sibling of its stem, for W&P's rules
                offset=stem.offset,
                split_error=0.0,
                segments=segments,
            )
        )
        return stem_dir

    # ------------------------------------------------------------------ children

    def children(self, g: _Grown) -> None:
        p = self.p
        stem = g.stem
        level = stem.level + 1
        if level >= len(p.levels):
            self.leaf_stems.append(g)
            return
        lev = p.levels[level]
        trunk = stem.level == 0  # the trunk or a clone of it
        length = stem.length
        base = p.base_size * length if stem.parent_row < 0 else 0.0
        if trunk:  # the trunk carries nBranches; its clones their share by length
            count = lev.branches * min(1.0, length / self.trunk_length)
        elif stem.level == 1:
            ratio_max = max(p.levels[1].length_ratio + p.levels[1].length_ratio_var, 1e-9)
            rel = stem.length / max(stem.parent_length, 1e-9)
            count = lev.branches * (0.2 + 0.8 * min(rel / ratio_max, 1.0))
        else:
            count = lev.branches * (1.0 - 0.5 * stem.offset / max(stem.parent_length, 1e-9))
        n = int(round(count))
        if n <= 0 or length - base <= 0:
            return
        spacing = (length - base) / n
        phi = 2.0 * math.pi * float(self.rng.random())
        r_base = stem.radius(0.0)
        for i in range(n):
            offset = base + (i + 0.5 + 0.4 * self.u()) * spacing
            offset = min(max(offset, base), length)
            lmax = lev.length_ratio + lev.length_ratio_var * self.u()
            if trunk:
                env = shape_ratio(p.shape, (length - offset) / max(length - base, 1e-9))
                child_len = length * lmax * env
            else:
                child_len = lmax * (length - 0.6 * offset)
            if lev.down_angle_var_deg >= 0.0:
                down = lev.down_angle_deg + lev.down_angle_var_deg * self.u()
            else:
                env = shape_ratio("conical", (length - offset) / max(length - base, 1e-9))
                down = lev.down_angle_deg + lev.down_angle_var_deg * (1.0 - 2.0 * env)
            if lev.rotate_deg >= 0.0:
                phi += math.radians(lev.rotate_deg + lev.rotate_var_deg * self.u())
            else:
                side = 1.0 if i % 2 == 0 else -1.0
                phi = side * math.radians(180.0 + lev.rotate_deg + lev.rotate_var_deg * self.u())
            if child_len <= 1e-3:
                continue
            self.attach(g, lev, level, offset, child_len, down, phi, r_base)

    def attach(
        self,
        g: _Grown,
        lev: StemLevel,
        level: int,
        offset: float,
        child_len: float,
        down_deg: float,
        phi: float,
        r_base: float,
    ) -> None:
        """Queue a child stem of ``g`` at ``offset`` metres along it."""
        p = self.p
        k = int(np.clip(np.searchsorted(g.arc, offset, side="right") - 1, 0, len(g.rows) - 1))
        a = _unit(g.nodes[k + 1] - g.nodes[k])
        seg_len = float(g.arc[k + 1] - g.arc[k])
        # Azimuth reference: the parent's curve-plane normal, made perpendicular to a.
        ref = g.right - a * float(g.right @ a)
        ref = _unit(ref) if np.linalg.norm(ref) > 1e-9 else _perpendicular(a)
        radial = _rotate(ref, a, phi)
        down = math.radians(down_deg)
        d = _unit(math.cos(down) * a + math.sin(down) * radial)
        r_parent = float(min(g.radii[k], g.radii[k + 1]))
        r_child = min(
            r_base * (child_len / g.stem.length) ** p.ratio_power, CHILD_RADIUS_LIMIT * r_parent
        )
        # Keep the base disc inside the parent: within this segment along the axis, and
        # radially inside the parent's inscribed polygon at MIN_JUNCTION_FACETS facets.
        sin_a = math.sqrt(max(0.0, 1.0 - float(d @ a) ** 2))
        reach = r_child * sin_a
        t = offset - float(g.arc[k])
        t = min(max(t, reach), seg_len - reach) if seg_len > 2.0 * reach else 0.5 * seg_len
        r_in = r_parent * math.cos(math.pi / MIN_JUNCTION_FACETS)
        inset = 0.95 * sin_a * math.sqrt(max(r_in * r_in - r_child * r_child, 0.0))
        along = d - a * float(d @ a)
        out = _unit(along) if np.linalg.norm(along) > 1e-9 else radial
        start = g.nodes[k] + t * a + inset * out
        right = _cross(a, d)
        right = _unit(right) if np.linalg.norm(right) > 1e-9 else _perpendicular(d)
        self.queue.append(
            _Stem(
                level=level,
                order=g.stem.order + 1,
                start=start,
                direction=d,
                right=right,
                length=child_len,
                radius=self.profile(r_child, lev.taper, 0.0),
                parent_row=int(g.rows[k]),
                parent_length=g.stem.length,
                offset=offset,
            )
        )

    # ------------------------------------------------------------------ leaves

    def leaves(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, int]:
        """The leaves of the grown tree (call :meth:`build` first): vertices, triangles
        and the number of leaves, drawn from ``rng``."""
        lp = self.p.leaves
        if lp is None or lp.leaves_per_stem == 0 or not self.leaf_stems:
            return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), 0
        base_pts, mids, widths, sizes = [], [], [], []
        for g in self.leaf_stems:
            stem = g.stem
            rel = stem.offset / stem.parent_length if stem.parent_length > 0 else 1.0
            count = int(round(lp.leaves_per_stem * shape_ratio("tapered_cylindrical", rel)))
            if count <= 0:
                continue
            s = stem.length * (
                0.15 + 0.85 * (np.arange(count) + 0.5 + 0.4 * rng.uniform(-1, 1, count)) / count
            )
            k = np.clip(np.searchsorted(g.arc, s, side="right") - 1, 0, len(g.rows) - 1)
            seg = g.nodes[k + 1] - g.nodes[k]
            seg_len = np.linalg.norm(seg, axis=1)
            t_axis = seg / seg_len[:, None]
            frac = np.clip((s - g.arc[k]) / seg_len, 0.0, 1.0)
            centre = g.nodes[k] + (s - g.arc[k])[:, None] * t_axis
            radius = g.radii[k] + frac * (g.radii[k + 1] - g.radii[k])
            ref = g.right[None, :] - t_axis * (t_axis @ g.right)[:, None]
            norm = np.linalg.norm(ref, axis=1)
            ref = np.where(norm[:, None] > 1e-9, ref / np.maximum(norm, 1e-300)[:, None], 0.0)
            bad = norm <= 1e-9
            for i in np.flatnonzero(bad):
                ref[i] = _perpendicular(t_axis[i])
            side = np.cross(t_axis, ref)
            phi = float(rng.random()) * 2 * math.pi + np.radians(lp.rotate_deg) * np.arange(count)
            radial = np.cos(phi)[:, None] * ref + np.sin(phi)[:, None] * side
            if lp.droop > 0.0:
                radial = _droop(radial, t_axis, lp.droop)
            down = np.radians(lp.down_angle_deg + lp.down_angle_var_deg * rng.uniform(-1, 1, count))
            mid = np.cos(down)[:, None] * t_axis + np.sin(down)[:, None] * radial
            width = np.cross(t_axis, radial)
            width /= np.linalg.norm(width, axis=1, keepdims=True)
            base_pts.append(centre + (radius + lp.petiole_m)[:, None] * radial)
            mids.append(mid)
            widths.append(width)
            sizes.append(1.0 + lp.size_var * rng.uniform(-1, 1, count))
        if not base_pts:
            return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), 0
        base = np.concatenate(base_pts)
        mid = np.concatenate(mids)
        width = np.concatenate(widths)
        size = np.concatenate(sizes)
        # Turn each blade about its midrib toward facing up, by the bend fraction.
        normal = np.cross(mid, width)
        up = _UP[None, :] - mid * mid[:, 2:3]
        up_norm = np.linalg.norm(up, axis=1)
        ok = up_norm > 1e-9
        target = np.where(ok[:, None], up / np.maximum(up_norm, 1e-300)[:, None], normal)
        flip = np.einsum("ij,ij->i", normal, target) < 0  # a blade has two faces
        target[flip] *= -1.0
        gamma = np.arctan2(
            np.einsum("ij,ij->i", np.cross(normal, target), mid),
            np.einsum("ij,ij->i", normal, target),
        )
        turn = lp.bend * gamma
        width = np.cos(turn)[:, None] * width + np.sin(turn)[:, None] * normal
        pts, tris = LEAF_SHAPES[lp.shape]
        xy = np.array(pts, dtype=np.float64)
        length = lp.length_m * size
        vertices = (
            base[:, None, :]
            + (length[:, None] * xy[None, :, 0])[:, :, None] * mid[:, None, :]
            + (length[:, None] * lp.width_ratio * xy[None, :, 1])[:, :, None] * width[:, None, :]
        )
        n = len(base)
        faces = (
            np.array(tris, dtype=np.int64)[None, :, :] + (np.arange(n) * len(pts))[:, None, None]
        )
        return vertices.reshape(-1, 3), faces.reshape(-1, 3), n

    # ------------------------------------------------------------------ all of it

    def build(self) -> CylinderTable:
        """Grow the trunk and every stem queued from it; the table they make, validated."""
        p = self.p
        length = p.trunk_length_m + p.trunk_length_var_m * self.u()
        self.trunk_length = length
        roll = 2.0 * math.pi * float(self.rng.random())
        self.queue.append(
            _Stem(
                level=0,
                order=0,
                start=np.zeros(3),
                direction=_UP.copy(),
                right=np.array([math.cos(roll), math.sin(roll), 0.0]),
                length=length,
                radius=self.profile(length * p.radius_ratio, p.levels[0].taper, p.flare),
                parent_row=-1,
                parent_length=0.0,
                offset=0.0,
            )
        )
        while self.queue:
            self.children(self.grow(self.queue.popleft()))
        start = np.array(self.start)
        end = np.array(self.end)
        n = len(start)
        parent = np.array(self.parent, dtype=np.int64)
        extension = np.full(n, -1, dtype=np.int64)
        cont = np.flatnonzero(parent >= 0)
        cont = cont[np.array(self.branch)[parent[cont]] == np.array(self.branch)[cont]]
        extension[parent[cont]] = cont
        table = CylinderTable.from_endpoints(
            start,
            end,
            np.array(self.r0),
            parent=parent,
            branch=np.array(self.branch, dtype=np.int64),
            branch_order=np.array(self.order, dtype=np.int64),
            position_in_branch=np.array(self.position, dtype=np.int64),
            end_radius_m=np.array(self.r1),
            tag=np.full(n, "modelled"),
            extension=extension,
        )
        return table.validate(source=f"procedural tree {p.name!r}")
