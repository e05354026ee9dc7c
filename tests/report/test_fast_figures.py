"""Issue 25: the report's figures drawn by aggregation, in drawing processes or inline, and
the report levels of a run. Oracles: brute-force loops over the points, the inline
drawing (a figure drawn elsewhere is the same file), the files a level promises."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.report.test_report import _case
from treesim.compare import compare, write_comparison
from treesim.report import PNG_FILES, ReportParams, build_report, draw_report
from treesim.report import figures as F
from treesim.report.background import BackgroundDrawer, drawing_processes
from treesim.report.child import CHILD_ENV, RemoteTraceback
from treesim.report.data import ReportData


def test_the_largest_distance_per_cell_is_what_a_view_shows():
    rng = np.random.default_rng(0)
    u, v = rng.uniform(0, 1, 5000), rng.uniform(0, 2, 5000)
    d = rng.exponential(1.0, 5000)
    box = (0.0, 1.0, 0.0, 2.0, 10, 20)  # 0.1 m square cells
    top = F._max_raster(u, v, d, box)
    count = F._count_raster(u, v, box)
    want = np.full((20, 10), -np.inf)
    n = np.zeros((20, 10), int)
    for a, b, x in zip(u, v, d, strict=True):  # brute force: every point's cell
        i, j = min(int(b / 0.1), 19), min(int(a / 0.1), 9)
        want[i, j] = max(want[i, j], x)
        n[i, j] += 1
    assert np.array_equal(top, want) and np.array_equal(count, n)
    assert count.sum() == 5000


def test_cells_are_about_a_marker():
    # 120k points: the old markers were under a pixel, so one pixel; 1,000: ~2.4 pixels
    assert F._dot_px(120_000, 25_000, (0.15, 6.0), 130) == 1.0
    assert F._dot_px(1_000, 25_000, (0.15, 6.0), 130) == pytest.approx(6**0.5 * 130 / 72)


def _raster_figure(u, v, values, cell_px, paint, aspect="datalim"):
    """A report axes with the points as a raster, drawn: its pixels (RGB, top row first)
    and each point's pixel (row, column), from matplotlib's data transform."""
    import matplotlib

    with matplotlib.rc_context({**F._RC, "axes.grid": False}):
        fig = F._fixed_figure(4.0, 3.0)
        ax = F._grid(fig, 1, 1, margins_in=(0.6, 0.3, 0.5, 0.3))
        lims = (u.min() - 0.1, u.max() + 0.1, v.min() - 0.1, v.max() + 0.1)
        F._add_raster(ax, u, v, values, cell_px, paint, lims)
        ax.set_aspect("equal", adjustable=aspect)
        px = F.render_rgb(fig, 90)
    xy = ax.transData.transform(np.column_stack([u, v]))  # as the draw left it
    assert ax.bbox.contains(*xy.min(axis=0)) and ax.bbox.contains(*xy.max(axis=0))
    rows = px.shape[0] - 1 - np.floor(xy[:, 1]).astype(int)  # display y is upwards
    return px, rows, np.floor(xy[:, 0]).astype(int)


def test_a_view_shows_each_pixels_largest_distance_in_its_colour():
    """Oracle: matplotlib's transform puts each point in a pixel; a loop over the points
    finds each pixel's largest distance; the colour map gives its colour."""
    from matplotlib.colors import Normalize

    rng = np.random.default_rng(3)
    u, v = rng.normal(0, 1, 4000), rng.normal(0, 2, 4000)
    d = rng.exponential(1.0, 4000)
    d[:50] = np.nan  # a NaN distance draws nothing (as the scatter drew nothing)
    colours, norm = F.cmap(), Normalize(0.0, 2.0)
    px, rows, cols = _raster_figure(u, v, d, 1.0, F._paint_largest(colours, norm))
    top: dict[tuple[int, int], float] = {}
    for r, c, x in zip(rows, cols, d, strict=True):
        top[r, c] = x if (r, c) not in top else max(top[r, c], x)  # NaN wins, as in max
    lit = 0
    for (r, c), x in top.items():
        if np.isnan(x):
            continue
        lit += 1
        assert np.array_equal(px[r, c], colours(norm(x), bytes=True)[:3]), (r, c)
    # nothing else is coloured: pixels off white outside the frame's lines are the points'
    box = px[rows.min() : rows.max() + 1, cols.min() : cols.max() + 1]
    assert int((box != 255).any(axis=2).sum()) == lit


