"""Running a sweep: trees made ready, points run (resumably) on an executor, the outputs.

See :mod:`treesim.sweep` for what a sweep is and writes. Points go through batch's task
engine (:func:`treesim.batch._drive`: slots, a broken pool replaced, failures isolated)
on any executor; each point's work runs in a fresh process of its own
(:mod:`treesim.sweep.point`).
"""

from __future__ import annotations

import csv
import datetime as _dt
import hashlib
import json
import math
import os
import shutil
import sys
import time
import uuid
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

from ..atomic import atomic_path, write_text
from ..batch import BatchProgress, RowCounts, _drive, _install, _lock, _state
from ..errors import InvalidParameterError
from ..executors import Executor, ExecutorPlan, plan_executor
from ..jsonio import json_ready, write_json
from ..params import params_hash
from ..run import STAGES
from .config import Design, SweepConfig, load_sweep
from .pareto import pareto_front
from .trees import PreparedTree, derive_tolerance, prepare_tree

__all__ = [
    "FIGURES",
    "SweepResult",
    "fronts_of",
    "machine",
    "run_sweep",
    "sweep_columns",
]

#: The comparisons a point records: key, what the reference is.
REFERENCES = {
    "vs_truth": "truth mesh",
    "vs_field": "field cloud",
    "vs_mesh": "scanned mesh",
}


def _figures() -> list[dict[str, Any]]:
    out = []
    for ref, word in REFERENCES.items():
        for stat in ("mean", "p95"):
            out.append(
                {
                    "key": f"{ref}_accuracy_{stat}_m",
                    "label": f"accuracy {stat}, simulated → {word}",
                    "unit": "m",
                    "better": "lower",
                    "absolute": False,
                }
            )
        for stat in ("mean", "p95"):
            out.append(
                {
                    "key": f"{ref}_completeness_{stat}_m",
                    "label": f"completeness {stat}, {word} → simulated",
                    "unit": "m",
                    "better": "lower",
                    "absolute": False,
                }
            )
        out.append(
            {
                "key": f"{ref}_coverage",
                "label": f"coverage of the {word} within τ",
                "unit": "",
                "better": "higher",
                "absolute": False,
            }
        )
    out += [
        {
            "key": "dbh_error_m",
            "label": "|DBH error| (reconstruction − truth)",
            "unit": "m",
            "better": "lower",
            "absolute": True,
        },
        {
            "key": "height_error_m",
            "label": "|height error| (reconstruction − truth)",
            "unit": "m",
            "better": "lower",
            "absolute": True,
        },
        {
            "key": "volume_error_rel",
            "label": "|volume error| (reconstruction / truth − 1)",
            "unit": "",
            "better": "lower",
            "absolute": True,
        },
    ]
    return out


#: Accuracy figures with a Pareto front against time: ``key``, ``label``, ``unit``,
#: ``better`` (``lower`` or ``higher``) and ``absolute`` (the front is of |value|).
FIGURES: list[dict[str, Any]] = _figures()

#: The cost axis of every front: the loop's time without drawing its reports (read,
#: reconstruct, scan, both comparisons), so that the trade is one of science, whatever
#: report level the points drew (``time_report_s`` is beside it).
TIME = "time_science_s"
#: The stages :data:`TIME` adds up.
SCIENCE_STAGES = tuple(s for s in STAGES if s != "report")

_HEAD = ("id", "tree", "design", "label", "status", "reused")
_TIMES = (
    "repeats",
    "time_total_s",
    "time_total_min_s",
    "time_total_max_s",
    "time_total_sd_s",
    "time_science_s",
    *(f"time_{s}_s" for s in STAGES),
    "time_truth_compare_s",
    "peak_rss_mib",
    "base_rss_mib",
    "threads",
)
_SIZES = ("field_points", "points", "rays", "tolerance_m")
_TREE = (
    "dbh_m",
    "truth_dbh_m",
    "dbh_error_m",
    "height_m",
    "truth_height_m",
    "height_error_m",
    "volume_total_m3",
    "truth_volume_total_m3",
    "volume_error_m3",
    "volume_error_rel",
)
_CMP = tuple(
    f"{ref}_{k}"
    for ref in REFERENCES
    for k in (
        "accuracy_mean_m",
        "accuracy_p95_m",
        "completeness_mean_m",
        "completeness_p95_m",
        "coverage",
        "chamfer_m",
        "hausdorff_m",
    )
)
_TAIL = ("on_fronts", "repeatable", "error_class", "error", "report", "folder", "hash")


