"""``treesim.reconstruct.preprocess`` was split by topic (issue 22); what users imported
from it before the split still imports from there, as the very objects the topic
modules define (so a patch or an ``is`` check on either name sees the same thing)."""

from __future__ import annotations

import importlib

import pytest

#: The public names of ``treesim.reconstruct.preprocess`` before the split, and the
#: module each lives in now.
MOVED = {
    "nearest_neighbors": "neighbours",
    "KEPT_NEIGHBORS": "neighbours",
    "validate_tree_cloud": "validate",
    "PLANE_SD_RATIO": "validate",
    "LINE_SD_RATIO": "validate",
    "voxel_downsample": "thin",
    "statistical_outliers": "outliers",
    "SOR_LOCAL_RATIO": "outliers",
    "SOR_MAX_SPARSITY": "outliers",
    "estimate_normals": "normals",
    "LINE_NEIGHBOURHOOD": "normals",
    "find_ground": "ground",
    "GROUND_BAND_M": "ground",
    "GROUND_MAX_TILT_DEG": "ground",
    "GROUND_MIN_AREA_M2": "ground",
    "GROUND_MIN_FILL": "ground",
    "GROUND_RANSAC_TRIALS": "ground",
    "GROUND_RANSAC_SEED": "ground",
    "leaf_measure": "leaf_measure",
    "LEAF_NORMAL_SPREAD": "leaf_measure",
    "LEAF_RADIUS_M": "leaf_measure",
    "LEAF_PRESENT_FRACTION": "leaf_measure",
}


@pytest.mark.parametrize("name", sorted(MOVED))
def test_a_moved_name_still_imports_from_preprocess(name):
    preprocess = importlib.import_module("treesim.reconstruct.preprocess")
    home = importlib.import_module(f"treesim.reconstruct.{MOVED[name]}")
    assert getattr(preprocess, name) is getattr(home, name)


def test_preprocess_exports_what_it_did():
    from treesim.reconstruct import preprocess

    assert sorted(preprocess.__all__) == sorted(
        [
            "PrepareParams",
            "PreparedCloud",
            "estimate_normals",
            "find_ground",
            "leaf_measure",
            "nearest_neighbors",
            "prepare",
            "validate_tree_cloud",
            "voxel_downsample",
        ]
    )
    for name in preprocess.__all__:
        assert callable(getattr(preprocess, name)), name
