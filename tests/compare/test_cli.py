"""``treesim compare``: files written, names scripts rely on, one-line errors.

These call ``treesim.cli.main``; they need ``treesim.cli.compare.register`` wired into
``treesim.cli.build_parser``.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.compare.shapes import centroids, open_cylinder, sample_faces
from tests.conftest import messages
from treesim.cli import main
from treesim.cloud import Cloud
from treesim.io import read_cloud, write_cloud
from treesim.io.mesh import write_mesh

REQUIRED_STATS = ("n", "mean_m", "rms_m", "median_m", "p95_m", "p99_m", "max_m")


@pytest.fixture(scope="module")
def half_cylinder(tmp_path_factory):
    """A mesh file and a cloud file covering half of it, from two 'stations'."""
    d = tmp_path_factory.mktemp("cmp")
    v, f = open_cylinder(0.2, 1.0, 256)
    mesh = write_mesh(d / "cyl.ply", v, f)
    half = centroids(v, f)[:, 0] > 0
    pts = sample_faces(v, f, half, 6000, seed=3)
    cloud = Cloud(
        pts,
        {
            "station": (pts[:, 1] > 0).astype(np.uint16),
            "label": np.ones(len(pts), np.uint8),
        },
        {"label_names": {0: "other", 1: "wood", 2: "leaf", 3: "ground"}},
    )
    cloud_path = write_cloud(d / "scan.laz", cloud)
    (d / "scan.json").write_text(
        json.dumps(
            {
                "scanner": {"horizontal_resolution_deg": 0.04, "vertical_resolution_deg": 0.04},
                "models_active": [],
                "stations": [
                    {"index": 0, "position_m": [5.0, -5.0, 0.5], "points": 3000},
                    {"index": 1, "position_m": [5.0, 5.0, 0.5], "points": 3000},
                ],
            }
        )
    )
    return d, mesh, cloud_path


def test_compare_writes_comparison_json(half_cylinder, tmp_path, capsys):
    d, mesh, cloud = half_cylinder
    out = tmp_path / "out"
    assert main(["compare", str(cloud), str(mesh), "-o", str(out), "--seed", "3"]) == 0
    printed = capsys.readouterr().out
    assert "accuracy" in printed and "completeness" in printed and "Hausdorff" in printed
    summary = json.loads((out / "comparison.json").read_text())
    for key in ("accuracy", "completeness"):
        assert set(REQUIRED_STATS) <= set(summary[key])
        assert isinstance(summary[key]["n"], int)
    for key in ("hausdorff_m", "chamfer_m", "tolerance_m", "coverage"):
        assert isinstance(summary[key], float)
    assert 0.4 < summary["coverage"] < 0.6  # half the surface is missing
    assert summary["accuracy"]["max_m"] < 1e-4  # LAZ stores 0.1 mm steps
    assert summary["reference"]["kind"] == "mesh"
    # an open mesh hides nothing: checked, nothing dropped, nothing said
    hidden = summary["reference"]["hidden_surface"]
    assert (hidden["parts"], hidden["closed_parts"], hidden["samples_dropped"]) == (1, 0, 0)
    assert "hidden surface" not in printed
    assert summary["parameters"]["seed"] == 3
    assert summary["parameters"]["hidden_surface"] == "drop"
    assert summary["parameters"]["tolerance_rule"] == "3 × point_spacing_m"
    assert set(summary["by_station"]) == {"0", "1"}
    assert "wood" in summary["by_label"]
    assert summary["inputs"]["scan"]["stations"][1]["position_m"] == [5.0, 5.0, 0.5]
    assert summary["software"]["treesim"]
    for name in ("cloud_distances", "reference_distances"):
        for suffix in (".ply", ".laz"):
            c = read_cloud(out / f"{name}{suffix}")
            assert "scalar_distance" in c.fields
    assert len(read_cloud(out / "cloud_distances.ply")) == 6000


def test_compare_options_and_cloud_reference(half_cylinder, tmp_path):
    d, mesh, cloud = half_cylinder
    ref = Cloud(read_cloud(cloud).points)
    ref_path = write_cloud(tmp_path / "ref.xyz", ref)
    out = tmp_path / "out"
    rc = main(["compare", str(cloud), str(ref_path), "-o", str(out), "--tolerance-m", "0.01"])
    assert rc == 0
    summary = json.loads((out / "comparison.json").read_text())
    assert summary["reference"]["kind"] == "cloud"
    assert summary["tolerance_m"] == 0.01
    assert summary["parameters"]["tolerance_rule"] == "given"
    assert summary["coverage"] == 1.0
    # a PLY without faces is a cloud; with faces, a mesh
    out2 = tmp_path / "out2"
    ply_cloud = write_cloud(tmp_path / "ref.ply", ref)
    assert main(["compare", str(cloud), str(ply_cloud), "-o", str(out2)]) == 0
    assert json.loads((out2 / "comparison.json").read_text())["reference"]["kind"] == "cloud"
    out3 = tmp_path / "out3"
    assert (
        main(["compare", str(cloud), str(mesh), "-o", str(out3), "--sample-spacing-m", "0.004"])
        == 0
    )
    s3 = json.loads((out3 / "comparison.json").read_text())
    assert s3["parameters"]["sample_spacing_m"] == pytest.approx(0.004, rel=1e-3)
    assert s3["reference"]["samples"] == pytest.approx(s3["reference"]["area_m2"] / 0.004**2, abs=1)


@pytest.mark.parametrize(
    ("make", "words"),
    [
        ("missing", "not found"),
        ("empty", "no points"),
        ("nan", "NaN"),
        ("single", "single point"),
        ("three", "only 3 points"),
        ("badtol", "--tolerance-m: expected a number > 0"),
    ],
)
def test_compare_errors_are_one_line(half_cylinder, tmp_path, capsys, make, words):
    d, mesh, cloud = half_cylinder
    args = [str(cloud), str(mesh)]
    if make == "missing":
        args[0] = str(tmp_path / "nope.laz")
    elif make == "empty":
        (tmp_path / "e.xyz").write_text("x y z\n")
        args[0] = str(tmp_path / "e.xyz")
    elif make == "nan":
        (tmp_path / "n.xyz").write_text("0 0 0\nnan 1 1\n1 1 1\n")
        args[0] = str(tmp_path / "n.xyz")
    elif make == "single":
        (tmp_path / "s.xyz").write_text("0 0 0\n")
        args[0] = str(tmp_path / "s.xyz")
    elif make == "three":
        (tmp_path / "t.xyz").write_text("0 0 0\n1 0 0\n0 1 0\n")
        args[0] = str(tmp_path / "t.xyz")
    else:
        args += ["--tolerance-m", "-1"]
    try:
        rc = main(["compare", *args, "-o", str(tmp_path / "o")])
    except SystemExit as exc:  # a usage error
        rc = exc.code
    err = "\n".join(messages(capsys.readouterr().err))
    assert rc == (2 if make == "badtol" else 1)
    assert err.startswith("treesim: error:") and "\n" not in err
    assert words in err
    assert not (tmp_path / "o").exists()  # nothing written
