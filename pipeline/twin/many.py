"""Many field plots become twins, one after another (``treesim plot from-cloud A.laz B.laz
-o OUT``): :func:`plots_from_clouds`.

Each plot's twin is :func:`~treesim.twin.plot_from_cloud`'s, in ``OUT/<id>/`` (``<id>`` the
cloud file's stem, named as :func:`treesim.batch.discover_inputs` names a batch's trees);
its trees run in parallel on the chosen executor, the plots one after another. ``OUT``
gets ``plots.csv`` and ``plots.json``: one row per plot (:data:`PLOT_COLUMNS`).

* A plot that fails (a cloud without ground, without stems, in feet read as metres ...)
  is listed with its error and the others go on; its folder keeps what was made and
  ``error.json`` (class, message, traceback).
* **Resumable**: a plot whose folder holds a finished twin made from the same cloud file
  (size, modification time, SHA-256 of its first and last MiB) with the same
  :class:`~treesim.twin.TwinParams` and treesim version is ``reused``: not made again, no
  file of it rewritten (:func:`~treesim.twin.finished_twin`). A plot half made (Ctrl-C)
  is made again, its finished trees reused by the batch.
* One run at a time may write into ``OUT`` (a lock file).
"""

from __future__ import annotations

import csv
import datetime as _dt
import os
import signal
import threading
import time
import traceback
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..atomic import atomic_path
from ..batch import RowCounts
from ..errors import EmptyInputError, InputFormatError, InvalidParameterError
from ..jsonio import write_json
from .core import TwinParams, _params_dict, finished_twin, plot_from_cloud
from .result import TWIN_FILES

__all__ = ["PLOTS_FILES", "PLOT_COLUMNS", "PlotsResult", "discover_plots", "plots_from_clouds"]

#: The summaries written into the output folder.
PLOTS_FILES = {"csv": "plots.csv", "json": "plots.json"}
#: Columns of ``plots.csv`` (``plots.json``'s ``plots`` has the same keys): ``status`` is
#: ``ok``, ``failed`` or ``reused``; ``trees`` and ``left_out`` count the twin's trees and
#: the stems left out of it; ``warnings`` counts its warnings (listed in its
#: ``from_cloud.json``); ``folder`` is the twin's, relative to the output folder.
PLOT_COLUMNS = (
    "id",
    "input",
    "status",
    "trees",
    "left_out",
    "warnings",
    "error_class",
    "error",
    "time_s",
    "folder",
)
#: A failed plot's error (class, message, traceback), in its folder.
ERROR_FILE = "error.json"
#: A folder holding one of these was made by treesim (a twin, a stand, a failed plot):
#: the clouds in it and below are its own, not plots.
_MADE_MARKERS = (TWIN_FILES["json"], TWIN_FILES["plot"], TWIN_FILES["labelled"], ERROR_FILE)

Progress = Callable[[float, str], None]


@dataclass
class PlotsResult(RowCounts):
    """What :func:`plots_from_clouds` did.

    Attributes
    ----------
    outdir : Path
    rows : list of dict
        One per plot, in input order, with the keys of :data:`PLOT_COLUMNS`.
    skipped_files : list of (Path, str)
        Files in input folders that were not point clouds, with the reason.
    warnings : dict of str to list of str
        Each plot's warnings (its ``from_cloud.json``'s), by id.
    elapsed_s : float
    summary_csv, summary_json : Path

    Examples
    --------
    >>> import treesim.twin as tw
    >>> res = tw.plots_from_clouds(["a.laz", "b.laz"], "twins/")  # doctest: +SKIP
    >>> print(res.summary_line())  # doctest: +SKIP
    2 plots: 2 made, 0 reused (not made again), 0 failed
    """

    outdir: Path
    rows: list[dict[str, Any]]
    skipped_files: list[tuple[Path, str]] = field(default_factory=list)
    warnings: dict[str, list[str]] = field(default_factory=dict)
    elapsed_s: float = 0.0
    summary_csv: Path = field(default_factory=Path)
    summary_json: Path = field(default_factory=Path)

    @property
    def n_reused(self) -> int:
        """Plots reused (a status of their own here, not a flag beside ``ok``)."""
        return self.count("reused")

    @property
    def failed(self) -> list[dict[str, Any]]:
        """The rows of the plots that failed."""
        return [r for r in self.rows if r["status"] == "failed"]

    def summary_line(self) -> str:
        """One line: plots made, reused, failed."""
        n = len(self.rows)
        return (
            f"{n} plot{'s' * (n != 1)}: {self.n_ok} made, {self.n_reused} reused (not made "
            f"again), {self.n_failed} failed"
        )


