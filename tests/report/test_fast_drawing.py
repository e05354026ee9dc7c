"""Issue 25: the report drawn cheaply must say the same. Oracles: Pillow's decoder and
matplotlib's own ``savefig`` for the PNG writer, brute-force distances for the occlusion
profile's shortcut."""

from __future__ import annotations

import io

import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg

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


def _busy_figure() -> object:
    """Axes of each kind a report draws: numbers with a grid, categories without one,
    a shared y axis without labels, equal aspect, a colour bar (ticks on the right)."""
    from matplotlib.cm import ScalarMappable

    fig = F._fixed_figure(7.0, 3.0)
    a, b, c = F._grid(fig, 1, 3, margins_in=(0.7, 0.6, 0.5, 0.35), wgap_in=0.6, sharey=False)
    a.bar(["all", "S0", "S1"], [90.0, 40.0, 55.5])
    a.grid(axis="x", visible=False)
    a.set_xlabel("station")
    a.set_ylabel("within τ (%)")
    b.plot([0.0, 3.0, 1.5], [0.0, 2.0, 7.0], marker="o")
    b.sharey(c)
    b.set_xlabel("points per m²")
    c.imshow(np.arange(12.0).reshape(3, 4), extent=(0.0, 4.0, 0.0, 3.0))
    c.set_aspect("equal", adjustable="datalim")
    c.set_xlabel("x (m)")
    fig.colorbar(ScalarMappable(), ax=c, extend="max").set_label("distance (mm)")
    return fig


def test_flat_axes_draw_the_pixels_of_matplotlibs_ticks():
    import matplotlib

    with matplotlib.rc_context(F._RC):
        fig = _busy_figure()
        fig.set_dpi(80)
        fig.canvas.draw()  # matplotlib's own ticks
        theirs = np.asarray(fig.canvas.buffer_rgba()).copy()
        fig = _busy_figure()
        F._flatten_axes(fig)
        flat = [a for ax in fig.axes for a in ax.get_children() if type(a).__name__ == "FlatAxis"]
        ours = F.render_rgb(fig, 80)
    # both axes of the three panels and the colour bar's long one (ticks on the right);
    # its short axis, without ticks on either side, is matplotlib's
    assert len(flat) == 7
    assert ours.shape == theirs[..., :3].shape and np.array_equal(ours, theirs[..., :3])


def test_cached_texts_draw_the_same_pixels_again():
    import matplotlib

    with matplotlib.rc_context(F._RC):
        first = F.render_rgb(_busy_figure(), 80)
        again = F.render_rgb(_busy_figure(), 80)  # every text from the cache now
        fig = _busy_figure()
        fig.set_dpi(80)
        plain = FigureCanvasAgg(fig)  # matplotlib's own text rendering
        plain.draw()
        theirs = np.asarray(plain.buffer_rgba())[..., :3]
    assert np.array_equal(first, again)
    # the same texts, placed at whole pixels: only some edge pixels of the glyphs differ
    # (3.2 % of this figure's pixels since its colour bar has a label)
    differ = np.abs(first.astype(int) - theirs.astype(int)).max(axis=2) > 0
    assert 0.0 < differ.mean() < 0.04


@pytest.mark.parametrize("odd", [False, True])
def test_tick_free_axes_draw_the_pixels_of_matplotlibs_axes(tmp_path, odd):
    """The report's axes make no tick until one is used; drawn (flat axes, and axes that
    matplotlib draws itself: a log scale, ticks on the right, all four spines, shared y)
    they give matplotlib's own Axes' pixels."""
    import matplotlib
    from matplotlib.axes import Axes

    def draw(axes_class: type) -> np.ndarray:
        fig = F._fixed_figure(5.0, 2.5)
        axes = F._grid(
            fig,
            1,
            2,
            margins_in=(0.7, 0.5, 0.5, 0.35),
            wgap_in=0.3,
            sharey=True,
            subplot_kw={"axes_class": axes_class},
        )
        for ax in axes:
            ax.plot([1.0, 2.0, 30.0], [0.5, 3.0, 1.0])
            for spine in ax.spines.values():
                spine.set_visible(True)
            ax.set_xlabel("x (m)")
        if odd:
            axes[0].set_xscale("log")
            axes[1].yaxis.tick_right()
            axes[1].tick_params(axis="x", colors="red", length=6)
            axes[1].grid(False)
        return F.render_rgb(fig, 80)

    with matplotlib.rc_context(F._RC):
        ours = draw(F._tick_free_axes_class())
        theirs = draw(Axes)
    assert ours.shape == theirs.shape and np.array_equal(ours, theirs)
    with matplotlib.rc_context(F._RC):
        fig = F._fixed_figure(3.0, 2.0)
        ax = F._grid(fig, 1, 1, margins_in=(0.5, 0.2, 0.4, 0.2))
        assert "majorTicks" not in vars(ax.xaxis) and "majorTicks" not in vars(ax.yaxis)


@pytest.mark.parametrize("size", [7.0, 9.5, 14.0])
@pytest.mark.parametrize("weight", ["normal", "bold"])
def test_the_report_renderer_lays_text_out_as_matplotlib(size, weight):
    """The report canvas' renderer keeps each font's height metrics (matplotlib reads
    them from the font's tables for every text at every draw): a text's layout, lines,
    gaps and box, is matplotlib's own renderer's."""
    from matplotlib.backends.backend_agg import RendererAgg
    from matplotlib.text import Text

    fig = F._fixed_figure(3.0, 2.0)
    ours = fig.canvas.get_renderer()
    theirs = RendererAgg(*fig.canvas.get_width_height(physical=True), fig.dpi)
    assert hasattr(ours, "_get_font_height_metrics")
    for s in ("x (m)", "two\nlines τ", "Ågp"):
        t = Text(0.5, 0.5, s, fontsize=size, fontweight=weight, linespacing=1.3)
        t.set_figure(fig)
        for _ in range(2):  # the second time from what the renderer kept
            (box, lines, descent), (want_box, want_lines, want_descent) = (
                t._get_layout(ours),
                t._get_layout(theirs),
            )
            assert box.bounds == want_box.bounds
            assert (lines, descent) == (want_lines, want_descent)


def test_pngs_written_behind_are_the_ones_written_at_once(tmp_path):
    """Oracle: the same figures saved inline; a failed write raises where it ends."""
    import matplotlib

    def draw(path):
        with matplotlib.rc_context(F._RC):
            return F._save(_busy_figure(), path, 60)

    at_once = [draw(tmp_path / f"a{i}.png") for i in range(3)]
    with F.writing_behind():
        behind = [draw(tmp_path / f"b{i}.png") for i in range(3)]
    for a, b in zip(at_once, behind, strict=True):
        assert a.read_bytes() == b.read_bytes()
    with pytest.raises(OSError), F.writing_behind():
        draw(tmp_path / "no such folder" / "c.png")
