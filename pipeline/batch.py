"""Many trees: :func:`run_batch` runs :func:`treesim.run_tree` on each, resumably.

Inputs are point cloud files, folders (every cloud inside, by suffix, recursively; text
tables without x, y, z columns, such as QSM cylinder tables, and PLY meshes are skipped
with a note) and CSV manifests (a ``path`` column, an optional ``id`` column and per-tree
settings in columns named as :data:`treesim.params.SETTINGS`, e.g. ``method``,
``resolution_deg``, ``stations``; relative paths are relative to the manifest).

The output folder holds

* ``trees/<id>/``: each finished tree's :func:`~treesim.run_tree` outputs and, written
  last, ``result.json`` (the tree's hash and summary row);
* ``trees/<id>.failed/``: a failed tree's partial outputs and ``error.json`` (error class,
  message, traceback);
* ``summary.csv`` and ``summary.json`` (one row per tree: status, error, key figures,
  time per stage) and ``index.html`` linking every report.

**Resumable.** A tree's hash covers its file's content (SHA-256), the settings that
decide its result (:func:`treesim.run.params_hash`; not thread counts) and treesim's
version. A tree whose ``trees/<id>/result.json`` holds the same hash is not run again, so
after Ctrl-C (or a crash) the same command finishes only the rest. Failed trees are tried
again.

**Atomic.** Each tree runs in ``.tmp/<id>-XXXX/`` inside the output folder; its
``result.json`` is written last, then the folder is renamed into place in one step. A
folder without ``result.json`` is never taken for a result, and ``.tmp/`` is emptied when
a batch starts. One batch at a time may use an output folder (a lock file).

**Failures** are recorded (class and message) and never stop the batch.
"""

from __future__ import annotations

import concurrent.futures as cf
import csv
import datetime as _dt
import hashlib
import json
import os
import re
import shutil
import tempfile
import time
import traceback
import uuid
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from filelock import FileLock, Timeout

from .atomic import atomic_path, write_text
from .errors import InputFormatError, InvalidParameterError, TreesimError
from .executors import Executor, ExecutorPlan, open_executor, plan_executor, slots, task_threads
from .jsonio import write_json as _write_json
from .params import RunParams, apply_settings, params_hash, run_preset
from .report.batch_index import batch_index_page
from .run import STAGES, file_sha256, run_tree

__all__ = [
    "BatchProgress",
    "BatchResult",
    "SUMMARY_COLUMNS",
    "TreeInput",
    "discover_inputs",
    "run_batch",
]

#: Columns of ``summary.csv`` (``summary.json`` has the same keys per tree).
FIGURE_COLUMNS: dict[str, tuple[str, ...]] = {
    "dbh_m": ("reconstruction", "dbh_m"),
    "height_m": ("reconstruction", "height_m"),
    "volume_total_m3": ("reconstruction", "volume_total_m3"),
    "volume_stem_m3": ("reconstruction", "volume_stem_m3"),
    "volume_branch_m3": ("reconstruction", "volume_branch_m3"),
    "n_cylinders": ("reconstruction", "n_cylinders"),
    "n_triangles": ("reconstruction", "n_triangles"),
    "field_points": ("inputs", "points"),
    "station_distance_m": ("scan", "station_rule", "distance_m"),
    "scan_points": ("scan", "points"),
    "vs_mesh_accuracy_p95_m": ("vs_mesh", "accuracy", "p95_m"),
    "vs_mesh_completeness_p95_m": ("vs_mesh", "completeness", "p95_m"),
    "vs_mesh_coverage": ("vs_mesh", "coverage"),
    "vs_mesh_chamfer_m": ("vs_mesh", "chamfer_m"),
    "vs_mesh_hausdorff_m": ("vs_mesh", "hausdorff_m"),
    "vs_field_accuracy_p95_m": ("vs_field", "accuracy", "p95_m"),
    "vs_field_completeness_p95_m": ("vs_field", "completeness", "p95_m"),
    "vs_field_coverage": ("vs_field", "coverage"),
    "vs_field_chamfer_m": ("vs_field", "chamfer_m"),
    "vs_field_hausdorff_m": ("vs_field", "hausdorff_m"),
    # a reference QSM (manifest column ``reference_qsm``): its figures
    "reference_dbh_m": ("reference_qsm", "figures", "dbh_m"),
    "reference_height_m": ("reference_qsm", "figures", "height_m"),
    "reference_volume_total_m3": ("reference_qsm", "figures", "volume_total_m3"),
}
TIME_COLUMNS = tuple(f"time_{s}_s" for s in (*STAGES, "total"))
SUMMARY_COLUMNS: tuple[str, ...] = (
    "id",
    "tree_id",
    "status",
    "reused",
    "input",
    "error_class",
    "error",
    "warnings",
    *FIGURE_COLUMNS,
    *TIME_COLUMNS,
    "report",
    "folder",
    "hash",
)