def sweep_columns(parameters: tuple[str, ...] | list[str]) -> list[str]:
    """The columns of ``sweep.csv`` (and the keys of each row of ``sweep.json``)."""
    return [*_HEAD, *parameters, *_TIMES, *_SIZES, *_TREE, *_CMP, *_TAIL]


def machine() -> dict[str, Any]:
    """The machine, for the record: CPU model, cores usable, memory, Python, platform."""
    import platform

    from .._system import cpu_count

    cpu = platform.processor() or platform.machine()
    mem = None
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal:"):
                mem = round(int(line.split()[1]) / 1024**2, 1)
    except OSError:
        pass
    return {
        "cpu": cpu,
        "arch": platform.machine(),
        "cores": cpu_count(),
        "memory_gib": mem,
        "python": platform.python_version(),
        "platform": platform.platform(terse=True),
    }


# -- tasks ----------------------------------------------------------------------------------
@dataclass(frozen=True, kw_only=True)
class _PointTask:
    id: str
    path: str  # the tree's field cloud (batch's engine names it in a failure)
    hash: str
    outdir: str
    threads: int
    name: str
    params: dict[str, Any]
    params_hash: str
    truth_mesh: str | None
    repeat: int
    done: dict[str, Any] | None = None  # result.json of a finished point needing repeats


def _child(task: _PointTask, out: Path, *, truth: bool) -> dict[str, Any]:
    """Run the point in a fresh process into ``out``; what it wrote (``point.json`` and
    ``run.json``), or ``{"error_class", "error"}``."""
    import subprocess

    out.mkdir(parents=True, exist_ok=True)
    spec = {
        "name": task.name,
        "cloud": task.path,
        "params": task.params,
        "params_hash": task.params_hash,
        "threads": task.threads,
        "outdir": str(out),
        "truth_mesh": task.truth_mesh,
        "truth": truth,
        "parent_pid": os.getpid(),
    }
    task_file = out / "point-task.json"
    write_json(task_file, spec)
    root = str(Path(__file__).resolve().parents[2])  # the same pipeline in the child
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (root, env.get("PYTHONPATH")) if p)
    with open(out / "point.log", "ab") as log:
        proc = subprocess.run(
            [sys.executable, "-m", "treesim.sweep.point", str(task_file)],
            stdout=log,
            stderr=subprocess.STDOUT,
            env=env,
            check=False,
        )
    if (out / "point.json").is_file() and proc.returncode == 0:
        got = json.loads((out / "point.json").read_text(encoding="utf-8"))
        got["run"] = json.loads((out / "run.json").read_text(encoding="utf-8"))
        return got
    try:
        err = json.loads((out / "error.json").read_text(encoding="utf-8"))
        return {"error_class": err["error_class"], "error": err["error"]}
    except (OSError, ValueError, KeyError):
        how = f"signal {-proc.returncode}" if proc.returncode < 0 else f"status {proc.returncode}"
        return {
            "error_class": "ProcessDied",
            "error": f"the point's process ended with {how} and no result (killed, or out "
            f"of memory?); see {out.name}/point.log",
        }


def _figures_of(run: dict[str, Any], point: dict[str, Any]) -> dict[str, Any]:
    """What a point measured (not how long it took), from ``run.json`` and ``point.json``."""
    return {
        "reconstruction": run.get("reconstruction", {}),
        "scan": {k: run.get("scan", {}).get(k) for k in ("points", "rays_cast")},
        "field_points": run.get("inputs", {}).get("points"),
        "vs_mesh": run.get("vs_mesh", {}),
        "vs_field": run.get("vs_field", {}),
        "vs_truth": point.get("vs_truth"),
        "time_truth_compare_s": point.get("time_truth_compare_s"),
    }


