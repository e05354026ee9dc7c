"""A field plot becomes a digital twin (``treesim plot from-cloud``).

A plot cloud (a merged LAS/LAZ, or an E57 project whose scans carry their poses) goes
through these stages, each in its own module:

1. **Ground** (:mod:`treesim.plot.dtm`): a cloth simulation filter (CSF) classifies the
   ground; a DTM raster is built from it; every point gets its height above ground.
2. **Stems** (:mod:`treesim.plot.stems`): vertical, linear structure in a stripe above
   the ground is clustered into stems; a circle fitted to each stem's slab at 1.3 m gives
   its position and DBH (the *slab DBH*, a reference independent of the QSM).
3. **Trees**: every point above the ground goes to the stem it is reached from along the
   shortest path through the cloud (understory and strays to none); each tree's points are
   written as ``trees/tree_NNNN.laz`` with a ``tree_id`` field.
4. **Reconstruction**: each tree's cloud is reconstructed (a QSM) through
   :func:`treesim.batch.run_batch`, in parallel on the local or Dask executor, resumably:
   a second run reuses the trees already reconstructed from the same cloud and settings.
   Trees that fail are listed with the reason and left out of the twin, never silently.
   The twin's table of each tree (``trees/tree_NNNN.cylinders.csv``) is the QSM with its
   foot set on the DTM: the cylinders below the stem's lowest measured one (modelled from
   a cloud whose ground was taken away) are laid on the line from the stem's axis at the
   ground to that cylinder, so the tree stands on the terrain where its stem stands.
5. **The twin**: ``plot.toml`` with the DTM as terrain (``dtm.asc``) and every tree as its
   QSM (``source = "qsm"``) with its field cloud (``field_cloud``); ``trees.csv``; the
   whole cloud labelled (``plot_labelled.laz``: ``tree_id``, 0 for none, and ``ground``);
   ``from_cloud.json`` (every figure, what was left out and why, warnings) and a report
   (``report.html`` with ``map.png``, ``dbh_height.png``).

Coordinates stay the input's (a georeferenced plot keeps its coordinates; the numerics
run in a local float64 frame). A LAS/LAZ whose coordinate system declares feet is
converted to metres (``units="auto"``, the default); ``units="ft"`` or ``"us-ft"`` says so
for a cloud that declares nothing; trees implausibly large for metres are refused with a
message that asks.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..cloud import Cloud
from ..errors import InputFormatError
from ..params._fields import check_bounds, param
from .result import TWIN_FILES, TwinResult

__all__ = [
    "TWIN_FILES",
    "UNITS",
    "TwinParams",
    "TwinResult",
    "declared_units",
    "finished_twin",
    "plot_from_cloud",
    "stand_on_ground",
]

#: Length units a plot cloud may come in, and their size in metres.
UNITS: dict[str, float] = {"m": 1.0, "ft": 0.3048, "us-ft": 1200.0 / 3937.0}
#: Folder of the trees' field clouds, and of their reconstructions (a batch folder).
CLOUDS_DIR = "trees"
RECONSTRUCT_DIR = "reconstruct"
#: Beyond these, the trees of a cloud in metres are implausible (feet read as metres).
PLAUSIBLE_MEDIAN_DBH_M = 1.2
PLAUSIBLE_HEIGHT_M = 100.0
#: A QSM whose DBH differs from its stem's slab DBH by more than this share is flagged.
DBH_DISAGREEMENT = 0.10

Progress = Callable[[float, str], None]


@dataclass(frozen=True, kw_only=True)
class TwinParams:
    """Settings of :func:`plot_from_cloud` (``treesim plot from-cloud``).

    Examples
    --------
    >>> import treesim as ts
    >>> ts.TwinParams(units="ft", preset="draft").units
    'ft'
    """

    units: str = param(
        "auto",
        choices=("auto", *UNITS),
        help="the cloud's length unit (ft, us-ft: converted to metres; auto: the one its "
        "LAS coordinate system declares, else metres)",
    )
    dtm_cell_m: float = param(0.5, unit="m", gt=0.0, le=10.0, help="the DTM raster's cell size")
    min_tree_points: int = param(
        300, ge=10, le=10_000_000, help="trees with fewer points are left out"
    )
    preset: str = param(
        "standard",
        choices=("draft", "standard", "fine"),
        help="the run preset whose reconstruction settings each tree gets",
    )
    facets: int = param(16, ge=3, le=256, help="vertices per ring of the twin's tree tubes")

    def __post_init__(self) -> None:
        check_bounds(self)


def _say(progress: Progress | None) -> Progress:
    return progress or (lambda f, m: None)


#: GeoTIFF ProjLinearUnitsGeoKey codes (EPSG units) of the units treesim converts.
_GEOKEY_UNITS = {9001: "m", 9002: "ft", 9003: "us-ft"}
_PROJ_LINEAR_UNITS_KEY = 3076


def declared_units(path: str | Path) -> str | None:
    """The horizontal length unit a LAS/LAZ file's coordinate system declares (``m``,
    ``ft`` or ``us-ft``), from its WKT or GeoTIFF keys; None when it declares none (or is
    not LAS/LAZ).

    Examples
    --------
    >>> from treesim.twin import declared_units
    >>> declared_units("plot_in_state_plane_feet.laz")  # doctest: +SKIP
    'us-ft'
    """
    import re

    p = Path(path)
    if p.suffix.lower() not in (".las", ".laz"):
        return None
    import laspy

    try:
        with laspy.open(p) as f:
            vlrs = list(f.header.vlrs) + list(getattr(f.header, "evlrs", None) or [])
    except Exception:  # the reader proper says what is wrong with the file
        return None
    for v in vlrs:
        wkt = getattr(v, "string", None)
        if isinstance(wkt, str) and ("PROJCS" in wkt or "PROJCRS" in wkt):
            units = re.findall(r'(?:LENGTH)?UNIT\["([^"]+)"\s*,\s*([0-9.eE+-]+)', wkt)
            if units:
                factor = float(units[-1][1])
                for name, size in UNITS.items():
                    if abs(factor - size) < 1e-7:
                        return name
        keys = getattr(v, "geo_keys", None)
        if keys:
            for k in keys:
                if getattr(k, "id", None) == _PROJ_LINEAR_UNITS_KEY:
                    return _GEOKEY_UNITS.get(int(k.value_offset))
    return None


def _units(path: Path, units: str) -> tuple[str, list[str]]:
    """The unit to read the cloud in: the one given, or the one its CRS declares."""
    if units != "auto":
        return units, []
    found = declared_units(path)
    if found is None or found == "m":
        return "m", []
    return found, [
        f"{path.name}'s coordinate system is in {found}; its coordinates were converted to "
        "metres (give --units m to keep them as they are)"
    ]


def _read(path: Path, units: str) -> Cloud:
    from ..io import read_cloud

    cloud = read_cloud(path).validate()
    scale = UNITS[units]
    if scale != 1.0:
        stations = cloud.metadata.get("stations")
        cloud = Cloud(cloud.points * scale, cloud.fields, dict(cloud.metadata))
        if stations:
            cloud.metadata["stations"] = [[c * scale for c in s] for s in stations]
    return cloud


def _check_units(stems: list[Any], heights: np.ndarray, units: str) -> None:
    """Refuse trees too large for metres: a cloud in feet read as metres."""
    if not stems:
        return
    dbh = float(np.median([s.dbh_m for s in stems]))
    top = float(np.max(heights)) if len(heights) else 0.0
    if dbh > PLAUSIBLE_MEDIAN_DBH_M or top > PLAUSIBLE_HEIGHT_M:
        hint = (
            "is the cloud in feet? give --units ft (or us-ft)"
            if units == "m"
            else "check the cloud's units"
        )
        raise InputFormatError(
            f"the stems found are implausibly large for {units}: median DBH {dbh:.2f} m, "
            f"tallest tree {top:.1f} m; {hint}"
        )


def _ground(
    cloud: Cloud, tp: TwinParams, outdir: Path
) -> tuple[Any, np.ndarray, np.ndarray, dict[str, Any], list[str]]:
    from ..plot.dtm import ground_and_dtm, heights_above_ground

    t0 = time.perf_counter()
    ground, dtm, warnings = ground_and_dtm(cloud.points, cell_m=tp.dtm_cell_m)
    hag = heights_above_ground(cloud.points, dtm)
    dtm.write_asc(outdir / TWIN_FILES["dtm"])
    figures = {
        "points": int(len(cloud)),
        "ground_points": int(ground.sum()),
        "dtm_cell_m": float(dtm.cell_m),
        "dtm_shape": [int(v) for v in dtm.z.shape],
        "dtm_coverage": float(dtm.coverage),
        "time_s": time.perf_counter() - t0,
    }
    return dtm, ground, hag, figures, list(warnings)


def _stems_and_trees(
    cloud: Cloud, hag: np.ndarray, ground: np.ndarray, units: str
) -> tuple[list[Any], np.ndarray, np.ndarray, dict[str, Any], list[str]]:
    from ..plot.stems import detect_stems, segment_trees, tree_heights

    t0 = time.perf_counter()
    stems, warnings = detect_stems(cloud.points, hag)
    if not stems:
        raise InputFormatError(
            "no tree stems were found in the cloud (no vertical stem between about 1 and 3 m "
            "above the ground); is it a plot of trees, with its ground?"
            + (" " + "; ".join(warnings) if warnings else "")
        )
    labels = segment_trees(cloud.points, hag, stems, ground=ground)
    heights = tree_heights(hag, labels, len(stems))
    _check_units(stems, heights, units)
    figures = {
        "stems_found": len(stems),
        "points_in_trees": int((labels > 0).sum()),
        "time_s": time.perf_counter() - t0,
    }
    return stems, labels, heights, figures, list(warnings)


def _write_tree_clouds(
    cloud: Cloud,
    labels: np.ndarray,
    stems: list[Any],
    heights: np.ndarray,
    tp: TwinParams,
    outdir: Path,
) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """Each tree's points as ``trees/tree_NNNN.laz``; trees too small are left out."""
    from ..io import write_cloud

    folder = outdir / CLOUDS_DIR
    folder.mkdir(exist_ok=True)
    counts = np.bincount(labels, minlength=len(stems) + 1)
    kept, left = [], []
    for k, stem in enumerate(stems, start=1):
        row = {
            "tree_id": k,
            "x_m": float(stem.x_m),
            "y_m": float(stem.y_m),
            "slab_dbh_m": float(stem.dbh_m),
            "slab_arc_deg": float(stem.arc_deg),
            "base_xy_m": [float(stem.base_xyz_m[0]), float(stem.base_xyz_m[1])],
            "height_m": float(heights[k - 1]) if np.isfinite(heights[k - 1]) else None,
            "points": int(counts[k]),
        }
        if counts[k] < tp.min_tree_points:
            left.append({**row, "reason": f"only {counts[k]} points (< {tp.min_tree_points})"})
            continue
        sel = labels == k
        tree = Cloud(cloud.points[sel], {"tree_id": np.full(int(sel.sum()), k, np.int32)})
        name = f"tree_{k:04d}"
        write_cloud(folder / f"{name}.laz", tree)
        kept.append({**row, "id": name, "field_cloud": f"{CLOUDS_DIR}/{name}.laz"})
    return kept, left