_TEXT_SUFFIXES = (".xyz", ".txt", ".csv", ".asc", ".pts")
#: A folder holding this file is a plot (see :mod:`treesim.plot.io`).
_PLOT_FILE = "plot.toml"
_LOCK_NAME = ".treesim-batch.lock"


# -- inputs -------------------------------------------------------------------------------
@dataclass(frozen=True, kw_only=True)
class TreeInput:
    """One tree of a batch.

    Parameters
    ----------
    id : str
        Its output folder's name (``trees/<id>``).
    path : Path
    settings : tuple of (str, str)
        Per-tree settings from a manifest (see :data:`treesim.params.SETTINGS`), and its
        ``reference_qsm`` (a QSM table's path, set beside the reconstruction).
    kind : {"tree", "plot", "reconstruct"}
    """

    id: str
    path: Path
    settings: tuple[tuple[str, str], ...] = ()
    #: ``tree`` (a field cloud: the whole loop) or ``plot`` (a ``plot.toml``: the plot
    #: scan, one summary row per tree of it) or ``reconstruct`` (a field cloud: the
    #: reconstruction only, as ``treesim plot from-cloud`` runs its trees)
    kind: str = "tree"


def _sniff_not_a_cloud(p: Path) -> str | None:
    """Why a file found in a folder is not a tree cloud, or None when it looks like one."""
    suffix = p.suffix.lower()
    if suffix == ".ply":
        from .io.ply import ply_has_faces

        return "a mesh (PLY with faces)" if ply_has_faces(p) else None
    if suffix not in _TEXT_SUFFIXES:
        return None
    try:
        with open(p, encoding="utf-8", errors="replace") as fh:
            for _ in range(50):
                line = fh.readline()
                if not line:
                    return "an empty file"
                s = line.strip().lstrip("/#").strip()
                if s:
                    break
            else:
                return None
    except OSError as exc:
        return f"unreadable ({exc.strerror})"
    tokens = [t.strip().strip("\"'").lower() for t in re.split(r"[,;\s]+", s) if t.strip()]
    try:
        [float(t) for t in tokens]
        return None  # numbers: a headerless cloud
    except ValueError:
        pass
    if {"x", "y", "z"} <= set(tokens):
        return None
    return "a table without x, y, z columns (a QSM cylinder table?)"


def _is_manifest(p: Path) -> bool:
    if p.suffix.lower() != ".csv":
        return False
    try:
        with open(p, encoding="utf-8-sig", errors="replace") as fh:
            header = fh.readline()
    except OSError:
        return False
    names = {h.strip().strip("\"'").lower() for h in header.split(",")}
    return "path" in names and not {"x", "y", "z"} <= names


#: Manifest columns that are not settings (:data:`treesim.params.SETTINGS`).
_MANIFEST_COLUMNS = ("path", "id", "reference_qsm")


def _read_manifest(p: Path) -> list[tuple[Path, str | None, tuple[tuple[str, str], ...]]]:
    from .params import SETTINGS

    rows = []
    with open(p, encoding="utf-8-sig", newline="") as fh:
        reader = csv.DictReader(fh)
        cols = [c.strip().lower() for c in (reader.fieldnames or [])]
        unknown = [c for c in cols if c not in _MANIFEST_COLUMNS and c not in SETTINGS]
        if unknown:
            raise InvalidParameterError(
                f"{p.name}: unknown column(s) {', '.join(unknown)}; a manifest has 'path', "
                f"optionally 'id' and 'reference_qsm' (a QSM table to set beside the "
                f"reconstruction), and settings: {', '.join(SETTINGS)}"
            )
        for i, raw in enumerate(reader, start=2):
            row = {(k or "").strip().lower(): (v or "").strip() for k, v in raw.items()}
            if not row.get("path"):
                raise InvalidParameterError(f"{p.name} line {i}: the 'path' cell is empty")
            path = Path(row["path"])
            if not path.is_absolute():
                path = p.parent / path
            if row.get("reference_qsm"):
                ref = Path(row["reference_qsm"])
                row["reference_qsm"] = str(ref if ref.is_absolute() else p.parent / ref)
            settings = tuple((k, v) for k, v in row.items() if k not in ("path", "id") and v != "")
            rows.append((path, row.get("id") or None, settings))
    return rows