# -- inputs -------------------------------------------------------------------------------
def _clouds_in(
    folder: Path, suffixes: set[str], outdir: Path | None
) -> tuple[list[Path], list[tuple[Path, str]]]:
    """The cloud files below ``folder``, sorted: not in hidden folders nor in folders
    treesim made (:data:`_MADE_MARKERS`); files that are not clouds, with the reason."""
    from ..batch import _sniff_not_a_cloud

    own = {(outdir / name).resolve() for name in PLOTS_FILES.values()} if outdir else set()
    found: list[Path] = []
    for top, dirs, names in os.walk(folder):
        if any(m in names for m in _MADE_MARKERS):
            dirs[:] = []
            continue
        dirs[:] = sorted(d for d in dirs if not d.startswith("."))
        for name in names:
            f = Path(top) / name
            if not name.startswith(".") and f.suffix.lower() in suffixes:
                if f.resolve() not in own:
                    found.append(f)
    files, skipped = [], []
    for f in sorted(found):
        why = _sniff_not_a_cloud(f)
        if why:
            skipped.append((f, why))
        else:
            files.append(f)
    return files, skipped


def discover_plots(
    inputs: Iterable[str | Path] | str | Path, outdir: str | Path | None = None
) -> tuple[list[Any], list[tuple[Path, str]]]:
    """The plot clouds of files and folders, with their ids.

    A folder gives every point cloud file inside it (sorted, recursively), skipping hidden
    folders, folders treesim made (a twin, a stand, a failed plot) and files that are not
    clouds. Ids are the file's stem as :func:`treesim.batch.discover_inputs` names them
    (unique, safe characters). A file given twice is taken once.

    Parameters
    ----------
    inputs : str, Path or iterable of them
    outdir : str or Path, optional
        The output folder: its own summaries are not inputs.

    Returns
    -------
    plots : list of TreeInput
        ``id`` and ``path`` of each plot.
    skipped : list of (Path, str)
        Files in folders that are not point clouds, with the reason.

    Raises
    ------
    InputFormatError
        A path that does not exist or is not a point cloud file or a folder.
    EmptyInputError
        No point cloud found.

    Examples
    --------
    >>> from treesim.twin.many import discover_plots
    >>> plots, skipped = discover_plots(["field/"])  # doctest: +SKIP
    >>> [p.id for p in plots]  # doctest: +SKIP
    ['plot_01', 'plot_02']
    """
    from ..batch import discover_inputs
    from ..io import supported_suffixes

    suffixes = set(supported_suffixes())
    items = [inputs] if isinstance(inputs, str | Path) else list(inputs)
    out = Path(outdir) if outdir is not None else None
    files: list[Path] = []
    skipped: list[tuple[Path, str]] = []
    for item in items:
        p = Path(item)
        if p.is_dir():
            found, why = _clouds_in(p, suffixes, out)
            files += found
            skipped += why
        elif p.is_file():
            if p.suffix.lower() not in suffixes:
                raise InputFormatError(
                    f"{p}: not a point cloud ({', '.join(sorted(suffixes))}) or a folder of them"
                )
            files.append(p)
        else:
            raise InputFormatError(f"{p} not found; check the path")
    unique: dict[Path, Path] = {}
    for f in files:
        unique.setdefault(f.resolve(), f)
    files = list(unique.values())
    if not files:
        raise EmptyInputError(
            f"no point cloud file in {', '.join(str(i) for i in items)} (looked for "
            f"{', '.join(sorted(suffixes))}, outside twin folders)"
        )
    plots, _ = discover_inputs(files)
    if [t.path for t in plots] != files:  # a CSV with a 'path' column is a batch manifest
        raise InputFormatError(
            "a CSV manifest of trees is not a plot cloud; give the plots' cloud files or "
            "folders of them"
        )
    return plots, skipped


