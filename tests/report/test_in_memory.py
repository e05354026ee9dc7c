"""Issue 25: a run hands its report the comparison in memory; the report must hold what
reading the written files gives (the oracle: :meth:`ReportData.from_file`)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tests.report.test_report import _case
from treesim.cloud import Cloud
from treesim.compare import compare, write_comparison
from treesim.report.data import ReportData
from treesim.report.profile import occlusion_profile


def _same(a: ReportData, b: ReportData) -> None:
    for f in dataclasses.fields(ReportData):
        if f.name == "station_within":  # what the comparison knew: from memory only
            continue
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
            assert x.dtype == y.dtype and np.array_equal(x, y), f.name  # bit for bit
        else:
            assert x == y, f.name


@pytest.mark.parametrize("far", [False, True])
@pytest.mark.parametrize("suffix", [".laz", ".las"])
def test_in_memory_report_data_is_what_the_files_give_back(tmp_path, suffix, far):
    cloud, scene = _case()
    if far:  # georeferenced: offsets far from zero, rounding at 0.1 mm matters
        shift = np.array([512_345.678912, 6_712_345.123456, 123.456789])
        cloud = Cloud(cloud.points + shift, cloud.fields, {"label_names": {7: "twig"}})
        ref = Cloud(cloud.points[::3] + 0.0031, {}, {})
        res = compare(cloud, ref)
    else:
        res = compare(cloud, scene)
    write_comparison(res, tmp_path, formats=(suffix,))
    got = ReportData.from_written(res, tmp_path)
    want = ReportData.from_file(tmp_path)
    assert not np.array_equal(got.cloud_points, res.cloud.points)  # rounded, as stored
    _same(got, want)


def test_in_memory_report_data_reads_ply_files(tmp_path):
    cloud, scene = _case()
    res = compare(cloud, scene)
    write_comparison(res, tmp_path, formats=(".ply", ".laz"))
    _same(ReportData.from_written(res, tmp_path), ReportData.from_file(tmp_path))


@pytest.mark.parametrize("far", [False, True])
def test_profile_from_the_comparisons_station_distances_is_the_files_profile(tmp_path, far):
    """Reference points at τ ± a fraction of the LAS rounding from each station's points:
    where the comparison's own distances cannot tell, the profile must query, and its
    numbers are those of the profile of the saved files."""
    rng = np.random.default_rng(7)
    tau = 0.01
    ref = rng.uniform(0, 1, (4000, 3)) * [0.6, 0.6, 3.0]
    offsets = rng.normal(size=(3, 4000, 3))
    offsets /= np.linalg.norm(offsets, axis=2, keepdims=True)
    radius = tau + rng.uniform(-3e-4, 3e-4, (3, 4000, 1))  # many within the rounding
    pts = (ref[None] + offsets * radius)[:, ::2].reshape(-1, 3)
    station = np.repeat(np.arange(3, dtype=np.uint16), 2000)
    shift = np.array([512_345.678912, 6_712_345.123456, 123.456789]) if far else 0.0
    res = compare(Cloud(pts + shift, {"station": station}, {}), Cloud(ref + shift), tolerance_m=tau)
    assert sorted(res.station_distance_m) == [0, 1, 2]
    write_comparison(res, tmp_path, formats=(".laz",))
    got = ReportData.from_written(res, tmp_path)
    assert got.station_within is not None
    known = np.concatenate([k for k, _ in got.station_within.values()])
    assert 0.2 < known.mean() < 0.99  # some answered from memory, some queried
    assert occlusion_profile(got) == occlusion_profile(ReportData.from_file(tmp_path))
    # and the comparison's own per-station coverage is what its bits say
    for code, entry in res.by_station.items():
        within = np.unpackbits(res.station_distance_m[code][0], count=len(ref))
        assert entry["coverage"] == float(within.mean())
