"""The report's PNG plots, drawn with matplotlib's object API on the Agg canvas.

No pyplot and no global backend switch: every figure is a ``matplotlib.figure.Figure``
with its own ``FigureCanvasAgg``, so drawing a report never disturbs a caller's
interactive session and works without a display.
"""

from __future__ import annotations

import contextlib
import functools
import math
import struct
import threading
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from .data import ReportData
from .text import FLOAT_NOISE_M

#: Colours of the two directions, used by every plot and by the HTML page.
ACCURACY_COLOUR = "#2c6e9b"
COMPLETENESS_COLOUR = "#c2612d"
LABEL_COLOURS = {"wood": "#8a5a34", "leaf": "#4f8a3a", "ground": "#8c8170", "other": "#7b8794"}
#: Viridis without its palest yellow, which vanishes on white.
CMAP_RANGE = (0.0, 0.92)

_RC = {
    "font.size": 9.5,
    "axes.titlesize": 10.5,
    "axes.titleweight": "bold",
    "axes.titlelocation": "left",
    # titles at the top of their axes (above them nothing is drawn): matplotlib's automatic
    # title position measures every tick label of every axes at each draw, a sixth of a
    # report's drawing time
    "axes.titley": 1.0,
    "axes.labelsize": 9.5,
    "axes.labelcolor": "#333b45",
    "axes.edgecolor": "#9aa5b1",
    "axes.spines.top": False,
    "axes.spines.right": False,
    "axes.grid": True,
    "grid.color": "#e4e7eb",
    "grid.linewidth": 0.8,
    "xtick.color": "#52606d",
    "ytick.color": "#52606d",
    "legend.frameon": False,
    "figure.facecolor": "white",
    "savefig.facecolor": "white",
}


def cmap() -> Any:
    """The distance colour map (viridis truncated to :data:`CMAP_RANGE`)."""
    from matplotlib import colormaps
    from matplotlib.colors import ListedColormap

    base = colormaps["viridis"]
    return ListedColormap(base(np.linspace(*CMAP_RANGE, 256)), name="treesim_distance")


def unit_for(extent_m: float) -> tuple[str, float]:
    """A readable unit for axes spanning ``extent_m``: (name, metres -> unit factor)."""
    if extent_m >= 2.0:
        return "m", 1.0
    if extent_m >= 2e-3:
        return "mm", 1e3
    if extent_m >= 2e-6:
        return "µm", 1e6
    return "nm", 1e9


def accuracy_colour_limit(summary: dict[str, Any]) -> float:
    """Top of the accuracy colour scale (m): the p99 distance, at least 0.1 mm."""
    return max(float(summary["accuracy"]["p99_m"] or 0.0), 1e-4)


def completeness_colour_limit(summary: dict[str, Any]) -> float:
    """Top of the completeness colour scale (m): the p95 distance, at least τ."""
    return max(float(summary["completeness"]["p95_m"] or 0.0), float(summary["tolerance_m"]))


def _num(x: float) -> str:
    """A figure for a legend: 3 significant digits, and 0 for round-off (< 0.0005)."""
    return "0" if abs(x) < 5e-4 else f"{x:.3g}"


def _new_figure(w: float, h: float) -> Any:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(w, h), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


#: Most texts a report's canvases keep rendered (tick labels repeat across its figures).
TEXT_CACHE_SIZE = 4096


def _height_metrics(fonts: tuple[str, ...], size: float, dpi: float) -> tuple[Any, Any, Any]:
    """Ascent, descent and line gap of the font of files ``fonts`` at ``size`` points and
    ``dpi``, as matplotlib's text layout computes them from the font's tables (for each
    text, at every draw); Nones where the font has neither table."""
    from matplotlib import font_manager

    for table_name, gap_key, ascent_key, descent_key in (
        ("OS/2", "sTypoLineGap", "sTypoAscender", "sTypoDescender"),
        ("hhea", "lineGap", "ascent", "descent"),
    ):
        font = font_manager.get_font(fonts)
        table = font.get_sfnt_table(table_name)
        if table is None:
            continue
        scale = 1 / font.get_sfnt_table("head")["unitsPerEm"] * size * dpi / 72
        return table[ascent_key] * scale, -table[descent_key] * scale, table[gap_key] * scale
    return None, None, None


@functools.cache
def _canvas_class() -> type:
    """An Agg canvas whose renderer keeps each text it rendered, as one bitmap, and each
    text's size: a report draws the same tick labels and titles again and again, and
    matplotlib lays out and renders every glyph of every text at every draw (a third of
    a report's drawing time). A text is placed at whole pixels (as matplotlib did before
    3.10), so its pixels may differ from matplotlib's own by a fraction of a pixel's
    shift; mathtext, and text with font features or a language, are drawn by matplotlib.
    """
    import matplotlib as mpl
    from matplotlib import font_manager
    from matplotlib.backends.backend_agg import FigureCanvasAgg, RendererAgg, get_hinting_flag

    images: dict[tuple[Any, ...], tuple[np.ndarray, float, float, float]] = {}
    sizes: dict[tuple[Any, ...], tuple[float, float, float]] = {}

    found: dict[tuple[Any, ...], tuple[str, ...]] = {}

    def fonts_of(prop: Any) -> tuple[str, ...]:
        """The font files of ``prop``, looked up once per properties and rc families."""
        generic = tuple(
            tuple(mpl.rcParams[f"font.{f}"])
            for f in prop.get_family()
            if f"font.{f}" in mpl.rcParams
        )
        k = (hash(prop), generic)
        got = found.get(k)
        if got is None:
            got = found[k] = tuple(font_manager.fontManager._find_fonts_by_props(prop))
        return got

    def key(renderer: Any, s: str, prop: Any, *extra: Any) -> tuple[Any, ...]:
        size = prop.get_size_in_points()
        return (s, fonts_of(prop), size, renderer.dpi, get_hinting_flag(), *extra)

    def remember(cache: dict[Any, Any], k: tuple[Any, ...], value: Any) -> Any:
        if len(cache) >= TEXT_CACHE_SIZE:
            cache.clear()
        cache[k] = value
        return value

    def render(renderer: Any, s: str, prop: Any, aa: bool) -> tuple[Any, Any]:
        """Lay ``s`` out once: its size (width, height, descent) and its bitmap (with the
        bitmap's offset and the descent), both kept."""
        font = renderer._prepare_font(prop)
        font.set_text(s, 0.0, flags=get_hinting_flag())
        w, h = font.get_width_height()
        d = font.get_descent() / 64.0
        font.draw_glyphs_to_bitmap(antialiased=aa)
        xo, yo = font.get_bitmap_offset()
        image = np.array(font.get_image(), dtype=np.uint8)
        size = remember(sizes, key(renderer, s, prop), (w / 64.0, h / 64.0, d))
        return size, remember(images, key(renderer, s, prop, aa), (image, xo / 64, yo / 64, d))

    heights: dict[tuple[Any, ...], tuple[Any, Any, Any]] = {}

    class Renderer(RendererAgg):
        def _get_font_height_metrics(self, prop: Any) -> tuple[Any, Any, Any]:
            # matplotlib's own numbers (Text._get_layout), kept per font, size and dpi
            k = (fonts_of(prop), prop.get_size_in_points(), self.dpi)
            got = heights.get(k)
            if got is None:
                got = remember(heights, k, _height_metrics(k[0], k[1], self.dpi))
            return got

        def get_text_width_height_descent(self, s: str, prop: Any, ismath: Any) -> Any:
            if ismath:
                return super().get_text_width_height_descent(s, prop, ismath)
            got = sizes.get(key(self, s, prop))
            if got is None:  # rendered now too: matplotlib measures a text, then draws it
                got = render(self, s, prop, bool(mpl.rcParams["text.antialiased"]))[0]
            return got

        def draw_text(self, gc: Any, x: float, y: float, s: str, prop: Any, angle: float,
                      ismath: Any = False, mtext: Any = None) -> None:  # fmt: skip
            plain = mtext is None or not (mtext.get_fontfeatures() or mtext.get_language())
            if ismath or not plain:
                super().draw_text(gc, x, y, s, prop, angle, ismath, mtext)
                return
            aa = bool(gc.get_antialiased())
            k = key(self, s, prop, aa)
            got = images.get(k)
            if got is None:
                got = render(self, s, prop, aa)[1]
            image, xo, yo, descent = got
            # (x, y): the baseline's left end, y downwards; the bitmap's lower left corner
            xd = descent * math.sin(math.radians(angle))
            yd = descent * math.cos(math.radians(angle))
            try:
                self._renderer.draw_text_image(
                    image, round(x + xo + xd), round(y + yo + yd) + 1, angle, gc
                )
            except TypeError:  # a matplotlib whose renderer takes a font, not a bitmap
                super().draw_text(gc, x, y, s, prop, angle, ismath, mtext)

    class Canvas(FigureCanvasAgg):
        def get_renderer(self) -> Any:
            w, h = self.get_width_height(physical=True)
            k = w, h, self.figure.dpi
            if self._lastKey != k:
                self.renderer = Renderer(w, h, self.figure.dpi)
                self._lastKey = k
            return self.renderer

    return Canvas


