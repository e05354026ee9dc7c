"""A one-station plan bounds its triangles once (issue 25): the occupancy grid is fed the
bounds that choose the triangles to load, and the triangles' bounds are computed corner by
corner. The oracles: the two-pass plan (each pass bounds the triangles itself, as every
plan did before) and the plain (n, 3, 3) formulas, written out here; bit for bit."""

from __future__ import annotations

import importlib

import numpy as np
import pytest

from tests.conftest import box_arrays
from treesim.frame import LocalFrame
from treesim.models import generate_tree
from treesim.scan import ScannerSpec, Station
from treesim.scene import MeshPart, Scene

occupancy = importlib.import_module("treesim.scan.occupancy")
planning = importlib.import_module("treesim.scan.planning")


def _scene(ground: bool) -> Scene:
    v, f, _ = generate_tree("sapling", seed=3).mesh(facets=8)
    parts = [MeshPart(vertices=v, faces=f, label="wood", name="sapling")]
    if ground:
        g = box_arrays((-8.0, -8.0, v[:, 2].min() - 0.2), (8.0, 8.0, v[:, 2].min()))
        parts.append(MeshPart(vertices=g[0], faces=g[1], label="ground", name="ground"))
    return Scene(parts)


def _plan(scene, station, spec):
    return planning.plan_scan(
        scene, [station], spec, window=True, cull=True, lod="auto", nthreads=1,
        max_rays=None, check_inside=False, frame=LocalFrame(origin=(0.0, 0.0, 0.0)),
    )  # fmt: skip


@pytest.mark.parametrize(
    "ground, station, spec",
    [
        # near the tree: long tube facets are bisected; the tree is partly beyond range
        (True, Station(position_m=(2.0, 0.5, 1.2)), ScannerSpec(max_range_m=6.0)),
        # tilted, a partial field of view: triangles outside it are not loaded
        (
            False,
            Station(position_m=(-4.0, 1.0, 1.5), heading_deg=240.0, pitch_deg=10.0),
            ScannerSpec(horizontal_fov_deg=(0.0, 120.0), vertical_fov_deg=(-30.0, 60.0)),
        ),
    ],
)
def test_the_one_pass_plan_is_the_two_pass_one(monkeypatch, ground, station, spec):
    scene = _scene(ground)
    spec = spec.with_(horizontal_resolution_deg=0.2, vertical_resolution_deg=0.2)
    once = _plan(scene, station, spec)
    monkeypatch.setattr(planning._Shared, "of", classmethod(lambda cls, *a: None))
    twice = _plan(scene, station, spec)
    assert once.geometry == twice.geometry
    assert 0 < once.geometry["loaded"] < once.geometry["triangles"]  # some left out
    a, b = once.plans[0].grid, twice.plans[0].grid
    assert type(a) is type(b) is occupancy.SparseGrid
    assert 0 < a.n_pulses == b.n_pulses < once.plans[0].n_window  # the cull culled
    for x, y in zip(a.indices(0, a.n_pulses), b.indices(0, b.n_pulses), strict=True):
        np.testing.assert_array_equal(x, y)


def _plain_bounds(tri: np.ndarray) -> tuple[np.ndarray, ...]:
    """The bounds' formulas on (n, 3, 3) triangles, reductions along axis 1."""
    x, y, z = tri[:, :, 0], tri[:, :, 1], tri[:, :, 2]
    r_max = np.hypot(x, y).max(axis=1)
    best = np.full(len(x), np.inf)
    for i in range(3):
        j = (i + 1) % 3
        ax, ay, ex, ey = x[:, i], y[:, i], x[:, j] - x[:, i], y[:, j] - y[:, i]
        ee = ex * ex + ey * ey
        with np.errstate(invalid="ignore", divide="ignore"):
            t = np.clip(np.where(ee > 0, -(ax * ex + ay * ey) / ee, 0.0), 0.0, 1.0)
        best = np.minimum(best, np.hypot(ax + t * ex, ay + t * ey))
    c = [x[:, i] * y[:, (i + 1) % 3] - y[:, i] * x[:, (i + 1) % 3] for i in range(3)]
    inside = ((c[0] >= 0) & (c[1] >= 0) & (c[2] >= 0)) | ((c[0] <= 0) & (c[1] <= 0) & (c[2] <= 0))
    best[inside] = 0.0
    z_min, z_max = z.min(axis=1), z.max(axis=1)
    el_hi = np.arctan2(z_max, np.where(z_max >= 0, best, r_max))
    el_lo = np.arctan2(z_min, np.where(z_min >= 0, r_max, best))
    az = np.arctan2(y, x)
    rel = (az - az[:, :1] + np.pi) % (2 * np.pi) - np.pi
    dz = np.where((z_min <= 0) & (z_max >= 0), 0.0, np.minimum(np.abs(z_min), np.abs(z_max)))
    return (
        az[:, 0] + rel.min(axis=1), az[:, 0] + rel.max(axis=1), best <= 1e-12 * r_max,
        el_lo, el_hi, np.hypot(best, dz),
    )  # fmt: skip


def _triangles(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and faces around a station: far and near, across the azimuth seam, over
    the station (containing the vertical axis), some degenerate."""
    rng = np.random.default_rng(7)
    v = np.concatenate(
        [
            rng.normal(size=(n, 3)) * 5.0,
            rng.normal(size=(n, 3)) * 1e-3,
            np.round(rng.normal(size=(n, 3)), 1),  # ties, zeros and repeated corners
            np.column_stack(
                [-rng.random(n) * 3 - 0.1, rng.normal(size=n) * 1e-9, rng.normal(size=n)]
            ),
        ]
    )
    f = rng.integers(0, len(v), size=(4 * n, 3))
    return v, f


def test_corner_by_corner_bounds_are_the_plain_formulas_bit_for_bit():
    v, f = _triangles(5000)
    want = _plain_bounds(v[f])
    for b in (occupancy.triangle_bounds(v[f]), occupancy.face_bounds(v, f)):
        got = (b.az_lo, b.az_hi, b.full_az, b.el_lo, b.el_hi, b.d_min)
        for g, w in zip(got, want, strict=True):
            np.testing.assert_array_equal(g, w, strict=True)
    assert want[2].any() and not want[2].all()  # some contain the axis


def test_bisecting_corner_rows_is_the_plain_bisection_bit_for_bit():
    v, f = _triangles(5000)
    tri = v[f]
    e = np.stack([np.linalg.norm(tri[:, (j + 1) % 3] - tri[:, j], axis=1) for j in range(3)], 1)
    k = e.argmax(axis=1)
    i = np.arange(len(tri))
    a, b, c = tri[i, k], tri[i, (k + 1) % 3], tri[i, (k + 2) % 3]
    m = 0.5 * (a + b)
    want = np.concatenate([np.stack([a, m, c], axis=1), np.stack([m, b, c], axis=1)])
    got = occupancy._bisect_longest(occupancy.face_rows(v, f))
    np.testing.assert_array_equal(got.transpose(2, 0, 1), want, strict=True)
    assert len(set(k.tolist())) == 3
