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


def _same(a: ReportData, b: ReportData) -> None:
    for f in dataclasses.fields(ReportData):
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