# -- one plot -----------------------------------------------------------------------------
@contextmanager
def _noting_interrupts() -> Iterator[Callable[[], bool]]:
    """Note a Ctrl-C while the block runs (it still raises KeyboardInterrupt): a library
    that turns it into an error of its own (lazrs writing a LAZ) must not make it pass for
    a failed plot. Installed only in the main thread over a Python handler."""
    seen = [False]
    previous = signal.getsignal(signal.SIGINT)
    if threading.current_thread() is not threading.main_thread() or not callable(previous):
        yield lambda: False
        return

    def on_sigint(signum: int, frame: Any) -> None:
        seen[0] = True
        previous(signum, frame)
        raise KeyboardInterrupt

    signal.signal(signal.SIGINT, on_sigint)
    try:
        yield lambda: seen[0]
    finally:
        if signal.getsignal(signal.SIGINT) is on_sigint:
            signal.signal(signal.SIGINT, previous)


def _row(base: dict[str, Any], status: str, twin: Any, t0: float) -> dict[str, Any]:
    return {
        **base,
        "status": status,
        "trees": len(twin.trees),
        "left_out": len(twin.left_out),
        "warnings": len(twin.warnings),
        "error_class": None,
        "error": None,
        "time_s": round(time.perf_counter() - t0, 2),
    }


def _failed(base: dict[str, Any], folder: Path, exc: Exception, t0: float) -> dict[str, Any]:
    """The row of a plot that failed; its error (with the traceback) in its folder."""
    from ..batch import _one_line

    folder.mkdir(parents=True, exist_ok=True)
    write_json(
        folder / ERROR_FILE,
        {
            "input": base["input"],
            "error_class": type(exc).__name__,
            "error": str(exc),
            "traceback": "".join(traceback.format_exception(exc)),
        },
    )
    return {
        **base,
        "status": "failed",
        "trees": None,
        "left_out": None,
        "warnings": None,
        "error_class": type(exc).__name__,
        "error": _one_line(exc),
        "time_s": round(time.perf_counter() - t0, 2),
    }


def _plot_progress(say: Progress, i: int, n: int, pid: str) -> Progress:
    """Plot ``i`` of ``n``'s progress as the whole run's."""

    def stage(fraction: float, message: str) -> None:
        say((i + min(fraction, 1.0)) / n, f"plot {i + 1}/{n} {pid}: {message}")

    return stage


def _one_plot(
    plot: Any,
    out: Path,
    tp: TwinParams,
    run: dict[str, Any],
    say: Progress,
    interrupted: Callable[[], bool],
) -> tuple[dict[str, Any], list[str]]:
    """One plot's row and warnings: its finished twin reused, or made, or its failure."""
    folder = out / plot.id
    t0 = time.perf_counter()
    base = {"id": plot.id, "input": str(plot.path), "folder": plot.id}
    done = finished_twin(plot.path, folder, tp)
    if done is not None:
        say(1.0, "reused (made before from the same cloud and settings)")
        return _row(base, "reused", done, t0), list(done.warnings)

    def trees(p: Any) -> None:
        say(0.25 + 0.65 * p.finished / max(p.total, 1), f"trees {p.finished}/{p.total}")

    try:
        twin = plot_from_cloud(plot.path, folder, tp, **run, progress=say, batch_progress=trees)
    except Exception as exc:  # listed with its reason; the other plots go on
        if interrupted():
            raise KeyboardInterrupt from exc
        return _failed(base, folder, exc, t0), []
    (folder / ERROR_FILE).unlink(missing_ok=True)
    return _row(base, "ok", twin, t0), list(twin.warnings)


