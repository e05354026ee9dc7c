"""Adaptive beam sampling agrees with the brute-force beam model within the manual's
tolerance (docs/commands/scan.md): the same number of returns for 99.9 % of pulses,
ranges within 0.1 mm for 95 % of returns and within 5 mm for all, intensities within 8
counts (of 65535) for 99.9 % of returns."""

from __future__ import annotations

import numpy as np
import pytest

from tests.conftest import box_arrays, bundled_path, cylinder_arrays
from tests.scan.beam_agreement import agreement
from treesim.models import cylinders_to_mesh, read_cylinders
from treesim.params import ScanParams
from treesim.scan import ScannerSpec, Station, scan, stations_for
from treesim.scene import MeshPart, Scene


def within_tolerance(adaptive, full) -> dict[str, float]:
    g = agreement(adaptive.cloud, full.cloud)
    assert g["pulses"] > 0
    assert g["same_count"] >= 0.999, g
    assert g["range_within_0.1mm"] >= 0.95, g
    assert g["range_max_m"] <= 0.005, g
    assert g["intensity_within_8"] >= 0.999, g
    return g


def pole_before_wall(wall_lo, wall_hi, pole_radius, pole_facets, pole_base):
    """A wood pole (``cylinder_arrays``) in front of an ``other`` wall (a box)."""
    wall = box_arrays(wall_lo, wall_hi)
    pole = cylinder_arrays(pole_radius, 2.0, pole_facets, pole_base)
    return Scene(
        [
            MeshPart(vertices=wall[0], faces=wall[1], label="other", name="wall"),
            MeshPart(vertices=pole[0], faces=pole[1], label="wood", name="pole"),
        ]
    )


def both(scene, stations, spec):
    a = scan(scene, stations, spec)
    f = scan(scene, stations, spec.with_(beam_sampling="full"))
    return a, f


def test_a_pole_in_front_of_a_wall():
    scene = pole_before_wall((20.0, -3.0, -1.0), (20.2, 3.0, 3.0), 0.1, 64, (10.0, 0.0, 0.0))
    spec = ScannerSpec(
        horizontal_resolution_deg=0.05,
        vertical_resolution_deg=0.05,
        beam_divergence_mrad=1.0,
        subrays=19,
        range_resolution_m=0.5,
        return_mode="all",
    )
    a, f = both(scene, [Station(position_m=(0.0, 0.0, 1.0))], spec)
    g = within_tolerance(a, f)
    assert (a.cloud.fields["number_of_returns"] == 2).any()  # the edge splits pulses
    assert a.rays_cast < 0.3 * f.rays_cast  # sub-rays only near the pole's edges
    reasons = a.lod["beam"]["reasons"]
    assert reasons["edge"] > 0 and a.lod["beam"]["sampling"] == "adaptive"
    # the pole's 64 facets bend within a footprint (10 mm at 10 m): within 0.1 mm
    assert g["range_max_m"] < 1e-4
    assert g["intensity_same"] == 1.0


def test_twigs_thinner_than_the_spacing_are_not_missed():
    # 1 mm twigs at 10 m, 0.05° apart (8.7 mm): central rays miss most of them, the
    # beam's sub-rays do not; the thin-geometry rule must hand those pulses sub-rays
    parts = [MeshPart(*box_arrays((30.0, -3.0, -1.0), (30.2, 3.0, 4.0)), label="other")]
    for k, y in enumerate(np.linspace(-1.0, 1.0, 9)):
        v, f = cylinder_arrays(0.0005, 2.5, 8, (10.0, y, 0.0))
        parts.append(MeshPart(vertices=v, faces=f, label="wood", name=f"twig{k}"))
    scene = Scene(parts)
    spec = ScannerSpec(
        horizontal_resolution_deg=0.05,
        vertical_resolution_deg=0.05,
        beam_divergence_mrad=1.2,
        subrays=19,
        return_mode="all",
    )
    a, f = both(scene, [Station(position_m=(0.0, 0.0, 1.0))], spec)
    within_tolerance(a, f)
    assert a.lod["beam"]["reasons"]["thin"] > 0
    assert (a.cloud.fields["label"] == 1).sum() == (f.cloud.fields["label"] == 1).sum() > 0


