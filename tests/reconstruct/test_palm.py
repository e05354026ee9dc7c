"""Palms (issue 21): a palm's fronds are leaves; its wood is the stem and the rachises.

The real palm of ``tests/data/trees/pytlidar_palm2`` (PROVENANCE.md there) came out with
its fronds as wood: at field density (24 mm spacing in its crown) a frond's hanging
leaflets are lines of points, as twigs are, and the classifier of 90c2cd1 called only
20 % of its points leaf; its QSM held 2.3 x the stem's volume in branches (997 L in all).
The procedural ``palm`` preset, whose leaflets hang in dense V-shaped curtains as the
real palm's do, reproduces that when scanned as sparsely (0.2°): ``auto`` finds no leaves
(leaf share 0.11) and its branches come out at 7.9 x the truth (total +190 %).

Both failed until 2026-11-27 (strict xfail). A classifier refitted with palm scans
passed both but failed 7 real-tree tests (needle-on pines' DBH, stem profiles), so the
shipped classifier stays as it was and the frond model (``leafwood_fronds_model.json``:
the same features, fitted with palm scans too; ``scripts/fit_leafwood.py --fronds``) is
asked for a second opinion only where the first QSM warns that leaves may have been
taken for wood (``treesim.reconstruct.SECOND_OPINION_CODES``); its model is kept where it
clears those warnings with no more warnings in all and the same DBH. Measured on
2026-11-27: the sparse palm stem -2.3 %, total -8.8 %; the real palm's leaf share 0.83,
branches 90 L under a stem of 317 L (997 L in all before, 407 L now).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.reconstruct.leafon import scan_preset
from treesim.io import read_cloud
from treesim.reconstruct import reconstruct

REAL_PALM = Path(__file__).resolve().parents[1] / "data" / "trees" / "pytlidar_palm2"


def _codes(figures: dict) -> list[str]:
    return [w["code"] for w in figures["warnings"]]


@pytest.mark.slow
def test_a_sparse_palm_scan_keeps_its_fronds_out_of_the_wood():
    """The issue's bounds for generated trees: DBH within 5 mm, stem volume within 5 %,
    total within 10 % of the exact table, with auto separation."""
    tree, cloud = scan_preset("palm", 0.2)
    truth = tree.truth()
    f = reconstruct(cloud).figures
    print({k: round(f[k] / truth[k] - 1, 4) for k in ("volume_stem_m3", "volume_total_m3")})
    assert f["leaves_present"] is True and f["leaf_separation"] == "auto"
    assert abs(f["dbh_m"] - truth["dbh_m"]) <= 0.005
    assert f["volume_stem_m3"] == pytest.approx(truth["volume_stem_m3"], rel=0.05)
    assert f["volume_total_m3"] == pytest.approx(truth["volume_total_m3"], rel=0.10)
    assert not {"leaves_as_wood", "volume_total_high"} & set(_codes(f))


@pytest.mark.slow
def test_the_real_palms_fronds_are_taken_for_leaves():
    """No exact truth here: the fronds must be called leaf (auto separates), and the
    branches (rachises) must stay below the stem's volume, where they were 2.3 x it."""
    f = reconstruct(read_cloud(REAL_PALM / "tree_2.laz")).figures
    print(f["leaf_share"], f["volume_stem_m3"], f["volume_branch_m3"])
    assert f["leaves_present"] is True and f["leaf_separation"] == "auto"
    assert f["volume_branch_m3"] < f["volume_stem_m3"]
    assert not {"leaves_as_wood", "volume_total_high"} & set(_codes(f))