#: What a plain axis' tick settings may say (anything else: matplotlib draws that axis).
_PLAIN_TICK_KEYS = frozenset({"gridOn", "tick1On", "tick2On", "label1On", "label2On"})


@functools.cache
def _flat_axis_class() -> type:
    """An artist that draws one axis as matplotlib does (the ticks its locator and
    formatter give, tick marks, grid lines, tick labels, the axis label below or beside
    them) with one line for all tick marks, one for all grid lines and one text per
    label: matplotlib builds a ``Tick`` of five artists for every tick of every axis,
    about a third of a report's drawing time. Settings are read from the rc parameters
    when it is made, as matplotlib's ticks read them."""
    import matplotlib as mpl
    from matplotlib import transforms as mtransforms
    from matplotlib.artist import Artist

    class FlatAxis(Artist):
        def __init__(self, axis: Any, side: str) -> None:
            super().__init__()
            self.axis = axis
            self.side = side  # bottom, left or right: where its ticks and labels are
            self.which = "2" if side == "right" else "1"  # matplotlib's tick1 or tick2
            self.set_zorder(axis.get_zorder())
            name = axis.axis_name
            rc = mpl.rcParams
            kw = axis._major_tick_kw
            self.is_x = name == "x"
            self.size = float(rc[f"{name}tick.major.size"])
            self.width = float(rc[f"{name}tick.major.width"])
            self.colour = rc[f"{name}tick.color"]
            label_colour = rc[f"{name}tick.labelcolor"]
            self.label_colour = self.colour if label_colour == "inherit" else label_colour
            self.label_size = rc[f"{name}tick.labelsize"]
            self.direction = rc[f"{name}tick.direction"]
            self.pad = float(rc[f"{name}tick.major.pad"])
            self.grid = {
                "color": rc["grid.color"],
                "linestyle": rc["grid.linestyle"],
                "linewidth": rc["grid.linewidth"],
                "alpha": rc["grid.alpha"],
            }
            first = self.which == "1"
            self.grid_on = bool(kw["gridOn"])
            self.tick_on = bool(kw.get(f"tick{self.which}On", first))
            self.label_on = bool(kw.get(f"label{self.which}On", first))

        def draw(self, renderer: Any) -> None:
            axis = self.axis
            ax = axis.axes
            locs = np.asarray(axis.get_majorticklocs(), dtype=np.float64)
            formatter = axis.major.formatter
            labels = formatter.format_ticks(locs)
            lo, hi = sorted(axis.get_view_interval())
            slack = 1e-10 * (hi - lo)  # matplotlib's tolerance for a tick at the edge
            shown = (locs >= lo - slack) & (locs <= hi + slack)
            locs = locs[shown]
            labels = [s for s, keep in zip(labels, shown, strict=True) if keep]
            for part in _flat_axis_lines(self, locs):
                part.draw(renderer)
            boxes = _flat_axis_labels(self, locs, labels, renderer)
            # the axis label clear of the tick labels, as matplotlib places it
            box = mtransforms.Bbox.union([*boxes, ax.spines.get(self.side, ax).get_window_extent()])
            gap = axis.labelpad * ax.figure.dpi / 72
            x, y = axis.label.get_position()
            at = {"bottom": (x, box.y0 - gap), "left": (box.x0 - gap, y)}
            axis.label.set_position(at.get(self.side, (box.x1 + gap, y)))
            _draw_text(axis.label, renderer)
            offset = formatter.get_offset()
            if offset:
                axis.offsetText.set_text(offset)
                axis._update_offset_text_position(boxes, boxes)
                axis.offsetText.draw(renderer)
            self.stale = False

    return FlatAxis


def _flat_axis_lines(flat: Any, locs: np.ndarray) -> list[Any]:
    """A flat axis' grid lines and tick marks at ``locs`` (:func:`_flat_axis_class`)."""
    from matplotlib import lines as mlines

    ax, fig = flat.axis.axes, flat.axis.axes.figure
    n = len(locs)
    parts: list[Any] = []
    if flat.grid_on and n:
        across = np.tile([0.0, 1.0, np.nan], n)
        at = np.repeat(locs, 3)
        xy = (at, across) if flat.is_x else (across, at)
        grid = mlines.Line2D(*xy, transform=_flat_axis_trans(flat, "grid"), marker="", **flat.grid)
        grid.set_clip_path(ax.patch)
        parts.append(grid)
    if flat.tick_on and n:
        out = flat.direction == "out"
        marker = {
            "bottom": mlines.TICKDOWN if out else mlines.TICKUP,
            "left": mlines.TICKLEFT if out else mlines.TICKRIGHT,
            "right": mlines.TICKRIGHT if out else mlines.TICKLEFT,
        }[flat.side]
        across = np.full(n, 1.0 if flat.which == "2" else 0.0)
        xy = (locs, across) if flat.is_x else (across, locs)
        parts.append(
            mlines.Line2D(
                *xy,
                transform=_flat_axis_trans(flat, f"tick{flat.which}"),
                linestyle="none",
                marker=marker,
                color=flat.colour,
                markeredgecolor=flat.colour,
                markersize=flat.size,
                markeredgewidth=flat.width,
                clip_on=False,
            )
        )
    for part in parts:
        part.set_figure(fig)
    return parts


def _flat_axis_trans(flat: Any, which: str) -> Any:
    """The axis' transform of its ``which`` (``grid``, ``tick1``, ``tick2``): data along
    it, axes across."""
    ax = flat.axis.axes
    return ax.get_xaxis_transform(which) if flat.is_x else ax.get_yaxis_transform(which)