def _timing_of(got: dict[str, Any]) -> dict[str, Any]:
    return {
        "timings_s": got["timings_s"],
        "peak_rss_mib": got["peak_rss_mib"],
        "base_rss_mib": got.get("base_rss_mib"),
        "threads": got.get("threads"),
        "warm_up_s": got.get("warm_up_s"),
    }


def _same(a: dict[str, Any], b: dict[str, Any]) -> bool:
    keys = ("reconstruction", "scan", "vs_mesh", "vs_field")
    return json.dumps(json_ready({k: a.get(k) for k in keys}), sort_keys=True) == json.dumps(
        json_ready({k: b.get(k) for k in keys}), sort_keys=True
    )


def _write_result(folder: Path, result: dict[str, Any]) -> None:
    result["finished"] = _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
    write_json(folder / "result.json", result)


def _run_point(task: _PointTask) -> dict[str, Any]:
    """Run a point (and its repeats) and install it as ``points/<id>`` (runs in a worker)."""
    out = Path(task.outdir)
    tmp_root = out / ".tmp"
    tmp_root.mkdir(parents=True, exist_ok=True)
    points = out / "points"
    points.mkdir(exist_ok=True)
    base = {"id": task.id, "input": task.path, "hash": task.hash}
    folder = points / task.id
    if task.done is None:
        tmp = tmp_root / f"{task.id}-{uuid.uuid4().hex[:12]}"
        got = _child(task, tmp, truth=True)
        if "error" in got:
            row = {**base, "status": "failed", **got, "folder": f"points/{task.id}.failed"}
            write_json(tmp / "error.json", {**row, **_read_json(tmp / "error.json")})
            _install(tmp, points / f"{task.id}.failed", tmp_root)
            return row
        result = {
            "kind": "treesim.sweep_result",
            "hash": task.hash,
            "id": task.id,
            "figures": _figures_of(got["run"], got),
            "runs": [_timing_of(got)],
            "repeat_errors": [],
        }
        _write_result(tmp, result)  # last: a folder without it is not a result
        _install(tmp, folder, tmp_root)
        shutil.rmtree(points / f"{task.id}.failed", ignore_errors=True)
    else:
        result = dict(task.done)
    # repeats: timings only, each in a fresh process, into a scratch folder
    while len(result["runs"]) < task.repeat:
        k = len(result["runs"]) + 1
        scratch = tmp_root / f"{task.id}-repeat{k}-{uuid.uuid4().hex[:8]}"
        got = _child(task, scratch, truth=False)
        if "error" in got:
            result["repeat_errors"] = [
                *result.get("repeat_errors", []),
                f"repeat {k}: {got['error_class']}: {got['error']}",
            ]
            shutil.rmtree(scratch, ignore_errors=True)
            break
        same = _same(result["figures"], _figures_of(got["run"], got))
        result["repeatable"] = bool(result.get("repeatable", True) and same)
        result["runs"] = [*result["runs"], _timing_of(got)]
        shutil.rmtree(scratch, ignore_errors=True)
        _write_result(folder, result)
    return {**base, "status": "ok", "result": result, "time_total_s": _mean_total(result)}


def _read_json(path: Path) -> dict[str, Any]:
    try:
        d = json.loads(path.read_text(encoding="utf-8"))
        return d if isinstance(d, dict) else {}
    except (OSError, ValueError):
        return {}


def _mean_total(result: dict[str, Any]) -> float | None:
    t = [r["timings_s"]["total"] for r in result.get("runs", [])]
    return sum(t) / len(t) if t else None


# -- rows -----------------------------------------------------------------------------------
def _get(d: Any, *path: str) -> Any:
    for k in path:
        if not isinstance(d, dict):
            return None
        d = d.get(k)
    return d