# -- summaries ----------------------------------------------------------------------------
def _write_summaries(
    res: PlotsResult, tp: TwinParams, run: dict[str, Any], interrupted: bool
) -> None:
    from .._version import __version__

    out = res.outdir
    csv_path = out / PLOTS_FILES["csv"]
    with atomic_path(csv_path) as tmp, open(tmp, "w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=list(PLOT_COLUMNS))
        w.writeheader()
        for r in res.rows:
            w.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in PLOT_COLUMNS})
    counts = {s: res.count(s) for s in ("ok", "reused", "failed")}
    json_path = write_json(
        out / PLOTS_FILES["json"],
        {
            "kind": "treesim.plots_from_clouds",
            "treesim": __version__,
            "finished": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
            "interrupted": interrupted,
            "elapsed_s": res.elapsed_s,
            "plots_total": len(res.rows),
            "counts": counts,
            "params": _params_dict(tp),
            "execution": {k: v for k, v in run.items() if v is not None},
            "skipped_files": [{"path": str(p), "reason": why} for p, why in res.skipped_files],
            "plots": [{k: r.get(k) for k in PLOT_COLUMNS} for r in res.rows],
        },
    )
    res.summary_csv, res.summary_json = csv_path, json_path


def _check_outdir(out: Path) -> None:
    if (out / TWIN_FILES["json"]).is_file():
        raise InvalidParameterError(
            f"{out} holds the twin of one plot ({TWIN_FILES['json']}); give another -o for "
            "many plots (each plot's twin goes into a folder of its own inside it)"
        )


def plots_from_clouds(
    inputs: Iterable[str | Path] | str | Path,
    outdir: str | Path,
    params: TwinParams | None = None,
    *,
    executor: str = "local",
    workers: int | None = None,
    threads: int | None = None,
    scheduler: str | None = None,
    progress: Progress | None = None,
) -> PlotsResult:
    """Make the twin of every plot cloud of ``inputs``, one plot after another, each into
    ``outdir/<id>/``, resumably (see the module notes).

    Parameters
    ----------
    inputs : str, Path or iterable of them
        Plot clouds (LAS/LAZ, E57, PLY, text) and folders of them (see
        :func:`discover_plots`).
    outdir : str or Path
        The output folder (created): a folder per plot, ``plots.csv``, ``plots.json``.
    params : TwinParams, optional
        The settings of every plot.
    executor : {"inline", "local", "dask"}
        Where each plot's trees are reconstructed (see :func:`treesim.run_batch`).
    workers : int, optional
    threads : int, optional
        Threads per tree (default cores // workers).
    scheduler : str, optional
        A running Dask scheduler's address.
    progress : callable(fraction, message), optional
        The whole run: fraction over all plots, the message naming the plot and its stage.

    Returns
    -------
    PlotsResult
        A plot that failed is a row with ``status`` ``failed`` and its error; nothing is
        raised for it.

    Raises
    ------
    InputFormatError, EmptyInputError
        An input that does not exist or is not a cloud or folder; no cloud at all.
    InvalidParameterError
        ``outdir`` holds the twin of one plot, or another run is writing into it.
    KeyboardInterrupt
        Ctrl-C: the summaries list the plots finished so far, which a second run reuses.

    Examples
    --------
    >>> import treesim.twin as tw
    >>> draft = tw.TwinParams(preset="draft")
    >>> res = tw.plots_from_clouds(["field/"], "twins/", draft)  # doctest: +SKIP
    >>> res.n_failed, res.summary_csv  # doctest: +SKIP
    (0, PosixPath('twins/plots.csv'))
    """
    from ..batch import _lock

    tp = params or TwinParams()
    out = Path(outdir)
    plots, skipped = discover_plots(inputs, out)
    _check_outdir(out)
    out.mkdir(parents=True, exist_ok=True)
    say = progress or (lambda f, m: None)
    run = {"executor": executor, "workers": workers, "threads": threads, "scheduler": scheduler}
    t0 = time.perf_counter()
    res = PlotsResult(out, [], skipped_files=skipped)
    n = len(plots)
    with _lock(out, "plot from-cloud"), _noting_interrupts() as interrupted:
        try:
            for i, plot in enumerate(plots):
                stage = _plot_progress(say, i, n, plot.id)
                row, warnings = _one_plot(plot, out, tp, run, stage, interrupted)
                res.rows.append(row)
                res.warnings[plot.id] = warnings
        finally:  # after Ctrl-C too: the plots finished so far
            res.elapsed_s = time.perf_counter() - t0
            _write_summaries(res, tp, run, interrupted=len(res.rows) < n)
    say(1.0, "done")
    return res