def _flat_axis_labels(flat: Any, locs: np.ndarray, labels: list[str], renderer: Any) -> list[Any]:
    """Draw a flat axis' tick labels where a matplotlib tick would put them (one text
    moved from label to label); their boxes."""
    from matplotlib.text import Text

    if not flat.label_on:
        return []
    ax = flat.axis.axes
    pad = flat.pad + (flat.size if flat.direction == "out" else 0.0)
    text = getattr(ax, f"get_{'x' if flat.is_x else 'y'}axis_text{flat.which}_transform")
    trans, va, ha = text(pad)
    t = Text(
        0.0,
        0.0,
        "",
        transform=trans,
        verticalalignment=va,
        horizontalalignment=ha,
        fontsize=flat.label_size,
        color=flat.label_colour,
    )
    t.set_figure(ax.figure)
    boxes = []
    across = 1.0 if flat.which == "2" else 0.0  # the axes' far side (tick2) or near one
    for loc, label in zip(locs, labels, strict=True):
        if not label:
            continue
        t.set_position((loc, across) if flat.is_x else (across, loc))
        t.set_text(label)
        box = _draw_text(t, renderer)
        if box is not None:
            boxes.append(box)
    return boxes


#: Layouts of texts (matplotlib's ``Text._get_layout``: box, lines, descent) by all they
#: depend on: a report lays the same tick labels out again and again.
_LAYOUTS: dict[tuple[Any, ...], tuple[Any, Any, Any]] = {}


def _text_layout(t: Any, renderer: Any) -> tuple[Any, Any, Any]:
    """``t._get_layout(renderer)``, kept (:data:`_LAYOUTS`)."""
    import matplotlib as mpl

    prop = t.get_fontproperties()
    rc = mpl.rcParams
    key = (
        t.get_text(),
        tuple(prop.get_family()),
        tuple(tuple(rc[f"font.{f}"]) for f in prop.get_family() if f"font.{f}" in rc),
        prop.get_style(),
        prop.get_variant(),
        prop.get_weight(),
        prop.get_stretch(),
        prop.get_size_in_points(),
        prop.get_file(),
        prop.get_math_fontfamily(),
        t._linespacing,
        t._get_multialignment(),
        t.get_rotation(),
        t.get_horizontalalignment(),
        t.get_verticalalignment(),
        t.get_rotation_mode(),
        t.get_usetex(),
        t.get_parse_math(),
        t.get_figure(root=True).dpi,
        type(renderer),
        rc["text.hinting"],
        rc["text.hinting_factor"],
        rc["text.kerning_factor"],
    )
    got = _LAYOUTS.get(key)
    if got is None:
        if len(_LAYOUTS) >= TEXT_CACHE_SIZE:
            _LAYOUTS.clear()
        got = _LAYOUTS[key] = t._get_layout(renderer)
    return got


def _draw_text(t: Any, renderer: Any) -> Any:
    """Draw the text ``t`` as its ``draw`` does, laid out once (:func:`_text_layout`);
    its box in display pixels (``get_window_extent``), None where it draws nothing.
    Text that is wrapped, boxed, with path effects or TeX: drawn by matplotlib."""
    from matplotlib import colors as mcolors

    if not t.get_visible() or t.get_text() == "":
        return None
    if t.get_wrap() or t.get_bbox_patch() or t.get_path_effects() or t.get_usetex():
        t.draw(renderer)
        return t.get_window_extent(renderer)
    t._renderer = renderer
    box, info, _ = _text_layout(t, renderer)
    posx, posy = t.get_transform().transform(t.get_unitless_position())
    if not (np.isfinite(posx) and np.isfinite(posy)):
        return None
    canvash = renderer.get_canvas_width_height()[1]
    gc = renderer.new_gc()
    gc.set_foreground(mcolors.to_rgba(t.get_color()), isRGBA=True)
    gc.set_alpha(t.get_alpha())
    gc.set_url(t.get_url())
    gc.set_antialiased(t._antialiased)
    gc.set_snap(t.get_snap())
    t._set_gc_clip(gc)
    angle = t.get_rotation()
    for line, _, (x, y) in info:
        clean, ismath = t._preprocess_math(line)
        y = y + posy
        renderer.draw_text(
            gc,
            x + posx,
            canvash - y if renderer.flipy() else y,
            clean,
            t.get_fontproperties(),
            angle,
            ismath=ismath,
            mtext=t if len(info) == 1 else None,
        )
    gc.restore()
    t.stale = False
    return box.translated(posx, posy)


def _flatten_axes(fig: Any) -> None:
    """Every plain axis of ``fig`` (ticks and labels below, left or right (a colour
    bar's), linear, no minor ticks, no tick settings of its own) drawn by a
    :func:`_flat_axis_class` artist in place of matplotlib's ticks; any other axis as
    before."""
    import matplotlib as mpl
    from matplotlib.ticker import NullLocator

    flat = _flat_axis_class()
    for ax in fig.axes:
        for axis in (ax.xaxis, ax.yaxis):
            kw = axis._major_tick_kw
            side = _plain_side(axis)
            plain = (
                side is not None
                and axis.get_visible()
                and set(kw) <= _PLAIN_TICK_KEYS
                and "gridOn" in kw
                and isinstance(axis.get_minor_locator(), NullLocator)
                and axis.get_scale() == "linear"
                and mpl.rcParams[f"{axis.axis_name}tick.direction"] in ("in", "out")
                and axis.label_position == side
                and axis._autolabelpos
            )
            if plain:
                axis.set_visible(False)
                ax.add_artist(flat(axis, side))


def _plain_side(axis: Any) -> str | None:
    """Where an axis' ticks and labels all are, as its tick settings say (an x axis
    below, a y axis left or right), or None (on both sides, or an x axis above)."""
    kw = axis._major_tick_kw
    one = kw.get("tick1On", True) or kw.get("label1On", True)
    two = kw.get("tick2On", False) or kw.get("label2On", False)
    if one and not two:
        return "bottom" if axis.axis_name == "x" else "left"
    if two and not one and axis.axis_name == "y":
        return "right"
    return None


class _NoNewTicks:
    """Within it, an axis whose tick lists were not made yet keeps them unmade (empty)."""

    def __init__(self, axis: Any) -> None:
        self.axis = axis
        self.unmade = [n for n in ("majorTicks", "minorTicks") if n not in vars(axis)]

    def __enter__(self) -> None:
        for name in self.unmade:
            setattr(self.axis, name, [])

    def __exit__(self, *exc: object) -> None:
        for name in self.unmade:  # made on first use again, from the axis' tick settings
            if not getattr(self.axis, name):
                delattr(self.axis, name)