def _row(
    pid: str,
    tree: PreparedTree,
    design: Design,
    values: dict[str, Any],
    raw: dict[str, Any],
) -> dict[str, Any]:
    row: dict[str, Any] = {
        "id": pid,
        "tree": tree.spec.id,
        "design": design.index,
        "label": ", ".join(design.labels),
        "status": raw.get("status", "not run"),
        "reused": bool(raw.get("reused")),
        **values,
        "hash": raw.get("hash"),
    }
    if row["status"] != "ok":
        row.update(
            {
                "error_class": raw.get("error_class"),
                "error": raw.get("error"),
                "folder": raw.get("folder"),
            }
        )
        return row
    import statistics

    res = raw["result"]
    runs = res["runs"]
    totals = [r["timings_s"]["total"] for r in runs]
    row.update(
        {
            "repeats": len(runs),
            "time_total_s": sum(totals) / len(totals),
            "time_total_min_s": min(totals),
            "time_total_max_s": max(totals),
            "time_total_sd_s": statistics.stdev(totals) if len(totals) > 1 else None,
            **{
                f"time_{s}_s": sum(r["timings_s"].get(s, 0.0) for r in runs) / len(runs)
                for s in STAGES
            },
            "time_science_s": sum(
                sum(r["timings_s"].get(s, 0.0) for s in SCIENCE_STAGES) for r in runs
            )
            / len(runs),
            "peak_rss_mib": max(r["peak_rss_mib"] for r in runs),
            "base_rss_mib": min(
                (r["base_rss_mib"] for r in runs if r.get("base_rss_mib") is not None),
                default=None,
            ),
            "threads": runs[0].get("threads"),
        }
    )
    f = res["figures"]
    rec = f.get("reconstruction", {})
    truth = tree.truth or {}
    row.update(
        {
            "time_truth_compare_s": f.get("time_truth_compare_s"),
            "field_points": f.get("field_points"),
            "points": _get(f, "scan", "points"),
            "rays": _get(f, "scan", "rays_cast"),
            "tolerance_m": _get(f, "vs_mesh", "tolerance_m"),
            "dbh_m": rec.get("dbh_m"),
            "height_m": rec.get("height_m"),
            "volume_total_m3": rec.get("volume_total_m3"),
            "truth_dbh_m": truth.get("dbh_m"),
            "truth_height_m": truth.get("height_m"),
            "truth_volume_total_m3": truth.get("volume_total_m3"),
        }
    )

    def diff(a: Any, b: Any) -> float | None:
        return a - b if isinstance(a, (int, float)) and isinstance(b, (int, float)) else None

    row["dbh_error_m"] = diff(row["dbh_m"], row["truth_dbh_m"])
    row["height_error_m"] = diff(row["height_m"], row["truth_height_m"])
    row["volume_error_m3"] = diff(row["volume_total_m3"], row["truth_volume_total_m3"])
    tv = row["truth_volume_total_m3"]
    row["volume_error_rel"] = (
        row["volume_error_m3"] / tv if row["volume_error_m3"] is not None and tv else None
    )
    for ref in REFERENCES:
        c = f.get(ref) or {}
        row.update(
            {
                f"{ref}_accuracy_mean_m": _get(c, "accuracy", "mean_m"),
                f"{ref}_accuracy_p95_m": _get(c, "accuracy", "p95_m"),
                f"{ref}_completeness_mean_m": _get(c, "completeness", "mean_m"),
                f"{ref}_completeness_p95_m": _get(c, "completeness", "p95_m"),
                f"{ref}_coverage": c.get("coverage"),
                f"{ref}_chamfer_m": c.get("chamfer_m"),
                f"{ref}_hausdorff_m": c.get("hausdorff_m"),
            }
        )
    row["repeatable"] = res.get("repeatable") if len(runs) > 1 else None
    errs = res.get("repeat_errors") or []
    if errs:
        row["error"] = "; ".join(errs)
    row["report"] = f"points/{pid}/report.html"
    row["folder"] = f"points/{pid}"
    return row