def _safe_id(text: str) -> str:
    s = re.sub(r"[^A-Za-z0-9._-]+", "_", text).strip("._") or "tree"
    return s[:100]


def discover_inputs(
    inputs: Iterable[str | Path | TreeInput],
) -> tuple[list[TreeInput], list[tuple[Path, str]]]:
    """Expand files, folders and manifests into the batch's trees.

    Returns
    -------
    trees : list of TreeInput
        In the order given (folders sorted), with unique ids (the file's stem; the parent
        folder's name is prefixed where stems collide).
    skipped : list of (Path, str)
        Files in folders that are not tree clouds, with the reason.

    Raises
    ------
    InputFormatError
        If a path given does not exist or is not a point cloud file, folder or manifest.
    InvalidParameterError
        If a manifest has an unknown column or an unreadable setting.
    """
    from .io import supported_suffixes

    suffixes = set(supported_suffixes())
    found: list[tuple[Path, str | None, tuple[tuple[str, str], ...]]] = []
    skipped: list[tuple[Path, str]] = []
    given: list[TreeInput] = []
    for item in inputs:
        if isinstance(item, TreeInput):
            given.append(item)
            continue
        p = Path(item)
        if p.is_dir():
            # a folder holding a plot.toml is a plot: its files are the plot's, not trees
            plots = sorted(
                f.parent
                for f in p.rglob(_PLOT_FILE)
                if not any(part.startswith(".") for part in f.relative_to(p).parts)
            )
            for d in plots:
                found.append((d / _PLOT_FILE, d.name, ()))
            files = sorted(
                f
                for f in p.rglob("*")
                if f.is_file()
                and f.suffix.lower() in suffixes
                and not any(part.startswith(".") for part in f.relative_to(p).parts)
                and not any(d == f.parent or d in f.parents for d in plots)
            )
            for f in files:
                why = _sniff_not_a_cloud(f)
                if why:
                    skipped.append((f, why))
                else:
                    found.append((f, None, ()))
        elif p.is_file():
            if p.suffix.lower() == ".toml":
                found.append((p, p.parent.name if p.name == _PLOT_FILE else None, ()))
            elif _is_manifest(p):
                found.extend(_read_manifest(p))
            elif p.suffix.lower() in suffixes:
                found.append((p, None, ()))
            else:
                raise InputFormatError(
                    f"{p}: not a point cloud ({', '.join(sorted(suffixes))}), a folder or a "
                    "CSV manifest with a 'path' column"
                )
        else:
            raise InputFormatError(f"{p} not found; check the path")
    # ids: the stem; parent-stem where stems collide; then -2, -3 ...
    stems = [_safe_id(pid or f.stem) for f, pid, _ in found]
    counts: dict[str, int] = {}
    for s in stems:
        counts[s] = counts.get(s, 0) + 1
    trees: list[TreeInput] = list(given)
    used = {t.id for t in trees}
    for (f, pid, settings), s in zip(found, stems, strict=True):
        tid = s if (counts[s] == 1 or pid) else _safe_id(f"{f.parent.name}-{f.stem}")
        base, k = tid, 2
        while tid in used:
            tid = f"{base}-{k}"
            k += 1
        used.add(tid)
        kind = "plot" if f.suffix.lower() == ".toml" else "tree"
        trees.append(TreeInput(id=tid, path=f, settings=settings, kind=kind))
    return trees, skipped


# -- one tree in a worker -----------------------------------------------------------------
@dataclass(frozen=True, kw_only=True)
class _Task:
    id: str
    path: str
    params: RunParams
    hash: str
    outdir: str
    threads: int
    kind: str = "tree"
    reference_qsm: str | None = None


def _dig(d: Any, path: tuple[str, ...]) -> Any:
    for k in path:
        if not isinstance(d, dict):
            return None
        d = d.get(k)
    return d


def _row_from_summary(summary: dict[str, Any]) -> dict[str, Any]:
    row = {k: _dig(summary, p) for k, p in FIGURE_COLUMNS.items()}
    # the reconstruction's plausibility warnings, by code (messages in the tree's run.json)
    found = _dig(summary, ("reconstruction", "warnings")) or []
    row["warnings"] = ";".join(w["code"] for w in found) or None
    t = summary.get("timings_s", {})
    row.update({f"time_{s}_s": t.get(s) for s in (*STAGES, "total")})
    return row


