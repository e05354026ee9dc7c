"""Grazing incidence up to 89.99° on planes: no spurious or missing hits.

A station 1 to 4 mm above a 30 m × 2 m plane (turned any way and tilted, triangulated
into coplanar triangles with many shared edges) sees it at incidences from ~89.9° to
beyond 89.99°. Which grid pulses hit is derivable in float64
(:func:`tests.extremes.shapes.rectangle_pulses`); float32 decides, so pulses whose ray
passes within float32's derived error of the border may go either way, and none other.
Every hit lies on the plane to float64 rounding (no neighbour's plane to err onto: the
triangles are coplanar), whatever the incidence.
"""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.extremes.shapes import (
    float32_ray_error_m,
    rectangle,
    rectangle_pulses,
    rotation_x,
    rotation_z,
)
from tests.extremes.test_range import bound_m
from treesim.scan import ScannerSpec, Station, scan
from treesim.scene import MeshPart, Scene

HALF = (15.0, 1.0)
SPEC = ScannerSpec(
    horizontal_resolution_deg=0.1, vertical_resolution_deg=0.001, vertical_fov_deg=(-40.0, 90.0)
)


@settings(max_examples=5, deadline=None, derandomize=True)
@given(
    height=st.floats(0.001, 0.004),
    gap=st.floats(2.0, 4.0),
    across=st.floats(-0.8, 0.8),
    yaw=st.floats(0.0, 360.0),
    tilt=st.floats(0.0, 8.0),
)
def test_a_plane_seen_at_grazing_incidence_gets_its_analytic_pulses(height, gap, across, yaw, tilt):
    rot = rotation_z(yaw) @ rotation_x(tilt)
    centre = np.array([3.0, -2.0, 1.0])
    v, f = rectangle(centre, rot, HALF, (12, 4))
    scene = Scene([MeshPart(vertices=v, faces=f, label="ground", name="plane")])
    # beyond the near edge, `height` above the plane: rays skim it towards the far edge
    station = centre + (-HALF[0] - gap) * rot[:, 0] + across * rot[:, 1] + height * rot[:, 2]
    res = scan(scene, [Station(position_m=tuple(station))], SPEC)
    got = res.cloud.fields["scan_line"].astype(np.int64) * SPEC.n_azimuth
    got += res.cloud.fields["scan_column"].astype(np.int64)
    eps = float32_ray_error_m(HALF[0] + gap, 2 * HALF[0] + gap, 2 * HALF[0])
    sure, possible, inc = rectangle_pulses(SPEC, station, centre, rot, HALF, eps)
    assert inc.max() > 89.99  # grazing pulses are among the sure ones
    missing = np.setdiff1d(sure, got)
    spurious = np.setdiff1d(got, possible)
    assert len(missing) == 0 and len(spurious) == 0, (missing[:5], spurious[:5], len(sure))
    assert len(sure) > 1000
    # on the plane to float64 rounding, at every incidence
    off = np.abs((res.cloud.points - centre) @ rot[:, 2])
    assert off.max() <= bound_m(2 * HALF[0] + gap, 2 * HALF[0] + 10.0), off.max()
    assert res.cloud.fields["incidence_deg"].max() > 89.99