def fronts_of(rows: list[dict[str, Any]]) -> dict[str, dict[str, list[str]]]:
    """For every figure of :data:`FIGURES`, per tree, the ids of the points on the
    Pareto front of (time, figure) (by increasing time). Trees without the figure (no
    truth) are left out."""
    ok = [r for r in rows if r.get("status") == "ok"]
    trees = list(dict.fromkeys(r["tree"] for r in ok))
    out: dict[str, dict[str, list[str]]] = {}
    for fig in FIGURES:
        per: dict[str, list[str]] = {}
        for t in trees:
            mine = [r for r in ok if r["tree"] == t and r.get(fig["key"]) is not None]
            if not mine:
                continue
            vals = [abs(r[fig["key"]]) if fig["absolute"] else r[fig["key"]] for r in mine]
            idx = pareto_front(
                [r.get(TIME) for r in mine], vals, higher_is_better=fig["better"] == "higher"
            )
            per[t] = [mine[i]["id"] for i in idx]
        if per:
            out[fig["key"]] = per
    return out


# -- the sweep ------------------------------------------------------------------------------
@dataclass
class SweepResult(RowCounts):
    """What :func:`run_sweep` did.

    Attributes
    ----------
    outdir : Path
    config : SweepConfig
    rows : list of dict
        One per point (tree × design), with every column of :func:`sweep_columns`.
    fronts : dict
        :func:`fronts_of` the rows.
    tolerance : dict
        τ and how it was chosen.
    plan : ExecutorPlan
    elapsed_s : float
        Wall time of this call (``sweep.json``'s ``elapsed_s``), not of earlier calls
        whose finished points it reused or timed again.
    interrupted : bool
    csv, json, html : Path

    Examples
    --------
    >>> import treesim as ts
    >>> result = ts.run_sweep("sweep.toml", "out/sweep")  # doctest: +SKIP
    >>> result.csv, result.html  # doctest: +SKIP
    (PosixPath('out/sweep/sweep.csv'), PosixPath('out/sweep/sweep.html'))
    """

    outdir: Path
    config: SweepConfig
    rows: list[dict[str, Any]]
    fronts: dict[str, dict[str, list[str]]]
    tolerance: dict[str, Any]
    plan: ExecutorPlan
    elapsed_s: float
    interrupted: bool = False
    csv: Path = field(default_factory=Path)
    json: Path = field(default_factory=Path)
    html: Path = field(default_factory=Path)


def _check_writable(out: Path) -> None:
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / f".treesim-write-test-{uuid.uuid4().hex[:8]}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise InvalidParameterError(
            f"cannot write into the output folder {out} ({exc.strerror or exc}); choose another -o"
        ) from None


def point_id(tree_id: str, design: Design) -> str:
    """A point's folder name: its tree and the start of its design's key (stable when
    other designs are added to or removed from the file)."""
    return f"{tree_id}-{design.key[:8]}"


def _point_hash(tree: PreparedTree, design: Design, tau_params_hash: str) -> str:
    from .._version import __version__

    text = json.dumps([tree.key, design.key, tau_params_hash, __version__])
    return hashlib.sha256(text.encode()).hexdigest()


