"""What a report shows: the comparison's figures and its per-point distances."""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .._version import software_versions
from ..cloud import LABEL_NAMES
from ..compare import DISTANCE_FIELD, Comparison
from ..errors import InputFormatError


@functools.cache
def _versions(*extra: str) -> tuple[tuple[str, str], ...]:
    """:func:`~treesim._version.software_versions`, looked up once per process (each
    look-up reads the installed packages' metadata: tens of milliseconds a report)."""
    return tuple(software_versions(*extra).items())


def report_software(*extra: str) -> dict[str, str]:
    """The versions a report records (a new dict each call; see :func:`_versions`).

    Examples
    --------
    >>> report_software("matplotlib")["treesim"] == software_versions()["treesim"]
    True
    """
    return dict(_versions(*extra))


#: Keys ``comparison.json`` must have for a report to be drawn.
REQUIRED_KEYS = ("accuracy", "completeness", "hausdorff_m", "chamfer_m", "tolerance_m", "coverage")


@dataclass
class ReportData:
    """A comparison's figures and per-point distances, in the shape the report needs.

    Attributes
    ----------
    summary : dict
        The content of ``comparison.json`` (figures, parameters, inputs, software).
    cloud_points : (n, 3) float64
        The compared cloud, input coordinates.
    cloud_distance_m : (n,) float64
        Accuracy: distance of each cloud point to the reference.
    cloud_station, cloud_label : (n,) int64 or None
    reference_points : (m, 3) float64
        Reference samples (mesh) or points (cloud).
    reference_distance_m : (m,) float64
        Completeness: distance of each reference sample to the cloud.
    reference_label : (m,) int64 or None
    label_names : dict of int -> str
    source_dir : Path or None
        Where ``comparison.json`` was read from.
    station_within : dict of int -> ((m,) bool, (m,) bool), optional
        Per station, what is already known of whether each reference point is within τ
        of that station's points: ``(known, within)`` (:meth:`from_written`, from the
        comparison's own per-station distances); the occlusion profile queries only the
        points not known.
    """

    summary: dict[str, Any]
    cloud_points: np.ndarray
    cloud_distance_m: np.ndarray
    cloud_station: np.ndarray | None
    cloud_label: np.ndarray | None
    reference_points: np.ndarray
    reference_distance_m: np.ndarray
    reference_label: np.ndarray | None
    label_names: dict[int, str]
    source_dir: Path | None = None
    station_within: dict[int, tuple[np.ndarray, np.ndarray]] | None = None

    @property
    def origin(self) -> np.ndarray:
        """(3,) float64 display origin: the frame origin when the data is georeferenced-far
        from zero (coordinates beyond 10 km), else zeros."""
        o = np.asarray(
            self.summary.get("parameters", {}).get("frame_origin_m") or (0.0, 0.0, 0.0),
            dtype=np.float64,
        )
        return o if np.abs(o).max() > 1e4 else np.zeros(3)

    @classmethod
    def from_comparison(
        cls, comparison: Comparison, *, inputs: dict[str, Any] | None = None
    ) -> ReportData:
        """Build from an in-memory :class:`~treesim.compare.Comparison`."""
        from ..jsonio import json_ready as _json_ready

        summary = _json_ready(
            {
                "kind": "treesim.comparison",
                **comparison.to_dict(),
                "inputs": dict(inputs or {}),
                "software": report_software(),
            }
        )
        station = comparison.cloud.fields.get("station")
        label = comparison.cloud.fields.get("label")
        return cls(
            summary=summary,
            cloud_points=comparison.cloud.points,
            cloud_distance_m=comparison.accuracy_m,
            cloud_station=None if station is None else np.asarray(station).astype(np.int64),
            cloud_label=None if label is None else np.asarray(label).astype(np.int64),
            reference_points=comparison.reference_points,
            reference_distance_m=comparison.completeness_m,
            reference_label=comparison.reference_label,
            label_names=dict(comparison.label_names),
        )

    @classmethod
    def from_written(cls, comparison: Comparison, folder: str | Path) -> ReportData:
        """What :meth:`from_file` reads from ``folder``, which :func:`~treesim.compare.\
write_comparison` has just written from ``comparison`` (LAS/LAZ distance clouds), built
        from the arrays in memory instead of decompressing the clouds: coordinates rounded
        to the files' scale and offsets (read from their headers) exactly as a reader gives
        them back, fields and label names as stored. The same values bit for bit; any
        other folder (PLY clouds, a count that does not match) is read from its files.

        Examples
        --------
        >>> import treesim as ts
        >>> c = ts.compare(ts.read_cloud("scan.laz"), "tree.ply")  # doctest: +SKIP
        >>> _ = ts.write_comparison(c, "out/vs_mesh", formats=(".laz",))  # doctest: +SKIP
        >>> ReportData.from_written(c, "out/vs_mesh").cloud_points.shape  # doctest: +SKIP
        (135634, 3)
        """
        p = Path(folder)
        summary = _read_summary(p / "comparison.json")
        outputs = summary.get("outputs", {})
        clouds = (comparison.distance_cloud(), comparison.reference_cloud())
        points, scales = [], []
        for kind, cloud in zip(("cloud_distances", "reference_distances"), clouds, strict=True):
            name = outputs.get(f"{kind}_laz") or outputs.get(f"{kind}_las")
            if f"{kind}_ply" in outputs or name is None:
                return cls.from_file(p)  # read as from_file would: its first choice, PLY
            got = _as_las_gives_back(cloud.points, p / name)
            if got is None:
                return cls.from_file(p)
            points.append(got[0])
            scales.append(got[1])
        return cls._of_clouds(
            summary,
            clouds,
            points,
            p,
            station_within=_station_within(comparison, summary, max(scales), clouds),
        )

    @classmethod
    def from_file(cls, path: str | Path) -> ReportData:
        """Read ``comparison.json`` (or the folder holding it) and its distance clouds."""
        from ..io import read_cloud

        p = Path(path)
        if p.is_dir():
            p = p / "comparison.json"
        summary = _read_summary(p)
        outputs = summary.get("outputs", {})

        def find(kind: str) -> Path:
            for key in (f"{kind}_ply", f"{kind}_laz", f"{kind}_las"):
                if key in outputs and (p.parent / outputs[key]).is_file():
                    return p.parent / outputs[key]
            for suffix in (".ply", ".laz", ".las"):
                if (p.parent / f"{kind}{suffix}").is_file():
                    return p.parent / f"{kind}{suffix}"
            raise InputFormatError(
                f"{p.parent} lacks {kind}.ply/.laz, which 'treesim compare' writes beside "
                "comparison.json; copy them along or run the comparison again"
            )

        cloud = read_cloud(find("cloud_distances"))
        ref = read_cloud(find("reference_distances"))
        for c, name in ((cloud, "cloud_distances"), (ref, "reference_distances")):
            if DISTANCE_FIELD not in c.fields:
                raise InputFormatError(f"{name} in {p.parent} has no {DISTANCE_FIELD} field")
        return cls._of_clouds(summary, (cloud, ref), (cloud.points, ref.points), p.parent)

    @classmethod
    def _of_clouds(
        cls,
        summary: dict[str, Any],
        clouds: tuple[Any, Any],
        points: Sequence[np.ndarray],
        source_dir: Path,
        station_within: dict[int, tuple[np.ndarray, np.ndarray]] | None = None,
    ) -> ReportData:
        """The report's data from the two distance clouds (accuracy, completeness) as a
        reader gives them, their ``points`` as read: fields as int64 and float64, label
        names from the reference's metadata, then the cloud's."""
        cloud, ref = clouds
        names = dict(LABEL_NAMES)
        for c in (ref, cloud):
            _update_label_names(names, c.metadata.get("label_names"))

        def opt(c: Any, name: str) -> np.ndarray | None:
            v = c.fields.get(name)
            return None if v is None else np.asarray(v).astype(np.int64)

        return cls(
            summary=summary,
            cloud_points=points[0],
            cloud_distance_m=np.asarray(cloud.fields[DISTANCE_FIELD], dtype=np.float64),
            cloud_station=opt(cloud, "station"),
            cloud_label=opt(cloud, "label"),
            reference_points=points[1],
            reference_distance_m=np.asarray(ref.fields[DISTANCE_FIELD], dtype=np.float64),
            reference_label=opt(ref, "label"),
            label_names=names,
            source_dir=source_dir,
            station_within=station_within,
        )