def _reconstruct(
    kept: list[dict[str, Any]],
    tp: TwinParams,
    outdir: Path,
    executor: str,
    workers: int | None,
    threads: int | None,
    scheduler: str | None,
    progress: Any,
) -> dict[str, dict[str, Any]]:
    """Reconstruct every tree through the batch machinery; rows by tree id."""
    from ..batch import TreeInput, run_batch
    from ..params import run_preset

    inputs = [
        TreeInput(id=r["id"], path=outdir / r["field_cloud"], kind="reconstruct") for r in kept
    ]
    result = run_batch(
        inputs,
        run_preset(tp.preset),
        outdir / RECONSTRUCT_DIR,
        executor=executor,
        workers=workers,
        threads=threads,
        scheduler=scheduler,
        progress=progress,
    )
    return {str(r["id"]): r for r in result.rows}


def stand_on_ground(table: Any, ground_xy: np.ndarray, dtm: Any) -> tuple[Any, dict[str, Any]]:
    """The table with its stem's foot on the DTM (see the module notes) and what changed.

    The stem's cylinders (``branch_order`` 0, in order) before its first ``measured`` one
    are laid, in equal pieces, on the straight line from the ground under ``ground_xy``
    (the stem's axis at the ground: the lowest DTM height under the foot's circle) to that
    cylinder's start, with its radius; without such cylinders the first measured one is
    lengthened down to the ground. Branches keep their geometry.
    """
    from dataclasses import replace as _replace

    stem = np.flatnonzero(np.asarray(table.branch_order) == 0)
    if len(stem) == 0:
        return table, {"foot": "no stem in the table"}
    stem = stem[np.argsort(np.asarray(table.position_in_branch)[stem], kind="stable")]
    measured = [i for i in stem if str(table.tag[i]) == "measured"]
    first = int(measured[0]) if measured else int(stem[0])
    foot = [
        int(i) for i in stem if int(i) != first and list(stem).index(i) < list(stem).index(first)
    ]
    start = np.array(table.start, dtype=np.float64)
    axis = np.array(table.axis, dtype=np.float64)
    length = np.array(table.length_m, dtype=np.float64)
    radius = np.array(table.radius_m, dtype=np.float64)
    end_radius = np.array(table.end_radius_m, dtype=np.float64)
    r = float(radius[first])
    ang = np.linspace(0.0, 2.0 * np.pi, 16, endpoint=False)
    ring_x = ground_xy[0] + r * np.cos(ang)
    ring_y = ground_xy[1] + r * np.sin(ang)
    g = np.array([ground_xy[0], ground_xy[1], float(np.min(dtm.height_at(ring_x, ring_y)))])
    top = start[first] if foot else start[first] + axis[first] * length[first]
    seg = top - g
    total = float(np.linalg.norm(seg))
    if total < 1e-6:
        return table, {"foot": "already on the ground"}
    pieces = foot if foot else [first]
    for k, i in enumerate(pieces):
        start[i] = g + seg * (k / len(pieces))
        axis[i] = seg / total
        length[i] = total / len(pieces)
        if foot:
            radius[i] = end_radius[i] = r
    moved = _replace(
        table, start=start, axis=axis, length_m=length, radius_m=radius, end_radius_m=end_radius
    )
    return moved, {
        "foot_cylinders_relaid": len(foot),
        "foot_from_z_m": float(g[2]),
        "foot_to_z_m": float(top[2]),
        "foot_offset_m": float(np.linalg.norm(np.asarray(table.start)[int(stem[0])][:2] - g[:2])),
    }


