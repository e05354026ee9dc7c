"""Palms (issue 21): a palm's fronds are leaves; its wood is the stem and the rachises.

The real palm of ``tests/data/trees/pytlidar_palm2`` (PROVENANCE.md there) came out with
its fronds as wood: at field density (24 mm spacing in its crown) a frond's hanging
leaflets are lines of points, as twigs are, and the classifier of 90c2cd1 called only
20 % of its points leaf; its QSM held 2.3 x the stem's volume in branches (997 L in all).
The procedural ``palm`` preset, whose leaflets hang in dense V-shaped curtains as the
real palm's do, reproduces that when scanned as sparsely (0.2°): ``auto`` finds no leaves
(leaf share 0.11) and its branches come out at 7.9 x the truth (total +190 %).

Both tests fail today (strict xfail: they turn red when they start to pass). Measured on
2026-11-27: a classifier refitted with palm scans (seeds 1 and 2 at 0.08 and 0.2°, and
the leaf-off aspen at 0.2°) passes both (the sparse palm: DBH -0.8 mm, stem -1.9 %, total
-9.7 %; the real palm: fronds called leaf, 438 L with branches 108 L, from 997 L), but it
failed 7 of the real-tree tests (test_real_tree_accuracy: two needle-on pines' DBH at
+5.3 % and -10.9 % of their stem slabs, three stem profiles off by > 10 %) and moved
the aspen-leafon headline recall from 0.977 to 0.9725, so it was not adopted: telling a
frond's leaflet curtain from a needle-clad stem at field density needs more than adding
palms to the training scans.
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


XFAIL = pytest.mark.xfail(
    strict=True, reason="issue 21: the classifier takes a palm's frond curtains for wood"
)


@pytest.mark.slow
@XFAIL
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
@XFAIL
def test_the_real_palms_fronds_are_taken_for_leaves():
    """No exact truth here: the fronds must be called leaf (auto separates), and the
    branches (rachises) must stay below the stem's volume, where they were 2.3 x it."""
    f = reconstruct(read_cloud(REAL_PALM / "tree_2.laz")).figures
    print(f["leaf_share"], f["volume_stem_m3"], f["volume_branch_m3"])
    assert f["leaves_present"] is True and f["leaf_separation"] == "auto"
    assert f["volume_branch_m3"] < f["volume_stem_m3"]
    assert not {"leaves_as_wood", "volume_total_high"} & set(_codes(f))
