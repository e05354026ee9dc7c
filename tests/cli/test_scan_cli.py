"""``treesim scan`` end to end: outputs, field names, and one-line errors on bad input."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import laspy
import numpy as np
import pytest
from plyfile import PlyData

from tests.conftest import box_arrays, cylinder_arrays, messages
from treesim.cli import main
from treesim.io.mesh import write_mesh

EXTRA_DIMS = {"station", "range_m", "incidence_deg", "label", "scan_line", "scan_column"}


@pytest.fixture()
def cylinder_obj(tmp_path: Path) -> Path:
    v, f = cylinder_arrays(0.15, 2.0, 256, (500000.0, 5500000.0, 300.0))
    return write_mesh(tmp_path / "cyl.obj", v, f)


def test_scan_writes_laz_with_standard_fields_and_extra_dims(cylinder_obj, tmp_path, capsys):
    out = tmp_path / "scan.laz"
    rc = main(
        [
            "scan",
            str(cylinder_obj),
            "-o",
            str(out),
            "--resolution-deg",
            "0.2",
            "--stations",
            "3",
            "--distance-m",
            "10",
            "--height-m",
            "1.5",
        ]
    )
    assert rc == 0
    printed = capsys.readouterr().out
    assert "points" in printed and "station" in printed
    las = laspy.read(out)
    assert EXTRA_DIMS <= set(las.point_format.extra_dimension_names)
    assert len(las.points) > 100
    assert set(np.unique(las["station"])) == {0, 1, 2}
    assert (np.asarray(las.return_number) == 1).all()
    assert np.asarray(las.intensity).max() > 0
    # 0.1 mm quantisation, georeferenced: points stay on the r = 0.15 m surface
    r = np.hypot(np.asarray(las.x) - 500000.0, np.asarray(las.y) - 5500000.0)
    assert np.abs(r - 0.15).max() < 0.15 * (1 - np.cos(np.pi / 256)) + 1e-4
    summary = json.loads(out.with_name("scan.json").read_text())
    assert summary["points"] == len(las.points)
    assert summary["rays_cast"] < summary["rays_full_fov"]
    assert len(summary["stations"]) == 3


def test_scan_writes_ply_with_double_coordinates_and_scalar_fields(cylinder_obj, tmp_path):
    out = tmp_path / "scan.ply"
    assert (
        main(
            [
                "scan",
                str(cylinder_obj),
                "-o",
                str(out),
                "--resolution-deg",
                "0.25",
                "--station",
                "500010,5500000,301.5",
            ]
        )
        == 0
    )
    v = PlyData.read(str(out))["vertex"].data
    assert v.dtype["x"] == np.float64 and v.dtype["y"] == np.float64
    assert EXTRA_DIMS | {"intensity", "return_number", "number_of_returns"} <= set(v.dtype.names)
    r = np.hypot(v["x"] - 500000.0, v["y"] - 5500000.0)
    assert np.abs(r - 0.15).max() < 0.15 * (1 - np.cos(np.pi / 256)) + 1e-6


def _run(args: list[str]) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "treesim.cli", *args], capture_output=True, text=True, timeout=120
    )


def _obj(tmp_path: Path, text: str, name: str = "bad.obj") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.mark.parametrize(
    "case",
    [
        "missing",
        "not_a_mesh",
        "garbage_obj",
        "empty_mesh",
        "nan_vertices",
        "negative_resolution",
        "inside",
        "bad_station",
        "bad_suffix",
    ],
)
def test_bad_input_gives_one_line_error_and_nonzero_exit(case, tmp_path, cylinder_obj):
    out = str(tmp_path / "o.laz")
    if case == "missing":
        args = ["scan", str(tmp_path / "nope.obj"), "-o", out]
    elif case == "not_a_mesh":
        args = ["scan", str(_obj(tmp_path, "1 2 3\n", "cloud.txt")), "-o", out]
    elif case == "garbage_obj":
        args = ["scan", str(_obj(tmp_path, "\x00\x01 this is not an obj \xff\n")), "-o", out]
    elif case == "empty_mesh":
        args = ["scan", str(_obj(tmp_path, "v 0 0 0\nv 1 0 0\nv 0 1 0\n")), "-o", out]
    elif case == "nan_vertices":
        text = "v 0 0 0\nv 1 0 0\nv nan 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\n"
        args = ["scan", str(_obj(tmp_path, text)), "-o", out]
    elif case == "negative_resolution":
        args = ["scan", str(cylinder_obj), "-o", out, "--resolution-deg", "-0.1"]
    elif case == "inside":
        v, f = box_arrays((-1, -1, 0), (1, 1, 2))
        mesh = write_mesh(tmp_path / "box.ply", v, f)
        args = ["scan", str(mesh), "-o", out, "--station", "0,0,1"]
    elif case == "bad_station":
        args = ["scan", str(cylinder_obj), "-o", out, "--station", "1,2"]
    else:
        args = ["scan", str(cylinder_obj), "-o", str(tmp_path / "o.docx")]
    res = _run(args)
    assert res.returncode != 0
    assert "Traceback" not in res.stderr
    lines = messages(res.stderr)
    assert len(lines) == 1 and lines[0].startswith("treesim: error:"), res.stderr
    assert not Path(out).exists()


def test_presets_are_listed():
    res = _run(["scan", "--list-presets"])
    assert res.returncode == 0
    assert "riegl-vz400" in res.stdout and "faro-focus3d-x330" in res.stdout


def test_nothing_in_range_writes_an_empty_cloud_and_says_why(tmp_path, capsys):
    v, f = box_arrays((100.0, -0.5, 0.0), (101.0, 0.5, 1.0))
    mesh = write_mesh(tmp_path / "far.ply", v, f)
    out = tmp_path / "none.laz"
    argv = ["scan", str(mesh), "-o", str(out), "--station", "0,0,0.5", "--max-range-m", "50"]
    assert main([*argv, "--resolution-deg", "1"]) == 0
    err = capsys.readouterr().err
    assert "no points" in err and "beyond 50 m from every station" in err
    assert laspy.read(out).header.point_count == 0
    assert json.loads(out.with_suffix(".json").read_text())["points"] == 0
