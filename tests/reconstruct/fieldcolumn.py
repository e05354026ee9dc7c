"""A truth that looks like the field (issue 21): a procedural tree on rough, sloping ground
among litter, understory shrubs and neighbours, scanned like a plot with the RIEGL VZ-400's
noise, then cut out as a vertical column the way field teams clip single trees from plot
scans (e.g. TreeLS's pine, a 2.5 m square column).

The cloud therefore holds what real single-tree clouds hold: the ground under the tree,
litter, shrubs (one at the stem foot), pieces of the neighbours' branches clipped at the
column's walls, and the needle-on or leaf-on target, whose stem foot stands on the slope
(its uphill side buried, as :class:`treesim.plot.Plot` places trees). The truth is the
target's own cylinder table (:meth:`treesim.plot.Plot.truth`): exact, whatever the scan
sees. The column is sized to hold the target's whole crown plus a margin; the generator
checks that it clips none of it.

Shared by ``test_field_column.py``, ``scripts/field_column.py`` and (later) benchmarks.
"""

from __future__ import annotations

import math
import tempfile
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from treesim.cloud import LABEL_CODES

__all__ = [
    "DEFAULT_STEP_DEG",
    "KINDS",
    "PART_CODES",
    "PARTS",
    "FieldColumn",
    "cached_field_column",
    "field_column",
]

#: What each point of a column is, in code order (``labels`` holds the index).
PARTS = ("ground", "litter", "shrub", "neighbour", "target_wood", "target_leaf")
PART_CODES = {name: code for code, name in enumerate(PARTS)}

#: Tree ids in the scene (the terrain is 0).
TARGET_ID = 1
NEIGHBOUR_ID0 = 11
SHRUB_ID0 = 21
LITTER_ID = 90

#: Margin between the target's outermost vertex and the column wall (m).
COLUMN_MARGIN_M = 0.3
#: DTM cell and terrain mesh cell (m).
TERRAIN_CELL_M = 0.1
#: Instrument height above the ground at each station (m).
STATION_HEIGHT_M = 1.5
#: The scanner's default angular step (deg). The VZ-400's usual 0.04° from stations 6-9 m
#: outside a 10 m column gives over a million points, most of them ground near the
#: stations; 0.08° keeps a column at 0.3-0.4 M points with the stem sampled every ~1.5 cm
#: (what 0.04° gives at ~20 m, a common plot-scan distance).
DEFAULT_STEP_DEG = 0.08


@dataclass(frozen=True)
class Kind:
    """A stand: the target's and the neighbours' preset, and the scene's counts."""

    target: str
    neighbour: str
    n_neighbours: int
    n_stations: int
    n_shrubs: int


#: The kinds of column: a needle-on conifer and a leaf-on broadleaf.
KINDS: dict[str, Kind] = {
    "conifer": Kind("balsam-fir", "balsam-fir", n_neighbours=3, n_stations=3, n_shrubs=4),
    "broadleaf": Kind("aspen-leafon", "aspen-leafon", n_neighbours=3, n_stations=3, n_shrubs=4),
}


class FieldColumn(NamedTuple):
    """A column cloud and its truth (unpacks as ``truth, points, labels``).

    Attributes
    ----------
    truth : dict
        The target's exact figures (``dbh_m``, ``height_m``, ``volume_stem_m3``,
        ``volume_branch_m3``, ``volume_total_m3``, ``n_cylinders``, ``base_z_m``,
        ``bounds_m``, ...) and how the scene was made (``kind``, ``seed``, ``step_deg``,
        ``column``, ``terrain``, ``stations``, ``neighbours``, ``shrubs``, ``litter``,
        ``part_points``).
    points : (n, 3) float64
        The column's points, metres, in the scene's frame (the target's stem base at
        x = y = 0, on the terrain).
    labels : (n,) uint8
        Each point's part, an index into :data:`PARTS`.
    """

    truth: dict[str, Any]
    points: np.ndarray
    labels: np.ndarray


# ------------------------------------------------------------------------------ terrain


