"""Small synthetic field clouds for the whole-loop tests: procedural saplings (4.2 m,
DBH 3.1 cm) scanned coarsely from three stations, written as PLY files."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from treesim.io import write_cloud
from treesim.models import generate_tree
from treesim.params import RunParams
from treesim.params import run_preset as preset
from treesim.report import ReportParams
from treesim.scan import ScannerSpec, ring_layout, scan
from treesim.scene import MeshPart, Scene

# The sapling's true DBH (3.06 cm: `tree.truth.json` of `treesim model generate --species
# sapling`; the manual's preset table rounds it to 3.1 cm), and half its last digit (0.01 cm)
README_SAPLING_DBH_M = 0.0306
README_DBH_ROUNDING_M = 0.05e-3
# The DBH the draft preset reconstructs from ``sapling0.ply`` (this fixture: 0.1°, 1 mm noise,
# 16 facets), measured 2026-11 on this code: -0.59 mm against the truth. The manual's
# draft figure (-0.3 mm) is for its own 0.02° cloud, so this one is pinned here instead.
SAPLING0_DRAFT_DBH_M = 0.03003
# pinned to 0.01 mm: half that digit is the whole tolerance
PINNED_DBH_ROUNDING_M = 0.005e-3


def sapling_cloud(seed: int, resolution_deg: float = 0.1):
    """A sapling's wood scanned from three stations 4 m out, with 1 mm range noise."""
    tree = generate_tree("sapling", seed=seed, leaves=False)
    v, f, _ = tree.mesh(16)
    scene = Scene([MeshPart(vertices=v, faces=f, label="wood")])
    lo, hi = scene.bounds
    stations = ring_layout(
        3,
        distance_m=4.0,
        height_m=1.5,
        centre_xy=((lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2),
        base_z_m=float(lo[2]),
    )
    spec = ScannerSpec(
        horizontal_resolution_deg=resolution_deg,
        vertical_resolution_deg=resolution_deg,
        range_noise_sd_m=0.001,
    )
    return tree, scan(scene, stations, spec, nthreads=2).cloud


@pytest.fixture(scope="session")
def saplings(tmp_path_factory) -> dict[str, Path]:
    """Two field clouds: ``sapling0.ply`` and ``sapling1.ply`` (seeds 0 and 1)."""
    d = tmp_path_factory.mktemp("saplings")
    out = {}
    for seed in (0, 1):
        _, cloud = sapling_cloud(seed)
        out[f"sapling{seed}"] = write_cloud(d / f"sapling{seed}.ply", cloud)
    return out


@pytest.fixture(scope="session")
def sapling0_qsm(tmp_path_factory) -> Path:
    """The exact cylinder table of ``sapling0``'s tree (its truth), as treesim's CSV."""
    from treesim.models import write_cylinders

    tree = generate_tree("sapling", seed=0, leaves=False)
    return write_cylinders(tmp_path_factory.mktemp("qsm") / "sapling0_truth.csv", tree.cylinders)


@pytest.fixture(scope="session")
def quick() -> RunParams:
    """The draft preset, reports without plots (drawing them was most of a run's time;
    tests/report draws them)."""
    return replace(preset("draft"), report=ReportParams(max_view_points=2_000, plots=False))