def test_the_bundled_coffee_tree_with_an_instruments_beam():
    table = read_cylinders(bundled_path("coffee_tree", "QSM_treeqsm_v2.4.1_cylinders.csv"))
    v, f = cylinders_to_mesh(table, facets=12, joints="miter")
    scene = Scene([MeshPart(vertices=v, faces=f, label="wood", name="coffee")])
    stations, _ = stations_for(scene.bounds, ScanParams(distance_m=8.0))
    spec = ScannerSpec(
        horizontal_resolution_deg=0.04,
        vertical_resolution_deg=0.04,
        beam_divergence_mrad=0.35,
        subrays=7,
        return_mode="all",
    )
    a, f = both(scene, stations, spec)
    within_tolerance(a, f)
    # branches a few samples across: most pulses are at an edge, but not all
    assert 0 < a.lod["beam"]["pulses_subrays"] < a.lod["beam"]["pulses_cast"]


@pytest.mark.parametrize("mode", ["first", "last", "strongest"])
def test_return_modes_keep_one_return_per_pulse(mode):
    scene = pole_before_wall((12.0, -2.0, -1.0), (12.2, 2.0, 3.0), 0.05, 32, (6.0, 0.0, 0.0))
    spec = ScannerSpec(
        horizontal_resolution_deg=0.1,
        vertical_resolution_deg=0.1,
        beam_divergence_mrad=2.0,
        subrays=7,
        return_mode=mode,
    )
    a, f = both(scene, [Station(position_m=(0.0, 0.0, 1.0))], spec)
    within_tolerance(a, f)
    key = a.cloud.fields["scan_column"].astype(np.int64) * 10**6 + a.cloud.fields["scan_line"]
    assert len(np.unique(key)) == len(key)


def test_lod_full_gives_every_pulse_its_subrays():
    scene = Scene([MeshPart(*box_arrays((5.0, -0.5, 0.0), (6.0, 0.5, 2.0)), label="wood")])
    spec = ScannerSpec(
        horizontal_resolution_deg=0.2, vertical_resolution_deg=0.2, beam_divergence_mrad=3.0
    )
    st = [Station(position_m=(0.0, 0.0, 1.0))]
    full = scan(scene, st, spec, lod="full")
    brute = scan(scene, st, spec.with_(beam_sampling="full"))
    assert full.rays_cast == brute.rays_cast == full.summary()["pulses_cast"] * spec.subrays
    assert full.lod["beam"]["sampling"] == "full" and "lod full" in full.lod["beam"]["why"]
    np.testing.assert_array_equal(full.cloud.points, brute.cloud.points)


def test_neighbours_found_by_table_or_by_search_alike(monkeypatch):
    # blocks small enough get a dense neighbour table, others a search in sorted keys:
    # both must flag the same pulses
    import sys

    beam = sys.modules["treesim.scan.beam"]
    scene = pole_before_wall((8.0, -1.0, -1.0), (8.2, 1.0, 2.0), 0.04, 24, (5.0, 0.1, -0.5))
    spec = ScannerSpec(
        horizontal_resolution_deg=0.1,
        vertical_resolution_deg=0.1,
        beam_divergence_mrad=2.0,
        subrays=7,
        return_mode="all",
    )
    st = [Station(position_m=(0.0, 0.0, 0.5))]
    dense = scan(scene, st, spec)
    monkeypatch.setattr(beam, "_DENSE_NEIGHBOUR_CELLS", 0)
    searched = scan(scene, st, spec)
    assert dense.lod["beam"]["reasons"] == searched.lod["beam"]["reasons"]
    assert dense.lod["beam"]["reasons"]["edge"] > 0
    np.testing.assert_array_equal(dense.cloud.points, searched.cloud.points)
