"""Known truth: procedural presets scanned from three stations at 0.04° with the RIEGL
VZ-400's noise (3 mm range σ, seeded), rebuilt by the QSM, scored against the generator's
own cylinder table (issue 5's targets, under issue 13's noise)."""

from __future__ import annotations

import re
from functools import cache
from pathlib import Path

import pytest

from treesim.cloud import Cloud
from treesim.models import SPECIES as PRESETS
from treesim.models import generate_tree
from treesim.params import instrument, model_fields
from treesim.reconstruct import ReconstructParams, reconstruct
from treesim.scan import ScannerSpec, ring_layout, scan
from treesim.scene import MeshPart, Scene

LEAF_OFF = [name for name, p in PRESETS.items() if not name.endswith("leafon")]
PAGE = Path(__file__).resolve().parents[2] / "docs" / "guides" / "reconstruction.md"
README_COLUMNS = ("dbh_mm", "stem_pct", "total_pct", "height_pct", "noise_mm")
#: The instrument whose noise the field clouds carry (range σ 3 mm, pointing 0.0005°).
INSTRUMENT = instrument("riegl-vz400")


def readme_qsm_table() -> dict[str, dict[str, tuple[float, float]]]:
    """The manual's QSM table (docs/guides/reconstruction.md): per preset, per column, the
    printed figure and half its last printed digit (the figure's own rounding)."""
    text = PAGE.read_text(encoding="utf-8")
    head = "| preset | DBH error | stem volume | total volume | height | noise σ (estimated) |"
    assert head in text, "the manual's QSM table header changed; update this test with it"
    rows = {}
    for line in text[text.index(head) :].splitlines()[2:]:
        if not line.startswith("|"):
            break
        cells = [c.strip() for c in line.strip("|").split("|")]
        name = cells[0].strip("`")
        figures = {}
        for col, cell in zip(README_COLUMNS, cells[1:], strict=True):
            m = re.fullmatch(r"([+\u2212-]?)(\d+)(?:\.(\d+))? ?(mm|%)", cell)
            assert m, f"unparsed cell {cell!r} ({name}, {col})"
            sign = -1.0 if m.group(1) in ("-", "\u2212") else 1.0
            value = sign * float(m.group(2) + "." + (m.group(3) or "0"))
            half_digit = 0.5 * 10.0 ** -len(m.group(3) or "")
            figures[col] = (value, half_digit)
        rows[name] = figures
    return rows


def measured(truth: dict, fig: dict) -> dict[str, float]:
    """The table's figures: DBH error in mm, volumes and height in % of the truth, the
    noise σ the QSM estimated in mm."""
    return {
        "dbh_mm": (fig["dbh_m"] - truth["dbh_m"]) * 1e3,
        "stem_pct": (fig["volume_stem_m3"] / truth["volume_stem_m3"] - 1) * 100,
        "total_pct": (fig["volume_total_m3"] / truth["volume_total_m3"] - 1) * 100,
        "height_pct": (fig["height_m"] / truth["height_m"] - 1) * 100,
        "noise_mm": fig["noise_sd_m"] * 1e3,
    }


def scan_preset(name: str):
    tree = generate_tree(name, seed=0, leaves=False)
    v, f, _ = tree.mesh(32)
    scene = Scene([MeshPart(vertices=v, faces=f, label="wood")])
    lo, hi = scene.bounds
    stations = ring_layout(
        3,
        distance_m=max(10.0, 0.5 * (hi[2] - lo[2])),
        height_m=1.5,
        centre_xy=((lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2),
        base_z_m=lo[2],
    )
    spec = ScannerSpec(
        horizontal_resolution_deg=0.04,
        vertical_resolution_deg=0.04,
        seed=0,
        **model_fields(beam=False, noise=True, figures=vars(INSTRUMENT)),
    )
    return tree.truth(32), scan(scene, stations, spec).cloud


@cache
def rebuilt(name: str):
    """(truth, figures) of a preset, scanned and rebuilt once per test session."""
    truth, cloud = scan_preset(name)
    # the scans hold wood only: auto would find no leaves and build the same model, after
    # running the wood/leaf classifier for 15-20 s on each of these 0.5-0.7 M points
    params = ReconstructParams(method="qsm", separate_leaves="off")
    return truth, reconstruct(Cloud(cloud.points), params).figures


def test_readme_qsm_table_lists_every_leaf_off_preset():
    assert sorted(readme_qsm_table()) == sorted(LEAF_OFF)


@pytest.mark.slow
@pytest.mark.parametrize("name", LEAF_OFF)
def test_qsm_on_noisy_scans_meets_the_targets_and_the_readme(name):
    """Issue 13's targets on the VZ-400-noisy scans (DBH within 5 mm, stem volume within
    5 %, total within 10 %; height within 2 %), the noise σ estimated from the data, and
    the manual's figures."""
    truth, fig = rebuilt(name)
    got = measured(truth, fig)
    print(name, {k: round(v, 3) for k, v in got.items()})
    assert abs(got["dbh_mm"]) <= 5.0, got
    assert abs(got["stem_pct"]) <= 5.0, got
    assert abs(got["total_pct"]) <= 10.0, got
    assert abs(got["height_pct"]) <= 2.0, got
    assert fig["watertight"] is True
    # the points' scatter about the surface, as the stem's circle fits see it: the range
    # noise projected on the surface normal (incidence 0-90°, so below the range σ) and
    # somewhat averaged by the 5 mm voxels; nowhere near a noiseless scan's ~0.3 mm
    assert 0.4 * INSTRUMENT.range_noise_sd_m <= fig["noise_sd_m"] <= INSTRUMENT.range_noise_sd_m
    # deterministic code and seeded noise: each figure must round to what the manual
    # prints, so the tolerance is half the printed last digit (0.05 mm, 0.05 %)
    printed = readme_qsm_table()[name]
    off = {
        col: (round(got[col], 3), value)
        for col, (value, half_digit) in printed.items()
        if abs(got[col] - value) > half_digit
    }
    assert not off, f"{name}: measured vs the manual {off}"


def test_qsm_is_deterministic_on_a_preset():
    _, cloud = scan_preset("sapling")
    a = reconstruct(Cloud(cloud.points)).cylinders
    b = reconstruct(Cloud(cloud.points.copy())).cylinders
    assert a.identical(b)


@pytest.mark.slow
def test_the_palms_qsm_is_read_as_a_palm():
    """The palm's QSM (the scan above) shows Corner's model: a terminal crown, whose stem
    may be as full as a cylinder; its truth table does (test_plausibility), and so must
    the QSM, or every palm's untapered stem is reported as implausible."""
    _, fig = rebuilt("palm")
    assert fig["plausibility"]["terminal_crown"] is True
    lo, hi = fig["plausibility"]["stem_form_factor_range"]
    assert lo <= fig["plausibility"]["stem_form_factor"] <= hi
    assert "form_factor_high" not in [w["code"] for w in fig["warnings"]]