def _install(src: Path, dest: Path, tmp_root: Path) -> None:
    """Move folder ``src`` to ``dest`` (replacing it) with renames only."""
    old = None
    if dest.exists():
        old = Path(tempfile.mkdtemp(prefix=f"{dest.name}-old-", dir=tmp_root))
        os.rename(dest, old / "x")
    os.rename(src, dest)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    if isinstance(exc, MemoryError):
        return "out of memory; use a coarser preset or fewer workers"
    return text or type(exc).__name__


def _run_task(task: _Task) -> dict[str, Any]:
    """Run one tree into a temporary folder and move it into place (runs in a worker)."""
    out = Path(task.outdir)
    tmp_root = out / ".tmp"
    tmp_root.mkdir(parents=True, exist_ok=True)
    tmp = tmp_root / f"{task.id}-{uuid.uuid4().hex[:12]}"
    tmp.mkdir()  # (not mkdtemp: its 0700 mode would stick to the result folder)
    threads = task_threads(task.threads)
    base = {"id": task.id, "input": task.path, "hash": task.hash}
    t0 = time.perf_counter()
    try:
        if task.kind == "plot":
            row = {**base, **_run_plot(task, tmp, threads)}
        elif task.kind == "reconstruct":
            row = {**base, **_run_reconstruct(task, tmp, threads)}
        else:
            res = run_tree(
                task.path,
                task.params.with_threads(threads),
                tmp,
                name=task.id,
                reference_qsm=task.reference_qsm,
                report_auto="summary",  # report.level auto: pages, no plots, per tree
            )
            row = {
                **base,
                "status": "ok",
                **_row_from_summary(res.summary),
                "report": f"trees/{task.id}/report.html",
                "folder": f"trees/{task.id}",
            }
        _write_json(
            tmp / "result.json",
            {
                "kind": "treesim.batch_tree",
                "hash": task.hash,
                "finished": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
                "threads": threads,
                "row": row,
            },
        )
        trees = out / "trees"
        trees.mkdir(exist_ok=True)
        _install(tmp, trees / task.id, tmp_root)
        shutil.rmtree(trees / f"{task.id}.failed", ignore_errors=True)
        return row
    except Exception as exc:
        row = {
            **base,
            "status": "failed",
            "error_class": type(exc).__name__,
            "error": _one_line(exc),
            "time_total_s": time.perf_counter() - t0,
            "folder": f"trees/{task.id}.failed",
        }
        try:
            _write_json(
                tmp / "error.json",
                {
                    **row,
                    "treesim_error": isinstance(exc, TreesimError),
                    "traceback": traceback.format_exc(),
                },
            )
            trees = out / "trees"
            trees.mkdir(exist_ok=True)
            _install(tmp, trees / f"{task.id}.failed", tmp_root)
        except OSError:
            shutil.rmtree(tmp, ignore_errors=True)
        return row
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


# -- progress -----------------------------------------------------------------------------
@dataclass(frozen=True, kw_only=True)
class BatchProgress:
    """Where a batch stands (passed to the ``progress`` callback).

    Attributes
    ----------
    total, done, failed, reused, running : int
        Trees in the batch; finished this run; failed; unchanged from an earlier run
        (not run again); running now.
    elapsed_s : float
    eta_s : float or None
        Time left, from the rate at which trees finish (None until one has).
    last : dict or None
        The row of the tree that just finished, if any.
    plots : int
        How many of the ``total`` inputs are plots (each gives one row per tree of it),
        on the first call.
    """

    total: int
    done: int
    failed: int
    reused: int
    running: int
    elapsed_s: float
    eta_s: float | None
    last: dict[str, Any] | None = None
    plots: int = 0

    @property
    def finished(self) -> int:
        return self.done + self.failed + self.reused


# -- the batch ----------------------------------------------------------------------------
class RowCounts:
    """Counts over the ``rows`` of a finished batch or sweep (each row a dict with its
    ``status``, ``ok``, ``failed`` or ``not run``, and ``reused``)."""

    rows: list[dict[str, Any]]

    def count(self, status: str) -> int:
        return sum(1 for r in self.rows if r.get("status") == status)

    @property
    def n_ok(self) -> int:
        return self.count("ok")

    @property
    def n_failed(self) -> int:
        return self.count("failed")

    @property
    def n_reused(self) -> int:
        return sum(1 for r in self.rows if r.get("reused"))

    def tally(self, noun: str) -> str:
        """One line of what ran: ``"12 trees: 3 run, 9 unchanged (not run again), 0
        failed"`` (``noun`` plural)."""
        return (
            f"{len(self.rows)} {noun}: {self.n_ok - self.n_reused} run, {self.n_reused} "
            f"unchanged (not run again), {self.n_failed} failed"
        )


