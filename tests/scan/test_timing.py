"""Scanner time (issue 26): each pulse's time from the scanner's mechanics, known answers.

Oracles: times worked out by hand for a synthetic scanner; the instruments' data-sheet
figures (RIEGL VZ-400 data sheet 2014-09-19: effective measurement rate 122,000 meas./s
at 300 kHz; FARO Focus3D X 330 tech sheet 2013: 10,240 3D-pixels per 360° at the 1/4
resolution, 122,000 points/s, the head turning half a turn); the analytic grid.
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.conftest import box_arrays, cylinder_arrays
from treesim.params import INSTRUMENTS, ScannerSpec, instrument
from treesim.scan import Station, scan
from treesim.scan.timing import pulse_times_s, station_duration_s
from treesim.scene import MeshPart, Scene

#: 5 lines (0..40° by 10°) × 36 columns, 1000 pulses/s: 5 ms per line, 1 ms per pulse.
SYNTH = dict(
    horizontal_resolution_deg=10.0,
    vertical_resolution_deg=10.0,
    vertical_fov_deg=(0.0, 40.0),
    pulse_rate_hz=1000.0,
)


def _grid(spec: ScannerSpec) -> tuple[np.ndarray, np.ndarray]:
    """Every (line, column) of the field of view, column-major (line fastest)."""
    cols, lines = np.meshgrid(np.arange(spec.n_azimuth), np.arange(spec.n_elevation))
    return lines.T.ravel(), cols.T.ravel()


def test_synthetic_scanner_times_by_hand():
    spec = ScannerSpec(**SYNTH)
    lines, cols = _grid(spec)
    t = pulse_times_s(spec, lines, cols)
    duration = station_duration_s(spec)
    assert duration == pytest.approx(36 * 5 * 1e-3, rel=1e-12)  # 0.18 s
    assert t[0] == 0.0
    assert t[-1] == pytest.approx(duration - 1e-3, rel=1e-12)  # one pulse period before
    # pulse (line, column) at column × 5 ms + line × 1 ms
    assert np.allclose(t, cols * 5e-3 + lines * 1e-3, rtol=0, atol=1e-15)
    per_line = t.reshape(36, 5)
    assert (np.diff(per_line, axis=1) > 0).all()  # monotone within a line
    assert np.allclose(np.diff(per_line[:, 0]), 5e-3, rtol=0, atol=1e-15)  # line to line
    assert np.all(np.diff(t) > 0)  # and across the whole scan


def test_unused_mirror_arc_and_line_rate_limit():
    # a 90° mirror cycle: 9 pulse intervals per line, 4 of them dead
    spec = ScannerSpec(**SYNTH, mirror_cycle_deg=90.0)
    m = spec.mechanics()
    assert (m.cycle_pulses, m.line_period_s, m.pulse_period_s) == pytest.approx((9, 9e-3, 1e-3))
    assert station_duration_s(spec) == pytest.approx(36 * 9e-3)
    t = pulse_times_s(spec, np.array([4, 0]), np.array([35, 35]))
    assert t == pytest.approx([35 * 9e-3 + 4e-3, 35 * 9e-3])
    # at most 50 lines/s: 20 ms per line, the 9 intervals spread over it
    capped = spec.with_(max_line_rate_hz=50.0).mechanics()
    assert (capped.line_period_s, capped.pulse_period_s) == pytest.approx((0.02, 0.02 / 9))
    assert capped.duration_s == pytest.approx(36 * 0.02)
    assert capped.head_rate_deg_s == pytest.approx(10.0 / 0.02)


def test_two_sided_mirror_half_turn_by_hand():
    # 36 columns: a mirror turn scans column j up and column j + 18 down (through 90°)
    spec = ScannerSpec(**{**SYNTH, "vertical_fov_deg": (-60.0, 90.0)}, two_sided_mirror=True)
    m = spec.mechanics()
    assert spec.n_elevation == 16 and m.n_lines == 18
    # used arc: -60° up to 90° and down to -60° behind: 300° + one step = 31 pulses
    assert m.cycle_pulses == 31 and m.line_period_s == pytest.approx(0.031)
    t = pulse_times_s(spec, np.array([0, 15, 15, 0, 0]), np.array([0, 0, 18, 18, 35]))
    assert t == pytest.approx([0.0, 0.015, 0.015, 0.030, 17 * 0.031 + 0.030])
    # a 360° mirror (60° blind below the head): 36 intervals per turn
    faro_like = spec.with_(mirror_cycle_deg=360.0)
    assert faro_like.mechanics().duration_s == pytest.approx(18 * 0.036)
    # not a full turn: one column per mirror turn, the back unused
    part = spec.with_(horizontal_fov_deg=(0.0, 90.0)).mechanics()
    assert not part.two_sided and part.n_lines == 10


def test_riegl_vz400_against_its_data_sheet():
    vz = instrument("riegl-vz400")
    spec = vz.spec()
    # the data sheet's effective measurement rate, 122,000 meas./s at 300 kHz, over the
    # 9,000 × 2,501 pulses of the 360° × 100° field at 0.04°: 184.5 s
    sheet_s = 9000 * 2501 / 122_000
    duration = station_duration_s(spec)
    assert abs(duration / sheet_s - 1) < 0.10
    assert duration == pytest.approx(180.0)  # 6,000 pulses of 300 kHz per line, 9,000 lines
    m = spec.mechanics()
    # inside the sheet's line and head speeds: 3-120 lines/s, 0-60°/s
    assert 3 <= m.line_rate_hz <= 120 and 0 < m.head_rate_deg_s <= 60
    # the plan's field time is the same model
    assert vz.scan_time_s(spec) == duration
    assert vz.station_time_s(spec) == 240.0 + duration
    # the coarsest vertical step at 100 kHz the sheet lists, 0.288°, needs 120 lines/s
    coarse = spec.with_(vertical_resolution_deg=0.288, pulse_rate_hz=100_000.0).mechanics()
    assert coarse.line_rate_hz == pytest.approx(120.0)


def test_faro_focus3d_x330_at_a_listed_setting():
    faro = instrument("faro-focus3d-x330")
    # the tech sheet's 1/4 resolution: 10,240 3D-pixels on 360° (0.03515625°), at its
    # 122,000 points/s; the head turns half a turn, each mirror turn 10,240 pulses
    step = 360 / 10_240
    spec = faro.spec(horizontal_resolution_deg=step, vertical_resolution_deg=step)
    sheet_s = (10_240 / 2) * 10_240 / 122_000  # 429.8 s
    duration = station_duration_s(spec)
    assert abs(duration / sheet_s - 1) < 0.10
    assert 3 * 60 <= duration <= 8 * 60  # the 3-8 min per scan reported for Focus scanners
    assert spec.mechanics().line_rate_hz < 97  # under the sheet's 97 Hz mirror
    assert faro.scan_time_s(spec) == duration


def test_every_instrument_times_its_own_grid():
    for p in INSTRUMENTS.values():
        spec = p.spec(**{"horizontal_resolution_deg": 0.5, "vertical_resolution_deg": 0.5})
        lines, cols = _grid(spec)
        t = pulse_times_s(spec, lines, cols)
        d = station_duration_s(spec)
        assert t.min() == 0.0 and t.max() < d
        # every pulse at its own time, but the zenith line a two-sided mirror sees twice
        assert len(np.unique(t)) >= len(t) - spec.n_azimuth // 2


def _cylinder_scan(spec: ScannerSpec, wall: bool = False):
    v, f = cylinder_arrays(0.15, 2.0, 64, (500000.0, 5500000.0, 300.0))
    parts = [MeshPart(vertices=v, faces=f, label="wood", name="cylinder")]
    if wall:  # 2 m behind the cylinder: the beam's footprint straddles both at its edges
        v, f = box_arrays((499997.9, 5499998.0, 300.0), (499998.0, 5500002.0, 302.0))
        parts.append(MeshPart(vertices=v, faces=f, label="other", name="wall"))
    scene = Scene(parts)
    st = Station(position_m=(500010.0, 5500000.0, 301.5))
    return scan(scene, [st], spec)


def test_points_carry_times_and_stay_unchanged():
    base = ScannerSpec(horizontal_resolution_deg=0.2, vertical_resolution_deg=0.2)
    a = _cylinder_scan(base)
    b = _cylinder_scan(base.with_(pulse_rate_hz=50_000.0, mirror_cycle_deg=300.0))
    assert len(a.cloud) > 100
    assert np.array_equal(a.cloud.points, b.cloud.points)  # bit for bit
    for name in ("scan_line", "scan_column", "range_m"):
        assert np.array_equal(a.cloud.fields[name], b.cloud.fields[name])
    f = a.cloud.fields
    assert f["time_s"].dtype == np.float64
    # each point at its pulse's hand-computed time: n_el pulses of 122 kHz per line
    n_el = base.n_elevation
    want = (f["scan_column"] * n_el + f["scan_line"]) / 122_000.0
    assert np.allclose(f["time_s"], want, rtol=1e-13, atol=0)
    st = a.summary()["stations"][0]
    assert st["scan_duration_s"] == pytest.approx(base.n_azimuth * n_el / 122_000.0)
    assert a.summary()["timing"]["duration_s"] == st["scan_duration_s"]


@pytest.mark.parametrize("sampling", ["full", "adaptive"])
def test_all_returns_of_a_pulse_share_its_time(sampling):
    spec = ScannerSpec(
        horizontal_resolution_deg=0.2,
        vertical_resolution_deg=0.2,
        beam_divergence_mrad=30.0,
        return_mode="all",
        beam_sampling=sampling,
    )
    f = _cylinder_scan(spec, wall=True).cloud.fields
    key = f["scan_column"].astype(np.int64) * 100_000 + f["scan_line"]
    assert (f["number_of_returns"] > 1).any()
    _, first, inverse = np.unique(key, return_index=True, return_inverse=True)
    assert np.array_equal(f["time_s"], f["time_s"][first][inverse.ravel()])
    want = (f["scan_column"] * spec.n_elevation + f["scan_line"]) / spec.pulse_rate_hz
    assert np.allclose(f["time_s"], want, rtol=1e-13, atol=0)
