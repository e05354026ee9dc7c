"""Fixtures shared by the I/O tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from treesim.cloud import LABEL_NAMES, Cloud

#: ../shared/data next to the repository (absent in a user's clone).
SHARED_DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"

#: A georeferenced point (UTM-like easting/northing) that float32 cannot hold to 1 mm.
GEO_ORIGIN = np.array([500000.123456, 5500000.654321, 300.5])


@pytest.fixture
def geo_cloud() -> Cloud:
    """Six georeferenced points with the fields a simulated scan carries."""
    n = 6
    steps = np.arange(n, dtype=np.float64)
    points = GEO_ORIGIN + np.column_stack([steps * 0.0123, -steps * 1.5, steps * 0.25])
    points[0] = GEO_ORIGIN
    fields = {
        "intensity": np.array([0, 100, 1000, 40000, 65535, 7], dtype=np.uint16),
        "return_number": np.array([1, 1, 2, 1, 3, 2], dtype=np.uint8),
        "number_of_returns": np.array([1, 2, 2, 3, 3, 2], dtype=np.uint8),
        "station": np.array([0, 0, 1, 1, 2, 65535], dtype=np.uint16),
        "range_m": np.array([1.5, 2.25, 3.125, 10.0, 0.001, 123.456789]),
        "incidence_deg": np.array([0.0, 12.5, 45.0, 89.9, 30.0, 60.0], dtype=np.float32),
        "label": np.array([0, 1, 2, 3, 1, 2], dtype=np.uint8),
        "scan_line": np.array([-5, 0, 1, 2, 3, 2_000_000], dtype=np.int32),
        "scan_column": np.array([0, 10, 20, 30, 40, 50], dtype=np.int32),
    }
    return Cloud(points, fields, {"label_names": dict(LABEL_NAMES), "scanner": {"fov": 300}})