@dataclass
class BatchResult(RowCounts):
    """What :func:`run_batch` did.

    Attributes
    ----------
    outdir : Path
    rows : list of dict
        One per tree, in input order, with every column of :data:`SUMMARY_COLUMNS`
        (``summary.json``'s ``trees``; ``status`` is ``ok``, ``failed`` or ``not run``).
    skipped_files : list of (Path, str)
        Files in input folders that were not tree clouds.
    plan : ExecutorPlan
    elapsed_s : float
    interrupted : bool
    summary_csv, summary_json, index_html : Path

    Examples
    --------
    >>> import treesim as ts
    >>> trees = ["tree1.laz", "tree2.laz"]
    >>> result = ts.run_batch(trees, ts.run_preset("draft"), "out/batch")  # doctest: +SKIP
    >>> result.n_ok, result.n_failed, result.summary_csv  # doctest: +SKIP
    (2, 0, PosixPath('out/batch/summary.csv'))
    """

    outdir: Path
    rows: list[dict[str, Any]]
    skipped_files: list[tuple[Path, str]]
    plan: ExecutorPlan
    elapsed_s: float
    interrupted: bool = False
    summary_csv: Path = field(default_factory=Path)
    summary_json: Path = field(default_factory=Path)
    index_html: Path = field(default_factory=Path)


@contextmanager
def _lock(outdir: Path, what: str = "batch") -> Iterator[None]:
    """Hold the output folder's lock file for the block (one batch or sweep at a time).

    The lock is :mod:`filelock`'s (``flock`` on POSIX, ``msvcrt.locking`` on Windows), tried
    once without waiting: a second writer into the same folder fails at once with an
    :class:`InvalidParameterError`, on every platform (there is no silent no-lock).
    """
    lock = FileLock(outdir / _LOCK_NAME, timeout=0)
    try:
        lock.acquire()
    except Timeout:
        raise InvalidParameterError(
            f"another {what} is writing into {outdir}; wait for it or choose another -o"
        ) from None
    try:
        yield
    finally:
        lock.release()


def _finished_row(outdir: Path, tree_id: str, tree_hash: str) -> dict[str, Any] | None:
    """The row of a finished result with this hash, or None."""
    p = outdir / "trees" / tree_id / "result.json"
    try:
        res = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(res, dict) or res.get("hash") != tree_hash or "row" not in res:
        return None
    return dict(res["row"])


def run_batch(
    inputs: Sequence[str | Path | TreeInput] | str | Path,
    params: RunParams | None = None,
    outdir: str | Path = "out/batch",
    *,
    executor: str | Executor = "inline",
    workers: int | None = None,
    threads: int | None = None,
    scheduler: str | None = None,
    progress: Callable[[BatchProgress], None] | None = None,
) -> BatchResult:
    """Run the loop on many trees; skip those already finished with the same inputs.

    Parameters
    ----------
    inputs : sequence of path or TreeInput
        Cloud files, folders and CSV manifests (see the module doc).
    params : RunParams, optional
        Settings for every tree (default the ``standard`` preset); manifest columns
        override them per tree.
    outdir : str or Path
        The batch folder (created if missing).
    executor : {"inline", "local", "dask"}
    workers : int, optional
        Worker processes (``local``, local dask cluster); default one per core.
    threads : int, optional
        Threads per tree; default ``cores // workers`` (see
        :func:`treesim.executors.plan_executor`).
    scheduler : str, optional
        A running dask scheduler's address.
    progress : callable(BatchProgress), optional
        Called when a tree finishes and about twice a second (e.g. the command line's
        :class:`treesim.cli.progress.BatchProgressBar`).

    Returns
    -------
    BatchResult

    Raises
    ------
    KeyboardInterrupt
        After writing the summary of what finished (the next run does only the rest).
    TreesimError
        For unusable inputs (a missing path, a bad manifest) before any tree runs.

    Examples
    --------
    >>> import treesim as ts
    >>> trees = ["tree1.laz", "tree2.laz"]
    >>> result = ts.run_batch(trees, ts.run_preset("draft"), "out/batch")  # doctest: +SKIP
    >>> result.summary_csv  # doctest: +SKIP
    PosixPath('out/batch/summary.csv')
    """
    t_start = time.perf_counter()
    if isinstance(inputs, (str, Path)):
        inputs = [inputs]
    params = params or run_preset()
    trees, skipped_files = discover_inputs(inputs)
    if not trees:
        raise InputFormatError("no point clouds found in the inputs; nothing to run")
    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    plan = plan_executor(
        executor, workers=workers, threads=threads, scheduler=scheduler, n_tasks=len(trees)
    )
    with _lock(out):
        return _run_locked(trees, skipped_files, params, out, plan, progress, t_start)


