"""Windows, labels, beam divergence, return modes, limits and bad input."""

from __future__ import annotations

import math
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from tests.conftest import box_arrays, cylinder_arrays
from tests.scan.test_scan_precision import BOUND_M
from treesim.errors import InvalidParameterError, ResourceLimitError, ScanError
from treesim.scan import ScannerSpec, Station, scan
from treesim.scan import instrument as preset
from treesim.scan.rays import box_window
from treesim.scene import MeshPart, Scene

# incidence_deg is stored as float32: one ULP at 90° is 7.6e-6°
INCIDENCE_FLOAT32_DEG = float(np.spacing(np.float32(90.0)))


def box_scene(lo, hi, label="wood") -> Scene:
    v, f = box_arrays(lo, hi)
    return Scene([MeshPart(vertices=v, faces=f, label=label, name=label)])


def same_points(a, b):
    ka = np.lexsort((a.cloud.fields["scan_column"], a.cloud.fields["scan_line"]))
    kb = np.lexsort((b.cloud.fields["scan_column"], b.cloud.fields["scan_line"]))
    np.testing.assert_array_equal(a.cloud.points[ka], b.cloud.points[kb])


@pytest.mark.parametrize(
    "station",
    [
        Station(position_m=(0.0, 0.0, 1.0)),  # object straddles azimuth 0/360
        Station(position_m=(0.0, 0.0, 1.0), heading_deg=100.0),
        Station(position_m=(0.0, 0.0, 1.0), heading_deg=-30.0, pitch_deg=12.0, roll_deg=-7.0),
        Station(position_m=(5.0, 0.2, 3.0)),  # inside the box's footprint, above it
    ],
    ids=["wrap", "heading", "tilted", "above"],
)
def test_window_matches_full_field_of_view(station):
    scene = box_scene((4.0, -0.5, 0.0), (6.0, 0.5, 2.0))
    spec = ScannerSpec(
        horizontal_resolution_deg=0.25, vertical_resolution_deg=0.25, vertical_fov_deg=(-90.0, 90.0)
    )
    win = scan(scene, [station], spec)
    full = scan(scene, [station], spec, window=False)
    assert len(win.cloud) > 100
    same_points(win, full)
    assert win.rays_cast <= full.rays_cast


def test_window_matches_with_a_partial_horizontal_fov():
    scene = box_scene((4.0, -0.5, 0.0), (6.0, 0.5, 2.0))
    spec = ScannerSpec(
        horizontal_resolution_deg=0.2, vertical_resolution_deg=0.2, horizontal_fov_deg=(-3.0, 2.0)
    )
    st = [Station(position_m=(0.0, 0.0, 1.0))]
    win, full = scan(scene, st, spec), scan(scene, st, spec, window=False)
    same_points(win, full)
    az = np.degrees(np.arctan2(win.cloud.points[:, 1], win.cloud.points[:, 0]))
    assert az.min() >= -3.0 - 1e-9 and az.max() <= 2.0 + 1e-9


def test_box_window_is_exact_for_a_box():
    w = box_window(np.array([4.0, -1.0, -1.0]), np.array([6.0, 1.0, 3.0]))
    assert w.azimuth_deg == pytest.approx(
        (-math.degrees(math.atan(1 / 4)), math.degrees(math.atan(1 / 4)))
    )
    assert w.elevation_deg[1] == pytest.approx(math.degrees(math.atan2(3.0, 4.0)))
    assert w.elevation_deg[0] == pytest.approx(math.degrees(math.atan2(-1.0, 4.0)))