def _twin_trees(
    kept: list[dict[str, Any]],
    rows: dict[str, dict[str, Any]],
    tp: TwinParams,
    outdir: Path,
    dtm: Any,
) -> tuple[list[Any], list[dict[str, Any]], list[dict[str, Any]], list[str]]:
    """PlotTrees of the reconstructed trees; the failures left out; DBH disagreements."""
    from ..models import qsm_mesh, read_cylinders, write_cylinders
    from ..plot import PlotTree
    from ..plot._sources import stem_base

    trees, table_rows, left, warnings = [], [], [], []
    for r in kept:
        row = rows.get(r["id"], {})
        if row.get("status") != "ok":
            reason = row.get("error") or row.get("status") or "not run"
            left.append({**r, "reason": f"reconstruction failed: {reason}"})
            continue
        qsm_path = f"{RECONSTRUCT_DIR}/{row['folder']}/cylinders.csv"
        table, foot = stand_on_ground(
            read_cylinders(outdir / qsm_path), np.asarray(r["base_xy_m"]), dtm
        )
        table_path = f"{CLOUDS_DIR}/{r['id']}.cylinders.csv"
        write_cylinders(outdir / table_path, table)
        v, _, _ = qsm_mesh(table, facets=tp.facets)
        base = stem_base(v)
        qsm_dbh = row.get("dbh_m")
        if qsm_dbh and abs(qsm_dbh / r["slab_dbh_m"] - 1.0) > DBH_DISAGREEMENT:
            warnings.append(
                f"tree {r['tree_id']}: the QSM's DBH {qsm_dbh * 100:.1f} cm differs from its "
                f"stem's slab circle {r['slab_dbh_m'] * 100:.1f} cm by more than "
                f"{DBH_DISAGREEMENT:.0%}"
            )
        trees.append(
            PlotTree(
                tree_id=int(r["tree_id"]),
                x_m=float(base[0]),
                y_m=float(base[1]),
                # the table stands where the tree grew (its foot on the DTM): placed as
                # it is, not seated on the terrain again
                z_m=float(base[2]),
                source="qsm",
                path=table_path,
                # the figures measured in the field cloud (the QSM's are in from_cloud.json)
                dbh_m=float(r["slab_dbh_m"]),
                height_m=r["height_m"],
                field_cloud=r["field_cloud"],
            )
        )
        table_rows.append(
            {
                **{k: v for k, v in r.items() if k not in ("id",)},
                "qsm_dbh_m": qsm_dbh,
                "qsm_height_m": row.get("height_m"),
                "volume_total_m3": row.get("volume_total_m3"),
                "volume_stem_m3": row.get("volume_stem_m3"),
                "qsm": qsm_path,
                "twin_table": table_path,
                **foot,
                "qsm_warnings": row.get("warnings"),
            }
        )
    return trees, table_rows, left, warnings


