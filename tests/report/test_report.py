"""The report: report.json, PNG plots, one offline HTML page that renders in Chromium."""

from __future__ import annotations

import html
import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from tests.compare.shapes import centroids, open_cylinder, sample_faces
from tests.report.browser import open_page
from treesim.cli import main
from treesim.cloud import LABEL_CODES, Cloud
from treesim.compare import compare, write_comparison
from treesim.report import PNG_FILES, ReportParams, build_report, summary_paragraph
from treesim.report.text import length
from treesim.scene import MeshPart, Scene

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _case():
    """Two stations see the east half of a cylinder (wood) and a quarter of the west (leaf)."""
    r = 0.2
    v, f = open_cylinder(r, 1.2, 256)
    c = centroids(v, f)
    east = c[:, 0] > 0
    scene = Scene(
        [
            MeshPart(vertices=v, faces=f[east], label="wood", name="east"),
            MeshPart(vertices=v, faces=f[~east], label="leaf", name="west"),
        ]
    )
    p0 = sample_faces(v, f, east, 5000, seed=1)
    p1 = sample_faces(v, f, (~east) & (c[:, 1] > 0), 2500, seed=2)
    p1 = p1 + np.random.default_rng(4).normal(scale=0.002, size=p1.shape)
    cloud = Cloud(
        np.concatenate([p0, p1]),
        {
            "station": np.repeat(np.array([0, 1], np.uint16), [5000, 2500]),
            "label": np.repeat(
                np.array([LABEL_CODES["wood"], LABEL_CODES["leaf"]], np.uint8), [5000, 2500]
            ),
        },
    )
    return cloud, scene


@pytest.fixture(scope="module")
def report_dir(tmp_path_factory):
    cloud, scene = _case()
    res = compare(cloud, scene)
    d = tmp_path_factory.mktemp("report")
    scan = {
        "scanner": {"horizontal_resolution_deg": 0.04, "vertical_resolution_deg": 0.04},
        "models_active": ["range_noise"],
        "stations": [
            {"index": 0, "position_m": [6.0, 0.0, 0.6], "points": 5000},
            {"index": 1, "position_m": [-3.0, 5.2, 0.6], "points": 2500},
        ],
    }
    write_comparison(res, d, inputs={"cloud": "scan.laz", "reference": "tree.obj", "scan": scan})
    files = build_report(d, params=ReportParams(max_view_points=5000))
    return d, files, res


def test_report_files(report_dir):
    d, files, res = report_dir
    for key, name in PNG_FILES.items():
        data = files[key].read_bytes()
        assert files[key] == d / name
        assert data.startswith(PNG_MAGIC) and len(data) > 10_000, key
        assert b"matplotlib.org" not in data  # no software URL in the metadata
    rep = json.loads(files["report_json"].read_text())
    assert rep["kind"] == "treesim.report"
    assert rep["figures"]["coverage"] == pytest.approx(res.coverage)
    for key in ("accuracy", "completeness", "hausdorff_m", "chamfer_m", "tolerance_m"):
        assert key in rep["figures"]
    assert set(rep["figures"]["by_station"]) == {"0", "1"}
    assert rep["parameters"]["tolerance_rule"] == "3 × point_spacing_m"
    assert rep["parameters"]["report"]["max_view_points"] == 5000
    assert rep["software"]["matplotlib"] and rep["software"]["open3d"]
    assert rep["summary"].startswith("The cloud (7,500 points from 2 stations)")
    assert rep["files"]["report_html"] == "report.html"
    prof = rep["occlusion_profile"]
    assert prof["stations"] == ["S0", "S1"] and prof["tolerance_m"] == res.tolerance_m
    # station 0 saw the east half at every height, station 1 a quarter of the west
    assert min(prof["coverage"]["S0"]) > 0.45 and max(prof["coverage"]["S0"]) < 0.56
    assert min(prof["coverage"]["S1"]) > 0.2 and max(prof["coverage"]["S1"]) < 0.31