def test_labels_and_incidence_on_a_wall():
    # a leaf plate in front of a wood wall: every hit knows what it hit
    wall_v, wall_f = box_arrays((10.0, -2.0, 0.0), (10.2, 2.0, 2.0))
    leaf_v, leaf_f = box_arrays((5.0, -0.2, 0.8), (5.01, 0.2, 1.2))
    scene = Scene(
        [
            MeshPart(vertices=wall_v, faces=wall_f, label="wood", name="wall"),
            MeshPart(vertices=leaf_v, faces=leaf_f, label="leaf", name="leaf"),
        ]
    )
    st = Station(position_m=(0.0, 0.0, 1.0))
    res = scan(scene, [st], ScannerSpec(horizontal_resolution_deg=0.2, vertical_resolution_deg=0.2))
    p, lab = res.cloud.points, res.cloud.fields["label"]
    assert set(np.unique(lab)) == {1, 2}
    # the manual's scanner bound (docs/concepts.md: points within 1e-9 m of the mesh), absolute
    assert np.allclose(p[lab == 2, 0], 5.0, atol=BOUND_M, rtol=0)
    assert np.allclose(p[lab == 1, 0], 10.0, atol=BOUND_M, rtol=0)
    # incidence on the wall x = 10 (normal -x): cos(inc) = dx / |d|
    rel = p[lab == 1] - st.position
    expected = np.degrees(np.arccos(rel[:, 0] / np.linalg.norm(rel, axis=1)))
    np.testing.assert_allclose(
        res.cloud.fields["incidence_deg"][lab == 1], expected, atol=INCIDENCE_FLOAT32_DEG, rtol=0
    )
    assert res.cloud.fields["intensity"][lab == 1].max() > 0
    assert (res.cloud.fields["return_number"] == 1).all()
    assert (res.cloud.fields["number_of_returns"] == 1).all()


def test_beam_divergence_gives_multiple_returns_at_edges():
    # a pole's edge in front of a wall: pulses split between the two surfaces
    wall_v, wall_f = box_arrays((20.0, -3.0, -1.0), (20.2, 3.0, 3.0))
    pole_v, pole_f = cylinder_arrays(0.1, 2.0, 256, (10.0, 0.0, 0.0))
    scene = Scene(
        [
            MeshPart(vertices=wall_v, faces=wall_f, label="other", name="wall"),
            MeshPart(vertices=pole_v, faces=pole_f, label="wood", name="pole"),
        ]
    )
    st = [Station(position_m=(0.0, 0.0, 1.0))]
    base = ScannerSpec(
        horizontal_resolution_deg=0.05,
        vertical_resolution_deg=0.2,
        beam_divergence_mrad=3.0,
        subrays=19,
        range_resolution_m=0.5,
    )
    runs = {
        m: scan(scene, st, base.with_(return_mode=m)) for m in ("first", "last", "strongest", "all")
    }
    allc = runs["all"].cloud
    nr, rn = allc.fields["number_of_returns"], allc.fields["return_number"]
    assert (nr == 2).sum() > 0
    assert set(np.unique(rn)) == {1, 2}
    pulses = {tuple(x) for x in np.c_[allc.fields["scan_line"], allc.fields["scan_column"]]}
    assert (
        len(runs["first"].cloud)
        == len(runs["last"].cloud)
        == len(runs["strongest"].cloud)
        == len(pulses)
    )
    assert len(allc) == len(pulses) + int((rn == 2).sum())
    # first returns of split pulses lie on the pole (~10 m), last ones on the wall (~20 m)
    f = runs["first"].cloud
    split = f.fields["number_of_returns"] == 2
    assert np.all(f.fields["range_m"][split] < 10.5)
    last = runs["last"].cloud
    assert np.all(last.fields["range_m"][last.fields["number_of_returns"] == 2] > 19.5)
    assert runs["first"].models and "beam" in runs["first"].models[0]


def test_no_models_unless_asked():
    spec = preset("riegl-vz400").spec()
    assert not spec.beam_model and spec.range_noise_sd_m == 0 and spec.angular_jitter_sd_deg == 0
    assert spec.active_models() == []
    on = preset("riegl-vz400").spec(beam=True, noise=True)
    assert on.beam_divergence_mrad == 0.35 and on.range_noise_sd_m == 0.003


