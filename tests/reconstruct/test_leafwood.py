"""Wood/leaf separation and the leaf layer, with exact labels from the virtual scanner.

The acceptance figures of issue 13 §4 on the ``aspen-leafon`` preset (seed 0, which the
classifier was not fitted on: scripts/fit_leafwood.py uses seeds 1 and 2), scanned with
the RIEGL VZ-400 noise model from three stations. To keep the suite cheap the scans are
coarser than the field standard (0.04°): 0.08°, about 240 000 points after 5 mm voxels.
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.reconstruct.leafon import labelled_voxels, scan_preset, wood_scores
from treesim.cloud import LABEL_CODES, Cloud
from treesim.errors import ModelError, ReconstructionError
from treesim.models.leaves import leaf_layer
from treesim.reconstruct import reconstruct
from treesim.reconstruct.leafwood import separate_leaves

STEP_DEG = 0.08


@pytest.fixture(scope="module")
def leafon_scan():
    return scan_preset("aspen-leafon", STEP_DEG)


@pytest.mark.slow
def test_separation_finds_the_wood_of_the_leaf_on_aspen(leafon_scan):
    _, cloud = leafon_scan
    is_wood = cloud.fields["label"] == LABEL_CODES["wood"]
    pts, truth = labelled_voxels(cloud.points, is_wood, 0.005)
    result = separate_leaves(pts)
    precision, recall = wood_scores(result.wood, truth)
    print(f"\naspen-leafon at {STEP_DEG} deg: wood precision {precision:.3f}, recall {recall:.3f}")
    # issue 13 §4: at least 95 % of each (measured 0.974 and 0.981 at this step)
    assert precision >= 0.95
    assert recall >= 0.95


#: The headline of issue 22 (the README's feature table said "wood precision 0.99, recall
#: 0.98 on the aspen-leafon preset at 0.04°") and the figures of the bench_leaves block
#: behind it, now in docs/validation.md (2026-11-25: "wood precision 0.992, recall
#: 0.977"), measured as that block says: ``benchmarks/bench_leaves.py --step-deg 0.04``,
#: i.e. seed 0, VZ-400 noise, three stations, 5 mm voxels, scored against the scanner's
#: labels.
HEADLINE_STEP_DEG = 0.04
HEADLINE = {"precision": 0.99, "recall": 0.98}
MEASURED = {"precision": 0.992, "recall": 0.977}


@pytest.mark.slow
def test_separation_reaches_the_readme_headline_at_the_field_step():
    # ~0.9 M voxels: the field standard the README quotes, not the suite's cheaper 0.08°
    _, cloud = scan_preset("aspen-leafon", HEADLINE_STEP_DEG)
    is_wood = cloud.fields["label"] == LABEL_CODES["wood"]
    pts, truth = labelled_voxels(cloud.points, is_wood, 0.005)
    precision, recall = wood_scores(separate_leaves(pts).wood, truth)
    got = {"precision": precision, "recall": recall}
    print(f"\naspen-leafon at {HEADLINE_STEP_DEG} deg: wood precision {precision:.4f}, "
          f"recall {recall:.4f}")  # fmt: skip
    for key in HEADLINE:
        # each figure as printed: the headline to 2 decimals (recall 0.977 was printed
        # 0.98), the measured block to 3; a worse classifier falls below either
        assert round(got[key], 2) >= HEADLINE[key], (key, got[key])
        assert round(got[key], 3) >= MEASURED[key], (key, got[key])


def test_separation_refuses_a_tiny_cloud():
    with pytest.raises(ReconstructionError, match="at least"):
        separate_leaves(np.random.default_rng(0).random((20, 3)))


def test_separation_calls_a_bare_cylinder_wood():
    # a 10 cm-radius stem, 1 m long, sampled every 1 cm with 1 mm noise: all wood
    rng = np.random.default_rng(1)
    z, a = np.meshgrid(np.arange(0, 1.0, 0.01), np.arange(0, 2 * np.pi, 0.1))
    pts = np.column_stack([0.1 * np.cos(a.ravel()), 0.1 * np.sin(a.ravel()), z.ravel()])
    pts += rng.normal(0, 0.001, pts.shape)
    assert separate_leaves(pts).wood.mean() > 0.95


def test_leaf_layer_matches_the_seen_leaf_area():
    # a flat 1 m x 1 m sheet sampled every 1 cm: 1 m² seen, leaves of 5 cm -> 400 leaves
    g = np.arange(0, 1.0, 0.01)
    x, y = np.meshgrid(g, g)
    pts = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, 2.0)])
    layer = leaf_layer(pts, spacing_m=0.01, side_m=0.05, voxel_m=0.25)
    assert layer.n_leaves == 400
    assert layer.leaf_area_m2 == pytest.approx(1.0)
    assert layer.faces.shape == (800, 3) and layer.vertices.shape == (1600, 3)
    # leaves lie in the sheet's plane (normal from the plane fit), inside its volume
    assert np.abs(layer.vertices[:, 2] - 2.0).max() < 1e-9
    assert (layer.vertices[:, :2] > -0.04).all() and (layer.vertices[:, :2] < 1.04).all()
    again = leaf_layer(pts, spacing_m=0.01, side_m=0.05, voxel_m=0.25)
    assert np.array_equal(layer.vertices, again.vertices)  # seeded


def test_leaf_layer_checks_its_input():
    with pytest.raises(ModelError, match="side_m"):
        leaf_layer(np.zeros((10, 3)), spacing_m=0.01, side_m=0)
    assert leaf_layer(np.zeros((2, 3)), spacing_m=0.01).n_leaves == 0


def test_reconstruct_off_by_default_on_leaf_off_clouds():
    # auto: a leaf-off cloud (a bare cylinder) is not separated, and writes no labels
    g = np.arange(0, 2.0, 0.01)
    a = np.arange(0, 2 * np.pi, 0.1)
    z, t = np.meshgrid(g, a)
    pts = np.column_stack([0.1 * np.cos(t.ravel()), 0.1 * np.sin(t.ravel()), z.ravel()])
    model = reconstruct(Cloud(pts))
    assert model.labels is None and "points_wood" not in model.figures


# auto: the classifier's leaf share decides. Cases where preparation's normal-spread
# measure (the former statistic) read on the wrong side of its 0.25 cut: a sparse
# leaf-on scan (aspen-leafon at 0.12 deg: 0.04; balsam-fir: 0.19) and a dense leaf-off
# one (sapling at 0.04 deg: 0.19).
@pytest.mark.parametrize(
    ("preset", "step_deg", "leafy"),
    [
        ("aspen-leafon", 0.12, True),
        ("balsam-fir", 0.12, True),
        ("aspen", 0.12, False),
        ("sapling", 0.04, False),
    ],
)
def test_auto_tells_leaf_on_from_leaf_off(preset, step_deg, leafy):
    from treesim.reconstruct._leaves import LEAF_SHARE_CUT, separate
    from treesim.reconstruct.preprocess import prepare

    _, cloud = scan_preset(preset, step_deg)
    sep = separate(prepare(cloud.points, normals=False), "auto")
    share = sep.figures["leaf_share"]
    print(f"\n{preset} at {step_deg} deg: leaf share {share:.3f}")
    assert sep.used is leafy and sep.figures["leaves_present"] is leafy
    # with a margin: leaf-on presets read 0.56-0.63, leaf-off ones at most 0.137
    assert (share > LEAF_SHARE_CUT + 0.1) if leafy else (share < LEAF_SHARE_CUT - 0.05)