def test_html_is_self_contained(report_dir):
    d, files, res = report_dir
    page = files["report_html"].read_text(encoding="utf-8")
    assert "http://" not in page and "https://" not in page
    assert "<link" not in page and "@import" not in page and "url(" not in page
    srcs = re.findall(r'src="([^"]*)"', page)
    assert len(srcs) == len(PNG_FILES)
    assert all(s.startswith("data:image/png;base64,") for s in srcs)
    assert re.findall(r"<script[^>]*\ssrc=", page) == []
    # the summary, the tables and the parameters are on the page
    text = summary_paragraph(json.loads((d / "comparison.json").read_text()))
    assert text in html.unescape(page)
    assert f"{100 * res.coverage:.1f} %" in page
    assert "By station" in page and "By hit label" in page
    assert "τ" in page and "3 × point_spacing_m" in page
    assert 'id="viewer-data"' in page
    assert "Occlusion by height" in page and "coverage S1" in page


def test_report_from_memory_and_cli(report_dir, tmp_path, capsys):
    d, files, res = report_dir
    out = build_report(res, tmp_path / "mem", inputs={"cloud": "a.ply", "reference": "b.obj"})
    assert out["report_html"].is_file()
    assert "a.ply" in out["report_html"].read_text(encoding="utf-8")
    assert main(["report", str(d), "-o", str(tmp_path / "cli")]) == 0
    assert (tmp_path / "cli" / "report.html").is_file()
    assert (tmp_path / "cli" / "views_completeness.png").is_file()
    rc = main(["report", "--comparison", str(d / "comparison.json"), "-o", str(tmp_path / "c2")])
    assert rc == 0
    capsys.readouterr()
    assert main(["report", str(tmp_path / "nothing")]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("treesim: error:") and "\n" not in err and "treesim compare" in err


def test_plots_off_keeps_the_figures_and_says_where_each_plot_would_be(report_dir, tmp_path):
    d, files, res = report_dir
    out = tmp_path / "noplots"
    drawn = build_report(res, out, inputs={"cloud": "a.ply", "reference": "b.obj"})
    assert all(drawn[k].is_file() for k in PNG_FILES)
    again = build_report(res, out, params=ReportParams(plots=False))
    assert not any((out / name).exists() for name in PNG_FILES.values())  # the old ones too
    assert set(again) == {"report_json", "report_html"}
    rep = json.loads(again["report_json"].read_text())
    assert rep["files"] == {"report_html": "report.html"}
    assert rep["figures"]["coverage"] == pytest.approx(res.coverage)
    assert rep["parameters"]["report"]["plots"] is False
    page = again["report_html"].read_text(encoding="utf-8")
    assert "data:image/png" not in page and 'id="viewer-data"' in page
    assert page.count("not drawn (report.plots = false)") == len(PNG_FILES)


def test_summary_paragraph_known_text():
    s = {
        "accuracy": {
            "n": 1000,
            "mean_m": 5e-4,
            "rms_m": 6e-4,
            "median_m": 4e-4,
            "p95_m": 0.0012,
            "p99_m": 0.002,
            "max_m": 0.0081,
        },
        "completeness": {
            "n": 5000,
            "mean_m": 0.02,
            "rms_m": 0.03,
            "median_m": 0.001,
            "p95_m": 0.1,
            "p99_m": 0.12,
            "max_m": 0.153,
        },
        "hausdorff_m": 0.153,
        "chamfer_m": 0.01025,
        "tolerance_m": 0.004,
        "coverage": 0.624,
        "cloud": {"points": 1000},
        "reference": {"kind": "mesh"},
        "by_label": {"wood": {"coverage": 0.78}, "leaf": {"coverage": 0.45}},
        "by_station": {"0": {"coverage": 0.3}, "1": {"coverage": 0.41}, "2": {"coverage": 0.2}},
    }
    text = summary_paragraph(s)
    assert text.startswith(
        "The cloud (1,000 points from 3 stations) lies within 1.2 mm of the mesh for 95 % of "
        "its points (median 0.4 mm, farthest 8.1 mm)."
    )
    assert "It covers 62.4 % of the mesh surface within τ = 4 mm; the other 37.6 %" in text
    assert "the farthest part 0.153 m away" in text
    assert "Coverage by part: wood 78 %, leaf 45 %." in text
    assert "Station 1 alone covers the most (41 %); all 3 together cover 62 %." in text
    assert "Hausdorff distance is 0.153 m" in text and "Chamfer distance" in text
    assert "closed parts" not in text
    exact = dict(s, accuracy=dict(s["accuracy"], p95_m=1e-12, max_m=2e-12), coverage=0.999)
    text = summary_paragraph(exact)
    assert "to numerical precision" in text and "practically all" in text


def test_hidden_surface_is_reported_with_its_reason():
    """The dropped area and why: in the summary sentence and the HTML parameter rows."""
    from treesim.compare import HIDDEN_WHY
    from treesim.report.html import _parameter_rows

    hidden = {
        "rule": "drop",
        "why": HIDDEN_WHY,
        "parts": 497,
        "closed_parts": 497,
        "samples_drawn": 100_000,
        "samples_dropped": 23_400,
        "area_m2": 0.653,
        "area_share": 0.234,
        "area_se_m2": 0.0037,
        "visible_area_m2": 2.137,
    }
    stats = {k: 0.001 for k in ("mean_m", "rms_m", "median_m", "p95_m", "p99_m", "max_m")}
    s = {
        "accuracy": {"n": 10, **stats},
        "completeness": {"n": 76_600, **stats},
        "hausdorff_m": 0.001,
        "chamfer_m": 0.001,
        "tolerance_m": 0.004,
        "coverage": 0.9,
        "reference": {"kind": "mesh", "area_m2": 2.79, "hidden_surface": hidden},
    }
    assert (
        "0.653 m² (23.4 %) of the mesh's 2.79 m² lies inside other closed parts of it (buried "
        "end caps, branch bases inside their parents), where no scanner can see; it is left "
        "out of completeness and coverage." in summary_paragraph(s)
    )
    rows = dict(_parameter_rows(s))
    assert rows["hidden surface dropped"] == (
        f"0.653 m² ± 0.0037 (23.4 %; 23,400 of 100,000 samples): {html.escape(HIDDEN_WHY)} "
        "(497 closed parts of 497)"
    )
    none = dict(s, reference=dict(s["reference"], hidden_surface=dict(hidden, samples_dropped=0)))
    assert "closed parts" not in summary_paragraph(none)


def test_length_format():
    assert length(None) == "n/a" and length(float("nan")) == "n/a"
    assert length(1e-12) == "< 0.001 mm"
    assert length(0.0042) == "4.2 mm"
    assert length(0.283) == "0.283 m"


def test_html_renders_in_headless_chromium(report_dir, tmp_path):
    """The page in headless Chromium: plots present, 3D view drawn, no errors, nothing
    loaded from outside. The page records script errors, failed resources and
    ``console.error`` calls in ``<html data-errors>``, and logs nothing when all is well.

    It waits for the drawing itself (``data-drawn``, set by the view's first animation
    frame), not for a fixed time: a cold Chromium can take seconds to run that frame."""
    d, files, _ = report_dir
    shot = tmp_path / "report.png"
    page = open_page(files["report_html"], screenshot=shot)
    assert page["errors"] == "0", page["console"]
    assert page["viewer"] == "ready"
    assert page["drawn"] > 1000
    assert page["images"] == len(PNG_FILES) and page["images_ok"]
    assert page["console"] == [] and page["outside"] == []
    # the screenshot is a real, non-blank render of the page
    import matplotlib.image as mpimg

    img = mpimg.imread(shot)
    assert img.shape[0] == 2000 and img.shape[1] == 1280
    assert img[..., :3].std() > 0.05
    # keep it next to the report for a person to look at
    shutil.copy(shot, Path(d) / "screenshot.png")
