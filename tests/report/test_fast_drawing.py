"""Issue 25: the report drawn cheaply must say the same. Oracles: Pillow's decoder and
matplotlib's own ``savefig`` for the PNG writer, brute-force distances for the occlusion
profile's shortcut."""

from __future__ import annotations

import io

import numpy as np
import pytest

from treesim.report import figures as F
from treesim.report.profile import _CellGrid, _within


def test_png_bytes_decode_to_the_pixels_and_dpi():
    from PIL import Image

    rng = np.random.default_rng(0)
    for channels in (3, 4):
        px = rng.integers(0, 256, (37, 53, channels), dtype=np.uint8)
        im = Image.open(io.BytesIO(F.png_bytes(px, 130)))
        assert im.mode == ("RGB" if channels == 3 else "RGBA")
        assert np.array_equal(np.asarray(im), px)
        assert im.info["dpi"] == pytest.approx((130, 130), abs=0.01)  # whole pixels per metre


def test_a_report_figure_has_the_pixels_savefig_draws(tmp_path):
    from PIL import Image

    def draw() -> object:
        fig = F._fixed_figure(4.0, 2.5)
        ax = F._grid(fig, 1, 1, margins_in=(0.7, 0.15, 0.5, 0.35))
        ax.stairs([3.0, 1.0, 2.0], [0.0, 1.0, 2.0, 3.0], fill=True, color=F.ACCURACY_COLOUR)
        ax.set_title("title τ")
        ax.set_xlabel("distance (mm)")
        return fig

    import matplotlib

    with matplotlib.rc_context(F._RC):
        F._save(draw(), tmp_path / "ours.png", 90)
        draw().savefig(tmp_path / "mpl.png", dpi=90)
    ours = np.asarray(Image.open(tmp_path / "ours.png").convert("RGBA"))
    theirs = np.asarray(Image.open(tmp_path / "mpl.png").convert("RGBA"))
    assert ours.shape == theirs.shape and np.array_equal(ours, theirs)


@pytest.mark.parametrize("tau", [0.01, 0.3])
def test_within_tau_is_the_brute_force_answer(tau):
    from scipy.spatial.distance import cdist

    rng = np.random.default_rng(1)
    ref = rng.uniform(-1, 1, (3000, 3))
    pts = rng.uniform(-1, 1, (800, 3))
    # points at about τ from a reference point: the shortcut must not round them in
    near = ref[:200] + rng.normal(size=(200, 3)) * tau / np.sqrt(3)
    pts = np.concatenate([pts, near])
    want = cdist(ref, pts).min(axis=1) <= tau
    grid = _CellGrid.of(ref, tau)
    assert grid is not None
    assert np.array_equal(_within(ref, pts, tau, grid, 1), want)
    assert np.array_equal(_within(ref, pts, tau, None, 1), want)
    shared = grid.shared(pts)
    assert shared.any() and not shared.all()  # the shortcut decided some, not all
    assert want[shared].all()  # a shared cell is always within τ


def test_no_grid_without_a_positive_tau():
    ref = np.zeros((4, 3))
    assert _CellGrid.of(ref, 0.0) is None and _CellGrid.of(ref, float("nan")) is None