def run_sweep(
    config: SweepConfig | str | Path,
    outdir: str | Path,
    *,
    repeat: int | None = None,
    executor: str | Executor = "inline",
    workers: int | None = None,
    threads: int | None = None,
    scheduler: str | None = None,
    fresh: bool = False,
    progress: Callable[[BatchProgress], None] | None = None,
    say: Callable[[str], None] | None = None,
) -> SweepResult:
    """Run every point of a sweep (tree × design), reusing those already finished.

    Parameters
    ----------
    config : SweepConfig or path
        A checked configuration or its TOML file.
    outdir : str or Path
        The sweep's folder (created if missing; must be writable).
    repeat : int, optional
        Timings per point (default the file's ``repeat``). A finished point with fewer
        timings gets only the missing ones; one with more keeps them all.
    executor, workers, threads, scheduler
        As for :func:`treesim.run_batch`. ``inline`` (the default) runs one point at a
        time, the cleanest timings; every point runs in a fresh process of its own anyway.
    fresh : bool
        Make every tree ready and run every point again, ignoring finished ones (after
        changing treesim's code).
    progress : callable(BatchProgress), optional
        Called as points finish.
    say : callable(str), optional
        Notes on what happens before the points run (trees made ready, τ).

    Returns
    -------
    SweepResult

    Raises
    ------
    KeyboardInterrupt
        After writing the outputs of what finished (the next run does only the rest).
    TreesimError
        For an unusable configuration or output folder, before any point runs.

    Examples
    --------
    >>> import treesim as ts
    >>> result = ts.run_sweep("sweep.toml", "out/sweep")  # doctest: +SKIP
    >>> result.html  # doctest: +SKIP
    PosixPath('out/sweep/sweep.html')
    """
    t_start = time.perf_counter()
    cfg = config if isinstance(config, SweepConfig) else load_sweep(config)
    n_repeat = cfg.repeat if repeat is None else int(repeat)
    if isinstance(n_repeat, bool) or n_repeat < 1:
        raise InvalidParameterError(f"repeat must be >= 1, got {repeat!r}")
    cfg = replace(cfg, repeat=n_repeat)
    out = Path(outdir)
    _check_writable(out)
    n_points = len(cfg.trees) * len(cfg.designs)
    plan = plan_executor(
        executor, workers=workers, threads=threads, scheduler=scheduler, n_tasks=n_points
    )
    note = say or (lambda s: None)
    with _lock(out, "sweep"):
        shutil.rmtree(out / ".tmp", ignore_errors=True)
        from .._system import cpu_count

        prep_threads = plan.threads or cpu_count()
        trees = []
        for spec in cfg.trees:
            t0 = time.perf_counter()
            tree = prepare_tree(
                spec, cfg.reference, out / "trees", threads=prep_threads, fresh=fresh
            )
            trees.append(tree)
            note(
                f"tree {spec.id}: {spec.source}; field cloud {tree.field_points:,} points, "
                f"spacing {tree.point_spacing_m * 1000:.3g} mm ({time.perf_counter() - t0:.1f} s)"
            )
        windy = _windy_trees(cfg, trees, out, prep_threads, fresh, note)
        if cfg.tolerance_m is not None:
            tolerance = {"tolerance_m": cfg.tolerance_m, "rule": "given in the sweep file"}
        else:
            assert cfg.tolerance_factor is not None
            tolerance = derive_tolerance(trees, cfg.tolerance_factor)
        tau = float(tolerance["tolerance_m"])
        note(f"τ = {tau * 1000:.3g} mm for every coverage figure ({tolerance['rule']})")
        return _run_points(cfg, trees, tolerance, out, plan, fresh, progress, t_start, windy)


WIND_SETTINGS = ("wind_speed_m_s", "wind_direction_deg", "wind_turbulence_intensity", "wind_seed")


def design_wind(design: Design) -> tuple[float, ...] | None:
    """A design's wind (speed, direction, turbulence intensity, seed), None when still."""
    spec = design.params.scan.scanner
    if spec.wind_speed_m_s <= 0:
        return None
    return tuple(float(getattr(spec, k)) for k in WIND_SETTINGS)


