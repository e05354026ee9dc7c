"""Wind (issue 26) in the steps and the run: files carry the wind's share of each point.

Oracles: the scan without any wind settings (at 0 m/s the files are the same, field for
field and point for point) and the wind model's definition of ``wind_displacement_m`` (a
magnitude: never negative; a 5 m/s wind moves a 4 m sapling's twigs, so not all zero).
"""

from __future__ import annotations

import numpy as np
import pytest

import treesim as ts
from treesim.io import write_mesh
from treesim.models import generate_tree
from treesim.models.cylinders import write_cylinders
from treesim.params import ScanParams
from treesim.steps import scan_files


@pytest.fixture(scope="module")
def sapling(tmp_path_factory):
    """The sapling preset's mesh and cylinder table, as `treesim model` writes them."""
    folder = tmp_path_factory.mktemp("sapling")
    tree = generate_tree("sapling", seed=0)
    v, f, label = tree.mesh(8)
    mesh = write_mesh(folder / "tree.ply", v, f, face_label=label)
    table = write_cylinders(folder / "tree.cylinders.csv", tree.cylinders)
    return mesh, table


def _params(**wind) -> ScanParams:
    spec = ts.ScannerSpec(horizontal_resolution_deg=0.5, vertical_resolution_deg=0.5, **wind)
    return ScanParams(scanner=spec, n_stations=2)


@pytest.mark.parametrize("suffix", [".laz", ".ply"])
def test_windy_scan_files_carry_wind_displacement(sapling, tmp_path, suffix):
    mesh, table = sapling
    windy = _params(wind_speed_m_s=5.0, wind_cylinders=str(table))
    step = scan_files([mesh], windy, tmp_path / f"w{suffix}")
    cloud = ts.read_cloud(step.outputs["cloud"])
    d = np.asarray(cloud.fields["wind_displacement_m"], dtype=np.float64)
    assert len(d) == len(cloud) > 100
    assert np.all(d >= 0.0) and np.any(d > 0.0)
    assert step.summary["wind"]["wind_speed_m_s"] == 5.0


def test_still_scan_files_are_unchanged_by_the_wind_settings(sapling, tmp_path):
    """Wind 0 with a table and a seed: the fields and points of a scan with no wind settings."""
    mesh, table = sapling
    plain = ts.read_cloud(scan_files([mesh], _params(), tmp_path / "a.ply").outputs["cloud"])
    still = _params(wind_speed_m_s=0.0, wind_seed=7, wind_cylinders=str(table))
    calm = ts.read_cloud(scan_files([mesh], still, tmp_path / "b.ply").outputs["cloud"])
    assert sorted(calm.fields) == sorted(plain.fields)
    assert "wind_displacement_m" not in calm.fields
    np.testing.assert_array_equal(calm.points, plain.points)


def test_run_flag_sets_the_scanner_wind(capsys):
    """`treesim run --wind-speed-m-s` sets the run's scanner wind (the run sways the
    reconstruction by its own table: tests/sweep/test_wind_sweep.py runs it)."""
    from treesim.cli import main

    assert main(["run", "--preset", "draft", "--wind-speed-m-s", "4", "--print-params"]) == 0
    assert "wind_speed_m_s = 4.0" in capsys.readouterr().out
    assert main(["run", "--preset", "draft", "--print-params"]) == 0
    assert "wind_speed_m_s = 0.0" in capsys.readouterr().out