@functools.cache
def _tick_free_axes_class() -> type:
    """An Axes whose axes make no ``Tick`` until one is used: matplotlib makes each axis'
    first major and minor tick (five artists each) when it sets up a new Axes, to apply
    the grid and tick settings and the clip path to them (~15 % of a report's drawing),
    and a report's flat axes (:func:`_flatten_axes`) never use them. The settings are
    kept in the axis' tick settings, from which matplotlib makes every later tick (its
    own contract), and the clip path is given to each tick made later, so an axis that
    matplotlib does draw draws the same ticks."""
    from matplotlib import axis as maxis
    from matplotlib.axes import Axes

    def tick_free(base: type) -> type:
        class TickFreeAxis(base):  # type: ignore[misc, valid-type]
            _tick_clip: tuple[Any, Any] | None = None

            def set_tick_params(self, which: str = "major", reset: bool = False, **kw: Any):
                with _NoNewTicks(self):
                    super().set_tick_params(which, reset, **kw)

            def set_clip_path(self, path: Any, transform: Any = None) -> None:
                self._tick_clip = (path, transform)
                with _NoNewTicks(self):
                    super().set_clip_path(path, transform)

            def _get_tick(self, major: bool) -> Any:
                tick = super()._get_tick(major)
                if self._tick_clip is not None:
                    tick.set_clip_path(*self._tick_clip)
                return tick

            # no ticks asked for (``set_ticks([])``, a colour bar's short axis): none made
            def get_major_ticks(self, numticks: int | None = None) -> list[Any]:
                return [] if numticks == 0 else super().get_major_ticks(numticks)

            def get_minor_ticks(self, numticks: int | None = None) -> list[Any]:
                return [] if numticks == 0 else super().get_minor_ticks(numticks)

        TickFreeAxis.__name__ = f"TickFree{base.__name__}"
        return TickFreeAxis

    x_axis, y_axis = tick_free(maxis.XAxis), tick_free(maxis.YAxis)

    class TickFreeAxes(Axes):
        def _init_axis(self) -> None:  # Axes._init_axis, with the axes above
            self.xaxis = x_axis(self, clear=False)
            self.spines.bottom.register_axis(self.xaxis)
            self.spines.top.register_axis(self.xaxis)
            self.yaxis = y_axis(self, clear=False)
            self.spines.left.register_axis(self.yaxis)
            self.spines.right.register_axis(self.yaxis)

        def clear(self) -> None:
            super().clear()
            # a first tick places the four spines (its transforms ask them where they are);
            # with none made they are placed here, or the top and right ones are drawn in
            # data coordinates
            for spine in self.spines.values():
                spine._ensure_position_is_set()

    return TickFreeAxes


def _fixed_figure(w: float, h: float) -> Any:
    """A figure laid out by :func:`_grid`'s fixed margins: a report's plots have known
    labels, and the constrained layout's solver cost about half of their drawing time.
    Its canvas keeps the texts it rendered (:func:`_canvas_class`)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(w, h))
    _canvas_class()(fig)
    return fig


def _grid(
    fig: Any,
    rows: int,
    cols: int,
    *,
    margins_in: tuple[float, float, float, float],
    wgap_in: float = 0.0,
    hgap_in: float = 0.0,
    **kw: Any,
) -> Any:
    """``fig.subplots(rows, cols)`` inside fixed margins (left, right, bottom, top) and
    gaps between panels, all in inches."""
    w, h = fig.get_size_inches()
    left, right, bottom, top = margins_in
    avg_w = max((w - left - right - (cols - 1) * wgap_in) / cols, 0.1)
    avg_h = max((h - bottom - top - (rows - 1) * hgap_in) / rows, 0.1)
    grid = {
        "left": left / w,
        "right": 1.0 - right / w,
        "bottom": bottom / h,
        "top": 1.0 - top / h,
        "wspace": wgap_in / avg_w,
        "hspace": hgap_in / avg_h,
    }
    sub = {"axes_class": _tick_free_axes_class(), **kw.pop("subplot_kw", {})}
    return fig.subplots(rows, cols, gridspec_kw=grid, subplot_kw=sub, **kw)


#: zlib level of the report's PNGs: level 3 writes files about as small as Pillow's
#: default (6, with its per-row filter search) in a fraction of the time.
PNG_LEVEL = 3


def png_bytes(pixels: np.ndarray, dpi: float) -> bytes:
    """A PNG of ``pixels`` ((h, w, 3) RGB or (h, w, 4) RGBA, uint8, top row first) at
    ``dpi``: one zlib stream of unfiltered rows (a figure's flat colours compress well
    without PNG's row filters, whose search is most of Pillow's encoding time).

    Examples
    --------
    >>> png_bytes(np.zeros((2, 3, 3), np.uint8), 100)[:8]
    b'\\x89PNG\\r\\n\\x1a\\n'
    """
    h, w, c = pixels.shape
    raw = np.empty((h, 1 + w * c), dtype=np.uint8)  # each row: filter type 0, its bytes
    raw[:, 0] = 0
    raw[:, 1:].reshape(h, w, c)[...] = pixels
    ppm = round(dpi / 0.0254)  # pixels per metre, as Pillow writes a dpi

    def chunk(kind: bytes, body: bytes) -> bytes:
        crc = zlib.crc32(body, zlib.crc32(kind)) & 0xFFFFFFFF
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", crc)

    return b"".join(
        (
            b"\x89PNG\r\n\x1a\n",
            chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2 if c == 3 else 6, 0, 0, 0)),
            chunk(b"pHYs", struct.pack(">IIB", ppm, ppm, 1)),
            chunk(b"IDAT", zlib.compress(raw, PNG_LEVEL)),
            chunk(b"IEND", b""),
        )
    )


def render_rgb(fig: Any, dpi: float) -> np.ndarray:
    """Draw ``fig`` on its Agg canvas at ``dpi``: its pixels, (h, w, 3) RGB where every
    pixel is opaque (a report's white figures), else (h, w, 4) RGBA."""
    return _opaque_as_rgb(_render_rgba(fig, dpi))


def _render_rgba(fig: Any, dpi: float) -> np.ndarray:
    """Draw ``fig`` on its Agg canvas at ``dpi``: its (h, w, 4) RGBA pixels (the
    canvas' own buffer)."""
    fig.set_dpi(dpi)
    _flatten_axes(fig)
    _hide_plain_backgrounds(fig)
    fig.canvas.draw()
    return np.asarray(fig.canvas.buffer_rgba())


def _hide_plain_backgrounds(fig: Any) -> None:
    """Not drawn: an axes' background that is the figure's own, opaque, plain colour
    (filling it again over the figure's changes no pixel; it still clips the axes)."""
    from matplotlib.colors import to_rgba

    back = fig.patch
    if not back.get_visible() or back.get_hatch() or back.get_alpha() not in (None, 1.0):
        return
    colour = to_rgba(back.get_facecolor())
    if colour[3] != 1.0:
        return
    for ax in fig.axes:
        patch = ax.patch
        plain = (
            patch.get_visible()
            and not patch.get_hatch()
            and patch.get_alpha() in (None, 1.0)
            and to_rgba(patch.get_facecolor()) == colour
            and (patch.get_linewidth() == 0 or to_rgba(patch.get_edgecolor())[3] == 0)
            and not patch.get_path_effects()
        )
        if plain:
            patch.set_visible(False)


def _opaque_as_rgb(rgba: np.ndarray) -> np.ndarray:
    """``rgba``'s RGB where every pixel is opaque, else ``rgba``."""
    return rgba[..., :3] if bool((rgba[..., 3] == 255).all()) else rgba


def _write_png(path: Path, rgba: np.ndarray, dpi: float) -> None:
    Path(path).write_bytes(png_bytes(_opaque_as_rgb(rgba), dpi))


#: Per thread: the PNG writers that :func:`writing_behind` opened, innermost last.
_WRITERS = threading.local()


@contextlib.contextmanager
def writing_behind() -> Iterator[None]:
    """Within it, each figure's PNG is encoded and written by a thread while the next
    figure is drawn (zlib and the file's write release the GIL); every file is written
    when it ends, where a failed write raises its error. The files are the same.

    Examples
    --------
    >>> with writing_behind():
    ...     pass
    """
    from concurrent.futures import ThreadPoolExecutor

    stack = _WRITERS.__dict__.setdefault("stack", [])
    with ThreadPoolExecutor(1, thread_name_prefix="treesim-png") as pool:
        pending: list[Any] = []
        stack.append((pool, pending))
        try:
            yield
        finally:
            stack.pop()
        for job in pending:
            job.result()


@contextlib.contextmanager
def gc_paused() -> Iterator[None]:
    """Within it, no cyclic garbage collection: drawing makes many small objects in
    cycles (figures, artists, transforms), and the collector's passes over them took
    about a twentieth of a run's report stage. The cycles are collected after it, by the
    next pass that the allocations trigger. Nests; the collector's state is restored.

    Examples
    --------
    >>> import gc
    >>> with gc_paused():
    ...     gc.isenabled()
    False
    """
    import gc

    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


def _save(fig: Any, path: Path, dpi: int) -> Path:
    """Write ``fig`` at ``dpi`` as a PNG (what ``savefig`` draws, encoded by
    :func:`png_bytes`): now, or by :func:`writing_behind`'s thread within it."""
    pixels = _render_rgba(fig, dpi)  # the figure's own buffer, which nothing draws on again
    stack = getattr(_WRITERS, "stack", None)
    if stack:
        pool, pending = stack[-1]
        pending.append(pool.submit(_write_png, path, pixels, dpi))
    else:
        _write_png(path, pixels, dpi)
    return path


def save_png(fig: Any, path: Path, dpi: int = 110) -> Path:
    """Write ``fig`` as a PNG at ``path`` atomically (a reader never sees half a file)."""
    from ..atomic import atomic_path

    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=dpi, metadata={"Software": None})
    return path