def _windy_trees(
    cfg: SweepConfig,
    trees: list[PreparedTree],
    out: Path,
    threads: int,
    fresh: bool,
    note: Callable[[str], None],
) -> dict[tuple[str, tuple[float, ...]], PreparedTree]:
    """Each procedural tree's field cloud scanned in each wind a design blows: a design
    with wind measures a tree scanned in that wind (the reference design, its wind
    settings the design's, the tree swaying by its exact cylinder table), so its DBH,
    volumes and truth comparisons carry the wind's share; the design's own scan of the
    reconstruction sways too (:func:`treesim.run.run_wind`). Field cloud files are used
    as they are. Kept in ``trees/wind-<speed>-<key>/<tree>/``."""
    winds = sorted({w for d in cfg.designs if (w := design_wind(d)) is not None})
    made: dict[tuple[str, tuple[float, ...]], PreparedTree] = {}
    for w in winds:
        speed, direction, intensity, seed = w
        ref = replace(
            cfg.reference,
            scanner=cfg.reference.scanner.with_(
                wind_speed_m_s=speed,
                wind_direction_deg=direction,
                wind_turbulence_intensity=intensity,
                wind_seed=int(seed),
                wind_cylinders=None,
            ),
        )
        key = hashlib.sha256(json.dumps(list(w)).encode()).hexdigest()[:8]
        root = out / "trees" / f"wind-{w[0]:g}-{key}"
        for tree in trees:
            if tree.spec.kind != "procedural":
                continue
            t0 = time.perf_counter()
            made[(tree.spec.id, w)] = prepare_tree(
                tree.spec, ref, root, threads=threads, fresh=fresh
            )
            note(
                f"tree {tree.spec.id} in a {w[0]:g} m/s wind: field cloud "
                f"{made[(tree.spec.id, w)].field_points:,} points "
                f"({time.perf_counter() - t0:.1f} s)"
            )
    return made


def _run_points(
    cfg: SweepConfig,
    trees: list[PreparedTree],
    tolerance: dict[str, Any],
    out: Path,
    plan: ExecutorPlan,
    fresh: bool,
    progress: Callable[[BatchProgress], None] | None,
    t_start: float,
    windy: dict[tuple[str, tuple[float, ...]], PreparedTree] | None = None,
) -> SweepResult:
    tau = float(tolerance["tolerance_m"])
    raw: dict[str, dict[str, Any]] = {}
    tasks: list[_PointTask] = []
    order: list[tuple[str, PreparedTree, Design]] = []
    for base in trees:
        for design in cfg.designs:
            pid = point_id(base.spec.id, design)
            # a windy design measures the tree scanned in its wind (procedural trees)
            tree = (windy or {}).get((base.spec.id, design_wind(design)), base)  # type: ignore[arg-type]
            order.append((pid, tree, design))
            p = replace(design.params, compare=replace(design.params.compare, tolerance_m=tau))
            ph = params_hash(p)
            h = _point_hash(tree, design, ph)
            done = None if fresh else _finished(out, pid, h)
            if done is not None and len(done["runs"]) >= cfg.repeat:
                raw[pid] = {
                    "id": pid,
                    "status": "ok",
                    "reused": True,
                    "hash": h,
                    "result": done,
                }
                continue
            tasks.append(
                _PointTask(
                    id=pid,
                    path=str(tree.cloud.resolve()),
                    hash=h,
                    outdir=str(out.resolve()),
                    threads=plan.threads,
                    name=f"{tree.spec.id} · design {design.index}",
                    params=p.to_dict(),
                    params_hash=ph,
                    truth_mesh=str(tree.truth_mesh.resolve()) if tree.truth_mesh else None,
                    repeat=cfg.repeat,
                    done=done,
                )
            )
    interrupted = False
    try:
        if progress is not None:  # where the sweep starts from (reused points counted)
            progress(_state(raw, len(order), 0, t_start, 0, None, None))
        if tasks:
            _drive(tasks, plan, raw, len(order), progress, t_start, fn=_run_point)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        shutil.rmtree(out / ".tmp", ignore_errors=True)
        rows = [
            _row(pid, tree, design, cfg.values_of(design), raw.get(pid, {"status": "not run"}))
            for pid, tree, design in order
        ]
        fronts = fronts_of(rows)
        on = {}
        for per in fronts.values():
            for ids in per.values():
                for i in ids:
                    on[i] = on.get(i, 0) + 1
        for r in rows:
            if r["status"] == "ok":
                r["on_fronts"] = on.get(r["id"], 0)
        cols = sweep_columns(cfg.parameters)
        rows = [{c: r.get(c) for c in cols} for r in rows]
        result = SweepResult(
            outdir=out,
            config=cfg,
            rows=rows,
            fronts=fronts,
            tolerance=tolerance,
            plan=plan,
            elapsed_s=time.perf_counter() - t_start,
            interrupted=interrupted,
        )
        _write_outputs(result, trees, list((windy or {}).values()))
    if interrupted:
        raise KeyboardInterrupt
    return result