def _run_locked(
    trees: list[TreeInput],
    skipped_files: list[tuple[Path, str]],
    params: RunParams,
    out: Path,
    plan: ExecutorPlan,
    progress: Callable[[BatchProgress], None] | None,
    t_start: float,
) -> BatchResult:
    from ._version import __version__

    shutil.rmtree(out / ".tmp", ignore_errors=True)

    rows: dict[str, dict[str, Any]] = {}
    tasks: list[_Task] = []
    for t in trees:
        base = {"id": t.id, "input": str(t.path)}
        try:
            given = dict(t.settings)
            ref = given.pop("reference_qsm", None)
            p = apply_settings(params, given, where=f"{t.id}: ")
            if not t.path.is_file():
                raise InputFormatError(f"{t.path} not found; check the path")
            h = file_sha256(t.path)
            if ref is not None:  # its figures are in the result: a new table runs again
                if t.kind == "plot":
                    raise InvalidParameterError(
                        f"{t.id}: reference_qsm is for one tree's cloud, not a plot"
                    )
                if not Path(ref).is_file():
                    raise InputFormatError(f"reference QSM {ref} not found; check the path")
                h = _chain_hash(h, Path(ref))
            if t.kind == "plot":  # the plot file and the files it names
                h = _plot_hash(t.path, h)
        except (TreesimError, OSError) as exc:
            rows[t.id] = {
                **base,
                "status": "failed",
                "error_class": type(exc).__name__,
                "error": _one_line(exc),
            }
            continue
        tree_hash = f"{h[:32]}-{params_hash(p)[:24]}-{__version__}"  # input, settings, version
        done = _finished_row(out, t.id, tree_hash)
        if done is not None:
            rows[t.id] = {**done, "reused": True}
            continue
        tasks.append(
            _Task(
                id=t.id,
                path=str(t.path.resolve()),
                params=p,
                hash=tree_hash,
                outdir=str(out.resolve()),
                threads=plan.threads,
                kind=t.kind,
                reference_qsm=ref,
            )
        )

    # largest files first: a big tree started last would run alone at the end
    tasks.sort(key=lambda t: -_size(t.path))
    interrupted = False
    try:
        if progress is not None:  # where the batch starts from (reused trees counted)
            plots = sum(1 for t in trees if t.kind == "plot")
            progress(_state(rows, len(trees), 0, t_start, 0, None, None, plots=plots))
        if tasks:
            _drive(tasks, plan, rows, len(trees), progress, t_start)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        shutil.rmtree(out / ".tmp", ignore_errors=True)
        ordered = [
            _normalise(r)
            for t in trees
            for r in _expand(
                rows.get(t.id, {"id": t.id, "input": str(t.path), "status": "not run"})
            )
        ]
        result = BatchResult(
            outdir=out,
            rows=ordered,
            skipped_files=skipped_files,
            plan=plan,
            elapsed_s=time.perf_counter() - t_start,
            interrupted=interrupted,
        )
        _write_summaries(result, params)
    if interrupted:
        raise KeyboardInterrupt
    return result


def _size(path: str) -> int:
    try:
        return os.path.getsize(path)
    except OSError:
        return 0


def _state(
    rows: dict[str, dict[str, Any]],
    total: int,
    running: int,
    t_start: float,
    ran: int,
    t_first: float | None,
    last: dict[str, Any] | None,
    *,
    plots: int = 0,
) -> BatchProgress:
    vals = list(rows.values())
    failed = sum(1 for r in vals if r.get("status") == "failed")
    reused = sum(1 for r in vals if r.get("reused"))
    done = len(vals) - failed - reused
    elapsed = time.perf_counter() - t_start
    eta = None
    if ran and t_first is not None:
        rate = ran / max(time.perf_counter() - t_first, 1e-9)
        eta = (total - len(vals)) / rate
    return BatchProgress(
        total=total,
        done=done,
        failed=failed,
        reused=reused,
        running=running,
        elapsed_s=elapsed,
        eta_s=eta,
        last=last,
        plots=plots,
    )