def test_station_inside_the_geometry_is_refused():
    scene = box_scene((-1.0, -1.0, 0.0), (1.0, 1.0, 2.0))
    with pytest.raises(ScanError, match="inside"):
        scan(scene, [Station(position_m=(0.0, 0.0, 1.0))])


def test_min_and_max_range_limit_the_points():
    scene = box_scene((4.0, -0.5, 0.0), (6.0, 0.5, 2.0))
    st = [Station(position_m=(0.0, 0.0, 1.0))]
    spec = ScannerSpec(horizontal_resolution_deg=0.5, vertical_resolution_deg=0.5)
    assert len(scan(scene, st, spec.with_(max_range_m=3.9)).cloud) == 0
    assert scan(scene, st, spec.with_(max_range_m=3.9)).rays_cast == 0
    r = scan(scene, st, spec.with_(max_range_m=4.2))
    assert 0 < len(r.cloud) and r.cloud.fields["range_m"].max() <= 4.2


@pytest.mark.parametrize(
    "kwargs",
    [
        {"horizontal_resolution_deg": -0.1},
        {"vertical_resolution_deg": 0},
        {"horizontal_resolution_deg": float("nan")},
        {"vertical_fov_deg": (30.0, 10.0)},
        {"min_range_m": 5.0, "max_range_m": 1.0},
        {"range_noise_sd_m": -1.0},
        {"return_mode": "middle"},
        {"subrays": 1},
    ],
)
def test_bad_scanner_settings_are_refused(kwargs):
    with pytest.raises(InvalidParameterError):
        ScannerSpec(**kwargs)


def test_billions_of_rays_are_refused_with_an_estimate():
    scene = box_scene((4.0, -0.5, 0.0), (6.0, 0.5, 2.0))
    spec = ScannerSpec(horizontal_resolution_deg=0.0005, vertical_resolution_deg=0.0005)
    # the full sphere: 720000 x 260001 pulses
    with pytest.raises(
        ResourceLimitError, match=r"needs 1\.87e\+11 rays .* about [\d.]+ (s|min|h|days) here"
    ):
        scan(scene, [Station(position_m=(0.0, 0.0, 1.0))], spec, window=False)
    # windowed it is 1.6e9, still over the default limit of 1e9
    with pytest.raises(ResourceLimitError, match=r"needs 1\.6e\+09 rays"):
        scan(scene, [Station(position_m=(0.0, 0.0, 1.0))], spec)


def test_a_large_scan_runs_in_bounded_memory():
    # ~6M rays, almost all misses inside the window (two poles far apart; cull=False
    # casts the whole window rectangle, not only where the poles can be): with
    # chunking the peak stays far below what casting them in one batch would take
    code = textwrap.dedent(
        """
        import numpy as np
        from treesim.scan import ScannerSpec, Station, scan
        from treesim.scene import MeshPart, Scene
        from tests.conftest import cylinder_arrays
        parts = []
        for y in (-8.0, 8.0):
            v, f = cylinder_arrays(0.05, 3.0, 64, (10.0, y, 0.0))
            parts.append(MeshPart(vertices=v, faces=f, label="wood"))
        spec = ScannerSpec(horizontal_resolution_deg=0.015, vertical_resolution_deg=0.015)
        r = scan(Scene(parts), [Station(position_m=(0.0, 0.0, 1.5))], spec, chunk_rays=1 << 17,
                 cull=False)
        # VmHWM: this process's own peak (ru_maxrss inherits the parent's across exec)
        hwm = [l for l in open("/proc/self/status") if l.startswith("VmHWM")][0].split()[1]
        print(r.rays_cast, len(r.cloud), hwm)
        """
    )
    out = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        check=True,
        cwd=str(__import__("pathlib").Path(__file__).parents[2]),
    )
    rays, points, maxrss_kib = (int(x) for x in out.stdout.split())
    assert rays > 5_000_000 and points > 0
    unchunked_bytes = rays * 200
    assert maxrss_kib * 1024 < 0.5 * unchunked_bytes + 600 * 2**20, (maxrss_kib, rays)
