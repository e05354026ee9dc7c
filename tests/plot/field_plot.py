"""A field plot with exact truth: a generated stand on a slope, scanned from known stations
with the RIEGL VZ-400's noise, written as a field team would hold it (an E57 project whose
scans carry their poses, and a merged LAZ).

Used by the twin and validation tests and by ``benchmarks/bench_twin.py``.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass(frozen=True)
class FieldPlot:
    """The files of a simulated field campaign and its truth."""

    folder: Path
    plot_file: Path  # the truth's plot.toml
    e57: Path | None  # the scans with their poses (None without pye57)
    laz: Path  # the same points merged, with station and tree_id fields
    stations: list[list[float]]
    truth: list[dict]  # per tree: tree_id, x_m, y_m, base_z_m, dbh_m, height_m, ...


def station_ring(plot, n: int, height_m: float = 1.5) -> list[tuple[float, float, float]]:
    """The plot centre and ``n - 1`` stations on a ring at 60 % of the radius."""
    cx, cy = plot.centre_xy
    pts = [(cx, cy)]
    for k in range(n - 1):
        a = 2 * math.pi * (k + 0.5) / (n - 1)
        pts.append((cx + 0.6 * plot.radius_m * math.cos(a), cy + 0.6 * plot.radius_m * math.sin(a)))
    return [(x, y, float(plot.terrain.height_at(x, y)) + height_m) for x, y in pts]


def make_field_plot(
    folder: Path,
    *,
    n_trees: int = 30,
    radius_m: float = 12.0,
    slope_deg: float = 15.0,
    n_stations: int = 5,
    resolution_deg: float = 0.1,
    species: str = "aspen:0.5,balsam-fir:0.5",
    seed: int = 1,
    facets: int = 32,
) -> FieldPlot:
    """Generate, scan and write a field plot into ``folder`` (reused when already there
    with the same settings)."""
    import treesim as ts
    from treesim.io import write_cloud
    from treesim.params import scan_params
    from treesim.plot.generate import StandParams

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    settings = dict(
        n_trees=n_trees, radius_m=radius_m, slope_deg=slope_deg, n_stations=n_stations,
        resolution_deg=resolution_deg, species=species, seed=seed, facets=facets,
    )  # fmt: skip
    done = folder / "field.json"
    if done.is_file() and json.loads(done.read_text())["settings"] == settings:
        d = json.loads(done.read_text())
        e57 = folder / "field.e57"
        return FieldPlot(
            folder, folder / "truth" / "plot.toml", e57 if e57.is_file() else None,
            folder / "field.laz", d["stations"], d["truth"],
        )  # fmt: skip
    stems_per_ha = n_trees / (math.pi * radius_m**2) * 10_000
    sp = StandParams(
        species=species, stems_per_ha=stems_per_ha, radius_m=radius_m, seed=seed,
        slope_deg=slope_deg, aspect_deg=90.0, facets=facets, leaves=False,
    )  # fmt: skip
    plot, stand = sp.generate()
    (folder / "truth").mkdir(exist_ok=True)
    plot_file = ts.write_plot(folder / "truth" / "plot.toml", plot, stand=stand)
    stations = station_ring(plot, n_stations)
    params = scan_params({}, instrument="riegl-vz400", noise=True, resolution_deg=resolution_deg)
    res = ts.scan_plot(plot, stations, params)
    cloud = res.cloud
    cloud.metadata["stations"] = [list(map(float, s)) for s in stations]
    laz = write_cloud(folder / "field.laz", cloud)
    e57 = None
    try:
        import pye57  # noqa: F401

        e57 = write_cloud(folder / "field.e57", cloud)
    except ImportError:
        pass
    truth = [plot.truth(t) for t in plot.tree_ids]
    done.write_text(
        json.dumps(
            {"settings": settings, "stations": cloud.metadata["stations"], "truth": truth},
            default=float,
        )
    )
    return FieldPlot(folder, plot_file, e57, laz, cloud.metadata["stations"], truth)


#: The smallest field plot that still makes a twin: 4 trees on a 10° slope, scanned from 2
#: stations at 0.25°. test_twin_inputs, test_twin_many and tests/service/test_twin_jobs all
#: use this one plot; :func:`small_field_plot` makes it once per test run.
SMALL_PLOT = dict(
    n_trees=4, radius_m=5.0, slope_deg=10.0, n_stations=2, resolution_deg=0.25, facets=16
)  # fmt: skip


def run_folder(tmp_path_factory) -> Path:
    """A temporary folder of this test run shared by all its pytest-xdist workers (each
    worker's base folder is ``popen-gwN`` inside the run's own), and by no other run."""
    base = tmp_path_factory.getbasetemp()
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base


def small_field_plot(tmp_path_factory) -> FieldPlot:
    """The :data:`SMALL_PLOT` field plot, made by the first test file of this run that asks
    for it (the others wait for it under a file lock, then read it: it is everyone's input,
    so a test copies what it changes)."""
    from filelock import FileLock

    folder = run_folder(tmp_path_factory) / "small-field-plot"
    with FileLock(f"{folder}.lock"):
        return make_field_plot(folder, **SMALL_PLOT)


def match(found_xy: np.ndarray, true_xy: np.ndarray, within_m: float) -> np.ndarray:
    """For each true position, the index of the found one within ``within_m`` (nearest,
    each found one used once), or -1."""
    out = np.full(len(true_xy), -1)
    if len(found_xy) == 0:
        return out
    d = np.linalg.norm(true_xy[:, None, :] - found_xy[None, :, :], axis=2)
    used: set[int] = set()
    for i, j in sorted(
        ((i, int(np.argmin(d[i]))) for i in range(len(true_xy))), key=lambda ij: d[ij[0], ij[1]]
    ):
        if d[i, j] <= within_m and j not in used:
            out[i] = j
            used.add(j)
    return out