def _write_twin(
    cloud: Cloud, trees: list[Any], tp: TwinParams, outdir: Path, stand: dict[str, Any]
) -> Path:
    from ..plot import Plot, Terrain
    from ..plot.io import write_plot

    xy = cloud.points[:, :2]
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    centre = 0.5 * (lo + hi)
    radius = float(np.linalg.norm(xy - centre, axis=1).max())
    plot = Plot(
        trees,
        terrain=Terrain(kind="dtm", path=TWIN_FILES["dtm"], base_dir=str(outdir)),
        radius_m=max(radius, 0.5),
        centre_xy=(float(centre[0]), float(centre[1])),
        facets=tp.facets,
        base_dir=str(outdir),
    )
    return write_plot(outdir / TWIN_FILES["plot"], plot, trees_csv=TWIN_FILES["trees"], stand=stand)


def _posed_stations(cloud: Cloud) -> list[list[float]] | None:
    """The scanners' positions when the cloud's scans carry poses (an E57 project)."""
    stations = cloud.metadata.get("stations")
    posed = cloud.metadata.get("stations_posed")
    if not stations or (posed is not None and not all(posed)):
        return None
    return [[float(c) for c in s] for s in stations]


def _write_stations_csv(path: Path, stations: list[list[float]]) -> Path:
    from ..atomic import write_text

    rows = ["station,x_m,y_m,z_m"] + [
        f"{i},{x!r},{y!r},{z!r}" for i, (x, y, z) in enumerate(stations)
    ]
    return write_text(path, "\n".join(rows) + "\n")