def _ref_word(summary: dict[str, Any]) -> str:
    return "mesh" if summary.get("reference", {}).get("kind", "mesh") == "mesh" else "reference"


def histograms(data: ReportData, path: Path, *, dpi: int = 130) -> Path:
    """Distance histograms, one panel per direction, as shares (%) of the points."""
    import matplotlib

    s = data.summary
    tau = float(s["tolerance_m"])
    ref = _ref_word(s)
    panels = [
        (
            f"Accuracy: cloud → {ref}",
            data.cloud_distance_m,
            s["accuracy"],
            ACCURACY_COLOUR,
            "share of cloud points (%)",
        ),
        (
            f"Completeness: {ref} → cloud",
            data.reference_distance_m,
            s["completeness"],
            COMPLETENESS_COLOUR,
            f"share of {ref} samples (%)",
        ),
    ]
    with matplotlib.rc_context(_RC):
        fig = _fixed_figure(11.0, 3.7)
        axes = _grid(fig, 1, 2, margins_in=(0.7, 0.15, 0.5, 0.55), wgap_in=0.85)
        for ax, (title, d, st, colour, ylabel) in zip(axes, panels, strict=True):
            d = np.asarray(d, dtype=np.float64)
            top = float(st["p99_m"] or 0.0)
            if top < FLOAT_NOISE_M:
                # float rounding (a noiseless scan on its own mesh): no histogram of noise,
                # the scale of τ and what the distances are, in words
                xmax = max(tau, 1e-4)
                unit, k = unit_for(xmax)
                ax.text(
                    0.5,
                    0.55,
                    f"every distance ≤ {float(st['max_m'] or 0.0) * 1e9:.2g} nm:\n"
                    "float rounding, exact by construction",
                    transform=ax.transAxes,
                    ha="center",
                    va="center",
                    fontsize=10,
                    color="#323f4b",
                )
                ax.axvline(tau * k, color="#b83232", lw=1.2, ls="-", label=f"τ {_num(tau * k)}")
                ax.set_xlim(0, xmax * k)
                ax.set_ylim(0, 100)
                ax.set_xlabel(f"distance ({unit})")
                ax.set_ylabel(ylabel)
                ax.set_title(f"{title}\n", loc="left")
                ax.text(0, 1.02, f"n = {len(d):,}", transform=ax.transAxes, fontsize=8.5)
                ax.legend(title=unit, fontsize=8, title_fontsize=8, loc="upper right")
                continue
            xmax = top * 1.15
            unit, k = unit_for(xmax)
            bins = np.linspace(0.0, xmax * k, 61)
            shown = d[d <= xmax]
            share, _ = np.histogram(shown * k, bins=bins)
            share = share * (100.0 / max(len(d), 1))
            # one filled outline and one set of white bin edges: the bars of a histogram
            # drawn as two artists, not sixty
            ax.stairs(share, bins, fill=True, color=colour, alpha=0.85, lw=0)
            ax.vlines(bins[1:-1], 0.0, np.maximum(share[:-1], share[1:]), color="white", lw=0.3)
            for q, name, ls in ((st["median_m"], "median", ":"), (st["p95_m"], "p95", "--")):
                if q is not None and q <= xmax:
                    ax.axvline(q * k, color="#323f4b", lw=1.0, ls=ls, label=f"{name} {_num(q * k)}")
            if tau <= xmax:
                ax.axvline(tau * k, color="#b83232", lw=1.2, ls="-", label=f"τ {_num(tau * k)}")
            ax.set_xlim(0, xmax * k)
            ax.set_xlabel(f"distance ({unit})")
            ax.set_ylabel(ylabel)
            beyond = int((d > xmax).sum())
            note = f"n = {len(d):,}"
            if beyond:
                note += f"; {beyond:,} beyond the axis (up to {float(st['max_m']) * k:.3g} {unit})"
            ax.set_title(f"{title}\n", loc="left")
            ax.text(0, 1.02, note, transform=ax.transAxes, fontsize=8.5, color="#616e7c")
            ax.legend(title=unit, fontsize=8, title_fontsize=8, loc="upper right")
        return _save(fig, path, dpi)


def cumulative(data: ReportData, path: Path, *, dpi: int = 130) -> Path:
    """Cumulative distance curves of both directions, with τ and the coverage marked."""
    import matplotlib

    s = data.summary
    tau = float(s["tolerance_m"])
    ref = _ref_word(s)
    tops = [float(s[k]["p99_m"] or 0.0) for k in ("accuracy", "completeness")]
    xmax = max(max(tops) * 1.05, 2.0 * tau)
    unit, k = unit_for(xmax)
    probs = np.linspace(0.0, 1.0, 1001)
    with matplotlib.rc_context(_RC):
        fig = _fixed_figure(11.0, 3.9)
        ax = _grid(fig, 1, 1, margins_in=(0.7, 0.15, 0.5, 0.35))
        for name, d, colour in (
            (f"accuracy (cloud → {ref})", data.cloud_distance_m, ACCURACY_COLOUR),
            (f"completeness ({ref} → cloud)", data.reference_distance_m, COMPLETENESS_COLOUR),
        ):
            # the same quantiles of the values sorted first: numpy selects 1001 of them
            # from unsorted ones by repeated partitioning, slowly where many are equal
            q = np.quantile(np.sort(np.asarray(d, dtype=np.float64)), probs)
            xs = np.concatenate([[0.0], q, [max(q[-1], xmax)]]) * k
            ys = np.concatenate([[0.0], probs, [1.0]]) * 100
            lines = ax.step(xs, ys, where="post", color=colour, lw=2.0)
            within = float((np.asarray(d) <= tau).mean())
            ax.plot([tau * k], [within * 100], "o", color=colour, ms=6, zorder=5)
            lines[-1].set_label(f"{name}: {within * 100:.1f} % within τ")
        ax.axvline(tau * k, color="#b83232", lw=1.2, label=f"τ = {tau * k:.3g} {unit}")
        ax.set_xlim(0, xmax * k)
        ax.set_ylim(0, 101)
        ax.set_xlabel(f"distance ({unit})")
        ax.set_ylabel("share within distance (%)")
        ax.set_title("Cumulative distance distributions")
        ax.legend(loc="lower right")
        return _save(fig, path, dpi)


