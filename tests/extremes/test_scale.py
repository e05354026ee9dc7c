"""Scale: a 1 mm twig beside a 1 m trunk, three orders of magnitude in one scene.

Both are vertical prisms (the trunk 16 facets, 1 m across, 2 m high; the twig 8 facets,
1 mm across, 1 m high), so which grid pulses hit each is derivable in float64 from the
grid's angles (:func:`tests.extremes.shapes.prism_pulses`). The scanner decides hits in
float32, so a pulse whose ray passes within float32's error of an edge may go either
way: :func:`tests.extremes.shapes.float32_ray_error_m` is that error, derived, and the
test asserts that every pulse that surely hits was recorded, that nothing else was, and
so that the counts agree within the pulses the float32 decision may flip.
"""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.extremes.shapes import float32_ray_error_m, prism, prism_pulses
from treesim.scan import ScannerSpec, Station, scan
from treesim.scene import MeshPart, Scene

TRUNK = (16, 0.5, 2.0)  # facets, radius (m), height (m)
TWIG = (8, 0.0005, 1.0)


@settings(max_examples=5, deadline=None, derandomize=True)
@given(
    distance=st.floats(3.0, 15.0),
    psi=st.floats(0.0, 360.0),
    z=st.floats(0.2, 0.8),
    side=st.sampled_from([-1.0, 1.0]),
    spin=st.floats(0.0, 45.0),
)
def test_a_1mm_twig_beside_a_1m_trunk_gets_its_analytic_pulses(distance, psi, z, side, spin):
    a = np.radians(psi)
    toward = np.array([np.cos(a), np.sin(a)])  # from the trunk to the station
    across = side * np.array([-np.sin(a), np.cos(a)])
    parts, outlines = [], []
    for (facets, radius, height), centre in [
        (TRUNK, np.zeros(2)),
        (TWIG, 1.5 * across + 0.5 * toward),  # beside the trunk, a little nearer
    ]:
        v, f = prism(facets, radius, height)
        turn = np.radians(spin)
        c, s = np.cos(turn), np.sin(turn)
        v[:, :2] = v[:, :2] @ np.array([[c, s], [-s, c]]) + centre
        parts.append(MeshPart(vertices=v, faces=f, label="wood", name=f"r={radius}"))
        outlines.append((v[:facets, :2], height))
    station = np.array([*(distance * toward), z])
    # about 6 columns across the twig, 0.5 degree between lines
    hres = np.degrees(2 * TWIG[1] / (distance - 0.5)) / 6
    spec = ScannerSpec(
        horizontal_resolution_deg=hres, vertical_resolution_deg=0.5, vertical_fov_deg=(-60, 60)
    )
    res = scan(Scene(parts), [Station(position_m=tuple(station))], spec)
    got = res.cloud.fields["scan_line"].astype(np.int64) * spec.n_azimuth + res.cloud.fields[
        "scan_column"
    ].astype(np.int64)
    assert len(np.unique(got)) == len(got)  # one return per pulse
    eps = float32_ray_error_m(distance, distance + 2.0, 3.0)
    sure, possible = [], []
    for corners, height in outlines:
        s, p = prism_pulses(spec, station, corners, height, eps)
        sure.append(s)
        possible.append(p)
    twig_sure, twig_possible = sure[1], possible[1]
    assert len(twig_sure) >= 4 * 7  # ~6 columns x 7 to 37 lines: the twig is resolved
    sure_all, possible_all = np.concatenate(sure), np.concatenate(possible)
    assert np.isin(sure_all, got).all(), np.setdiff1d(sure_all, got)[:10]
    assert np.isin(got, possible_all).all(), np.setdiff1d(got, possible_all)[:10]
    # so the twig's count is its analytic count, up to the pulses float32 may flip
    twig_got = np.isin(got, twig_possible).sum()
    assert len(twig_sure) <= twig_got <= len(twig_possible)
