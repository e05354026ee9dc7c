"""``treesim plot from-cloud``: a field plot becomes a twin, held to the generator's truth.

The field plot (``field_plot.py``): a generated 30-tree stand on a 15° slope, scanned
from 5 known stations with the RIEGL VZ-400's noise, written as an E57 with its poses and
a merged LAZ. Its trees, terrain and stations are known exactly.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import treesim as ts

from .field_plot import make_field_plot, match

#: Acceptance (issue 23).
MIN_DETECTED = 0.95  # of the trees with DBH >= 10 cm
POSITION_M = 0.10
DBH_M = 0.01
DTM_M = 0.05


#: Vertices per ring of the field plot's tree meshes (what the virtual scanner sees).
FACETS = 16


@pytest.fixture(scope="module")
def field(tmp_path_factory):
    return make_field_plot(tmp_path_factory.mktemp("field"), resolution_deg=0.2, facets=FACETS)


@pytest.fixture(scope="module")
def field_cloud(field):
    return ts.read_cloud(field.laz)


@pytest.fixture(scope="module")
def stages(field_cloud):
    """Ground, DTM, heights above ground and stems of the field plot."""
    from treesim.plot.dtm import ground_and_dtm, heights_above_ground
    from treesim.plot.stems import detect_stems

    ground, dtm, _ = ground_and_dtm(field_cloud.points)
    hag = heights_above_ground(field_cloud.points, dtm)
    stems, _ = detect_stems(field_cloud.points, hag)
    return ground, dtm, hag, stems


@pytest.mark.slow
def test_dtm_within_5_cm_under_every_tree(field, stages) -> None:
    _, dtm, _, _ = stages
    truth = ts.read_plot(field.plot_file).terrain
    xy = np.array([[t["x_m"], t["y_m"]] for t in field.truth])
    err = dtm.height_at(xy[:, 0], xy[:, 1]) - truth.height_at(xy[:, 0], xy[:, 1])
    assert np.abs(err).max() < DTM_M


@pytest.mark.slow
def test_stems_found_where_the_trees_stand(field, stages) -> None:
    """>= 95 % of the trees of DBH >= 10 cm found, none invented, positions within
    10 cm of the true stem at 1.3 m, DBH within 1 cm of the true table's."""
    _, _, _, stems = stages
    truth = field.truth
    big = [t for t in truth if t["dbh_m"] >= 0.10]
    true_xy = np.array([[t["x_m"], t["y_m"]] for t in truth])
    found_xy = np.array([[s.x_m, s.y_m] for s in stems])
    m = match(found_xy, true_xy, POSITION_M)
    detected = [i for i, t in enumerate(truth) if t["dbh_m"] >= 0.10 and m[i] >= 0]
    assert len(detected) >= math.ceil(MIN_DETECTED * len(big)), (len(detected), len(big))
    # none invented: every stem found is one of the true trees
    matched = set(int(j) for j in m if j >= 0)
    invented = [(s.x_m, s.y_m, s.dbh_m) for j, s in enumerate(stems) if j not in matched]
    assert invented == []
    # the scanner sees the stem's mesh, a regular polygon of FACETS sides inscribed in the
    # table's circle: its mean distance from the axis is the circle's radius times
    shrink = _polygon_mean_radius(FACETS)
    errors = [stems[m[i]].dbh_m - truth[i]["dbh_m"] * shrink for i in detected]
    assert np.abs(errors).max() < DBH_M, np.round(errors, 4)


def _polygon_mean_radius(n: int) -> float:
    """Mean distance from the centre of the perimeter of a regular n-gon inscribed in the
    unit circle (numerically, along one edge)."""
    t = np.linspace(-1.0, 1.0, 20_001) * math.sin(math.pi / n)
    return float(np.mean(np.hypot(math.cos(math.pi / n), t)))


def test_polygon_mean_radius() -> None:
    # a square inscribed in the unit circle, half-side a = 1/sqrt(2): the mean of
    # sqrt(a^2 + t^2) over t in [-a, a], in closed form
    a = 1 / math.sqrt(2)
    closed = 0.5 * (math.sqrt(2 * a * a) * a + a * a * math.asinh(1.0)) / a
    assert _polygon_mean_radius(4) == pytest.approx(closed, rel=1e-4)
    assert _polygon_mean_radius(1000) == pytest.approx(1.0, abs=1e-5)