def test_a_cloud_view_shades_each_cell_by_its_points():
    """Oracle: points set apart, 1, 2 and 5 in one pixel; each lights one cell of 3 x 3
    pixels, shaded over white as its count says (one point light, three or more full)."""
    from matplotlib.colors import to_rgb

    centres = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    counts = [1, 2, 5, 1]
    pts = np.repeat(centres, counts, axis=0) + 1e-9 * np.arange(sum(counts))[:, None]
    colour = "#2c6e9b"
    px, rows, cols = _raster_figure(
        pts[:, 0], pts[:, 1], None, 3.0, F._paint_density(colour), aspect="box"
    )
    rgb = np.round(np.array(to_rgb(colour)) * 255)
    first = np.cumsum([0, *counts[:-1]])
    for i, n in zip(first, counts, strict=True):
        alpha = min(0.45 + 0.275 * (n - 1), 1.0)
        want = rgb * alpha + 255 * (1 - alpha)  # over the white axes
        assert np.abs(px[rows[i], cols[i]] - want).max() <= 2, n
    assert int((px != 255).any(axis=2).sum()) >= 4 * 9  # frame lines aside
    lit = (px != 255).any(axis=2)
    for i in first:  # one 3 x 3 cell around each group's pixel, nothing beyond it
        r, c = rows[i], cols[i]
        assert 9 == int(lit[r - 2 : r + 3, c - 2 : c + 3].sum())


@pytest.fixture(scope="module")
def comparison_dir(tmp_path_factory):
    cloud, scene = _case()
    d = tmp_path_factory.mktemp("cmp")
    write_comparison(compare(cloud, scene), d, inputs={"cloud": "a.ply", "reference": "b.obj"})
    return d


def test_a_report_drawn_in_a_drawing_process_is_the_inline_one(comparison_dir, tmp_path):
    params = ReportParams(max_view_points=2000, max_plot_points=20_000, dpi=60)
    inline = build_report(comparison_dir, tmp_path / "inline", params=params)
    sent = ReportData.from_file(comparison_dir)  # its arrays pickled to the drawing process
    with BackgroundDrawer(workers=1) as drawer:
        assert drawer.apart and drawer.processes == 1
        drawer.submit("r", draw_report, tmp_path / "apart", params, sent)
        apart = drawer.results()["r"]
    assert set(apart) == set(inline) == {"report_json", "report_html", *PNG_FILES}
    for key in PNG_FILES:
        assert apart[key].read_bytes() == inline[key].read_bytes(), key
    a, b = (json.loads(p["report_json"].read_text()) for p in (apart, inline))
    assert a["figures"] == b["figures"] and a["occlusion_profile"] == b["occlusion_profile"]
    assert drawer.seconds["r"] > 0 and drawer.seconds["warm_up_0"] > 0
    assert drawer.fallback == []


def _fails(what: str) -> None:
    raise ValueError(what)


class _Unpicklable(Exception):
    def __init__(self, a: str, b: str) -> None:  # pickling re-creates it with one argument
        super().__init__(f"{a} {b}")


def _fails_unpicklably() -> None:
    raise _Unpicklable("cannot", "travel")


def test_a_failed_piece_raises_its_error_where_the_run_waits():
    with BackgroundDrawer(workers=1) as drawer:
        drawer.submit("bad", _fails, "no such comparison")
        with pytest.raises(ValueError, match="no such comparison") as got:
            drawer.results()
        assert isinstance(got.value.__cause__, RemoteTraceback)
        assert "_fails" in got.value.__cause__.text  # the drawing process's traceback
        assert drawer.fallback == []  # an error is the piece's, not the process's
    with BackgroundDrawer(workers=1) as drawer:
        drawer.submit("odd", _fails_unpicklably)
        with pytest.raises(RuntimeError, match="drawing 'odd' failed") as got:
            drawer.results()
        assert "cannot travel" in got.value.__cause__.text
    inline = BackgroundDrawer(workers=0)  # inline: at once
    with pytest.raises(ValueError, match="x"):
        inline.submit("bad", _fails, "x")


def test_a_bad_drawing_process_count_is_said_and_ignored(monkeypatch, caplog):
    monkeypatch.setenv("TREESIM_DRAWING_PROCESSES", "two")
    with caplog.at_level("WARNING", logger="treesim"):
        drawer = BackgroundDrawer.start()
    drawer.close()
    assert "TREESIM_DRAWING_PROCESSES='two' is not a whole number" in caplog.text
    monkeypatch.setenv("TREESIM_DRAWING_PROCESSES", "0")
    caplog.clear()
    with caplog.at_level("WARNING", logger="treesim"):
        drawer = BackgroundDrawer.start()
    assert drawer.processes == 0 and not caplog.text
    drawer.close()


def test_drawing_processes_only_with_idle_cores():
    assert drawing_processes(cores=1, load=0.0) == 0
    assert drawing_processes(cores=2, load=1.5) == 0  # a shared machine: take turns, no gain
    assert drawing_processes(cores=2, load=0.2) == 1  # one idle core: one drawing process
    assert drawing_processes(cores=4, load=2.5) == 1
    assert drawing_processes(cores=4, load=0.5) == 2


def test_an_exact_comparison_draws_no_view_of_its_accuracy(tmp_path):
    cloud, scene = _case()
    exact = compare(cloud.subset(np.arange(len(cloud)) < 5000), scene)  # station 0 lies on the mesh
    assert exact.to_dict()["accuracy"]["p99_m"] < 1e-9
    files = build_report(exact, tmp_path, params=ReportParams(dpi=50), inputs={})
    assert "views_accuracy" not in files and not (tmp_path / "views_accuracy.png").exists()
    assert files["views_completeness"].is_file()
    page = files["report_html"].read_text(encoding="utf-8")
    assert page.count("data:image/png") == len(PNG_FILES) - 1
    assert "every distance is float rounding" in page
    rep = json.loads(files["report_json"].read_text())
    assert set(rep["not_drawn"]) == {"views_accuracy"}