#: A tree in flight when a worker process dies is tried this many times in all.
_ATTEMPTS = 2


def _drive(
    tasks: list[Any],
    plan: ExecutorPlan,
    rows: dict[str, dict[str, Any]],
    total: int,
    progress: Callable[[BatchProgress], None] | None,
    t_start: float,
    fn: Callable[[Any], dict[str, Any]] = _run_task,
) -> None:
    """Submit ``fn(task)`` for each task, at most as many at once as the executor has
    slots; collect the rows it returns (``rows[task.id]``). A broken process pool (a
    worker killed, e.g. by the OOM killer) is replaced and its tasks are tried again; a
    task in flight at ``_ATTEMPTS`` breaks is failed. Tasks need ``id``, ``path`` and
    ``hash`` (a failure's row); :mod:`treesim.sweep` drives its points through here too."""
    pending = deque(tasks)
    attempts: dict[str, int] = {}
    t_first = time.perf_counter()
    ran = 0
    say = progress or (lambda p: None)
    while pending:
        broken = False
        with open_executor(plan) as ex:
            inflight: dict[cf.Future, Any] = {}
            while pending or inflight:
                n_slots = slots(plan, ex)  # a dask cluster may grow or shrink
                while pending and len(inflight) < n_slots and not broken:
                    task = pending.popleft()
                    inflight[ex.submit(fn, task)] = task
                if not inflight:
                    break
                done, _ = cf.wait(inflight, timeout=0.5, return_when=cf.FIRST_COMPLETED)
                if not done:
                    say(_state(rows, total, len(inflight), t_start, ran, t_first, None))
                for f in done:
                    task = inflight.pop(f)
                    try:
                        row = f.result()
                    except cf.CancelledError:
                        pending.append(task)
                        continue
                    except Exception as exc:  # the executor failed, not the tree
                        attempts[task.id] = attempts.get(task.id, 0) + 1
                        if isinstance(exc, cf.process.BrokenProcessPool):
                            broken = True
                            if attempts[task.id] < _ATTEMPTS:
                                pending.appendleft(task)
                                continue
                        row = {
                            "id": task.id,
                            "input": task.path,
                            "hash": task.hash,
                            "status": "failed",
                            "error_class": type(exc).__name__,
                            "error": (
                                "the worker process died while running this tree "
                                f"({_one_line(exc)}); it may need more memory than a worker has"
                                if broken
                                else _one_line(exc)
                            ),
                        }
                    ran += 1
                    rows[task.id] = row
                    say(_state(rows, total, len(inflight), t_start, ran, t_first, row))
                if broken and not inflight:
                    break


# -- plots --------------------------------------------------------------------------------
def _chain_hash(h: str, path: Path) -> str:
    """``h`` extended by the content of the file at ``path``."""
    return hashlib.sha256((h + file_sha256(path)).encode()).hexdigest()


def _plot_hash(path: Path, h: str) -> str:
    """The plot file's hash ``h`` with every file it names: its trees CSV, its terrain's
    DTM or ground cloud, and each tree's mesh, QSM table or cloud (a changed one runs the
    plot again)."""
    import tomllib

    from .plot.io import read_plot

    try:
        doc = tomllib.loads(Path(path).read_text(encoding="utf-8"))
        plot = read_plot(path)
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError, TreesimError):
        return h  # the run says what is wrong with it
    base = Path(path).parent
    files = [base / doc["trees"]] if isinstance(doc.get("trees"), str) else []
    if plot.terrain.file is not None:
        files.append(plot.terrain.file)
    for t in plot.trees:
        if t.path:
            p = Path(str(t.path))
            files.append(p if p.is_absolute() else base / p)
    for f in files:
        if f.is_file():  # a missing one fails the run, which names it
            h = _chain_hash(h, f)
    return h


#: Per-tree figures of a plot scan (``tree_figures``) as summary columns.
_PLOT_COLUMNS = {
    "dbh_m": "dbh_m",
    "height_m": "height_m",
    "n_triangles": "triangles",
    "scan_points": "points",
    "vs_mesh_coverage": "coverage",
    "vs_mesh_accuracy_p95_m": "accuracy_p95_m",
    "vs_mesh_completeness_p95_m": "completeness_p95_m",
}