#: Bytes read at each end of a plot's cloud for its fingerprint.
_FINGERPRINT_BYTES = 1 << 20


def _fingerprint(path: Path) -> dict[str, Any]:
    """What tells a plot's cloud from another for reuse: its size, modification time and
    the SHA-256 of its first and last MiB, and treesim's version."""
    import hashlib

    from .._version import __version__

    st = path.stat()
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        h.update(fh.read(_FINGERPRINT_BYTES))
        if st.st_size > _FINGERPRINT_BYTES:
            fh.seek(max(_FINGERPRINT_BYTES, st.st_size - _FINGERPRINT_BYTES))
            h.update(fh.read(_FINGERPRINT_BYTES))
    return {
        "size": int(st.st_size),
        "mtime_ns": int(st.st_mtime_ns),
        "ends_sha256": h.hexdigest(),
        "treesim": __version__,
    }


def _params_dict(tp: TwinParams) -> dict[str, Any]:
    return {k: getattr(tp, k) for k in tp.__dataclass_fields__}


def finished_twin(
    cloud_path: str | Path, outdir: str | Path, params: TwinParams | None = None
) -> TwinResult | None:
    """The twin already in ``outdir`` when it was made from this cloud with these
    settings, else None: its ``from_cloud.json`` names the same cloud (size, modification
    time, SHA-256 of its first and last MiB), the same :class:`TwinParams` and treesim
    version, and every file of the twin is there. Nothing is written.

    Parameters
    ----------
    cloud_path : str or Path
        The plot's cloud.
    outdir : str or Path
        The twin's folder.
    params : TwinParams, optional

    Examples
    --------
    >>> from treesim.twin import finished_twin
    >>> finished_twin("plot.laz", "twin/") is None  # doctest: +SKIP
    False
    """
    import json

    out = Path(outdir)
    try:
        figures = json.loads((out / TWIN_FILES["json"]).read_text(encoding="utf-8"))
        source = _fingerprint(Path(cloud_path))
    except (OSError, ValueError):
        return None
    if not isinstance(figures, dict) or figures.get("source") != source:
        return None
    if figures.get("params") != _params_dict(params or TwinParams()):
        return None
    trees = figures.get("trees") or []
    needed = [TWIN_FILES[k] for k in ("plot", "trees", "dtm", "labelled", "report")]
    needed += [str(r.get("twin_table", "")) for r in trees]
    if not trees or not all((out / n).is_file() for n in needed):
        return None
    plot_file = out / TWIN_FILES["plot"]
    left = figures.get("left_out") or []
    return TwinResult(out, plot_file, trees, left, list(figures.get("warnings") or []), figures)