def _read_summary(p: Path) -> dict[str, Any]:
    """``comparison.json``, checked to be a comparison a report can draw."""
    if not p.is_file():
        raise InputFormatError(
            f"{p} not found; run 'treesim compare CLOUD REFERENCE -o OUTDIR' first, "
            "then 'treesim report OUTDIR'"
        )
    try:
        summary = json.loads(p.read_text())
    except (OSError, ValueError) as exc:
        raise InputFormatError(f"{p} could not be read as JSON: {exc}") from exc
    missing = [k for k in REQUIRED_KEYS if k not in summary] if isinstance(summary, dict) else []
    if not isinstance(summary, dict) or missing:
        raise InputFormatError(f"{p} is not a treesim comparison (missing {', '.join(missing)})")
    return summary


def _update_label_names(names: dict[int, str], given: Any) -> None:
    """``names`` updated with a cloud's ``label_names`` metadata, as a reader takes them."""
    if isinstance(given, dict):
        try:
            names.update({int(k): str(v) for k, v in given.items()})
        except (TypeError, ValueError):
            pass


def _station_within(
    comparison: Comparison, summary: dict[str, Any], scale: float, clouds: tuple[Any, Any]
) -> dict[int, tuple[np.ndarray, np.ndarray]] | None:
    """What the comparison's per-station distances (its own coordinates) say of the
    saved, rounded ones: rounding moves each point by at most √3/2 × ``scale``, so a
    distance by at most √3 × ``scale`` (float rounding of the coordinates' size added):
    a sample within τ less that margin is within τ after rounding, one beyond τ plus it
    is not; those between are not known. None where the comparison kept no distances
    far enough beyond τ."""
    from ..compare import STATION_DISTANCE_BAND_M

    given = comparison.station_distance_m
    if not given:
        return None
    tau = float(summary["tolerance_m"])
    if not (math.isfinite(tau) and tau > 0 and math.isfinite(scale)):
        return None
    size = max(float(np.abs(c.points).max(initial=0.0)) for c in clouds)
    margin = math.sqrt(3.0) * scale * (1 + 1e-9) + 1e-12 * size + 1e-12
    if margin >= STATION_DISTANCE_BAND_M:  # an infinite distance would say nothing
        return None
    n = len(comparison.reference_points)
    out = {}
    for code, (packed, band, d) in given.items():
        # outside the band a distance is τ − band or nearer, or τ + band or farther
        within = np.unpackbits(packed, count=n).astype(bool)
        known = np.ones(n, dtype=bool)
        known[band] = (d <= tau - margin) | (d > tau + margin)
        within[band] = d <= tau - margin
        out[int(code)] = (known, within)
    return out


def _as_las_gives_back(points: np.ndarray, path: Path) -> tuple[np.ndarray, float] | None:
    """``points`` as the LAS/LAZ file ``path`` (written from them) gives them back: the
    writer's integers (rounded at the header's scale from its offsets) scaled and offset
    as :func:`treesim.io.las.read_las` does, and the largest scale; None where the header
    cannot be read or holds another number of points."""
    import laspy

    try:
        with open(path, "rb") as fh:
            header = laspy.LasHeader.read_from(fh)
    except (OSError, ValueError, laspy.errors.LaspyException):
        return None
    if int(header.point_count) != len(points):
        return None
    scales = np.asarray(header.scales, dtype=np.float64)
    offsets = np.asarray(header.offsets, dtype=np.float64)
    counts = np.rint((np.asarray(points, dtype=np.float64) - offsets) / scales)
    return counts.astype(np.int32).astype(np.float64) * scales + offsets, float(scales.max())