def _run_plot(task: _Task, out: Path, threads: int) -> dict[str, Any]:
    """Scan a plot (:func:`treesim.plot.scan.plot_scan_files`) with the batch's scan and
    compare settings: ``n_stations`` on a ring around the plot centre at ``distance_m``
    (default half the plot's radius), ``height_m`` above the terrain. Returns the plot's
    row, its trees' rows under ``trees``."""
    from .plot.io import read_plot
    from .plot.scan import plot_scan_files, plot_stations

    p = task.params
    t0 = time.perf_counter()
    plot = read_plot(task.path)
    stations = plot_stations(
        plot, n=int(p.scan.n_stations), distance_m=p.scan.distance_m, height_m=p.scan.height_m
    )
    step = plot_scan_files(plot, out, p.scan, stations=stations, compare=p.compare, threads=threads)
    total = time.perf_counter() - t0
    trees = []
    for i, r in enumerate(step.details["trees"]):
        trees.append(
            {
                "tree_id": r["tree_id"],
                **{col: r.get(key) for col, key in _PLOT_COLUMNS.items()},
                # the plot's times once, on its first tree's row (a sum stays right)
                **(
                    {"time_scan_s": step.summary["timings_s"]["scan"], "time_total_s": total}
                    if i == 0
                    else {}
                ),
            }
        )
    return {
        "status": "ok",
        "kind": "plot",
        "trees": trees,
        "report": f"trees/{task.id}/plot_scan.json",
        "folder": f"trees/{task.id}",
    }


def _run_reconstruct(task: _Task, out: Path, threads: int) -> dict[str, Any]:
    """Reconstruct one field cloud (:func:`treesim.steps.reconstruct_files`) with the
    batch's reconstruction settings; ``tree.ply``, ``cylinders.csv`` and ``tree.json`` go
    into the tree's folder. Returns its row."""
    from .steps import reconstruct_files

    t0 = time.perf_counter()
    step = reconstruct_files(task.path, task.params.reconstruct, out, threads=threads)
    total = time.perf_counter() - t0
    summary = step.summary
    return {
        "status": "ok",
        "kind": "reconstruct",
        **_row_from_summary(
            {"reconstruction": summary, "inputs": {"points": summary.get("points_input")}}
        ),
        "time_reconstruct_s": total,
        "time_total_s": total,
        "report": f"trees/{task.id}/tree.json",
        "folder": f"trees/{task.id}",
    }


def _expand(row: dict[str, Any]) -> list[dict[str, Any]]:
    """A plot's row as one row per tree (its ``trees``); any other row as it is."""
    trees = row.get("trees")
    if not isinstance(trees, list):
        return [row]
    base = {k: v for k, v in row.items() if k != "trees"}
    return [{**base, **t} for t in trees] or [base]


# -- summaries ----------------------------------------------------------------------------
def _normalise(row: dict[str, Any]) -> dict[str, Any]:
    """A row with every summary column, in order (``reused`` a bool)."""
    out = {c: row.get(c) for c in SUMMARY_COLUMNS}
    out["reused"] = bool(row.get("reused"))
    return out


def _write_summaries(result: BatchResult, params: RunParams) -> None:
    from ._version import __version__
    from .run import software_versions

    out = result.outdir
    rows = result.rows
    csv_path = out / "summary.csv"
    with atomic_path(csv_path) as tmp, open(tmp, "w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=list(SUMMARY_COLUMNS))
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if v is None else v) for k, v in r.items()})
    counts = {
        "trees": len(rows),
        "ok": sum(1 for r in rows if r["status"] == "ok"),
        "failed": sum(1 for r in rows if r["status"] == "failed"),
        "not_run": sum(1 for r in rows if r["status"] == "not run"),
        "reused": sum(1 for r in rows if r["reused"]),
    }
    json_path = out / "summary.json"
    _write_json(
        json_path,
        {
            "kind": "treesim.batch",
            "treesim": __version__,
            "finished": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
            "interrupted": result.interrupted,
            "elapsed_s": result.elapsed_s,
            "executor": result.plan.to_dict(),
            "counts": counts,
            "parameters": params.to_dict(),
            "skipped_files": [{"path": str(p), "reason": why} for p, why in result.skipped_files],
            "software": software_versions(),
            "trees": rows,
        },
    )
    idx = out / "index.html"
    write_text(
        idx,
        batch_index_page(
            rows,
            counts,
            skipped_files=result.skipped_files,
            interrupted=result.interrupted,
            executor=result.plan.describe(),
            elapsed_s=result.elapsed_s,
        ),
    )
    result.summary_csv, result.summary_json, result.index_html = csv_path, json_path, idx