def plot_from_cloud(
    cloud_path: str | Path,
    outdir: str | Path,
    params: TwinParams | None = None,
    *,
    executor: str = "local",
    workers: int | None = None,
    threads: int | None = None,
    scheduler: str | None = None,
    progress: Progress | None = None,
    batch_progress: Any = None,
) -> TwinResult:
    """Make a digital twin of a field plot from its point cloud (see the module notes).

    Parameters
    ----------
    cloud_path : str or Path
        The plot's cloud: LAS/LAZ, E57 (scans with poses), PLY or text.
    outdir : str or Path
        The twin's folder (created; a second run into it reuses finished trees;
        :func:`finished_twin` says whether the whole twin is there already).
    params : TwinParams, optional
    executor : {"inline", "local", "dask"}
        Where the trees are reconstructed (see :func:`treesim.run_batch`).
    workers : int, optional
    threads : int, optional
        Threads per tree (default cores // workers).
    scheduler : str, optional
        A running Dask scheduler's address.
    progress : callable(fraction, message), optional
        Stages of the plot.
    batch_progress : callable(BatchProgress), optional
        The reconstruction's progress, tree by tree.

    Returns
    -------
    TwinResult

    Raises
    ------
    InputFormatError
        A cloud with no ground, no stems, or trees implausibly large for its units.

    Examples
    --------
    >>> import treesim as ts
    >>> twin = ts.plot_from_cloud("plot.laz", "twin/")  # doctest: +SKIP
    >>> twin.plot_file  # doctest: +SKIP
    PosixPath('twin/plot.toml')
    """
    from ..io import write_cloud
    from ..jsonio import write_json
    from .report import write_twin_report

    tp = params or TwinParams()
    say = _say(progress)
    t0 = time.perf_counter()
    src = Path(cloud_path)
    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    # the twin's last word goes first: a folder half made again never passes for finished
    (out / TWIN_FILES["json"]).unlink(missing_ok=True)
    source = _fingerprint(src) if src.is_file() else None
    say(0.0, "reading")
    units, unit_warnings = _units(src, tp.units)
    cloud = _read(src, units)
    say(0.05, "ground")
    dtm, ground, hag, ground_fig, warnings = _ground(cloud, tp, out)
    warnings = unit_warnings + warnings
    say(0.15, "stems and trees")
    stems, labels, heights, stem_fig, w = _stems_and_trees(cloud, hag, ground, units)
    warnings += w
    labelled = Cloud(
        cloud.points,
        {"tree_id": labels.astype(np.int32), "ground": ground.astype(np.uint8)},
        {},
    )
    write_cloud(out / TWIN_FILES["labelled"], labelled)
    kept, left = _write_tree_clouds(cloud, labels, stems, heights, tp, out)
    say(0.25, f"reconstructing {len(kept)} trees")
    rows = (
        _reconstruct(kept, tp, out, executor, workers, threads, scheduler, batch_progress)
        if kept
        else {}
    )
    say(0.9, "writing the twin")
    trees, table_rows, failed, w = _twin_trees(kept, rows, tp, out, dtm)
    warnings += w
    left += failed
    if not trees:
        raise InputFormatError(
            f"no tree of {src.name} could be made into the twin: "
            + "; ".join(f"stem {r['tree_id']}: {r['reason']}" for r in left[:5])
        )
    stations = _posed_stations(cloud)
    if stations:
        _write_stations_csv(out / "stations.csv", stations)
    stand = {"kind": "from-cloud", "source": src.name, "units": units, "preset": tp.preset}
    plot_file = _write_twin(cloud, trees, tp, out, stand)
    figures = {
        "kind": "treesim.plot_from_cloud",
        "input": str(src),
        "source": source,
        "params": _params_dict(tp),
        "units": units,
        "stations": stations,
        "ground": ground_fig,
        "stems": stem_fig,
        "trees": table_rows,
        "left_out": left,
        "warnings": warnings,
        "time_total_s": time.perf_counter() - t0,
    }
    write_json(out / TWIN_FILES["json"], figures)
    result = TwinResult(out, plot_file, table_rows, left, warnings, figures)
    write_twin_report(result, dtm)
    say(1.0, "done")
    return result