def test_the_sweep_reads_the_trade_without_drawing_time():
    from treesim.report.sweep_page import _time_key
    from treesim.run import STAGES
    from treesim.sweep.engine import SCIENCE_STAGES, TIME, sweep_columns

    assert TIME == "time_science_s" and set(SCIENCE_STAGES) == set(STAGES) - {"report"}
    assert {"time_science_s", "time_report_s"} <= set(sweep_columns([]))
    rows = [{"status": "ok", "time_total_s": 3.0, "time_science_s": 1.0}]
    assert _time_key({"time": TIME, "rows": rows}) == "time_science_s"
    old = [{"status": "ok", "time_total_s": 3.0}]  # a sweep run before the column
    assert _time_key({"time": "time_total_s", "rows": old}) == "time_total_s"
    assert _time_key({"time": TIME, "rows": old}) == "time_total_s"


def _dies() -> str:
    import os
    import signal

    if os.environ.get(CHILD_ENV):  # in a drawing process: killed
        print("about to die", flush=True)
        os.kill(os.getpid(), signal.SIGKILL)
    return "drawn here"


def _echo(x: int) -> int:
    return x


def _where() -> str:
    import os

    return "apart" if os.environ.get(CHILD_ENV) else "here"


def test_a_piece_whose_process_died_is_drawn_again_here(caplog):
    with BackgroundDrawer(workers=1) as drawer:
        drawer.submit("dead", _dies)
        drawer.submit("next", _echo, 7)
        got = drawer.results()  # the process died under both: drawn again in this process
    assert got == {"dead": "drawn here", "next": 7}
    assert len(drawer.fallback) == 1
    assert "exit status -9" in drawer.fallback[0] and "about to die" in drawer.fallback[0]
    assert "drawing dead, next here" in drawer.fallback[0]
    assert "report drawing" in caplog.text  # the run's log says so


def test_a_drawer_whose_process_cannot_start_draws_here(monkeypatch, caplog):
    monkeypatch.setattr("sys.executable", "/nonexistent/python")
    with BackgroundDrawer(workers=2) as drawer:
        assert not drawer.apart and drawer.processes == 0
        drawer.submit("w", _where)
        assert drawer.results() == {"w": "here"}
    assert "no drawing process could start" in drawer.fallback[0]
    assert "no drawing process could start" in caplog.text


def test_pieces_go_to_the_least_busy_process_and_come_back_by_key():
    with BackgroundDrawer(workers=2) as drawer:
        for i in range(5):
            drawer.submit(f"e{i}", _echo, i)
        drawer.submit("w", _where)
        sent = [len(c.pending) for c in drawer._pool._processes.values()]
        got = drawer.results()
    assert sorted(sent) == [3, 3]
    assert got == {**{f"e{i}": i for i in range(5)}, "w": "apart"}


def test_closing_a_drawer_stops_a_process_still_drawing():
    import time

    drawer = BackgroundDrawer(workers=1)
    drawer.submit("nap", time.sleep, 60)
    (child,) = drawer._pool._processes.values()
    t0 = time.monotonic()
    drawer.close()  # not waited for: killed
    assert child.proc.poll() is not None and time.monotonic() - t0 < 30


def test_the_viewers_colour_table_is_matplotlibs():
    from treesim.report.html import VIEWER_LUT

    # the oracle: the distance colour map evaluated by matplotlib
    want = (F.cmap()(np.linspace(0, 1, 256))[:, :3] * 255).round().astype(np.uint8)
    assert VIEWER_LUT == want.tobytes()


def _loaded(name: str) -> bool:
    import sys

    return name in sys.modules


def test_a_drawing_process_imports_what_it_is_told_before_its_first_piece(monkeypatch):
    from treesim.report.background import PROCESSES_ENV

    monkeypatch.setenv(PROCESSES_ENV, "1")  # chosen, whatever the load
    with BackgroundDrawer.start(preload=["tabnanny"]) as drawer:
        assert drawer.processes == 1
        drawer.submit("t", _loaded, "tabnanny")  # a module nothing else imports
        assert drawer.results() == {"t": True}
    monkeypatch.setenv(PROCESSES_ENV, "0")
    assert BackgroundDrawer.start().processes == 0


def test_a_piece_sent_after_its_process_died_is_drawn_here_and_said():
    drawer = BackgroundDrawer(workers=1)
    (child,) = drawer._pool._processes.values()
    child.proc.kill()
    child.proc.wait()
    with drawer:
        drawer.submit("w", _where)
        assert drawer.results() == {"w": "here"}
    assert drawer.fallback[0] == "no drawing process is left; drawing w here"
    assert drawer.fallback[1].endswith("ended (exit status -9), owing no piece")