def _subsample(n: int, cap: int, seed: int) -> np.ndarray:
    if n <= cap:
        return np.arange(n)
    return np.sort(np.random.default_rng(seed).choice(n, size=cap, replace=False))


def _dot_px(n: int, area_pt2: float, clip: tuple[float, float], dpi: int) -> float:
    """Side (pixels) of one point's cell in an aggregated view of ``n`` points: the
    diameter of a scatter marker of ``area_pt2 / n`` points² (within ``clip``) at ``dpi``,
    at least one pixel. Sparse clouds get larger cells, as they got larger markers."""
    size_pt2 = float(np.clip(area_pt2 / max(n, 1), *clip))
    return max(1.0, float(np.sqrt(size_pt2)) * dpi / 72.0)


#: A raster panel: x0, x1, y0, y1 (its frame) and its cells nx, ny.
RasterBox = tuple[float, float, float, float, int, int]


def _cells(u: np.ndarray, v: np.ndarray, box: RasterBox) -> np.ndarray:
    """Flat cell index (row-major, row 0 at the bottom) of each point ``(u, v)``."""
    x0, x1, y0, y1, nx, ny = box
    ix = np.clip(((u - x0) * (nx / (x1 - x0))).astype(np.int64), 0, nx - 1)
    iy = np.clip(((v - y0) * (ny / (y1 - y0))).astype(np.int64), 0, ny - 1)
    return iy * nx + ix


def _max_raster(u: np.ndarray, v: np.ndarray, values: np.ndarray, box: RasterBox) -> np.ndarray:
    """The largest of ``values`` per cell of ``box`` ((ny, nx), ``-inf`` where no point
    falls): what a scatter drawing the largest values last shows on top."""
    out = np.full(box[4] * box[5], -np.inf)
    with np.errstate(invalid="ignore"):  # a NaN distance makes its cell NaN: not drawn
        np.maximum.at(out, _cells(u, v, box), values)
    return out.reshape(box[5], box[4])


def _count_raster(u: np.ndarray, v: np.ndarray, box: RasterBox) -> np.ndarray:
    """Points per cell of ``box`` ((ny, nx))."""
    return np.bincount(_cells(u, v, box), minlength=box[4] * box[5]).reshape(box[5], box[4])


#: What paints a raster: the points' display positions (pixels), their values (or None)
#: and the box of cells -> the cells' (ny, nx, 4) uint8 RGBA, alpha 0 where empty.
Painter = Any


