"""The real trees in ../shared/data read with the expected point counts."""

from __future__ import annotations

import numpy as np
import pytest

from treesim.io import read_cloud

from .conftest import SHARED_DATA

pytestmark = [
    pytest.mark.shared_data,
    pytest.mark.skipif(
        not SHARED_DATA.is_dir(),
        reason=f"shared test data not found at {SHARED_DATA} (only present next to the repo "
        "on the project's machines)",
    ),
]


def test_treels_pine_laz() -> None:
    cloud = read_cloud(SHARED_DATA / "trees" / "treels_pine" / "pine.laz").validate()
    assert len(cloud) == 73_851
    assert cloud.points.dtype == np.float64
    assert {"intensity", "return_number", "classification"} <= set(cloud.fields)
