"""Every real tree in ../shared/data/trees reconstructs with every method, sanely."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import bundled_path, shared_path
from treesim.io import read_cloud
from treesim.reconstruct import ReconstructParams, reconstruct

TREES = [
    ("coffee_tree", "cloud.txt"),
    ("adtree", "tree7.xyz"),
    ("adtree", "Lille_2.xyz"),
    ("archi_tree2", "Tree_2_point_cloud.las"),
    ("treels_pine", "pine.laz"),
]


PAGE = Path(__file__).resolve().parents[2] / "docs" / "guides" / "reconstruction.md"


def readme_coffee_figures() -> tuple[float, float, float]:
    """(litres, DBH cm, noise σ mm) the manual prints for treesim on the coffee tree."""
    text = " ".join(PAGE.read_text(encoding="utf-8").split())
    m = re.search(
        r"On the real coffee tree: treesim ([0-9.]+) L, DBH ([0-9.]+) cm "
        r"\(noise σ estimated ([0-9.]+) mm\)",
        text,
    )
    assert m, (
        "the manual's coffee-tree sentence (docs/guides/reconstruction.md) changed; "
        "update this test with it"
    )
    return float(m.group(1)), float(m.group(2)), float(m.group(3))


def tree_path(folder: str, name: str):
    """The bundled copy where the repository has one (the coffee tree), else shared data."""
    if folder == "coffee_tree":
        return bundled_path(folder, name)
    return shared_path("trees", folder, name)


def stem_width_m(points: np.ndarray, height_m: float = 1.3, band_m: float = 0.1) -> float:
    """Widest horizontal distance between two points of the slab at ``height_m`` above the
    lowest point (the cloud's own stem width there)."""
    from scipy.spatial.distance import pdist

    z0 = points[:, 2].min()
    q = points[np.abs(points[:, 2] - z0 - height_m) <= band_m / 2, :2]
    if len(q) > 3000:
        q = q[np.random.default_rng(0).choice(len(q), 3000, replace=False)]
    return float(pdist(q).max())


def mesh_cloud_distances(
    model, points: np.ndarray, n_samples: int = 20_000
) -> tuple[np.ndarray, np.ndarray, float]:
    """Each cloud point's distance to the mesh (Open3D's exact point-to-triangle distance),
    the distance from seeded area-weighted samples of the mesh's surface to the nearest
    cloud point (a k-d tree), and the cloud's median nearest-neighbour spacing; all
    computed here, not by treesim.compare. Coordinates are moved to the cloud's mean
    first (float64), so Open3D's float32 keeps millimetres on georeferenced clouds."""
    import open3d as o3d
    from scipy.spatial import cKDTree

    origin = points.mean(axis=0)
    pts, v, f = points - origin, model.vertices - origin, np.asarray(model.faces)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(v.astype(np.float32)), o3d.core.Tensor(f.astype(np.uint32)))
    to_mesh = scene.compute_distance(o3d.core.Tensor(pts.astype(np.float32))).numpy()
    rng = np.random.default_rng(0)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    area = np.linalg.norm(np.cross(b - a, c - a), axis=1)
    k = rng.choice(len(f), n_samples, p=area / area.sum())
    r1, r2 = np.sqrt(rng.random(n_samples)), rng.random(n_samples)
    samples = (1 - r1)[:, None] * a[k] + (r1 * (1 - r2))[:, None] * b[k] + (r1 * r2)[:, None] * c[k]
    tree = cKDTree(pts)
    to_cloud, _ = tree.query(samples)
    probe = pts[rng.choice(len(pts), min(n_samples, len(pts)), replace=False)]
    spacing = float(np.median(tree.query(probe, k=2)[0][:, 1]))
    return to_mesh.astype(np.float64), to_cloud, spacing