@functools.cache
def _raster_class() -> type:
    """An artist that draws points aggregated into square cells of whole pixels, laid on
    the figure's own pixel grid when it is drawn: each point lights the cell of the pixel
    its display position falls in (the axes' data transform at that draw), the cells
    coloured by a painter (:func:`_paint_largest`, :func:`_paint_density`). One uint8
    image drawn at whole pixels, without matplotlib's image resampling (most of what a
    view of a cloud cost to draw)."""
    from matplotlib.artist import Artist

    class PointRaster(Artist):
        def __init__(
            self, u: np.ndarray, v: np.ndarray, values: Any, cell_px: int, paint: Painter
        ) -> None:
            super().__init__()
            self.uv = np.column_stack([u, v])
            self.values = values
            self.cell_px = max(1, int(cell_px))
            self.paint = paint
            self.set_zorder(1)

        def draw(self, renderer: Any) -> None:
            if not self.get_visible():
                return
            ax = self.axes
            xy = ax.transData.transform(self.uv)
            bb = ax.bbox
            c0, r0 = math.floor(bb.x0), math.floor(bb.y0)
            w, h = math.ceil(bb.x1) - c0, math.ceil(bb.y1) - r0
            k = self.cell_px
            nx, ny = -(-w // k), -(-h // k)
            x, y = xy[:, 0], xy[:, 1]
            inside = (x >= c0) & (x < c0 + w) & (y >= r0) & (y < r0 + h)
            values = self.values
            if not inside.all():
                x, y = x[inside], y[inside]
                values = None if values is None else values[inside]
            box = (c0, c0 + nx * k, r0, r0 + ny * k, nx, ny)
            rgba = self.paint(x, y, values, box)
            if k > 1:
                rgba = np.repeat(np.repeat(rgba, k, axis=0), k, axis=1)[:h, :w]
            gc = renderer.new_gc()
            gc.set_clip_rectangle(ax.bbox)
            # row 0 of the image is its bottom row, at display row r0
            renderer.draw_image(gc, c0, r0, np.ascontiguousarray(rgba))
            gc.restore()
            self.stale = False

    return PointRaster


def _add_raster(
    ax: Any,
    u: np.ndarray,
    v: np.ndarray,
    values: np.ndarray | None,
    cell_px: float,
    paint: Painter,
    lims: tuple[float, float, float, float],
) -> Any:
    """Put the points ``(u, v)`` into ``ax`` as a :func:`_raster_class` artist of cells
    ``cell_px`` pixels wide (rounded), and the box ``lims`` (x0, x1, y0, y1) into its
    data limits, which its view does not pad (as an image's extent). Returns the artist."""
    raster = _raster_class()(u, v, values, round(cell_px), paint)
    ax.add_artist(raster)
    x0, x1, y0, y1 = lims
    raster.sticky_edges.x[:] = [x0, x1]
    raster.sticky_edges.y[:] = [y0, y1]
    ax.update_datalim([(x0, y0), (x1, y1)])
    ax.autoscale_view()
    return raster


def _paint_largest(colours: Any, norm: Any) -> Painter:
    """A painter: each cell the colour (``colours`` after ``norm``) of its largest value,
    as a scatter drawing the largest values last shows on top."""

    def paint(x: np.ndarray, y: np.ndarray, values: np.ndarray, box: RasterBox) -> np.ndarray:
        top = _max_raster(x, y, values, box)
        rgba = np.zeros((*top.shape, 4), dtype=np.uint8)
        hit = np.isfinite(top)  # empty cells (and NaN distances) stay clear
        rgba[hit] = colours(norm(top[hit]), bytes=True)
        return rgba

    return paint


def _paint_density(colour: str) -> Painter:
    """A painter: each cell ``colour``, one point light and three or more opaque (depth
    read as density)."""
    from matplotlib.colors import to_rgba

    rgb = np.round(np.array(to_rgba(colour)[:3]) * 255).astype(np.uint8)
    # the opacity of 0, 1, 2 and 3 or more points
    n = np.arange(4)
    alpha = np.round(np.clip(0.45 + 0.275 * (n - 1), 0.0, 1.0) * (n > 0) * 255).astype(np.uint8)

    def paint(x: np.ndarray, y: np.ndarray, values: Any, box: RasterBox) -> np.ndarray:
        count = _count_raster(x, y, box)
        rgba = np.empty((*count.shape, 4), dtype=np.uint8)
        rgba[..., :3] = rgb
        rgba[..., 3] = alpha[np.minimum(count, 3)]
        return rgba

    return paint


def _view_layout(
    ext: np.ndarray, panel_h: float, margin_in: float, max_width_in: float
) -> tuple[np.ndarray, float, float]:
    """Width ratios of the side (x-z, y-z) and top (x-y) panels from the data's extent
    ``ext`` (3,), and the figure's width and panel height (inches): panels ``panel_h``
    high plus ``margin_in``, scaled down together to at most ``max_width_in`` wide."""
    ratios = np.clip([ext[0] / ext[2], ext[1] / ext[2], ext[0] / ext[1]], 0.35, 3.0)
    width = float(ratios.sum() * panel_h + margin_in)
    if width > max_width_in:
        panel_h *= max_width_in / width
        width = max_width_in
    return ratios, panel_h, width


def views(
    points: np.ndarray,
    distance_m: np.ndarray,
    vmax_m: float,
    path: Path,
    *,
    title: str,
    colour_label: str,
    origin: np.ndarray,
    stations: list[tuple[int, np.ndarray]] | None = None,
    tau_m: float | None = None,
    max_points: int = 120_000,
    seed: int = 0,
    dpi: int = 130,
) -> Path:
    """Side (x-z, y-z) and top (x-y) views of points coloured by distance.

    Parameters
    ----------
    points : (n, 3) float64
    distance_m : (n,) float64
    vmax_m : float
        Top of the colour scale; larger distances take the top colour.
    origin : (3,) float64
        Subtracted from the coordinates for display (axes say so).
    stations : list of (index, (3,) float64), optional
        Scanner positions drawn in the top view.
    """
    import matplotlib
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    idx = _subsample(len(points), max_points, seed)
    p = np.asarray(points, dtype=np.float64)[idx] - origin
    d = np.asarray(distance_m, dtype=np.float64)[idx]
    lo, hi = p.min(axis=0), p.max(axis=0)
    ext = np.maximum(hi - lo, 1e-6 + 1e-3 * float((hi - lo).max()))
    ratios, panel_h, width = _view_layout(ext, 4.5, 3.1, 13.0)
    pad = 0.02 * float(ext.max())  # the outermost cells clear of the frame
    lo, hi = lo - pad, hi + pad
    unit, k = unit_for(vmax_m)
    norm = Normalize(0.0, vmax_m * k)
    colours = cmap()
    dot_px = _dot_px(len(p), 25_000, (0.15, 6.0), dpi)
    offs = "" if not np.any(origin) else " − origin"
    with matplotlib.rc_context({**_RC, "axes.grid": False}):
        fig = _fixed_figure(width, panel_h + 1.1)
        axes = _grid(
            fig,
            1,
            3,
            margins_in=(0.7, 1.05, 0.5, 0.6),
            wgap_in=0.75,
            width_ratios=list(ratios),
        )
        specs = (
            (0, 2, "side view (looking along +y)", "x", "z"),
            (1, 2, "side view (looking along −x)", "y", "z"),
            (0, 1, "top view", "x", "y"),
        )
        paint = _paint_largest(colours, norm)
        for ax, (i, j, name, xl, yl) in zip(axes, specs, strict=True):
            lims = (lo[i], hi[i], lo[j], hi[j])
            _add_raster(ax, p[:, i], p[:, j], d * k, dot_px, paint, lims)
            ax.set_aspect("equal", adjustable="datalim")
            ax.set_xlabel(f"{xl}{offs} (m)")
            ax.set_ylabel(f"{yl}{offs} (m)")
            ax.set_title(name, fontsize=9.5, fontweight="normal", color="#52606d")
            for spine in ax.spines.values():
                spine.set_visible(True)
                spine.set_color("#cbd2d9")
        if stations:
            _draw_stations(axes[2], stations, origin, lo[:2], hi[:2])
        sc = ScalarMappable(norm=norm, cmap=colours)
        w_in, h_in = fig.get_size_inches()
        y0, y1 = 0.5 / h_in, 1.0 - 0.6 / h_in
        cax = fig.add_axes(
            (1.0 - 0.9 / w_in, y0 + 0.075 * (y1 - y0), 0.14 / w_in, 0.85 * (y1 - y0)),
            axes_class=_tick_free_axes_class(),
        )
        cb = fig.colorbar(sc, cax=cax, extend="max")
        cb.set_label(f"{colour_label} ({unit})")
        if tau_m is not None and tau_m <= vmax_m:
            cb.ax.axhline(tau_m * k, color="#b83232", lw=2.0)
            cb.ax.text(
                -0.3,
                tau_m * k,
                "τ",
                transform=cb.ax.get_yaxis_transform(),
                ha="right",
                va="center",
                color="#b83232",
                fontsize=9,
                fontweight="bold",
            )
        if np.any(origin):
            title += " · origin = ({:,.3f}, {:,.3f}, {:,.3f}) m".format(*origin)
        fig.suptitle(title, x=0.01, ha="left", fontsize=10.5, fontweight="bold")
        return _save(fig, path, dpi)


def _draw_stations(
    ax: Any,
    stations: list[tuple[int, np.ndarray]],
    origin: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
) -> None:
    """Stations in a top view without zooming out: those outside the data's box are shown
    as a sight line from the centre to the box's edge, labelled with their distance."""
    margin = 0.06 * float((hi - lo).max())
    blo, bhi = lo - margin, hi + margin
    centre = 0.5 * (lo + hi)
    for s_idx, pos in stations:
        q = np.asarray(pos, dtype=np.float64)[:2] - origin[:2]
        rel = q - centre
        dist = float(np.hypot(*rel))
        inside = bool(np.all(q >= blo) and np.all(q <= bhi))
        if inside:
            end, label = q, f"S{s_idx}"
        else:
            with np.errstate(divide="ignore", invalid="ignore"):
                t = np.where(rel > 0, (bhi - centre) / rel, (blo - centre) / rel)
            t = float(np.nanmin(np.where(np.isfinite(t) & (t > 0), t, np.inf)))
            end = centre + 0.97 * t * rel
            label = f"S{s_idx} · {dist:.1f} m"
            ax.plot(
                [centre[0], end[0]],
                [centre[1], end[1]],
                color="#7b8794",
                lw=0.8,
                ls=(0, (4, 3)),
                zorder=0,
            )
        ax.plot(end[0], end[1], marker="^", color="#1f2933", ms=7, ls="none", zorder=6)
        offset, ha, va = _station_label_place(rel, sight_line=not inside)
        ax.annotate(
            label,
            (end[0], end[1]),
            xytext=offset,
            textcoords="offset points",
            ha=ha,
            va=va,
            fontsize=8,
            color="#1f2933",
            zorder=6,
        )


def _station_label_place(
    rel: np.ndarray, *, sight_line: bool
) -> tuple[tuple[float, float], str, str]:
    """Where a station's label goes (offset in points, horizontal and vertical
    alignment), clear of its sight line, which runs from the station towards ``-rel``:
    above the station, unless the line rises from it; then below it when the line is
    more level than steep, beside it (the side the line leaves) when steeper."""
    above = ((0.0, 7.0), "center", "baseline")
    dx, dy = float(rel[0]), float(rel[1])
    if not sight_line or dy >= 0.0:  # no line, or it runs level or down from the station
        return above
    if abs(dx) > abs(dy):
        return (0.0, -9.0), "center", "top"
    return ((-8.0, 0.0), "right", "center") if dx < 0 else ((8.0, 0.0), "left", "center")


def coverage_bars(data: ReportData, path: Path, *, dpi: int = 130) -> Path:
    """Coverage of the reference (% within τ) by all stations and by each station alone;
    a second panel per hit label when the reference carries labels."""
    import matplotlib

    s = data.summary
    tau = float(s["tolerance_m"])
    ref = _ref_word(s)
    stations = s.get("by_station", {})
    labels = {k: v for k, v in s.get("by_label", {}).items() if v.get("coverage") is not None}
    if len(labels) < 2:
        labels = {}
    unit, k = unit_for(tau)
    with matplotlib.rc_context(_RC):
        n_panels = 2 if labels else 1
        width = 3.2 + 0.55 * (len(stations) + 1) + (2.0 + 0.6 * len(labels) if labels else 0.0)
        fig = _fixed_figure(min(max(width, 5.5), 11.0), 3.6)
        axes = np.atleast_1d(
            _grid(fig, 1, n_panels, margins_in=(0.7, 0.15, 0.55, 0.35), wgap_in=0.85)
        )
        names = ["all"] + [f"S{key}" for key in stations]
        values = [s["coverage"]] + [v["coverage"] for v in stations.values()]
        colours = ["#1f2933"] + [COMPLETENESS_COLOUR] * len(stations)
        ax = axes[0]
        bars = ax.bar(names, np.array(values) * 100, color=colours, width=0.65)
        ax.bar_label(bars, labels=[f"{v * 100:.1f}" for v in values], padding=2, fontsize=8.5)
        ax.set_ylim(0, 109)
        ax.set_ylabel(f"{ref} within τ of the cloud (%)")
        ax.set_xlabel("station (all: every station together)" if stations else "")
        ax.set_title(f"Coverage by station (τ = {tau * k:.3g} {unit})")
        ax.grid(axis="x", visible=False)
        if labels:
            ax = axes[1]
            lnames = list(labels)
            lvals = [labels[n]["coverage"] for n in lnames]
            bars = ax.bar(
                lnames,
                np.array(lvals) * 100,
                color=[LABEL_COLOURS.get(n, "#7b8794") for n in lnames],
                width=0.6,
            )
            ax.bar_label(bars, labels=[f"{v * 100:.1f}" for v in lvals], padding=2, fontsize=8.5)
            ax.set_ylim(0, 109)
            ax.set_ylabel(f"{ref} part within τ (%)")
            ax.set_xlabel("hit label")
            ax.set_title("Coverage by part")
            ax.grid(axis="x", visible=False)
        return _save(fig, path, dpi)


#: Line colours of the stations in the occlusion profile (then grey).
STATION_COLOURS = ("#2c6e9b", "#c2612d", "#4f8a3a", "#8a5a34", "#7d3c98", "#b7791f")


def occlusion_profile(
    profile: dict[str, Any], path: Path, *, ref_word: str, dpi: int = 130
) -> Path:
    """Coverage (left) and point density (right) by height slice: one line per station
    alone and a thick one for all stations together (:mod:`treesim.report.profile`)."""
    import matplotlib

    edges = np.asarray(profile["edges_m"], dtype=np.float64)
    mid = 0.5 * (edges[:-1] + edges[1:])
    tau = float(profile["tolerance_m"])
    unit, k = unit_for(tau)
    names = ["all", *profile["stations"]]
    dens = profile.get("density_per_m2")
    with matplotlib.rc_context(_RC):
        fig = _fixed_figure(11.0, 4.6)
        ax_c, ax_d = _grid(fig, 1, 2, margins_in=(0.7, 0.15, 0.5, 0.35), wgap_in=0.3, sharey=True)
        for i, name in enumerate(names):
            whole = name == "all"
            colour = "#1f2933" if whole else STATION_COLOURS[(i - 1) % len(STATION_COLOURS)]
            style = {"color": colour, "lw": 2.6 if whole else 1.3, "marker": "o", "ms": 3}
            label = "all stations" if whole else f"{name} alone"
            cov = np.array([np.nan if v is None else 100 * v for v in profile["coverage"][name]])
            ax_c.plot(cov, mid, label=label, **style)
            if dens is not None:
                d = np.array([np.nan if v is None else v for v in dens[name]])
                ax_d.plot(d, mid, label=label, **style)
            else:
                ax_d.plot(profile["cloud_points"][name], mid, label=label, **style)
        if dens is None:
            ax_d.plot(
                profile["reference_points"],
                mid,
                color="#7b8794",
                lw=2.0,
                ls="--",
                label=f"{ref_word} points",
            )
        ax_c.set_xlim(-2, 102)
        ax_c.set_xlabel(f"{ref_word} within τ = {tau * k:.3g} {unit} (%)")
        ax_c.set_ylabel("height (m)")
        ax_c.set_title(f"Coverage by height above the lowest {ref_word} point")
        ax_c.set_ylim(edges[0], edges[-1])
        ax_d.set_xlabel(
            f"cloud points per m² of {ref_word} surface"
            if dens is not None
            else f"points per {profile['bin_m']:g} m slice"
        )
        ax_d.set_xlim(left=0)
        ax_d.set_title("Point density by height" if dens is not None else "Points by height")
        ax_d.legend(loc="best", fontsize=8)
        return _save(fig, path, dpi)


#: Colours of the clouds set side by side on the run page.
FIELD_COLOUR = "#52606d"
SIMULATED_COLOUR = ACCURACY_COLOUR


def clouds_side_by_side(
    clouds: list[tuple[str, np.ndarray, str]],
    path: Path,
    *,
    origin: np.ndarray,
    max_points: int = 120_000,
    seed: int = 0,
    dpi: int = 130,
) -> Path:
    """Clouds in the same three views on the same axes, one row each: side (x-z, y-z) and
    top (x-y).

    Parameters
    ----------
    clouds : list of (name, (n, 3) float64 points, colour)
    origin : (3,) float64
        Subtracted for display.
    """
    import matplotlib

    shown = []
    for i, (name, pts, colour) in enumerate(clouds):
        idx = _subsample(len(pts), max_points, seed + i)
        shown.append((name, np.asarray(pts, dtype=np.float64)[idx] - origin, colour, len(pts)))
    allp = np.concatenate([p for _, p, _, _ in shown])
    lo, hi = allp.min(axis=0), allp.max(axis=0)
    pad = 0.03 * float((hi - lo).max())
    lo, hi = lo - pad, hi + pad
    ext = np.maximum(hi - lo, 1e-6)
    ratios, panel_h, width = _view_layout(ext, 3.5, 2.6, 12.0)
    specs = ((0, 2, "side view (along +y)"), (1, 2, "side view (along −x)"), (0, 1, "top view"))
    axis = "xyz"
    offs = "" if not np.any(origin) else " − origin"
    with matplotlib.rc_context({**_RC, "axes.grid": False}):
        fig = _fixed_figure(width, (panel_h + 0.75) * len(shown))
        axes = np.atleast_2d(
            _grid(
                fig,
                len(shown),
                3,
                margins_in=(1.3, 0.1, 0.45, 0.3),
                wgap_in=0.6,
                hgap_in=0.75,
                width_ratios=list(ratios),
            )
        )
        for row, (name, p, colour, n) in zip(axes, shown, strict=True):
            dot_px = _dot_px(len(p), 12_000, (0.1, 4.0), dpi)
            paint = _paint_density(colour)
            for ax, (i, j, view) in zip(row, specs, strict=True):
                lims = (lo[i], hi[i], lo[j], hi[j])
                _add_raster(ax, p[:, i], p[:, j], None, dot_px, paint, lims)
                ax.set_xlim(lo[i], hi[i])
                ax.set_ylim(lo[j], hi[j])
                ax.set_aspect("equal", adjustable="box")
                ax.set_xlabel(f"{axis[i]}{offs} (m)")
                ax.set_ylabel(f"{axis[j]}{offs} (m)")
                ax.set_title(view, fontsize=9.5, fontweight="normal", color="#52606d")
            row[0].set_ylabel(f"{name}, {n:,} points\n\n{axis[2]}{offs} (m)", fontsize=9.5)
        return _save(fig, path, dpi)