def _rough_dtm(
    rng: np.random.Generator, half_m: float, slope_deg: float, aspect_deg: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """A sloping plane with cm-scale roughness on a ``TERRAIN_CELL_M`` grid over
    [-half_m, half_m]^2: (x, y, z (nx, ny), roughness sd in m)."""
    from scipy.ndimage import gaussian_filter

    from treesim.plot import Terrain

    n = int(round(2 * half_m / TERRAIN_CELL_M)) + 1
    xs = -half_m + TERRAIN_CELL_M * np.arange(n)
    gx, gy = np.meshgrid(xs, xs, indexing="ij")
    plane = Terrain(kind="slope", slope_deg=slope_deg, aspect_deg=aspect_deg).height_at(gx, gy)
    rough = np.zeros_like(plane)
    # micro-relief: hummocks of ~0.5 m (sd 2.5 cm) and clods of ~0.1 m (sd 0.8 cm)
    for sigma_cells, sd_m in ((5.0, 0.025), (1.0, 0.008)):
        f = gaussian_filter(rng.standard_normal(plane.shape), sigma_cells, mode="wrap")
        rough += sd_m * f / f.std()
    return xs, xs, plane + rough, float(rough.std())


def _write_asc(path: Path, xs: np.ndarray, ys: np.ndarray, z: np.ndarray) -> None:
    """``z`` (nx, ny) on cell centres ``xs``, ``ys`` as an ESRI ASCII grid."""
    rows = z.T[::-1]  # the first row is the northernmost
    head = (
        f"ncols {len(xs)}\nnrows {len(ys)}\n"
        f"xllcenter {float(xs[0])!r}\nyllcenter {float(ys[0])!r}\n"
        f"cellsize {TERRAIN_CELL_M!r}\n"
    )
    body = "\n".join(" ".join(repr(float(v)) for v in row) for row in rows)
    path.write_text(head + body + "\n", encoding="ascii")


# ------------------------------------------------------------------------------- litter


def _litter_parts(
    rng: np.random.Generator, terrain: Any, half_m: float, stem_clear_m: float
) -> tuple[list[Any], dict[str, int]]:
    """Twigs (thin hexagonal prisms lying on the ground) and flat pieces (dead leaves,
    bark: small quads 0.5-4 cm above it) over the column's square, none within
    ``stem_clear_m`` of the stem axis."""
    from treesim.models import CylinderTable, cylinders_to_mesh
    from treesim.scene import MeshPart

    area = (2 * half_m) ** 2

    def spots(n: int) -> np.ndarray:
        xy = rng.uniform(-half_m, half_m, (2 * n, 2))
        xy = xy[np.hypot(xy[:, 0], xy[:, 1]) > stem_clear_m]
        return xy[:n]

    # twigs: 1.5 per m^2, 8-45 cm long, 3-12 mm thick, lying on the ground (ends resting
    # up to 2 cm above it)
    n_tw = int(1.5 * area)
    xy = spots(n_tw)
    n_tw = len(xy)
    length = rng.uniform(0.08, 0.45, n_tw)
    radius = rng.uniform(0.0015, 0.006, n_tw)
    az = rng.uniform(0, 2 * np.pi, n_tw)
    d = np.stack([np.cos(az), np.sin(az)], 1)
    a = xy - 0.5 * length[:, None] * d
    b = xy + 0.5 * length[:, None] * d
    za = terrain.height_at(a[:, 0], a[:, 1]) + radius + rng.uniform(0.0, 0.02, n_tw)
    zb = terrain.height_at(b[:, 0], b[:, 1]) + radius + rng.uniform(0.0, 0.02, n_tw)
    start = np.column_stack([a, za])
    axis = np.column_stack([b, zb]) - start
    seg = np.linalg.norm(axis, axis=1)
    table = CylinderTable(
        start=start,
        axis=axis / seg[:, None],
        length_m=seg,
        radius_m=radius,
        parent=np.full(n_tw, -1, dtype=np.int64),
        branch=np.arange(n_tw, dtype=np.int64),
        branch_order=np.zeros(n_tw, dtype=np.int64),
        position_in_branch=np.ones(n_tw, dtype=np.int64),
    ).validate(source="litter twigs")
    tv, tf = cylinders_to_mesh(table, facets=6)

    # flat pieces: 6 per m^2, 2-8 cm, tilted up to 35 degrees, 0.5-4 cm above the ground
    n_fl = int(6 * area)
    xy = spots(n_fl)
    n_fl = len(xy)
    size = np.column_stack([rng.uniform(0.02, 0.08, n_fl), rng.uniform(0.015, 0.05, n_fl)])
    z = terrain.height_at(xy[:, 0], xy[:, 1]) + rng.uniform(0.005, 0.04, n_fl)
    az = rng.uniform(0, 2 * np.pi, n_fl)
    tilt = np.radians(rng.uniform(0, 35, n_fl))
    u = np.stack([np.cos(az) * np.cos(tilt), np.sin(az) * np.cos(tilt), np.sin(tilt)], 1)
    w = np.stack([-np.sin(az), np.cos(az), np.zeros(n_fl)], 1)
    c = np.column_stack([xy, z])
    corners = [
        c + 0.5 * (su * size[:, :1] * u + sw * size[:, 1:] * w)
        for su, sw in ((-1, -1), (1, -1), (1, 1), (-1, 1))
    ]
    fv = np.stack(corners, axis=1).reshape(-1, 3)
    q = 4 * np.arange(n_fl)[:, None]
    ff = np.concatenate([q + [0, 1, 2], q + [0, 2, 3]])
    parts = [
        MeshPart(tv, tf, "wood", "litter:twigs", LITTER_ID),
        MeshPart(fv, ff.astype(np.int64), "leaf", "litter:flat", LITTER_ID),
    ]
    return parts, {"twigs": n_tw, "flat_pieces": n_fl}


# -------------------------------------------------------------------------------- scene


def _wall_distance_m(half_m: float, angle: float) -> float:
    """Distance from the column's centre to its square wall along ``angle`` (radians)."""
    return half_m / max(abs(math.cos(angle)), abs(math.sin(angle)))


def _place_neighbour(
    xy: np.ndarray, angle: float, half_m: float, reach_m: float, rng: np.random.Generator
) -> tuple[float, float]:
    """Turn and distance of a neighbour standing along ``angle`` (radians) from the
    column's centre: its crown's widest side (``xy``: its vertices about its stem base,
    scaled) faces the column, and reaches ``reach_m`` past the wall (less where the stem
    would then stand closer than 0.8 m to the wall): (rotation_deg, distance_m)."""
    r = np.hypot(xy[:, 0], xy[:, 1])
    far = xy[np.argmax(r)]
    rot = angle + math.pi - math.atan2(far[1], far[0]) + float(rng.uniform(-0.4, 0.4))
    c, s = math.cos(rot), math.sin(rot)
    turned = xy @ np.array([[c, -s], [s, c]]).T
    toward = np.array([math.cos(angle), math.sin(angle)])

    def depth(d: float) -> float:
        p = np.abs(turned + d * toward)
        return float((half_m - p.max(axis=1)).max())

    lo = _wall_distance_m(half_m, angle) + 0.8
    hi = lo + float(r.max()) + 1.0
    if depth(lo) > reach_m:
        for _ in range(40):  # depth falls as the tree moves away
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if depth(mid) > reach_m else (lo, mid)
    return math.degrees(rot) % 360.0, lo


def _check_kind(kind: str) -> Kind:
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {', '.join(KINDS)}, got {kind!r}")
    return KINDS[kind]


def field_column(kind: str, seed: int = 0, step_deg: float = DEFAULT_STEP_DEG) -> FieldColumn:
    """A tree cut from a scanned plot column, with its exact truth.

    Parameters
    ----------
    kind : {"conifer", "broadleaf"}
        ``conifer``: the needle-on ``balsam-fir`` among balsam firs; ``broadleaf``: the
        leaf-on ``aspen-leafon`` among leaf-on aspens (:data:`KINDS`).
    seed : int
        Seeds everything: the trees, terrain, litter, placement and the scanner's noise.
        The same seed gives the same cloud, bit for bit.
    step_deg : float
        The scanner's angular step (horizontal and vertical), degrees (default
        :data:`DEFAULT_STEP_DEG`).

    Returns
    -------
    FieldColumn
        ``(truth, points, labels)``.

    Raises
    ------
    RuntimeError
        If the column would clip the target's crown, a neighbour's stem stood inside it
        or no neighbour reached into it (the scene is not what it claims to be).
    """
    from treesim.plot import Plot, PlotTree, Terrain
    from treesim.scan import Station, instrument, scan
    from treesim.scene import Scene

    spec_kind = _check_kind(kind)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    if not (math.isfinite(step_deg) and 0 < step_deg <= 1):
        raise ValueError(f"step_deg must be in (0, 1], got {step_deg!r}")
    rng = np.random.default_rng([seed, list(KINDS).index(kind)])
    slope_deg = float(rng.uniform(3.0, 7.0))
    aspect_deg = float(rng.uniform(0.0, 360.0))
    extent_m = 22.0  # the DTM's half width: the column, the neighbours, the stations

    with tempfile.TemporaryDirectory(prefix="fieldcolumn-") as tmp:
        xs, ys, zs, rough_sd = _rough_dtm(rng, extent_m, slope_deg, aspect_deg)
        dtm = Path(tmp) / "terrain.asc"
        _write_asc(dtm, xs, ys, zs)
        terrain = Terrain(kind="dtm", path=str(dtm))
        terrain.height_at(0.0, 0.0)  # read now: the surface is kept, the file may go

    # the target, its stem base at the origin on the rough slope
    target = PlotTree(
        tree_id=TARGET_ID,
        x_m=0.0,
        y_m=0.0,
        rotation_deg=float(rng.uniform(0, 360)),
        species=spec_kind.target,
        seed=seed,
        leaves=True,
    )
    tplot = Plot([target], terrain=terrain, radius_m=extent_m, facets=32)
    tparts = tplot.tree_parts(TARGET_ID)
    tvert = np.concatenate([p.vertices[np.unique(p.faces)] for p in tparts])
    truth = tplot.truth(TARGET_ID)
    half = float(np.abs(tvert[:, :2]).max()) + COLUMN_MARGIN_M
    top_z = float(tvert[:, 2].max())

    # neighbours: stems outside the column, crowns reaching 0.6-1.5 m into it
    others: list[PlotTree] = []
    a0 = rng.uniform(0, 2 * np.pi)
    n_nb = spec_kind.n_neighbours
    nb_angles = a0 + 2 * np.pi * np.arange(n_nb) / n_nb + rng.uniform(-0.3, 0.3, n_nb)
    from treesim.models import generate_tree

    neighbours = []
    for k, ang in enumerate(nb_angles):
        nseed = 1000 + 10 * seed + k
        scale = float(rng.uniform(0.85, 1.0))
        # its crown's outline from the wood (leaves add a few cm at the twig tips)
        nv = generate_tree(spec_kind.neighbour, seed=nseed, leaves=False).mesh(8)[0]
        rot_deg, dist = _place_neighbour(
            nv[:, :2] * scale, float(ang), half, float(rng.uniform(0.8, 1.8)), rng
        )
        tid = NEIGHBOUR_ID0 + k
        others.append(
            PlotTree(
                tree_id=tid,
                x_m=float(dist * math.cos(ang)),
                y_m=float(dist * math.sin(ang)),
                rotation_deg=rot_deg,
                species=spec_kind.neighbour,
                seed=nseed,
                scale=scale,
                leaves=True,
            )
        )
        neighbours.append(
            {"tree_id": tid, "x_m": others[-1].x_m, "y_m": others[-1].y_m, "scale": scale}
        )

    # understory: leafy saplings scaled to shrubs; the first low, at the stem foot
    shrubs = []
    for k in range(spec_kind.n_shrubs):
        if k == 0:
            r, scale = float(rng.uniform(0.5, 0.7)), float(rng.uniform(0.18, 0.22))
        else:
            r, scale = float(rng.uniform(1.2, half - 0.8)), float(rng.uniform(0.25, 0.45))
        ang = float(rng.uniform(0, 2 * np.pi))
        tid = SHRUB_ID0 + k
        others.append(
            PlotTree(
                tree_id=tid,
                x_m=r * math.cos(ang),
                y_m=r * math.sin(ang),
                rotation_deg=float(rng.uniform(0, 360)),
                species="sapling",
                seed=2000 + 10 * seed + k,
                scale=scale,
                leaves=True,
            )
        )
        shrubs.append({"tree_id": tid, "x_m": others[-1].x_m, "y_m": others[-1].y_m})
    oplot = Plot(others, terrain=terrain, radius_m=extent_m, facets=16)

    parts = list(tparts)
    for t in others:
        tp = oplot.tree_parts(t.tree_id)
        parts += tp
        if t.tree_id < SHRUB_ID0:
            v = np.concatenate([p.vertices[np.unique(p.faces)] for p in tp])
            inside = (np.abs(v[:, :2]) <= half).all(axis=1)
            if not inside.any():
                raise RuntimeError(f"{t.name}: no branch reaches into the column")
            low = v[v[:, 2] <= v[:, 2].min() + 0.3]
            if (np.abs(low[:, :2]) <= half).all(axis=1).any():
                raise RuntimeError(f"{t.name}: its stem stands inside the column")
    stem_r = 0.5 * float(truth["dbh_m"] or 0.1)
    litter, litter_counts = _litter_parts(rng, terrain, half, stem_clear_m=2 * stem_r + 0.05)
    parts += litter
    ground_half = half + 1.0
    lo = -ground_half - (-ground_half) % TERRAIN_CELL_M
    parts.append(terrain.mesh((lo, lo), (-lo, -lo), TERRAIN_CELL_M))
    scene = Scene(parts)

    # stations between the neighbours, outside the column, 1.5 m above the ground
    n_st = spec_kind.n_stations
    st_angles = a0 + np.pi / n_nb + 2 * np.pi * np.arange(n_st) / n_st
    stations = []
    for ang in st_angles:
        d = _wall_distance_m(half, float(ang)) + float(rng.uniform(5.0, 7.0))
        x, y = d * math.cos(ang), d * math.sin(ang)
        z = float(terrain.height_at(x, y)) + STATION_HEIGHT_M
        stations.append(Station(position_m=(x, y, z)))
    spec = instrument("riegl-vz400").spec(
        noise=True,
        horizontal_resolution_deg=step_deg,
        vertical_resolution_deg=step_deg,
        seed=seed,
    )
    cloud = scan(scene, stations, spec, nthreads=2).cloud
    pts = cloud.points
    tree_id = cloud.fields["tree_id"]
    label = cloud.fields["label"]

    # every point of the target must be inside the column (so the cut clips none of it)
    is_target = tree_id == TARGET_ID
    z_lo = float(zs[(np.abs(xs) <= half)][:, np.abs(ys) <= half].min()) - 0.3
    z_hi = top_z + 0.5
    keep = (np.abs(pts[:, :2]) <= half).all(axis=1) & (pts[:, 2] >= z_lo) & (pts[:, 2] <= z_hi)
    if (is_target & ~keep).any():
        raise RuntimeError(
            f"the column clips {int((is_target & ~keep).sum())} points of the target's crown"
        )
    pts, tree_id, label = pts[keep], tree_id[keep], label[keep]
    labels = np.full(len(pts), 255, dtype=np.uint8)
    labels[tree_id == 0] = PART_CODES["ground"]
    labels[tree_id == LITTER_ID] = PART_CODES["litter"]
    labels[(tree_id >= SHRUB_ID0) & (tree_id < LITTER_ID)] = PART_CODES["shrub"]
    labels[(tree_id >= NEIGHBOUR_ID0) & (tree_id < SHRUB_ID0)] = PART_CODES["neighbour"]
    on_target = tree_id == TARGET_ID
    labels[on_target & (label == LABEL_CODES["wood"])] = PART_CODES["target_wood"]
    labels[on_target & (label == LABEL_CODES["leaf"])] = PART_CODES["target_leaf"]
    if (labels == 255).any():
        raise RuntimeError(f"{int((labels == 255).sum())} points belong to no known part")

    truth = {
        **truth,
        "kind": kind,
        "species": spec_kind.target,
        "seed": seed,
        "step_deg": step_deg,
        "instrument": "riegl-vz400",
        "noise": True,
        "column": {
            "shape": "square",
            "centre_xy_m": [0.0, 0.0],
            "half_width_m": half,
            "z_min_m": z_lo,
            "z_max_m": z_hi,
            "margin_m": COLUMN_MARGIN_M,
        },
        "terrain": {
            "slope_deg": slope_deg,
            "aspect_deg": aspect_deg,
            "roughness_sd_m": rough_sd,
            "cell_m": TERRAIN_CELL_M,
        },
        "stations_m": [list(s.position_m) for s in stations],
        "neighbours": neighbours,
        "shrubs": shrubs,
        "litter": litter_counts,
        "points": int(len(pts)),
        "part_points": {name: int((labels == c).sum()) for name, c in PART_CODES.items()},
    }
    return FieldColumn(truth, pts, labels)


@cache
def cached_field_column(
    kind: str, seed: int = 0, step_deg: float = DEFAULT_STEP_DEG
) -> FieldColumn:
    """:func:`field_column`, made once per process and kind, seed and step (the arrays
    are read-only: copy them before changing them)."""
    col = field_column(kind, seed, step_deg)
    col.points.setflags(write=False)
    col.labels.setflags(write=False)
    return col