@pytest.mark.slow
@pytest.mark.parametrize("method", ["qsm", "poisson", "bpa"])
@pytest.mark.parametrize("tree", TREES, ids=[t[1] for t in TREES])
def test_real_tree_reconstructs_sanely(tree, method):
    path = tree_path(*tree)
    cloud = read_cloud(path)
    params = ReconstructParams(method=method, timeout_s=300)
    model = reconstruct(cloud, params)
    fig = model.figures
    assert fig["n_triangles"] > 100
    assert len(model.vertices) and np.isfinite(model.vertices).all()
    # the mesh stays where the tree is (input coordinates, float64)
    lo, hi = cloud.points.min(axis=0), cloud.points.max(axis=0)
    pad = 0.1 * (hi - lo).max()
    assert (model.vertices.min(axis=0) >= lo - pad).all()
    assert (model.vertices.max(axis=0) <= hi + pad).all()
    if method in ("poisson", "bpa"):
        to_mesh, to_cloud, spacing = mesh_cloud_distances(model, cloud.points)
        # the cloud on the mesh: at least 60 % of its points within 5 cm (measured 69-94 %
        # over these trees, 2026-11-26; the ground, understory and outliers the
        # preparation removes are not meshed)
        assert (to_mesh < 0.05).mean() >= 0.6, np.percentile(to_mesh, [50, 90])
        if method == "bpa":
            # the mesh on the cloud: ball pivoting's vertices are cloud points, so 95 % of
            # its surface lies within 4 point spacings of one (measured 0.9-2.4)
            assert np.percentile(to_cloud, 95) <= 4 * spacing, (to_cloud.max(), spacing)
        else:
            # screened Poisson is a smooth implicit surface, not through the points: half
            # its surface within max(8 cm, 3 spacings) of a point, 95 % within max(25 cm,
            # 6 spacings) (measured at most 5.8 and 16 cm, the sparse Lille_2 10.3 and
            # 23 cm = 1.7 and 3.7 of its 6.2 cm spacings)
            assert np.median(to_cloud) <= max(0.08, 3 * spacing), (np.median(to_cloud), spacing)
            assert np.percentile(to_cloud, 95) <= max(0.25, 6 * spacing), spacing
    if method == "qsm":
        assert fig["volume_total_m3"] > 0 and fig["volume_stem_m3"] > 0
        assert fig["watertight"]
        width = stem_width_m(cloud.points)
        # 10 % slack: a sparse slab (14 points on Lille_2) under-samples the stem's outline
        assert 0 < fig["dbh_m"] <= 1.1 * width, (fig["dbh_m"], width)
    # leaf-on input is reported as such (Lille_2 is a leaf-on urban tree), leaf-off is not
    if tree[1] == "Lille_2.xyz":
        assert fig["leaves_present"] is True
    if tree[1] in ("cloud.txt", "Tree_2_point_cloud.las"):
        assert fig["leaves_present"] is False


def test_coffee_tree_beside_the_published_qsms(capsys):
    path = tree_path("coffee_tree", "cloud.txt")
    fig = reconstruct(read_cloud(path)).figures
    with capsys.disabled():
        print(
            f"\ncoffee tree: treesim {fig['volume_total_m3'] * 1000:.1f} L, DBH "
            f"{fig['dbh_m'] * 100:.2f} cm (noise σ estimated {fig['noise_sd_m'] * 1e3:.1f} mm) "
            "| TreeQSM 2.4.1 21.6 L, 7.35 cm | SimpleForest 30.0 L"
        )
    # two published models of this cloud differ by 40 %; ours must sit in that span's
    # neighbourhood and the DBH near both tools' 7.35 cm
    assert 15.0 <= fig["volume_total_m3"] * 1000 <= 35.0
    assert abs(fig["dbh_m"] - 0.0735) < 0.005
    # and, deterministic, exactly what the manual prints: within half its last digit
    # (19.6 L: 0.05 L; 7.21 cm: 0.005 cm; 1.4 mm: 0.05 mm)
    litres, dbh_cm, noise_mm = readme_coffee_figures()
    assert fig["volume_total_m3"] * 1000 == pytest.approx(litres, abs=0.05)
    assert fig["dbh_m"] * 100 == pytest.approx(dbh_cm, abs=0.005)
    assert fig["noise_sd_m"] * 1e3 == pytest.approx(noise_mm, abs=0.05)