def _finished(out: Path, pid: str, h: str) -> dict[str, Any] | None:
    res = _read_json(out / "points" / pid / "result.json")
    if res.get("hash") != h or not res.get("runs"):
        return None
    return res


# -- outputs --------------------------------------------------------------------------------
def _csv_value(v: Any) -> Any:
    if v is None:
        return ""
    if isinstance(v, float) and not math.isfinite(v):
        return ""
    if isinstance(v, (list, dict)):
        return json.dumps(v)
    return v


def sweep_document(
    result: SweepResult, trees: list[PreparedTree], windy: list[PreparedTree] | None = None
) -> dict[str, Any]:
    """``sweep.json``'s content."""
    from .._version import __version__
    from ..run import software_versions

    cfg = result.config
    rows = result.rows
    counts = {
        "points": len(rows),
        "ok": result.n_ok,
        "failed": result.n_failed,
        "not_run": result.count("not run"),
        "reused": result.n_reused,
    }
    return {
        "kind": "treesim.sweep",
        "treesim": __version__,
        "name": cfg.name,
        "description": cfg.description,
        "config": {"path": str(cfg.path) if cfg.path else None, "content": cfg.raw},
        "finished": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "interrupted": result.interrupted,
        "elapsed_s": result.elapsed_s,
        "executor": result.plan.to_dict(),
        "machine": machine(),
        "software": software_versions(),
        "repeat": cfg.repeat,
        "preset": cfg.preset,
        "base": cfg.base,
        "parameters": cfg.parameter_info(),
        "tolerance": result.tolerance,
        "reference": json_ready(asdict(cfg.reference)),
        "trees": [
            {
                "id": t.spec.id,
                "kind": t.spec.kind,
                "source": t.spec.source,
                "field_points": t.field_points,
                "point_spacing_m": t.point_spacing_m,
                "truth": t.truth,
                "reference_scan": t.info.get("reference_scan"),
            }
            for t in trees
        ],
        # procedural trees scanned in a design's wind (:func:`_windy_trees`)
        **(
            {
                "trees_in_wind": [
                    {
                        "id": t.spec.id,
                        "wind_speed_m_s": t.info["reference_scan"]["settings"]["scanner"][
                            "wind_speed_m_s"
                        ],
                        "field_points": t.field_points,
                        "point_spacing_m": t.point_spacing_m,
                        "reference_scan": t.info.get("reference_scan"),
                    }
                    for t in windy
                ]
            }
            if windy
            else {}
        ),
        "designs": [
            {
                "index": d.index,
                "key": d.key,
                "labels": list(d.labels),
                "given": d.given,
                "values": cfg.values_of(d),
                "parameters": d.params.to_dict(),
            }
            for d in cfg.designs
        ],
        "figures": FIGURES,
        "time": TIME,
        "counts": counts,
        "fronts": result.fronts,
        "columns": sweep_columns(cfg.parameters),
        "rows": rows,
    }


def _write_outputs(
    result: SweepResult, trees: list[PreparedTree], windy: list[PreparedTree] | None = None
) -> None:
    from ..report.sweep_page import sweep_page

    out = result.outdir
    cols = sweep_columns(result.config.parameters)
    csv_path = out / "sweep.csv"
    with atomic_path(csv_path) as tmp, open(tmp, "w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=cols)
        w.writeheader()
        for r in result.rows:
            w.writerow({k: _csv_value(r.get(k)) for k in cols})
    doc = sweep_document(result, trees, windy)
    json_path = write_json(out / "sweep.json", doc)
    html_path = out / "sweep.html"
    write_text(html_path, sweep_page(json_ready(doc)))
    result.csv, result.json, result.html = csv_path, json_path, html_path
