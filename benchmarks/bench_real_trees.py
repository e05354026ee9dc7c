"""Real field trees: treesim beside PyTLidar 1.1.2, the peer models and the slab reference.

For every real single-tree cloud in ``../shared/data/trees`` (``--shared``; skipped with a
note when absent) and under ``tests/data/trees/`` (public clouds added to the repository,
each folder with its PROVENANCE.md; none is fine), measured side by side in one run:

* **treesim**: ``treesim.reconstruct.reconstruct(cloud)`` with defaults in a fresh child
  process per tree: wall time of the call, peak RSS of the child (``ru_maxrss``), DBH,
  height, stem and total volume, form factor = stem volume / (pi/4 DBH^2 height), and the
  plausibility warnings of ``tree.json`` (``figures["warnings"]``) where it has them;
* **PyTLidar 1.1.2** (the TreeQSM port on PyPI, GPL-3), in its own virtualenv
  (``.bench-venvs/pytlidar``, created on first use with ``python3 -m venv`` and
  ``pip install PyTLidar==1.1.2``; ``--skip-pytlidar`` leaves it out), one model per tree
  in a child process with its automatic parameters (``build_inputs`` with one value of
  each patch diameter, as its README's quick start) and numpy's global seed 0 (its cover
  sets draw from it): the same figures, its own DBH (``DBHqsm``: the trunk cylinder at
  1.3 m along the trunk) and height;
* **peer models** that come with the data (cylinder tables beside the cloud, e.g. the
  coffee tree's TreeQSM and SimpleForest tables), read with ``treesim.models``;
* **the slab reference** (``tests/reconstruct/slab_reference.py``, computed from the
  cloud alone): DBH at 1.3 m with its verdict, the taper of the clean slabs, the height.
  Per tool: the DBH error against the slab (where the slab is clean) and the stem radius
  error against the clean slabs (max |r_model(z) - r_slab(z)| / r_slab(z), the model's
  stem radius at each slab's height from its stem cylinders).

The 1.3 m slab of every tree is drawn to ``docs/img/real_trees/NAME.png``.

Usage: ``python benchmarks/bench_real_trees.py [--trees coffee,pine] [--skip-pytlidar]
[--docs] [--reuse]`` (``--docs`` writes the table into ``docs/validation.md`` between
``<!-- bench-real-trees:begin -->`` and ``<!-- bench-real-trees:end -->``; ``--reuse``
keeps each (tree, tool) result already measured in ``--out`` and runs the rest).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from dataclasses import dataclass, field
from datetime import date
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks import docs_part  # noqa: E402
from tests.reconstruct import slab_reference as sr  # noqa: E402

DOCS_PART = "bench-real-trees"
SHARED_TREES = ROOT.parent / "shared" / "data" / "trees"
REPO_TREES = ROOT / "tests" / "data" / "trees"
IMG_DIR = ROOT / "docs" / "img" / "real_trees"
VENV = ROOT / ".bench-venvs" / "pytlidar"
PYTLIDAR = "PyTLidar==1.1.2"
CLOUD_SUFFIXES = {".las", ".laz", ".xyz", ".txt", ".ply", ".pts", ".csv"}
#: A file in a tree's folder whose name holds one of these is a model, not a cloud.
MODEL_WORDS = ("qsm", "cylinder", "simpleforest")


@dataclass
class Tree:
    """One real cloud and the peer models beside it."""

    name: str
    cloud: Path
    source: str
    peers: list[tuple[str, Path]] = field(default_factory=list)


def _is_model(path: Path) -> bool:
    return any(w in path.name.lower() for w in MODEL_WORDS)


def _peer_label(path: Path) -> str:
    low = path.name.lower()
    if "simpleforest" in low:
        return "SimpleForest (peer)"
    if "treeqsm" in low or "qsm" in low:
        return "TreeQSM (peer)"
    return f"{path.stem} (peer)"


def find_trees(shared: Path, repo: Path) -> tuple[list[Tree], list[str]]:
    """The clouds under ``shared`` and ``repo`` (one tree per cloud file) and notes."""
    trees, notes = [], []
    for root, label in ((shared, "shared"), (repo, "repo")):
        if not root.is_dir():
            notes.append(f"{label}: {root} is absent, skipped")
            continue
        for folder in sorted(p for p in root.iterdir() if p.is_dir()):
            files = sorted(p for p in folder.iterdir() if p.is_file())
            models = [p for p in files if _is_model(p) and p.suffix.lower() in {".csv", ".txt"}]
            clouds = [p for p in files if p.suffix.lower() in CLOUD_SUFFIXES and not _is_model(p)]
            for c in clouds:
                name = folder.name if len(clouds) == 1 else f"{folder.name}/{c.stem}"
                trees.append(
                    Tree(name, c, label, [(_peer_label(m), m) for m in models if len(clouds) == 1])
                )
        if not any(t.source == label for t in trees):
            notes.append(f"{label}: no clouds in {root}")
    return trees, notes


# ---------------------------------------------------------------------- children

_TREESIM_CHILD = r"""
import json, resource, sys, time
sys.path.insert(0, {root!r})
from treesim.io import read_cloud
from treesim.reconstruct import reconstruct
cloud = read_cloud({cloud!r})
t0 = time.perf_counter()
model = reconstruct(cloud)
wall = time.perf_counter() - t0
model.write({out!r})
f = model.figures
keys = ("dbh_m", "height_m", "volume_stem_m3", "volume_total_m3", "points_input",
        "leaves_present", "warnings", "plausibility")
out = {{k: f.get(k) for k in keys}}
out.update(time_s=wall, peak_rss_mib=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
print(json.dumps(out, default=str))
"""

_PYTLIDAR_CHILD = r"""
import json, os, resource, sys, time
import numpy as np
np.random.seed(0)
from PyTLidar import build_inputs, run_qsm
P = np.load({npy!r})
os.makedirs({out!r}, exist_ok=True)
t0 = time.perf_counter()
inputs = build_inputs(P, n_patchdiam=(1, 1, 1), names=["tree"], savemat=0, savetxt=0,
                      savepdf=0)[0]
models, _ = run_qsm(P, inputs, results_dir={out!r})
wall = time.perf_counter() - t0
m = models[0]
c, td = m["cylinder"], m["treedata"]
np.savez({out!r} + "/cylinders.npz", radius=c["radius"], length=c["length"],
         start=c["start"], axis=c["axis"], branch=c["branch"])
out = dict(dbh_m=float(td["DBHqsm"]), dbh_cyl_m=float(td["DBHcyl"]),
           height_m=float(td["TreeHeight"]), volume_stem_m3=float(td["TrunkVolume"]) / 1000,
           volume_total_m3=float(td["TotalVolume"]) / 1000, time_s=wall,
           peak_rss_mib=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
           params={{k: np.asarray(inputs[k]).tolist() for k in
                   ("PatchDiam1", "PatchDiam2Min", "PatchDiam2Max")}})
print(json.dumps(out))
"""


def _child(cmd: list[str], timeout_s: float) -> dict[str, Any]:
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, cwd=ROOT)
    except subprocess.TimeoutExpired:
        return {"error": f"ran past {timeout_s:.0f} s"}
    lines = [ln for ln in proc.stdout.strip().splitlines() if ln.startswith("{")]
    if proc.returncode != 0 or not lines:
        tail = (proc.stderr.strip().splitlines() or ["no output"])[-1]
        return {"error": f"child exited {proc.returncode}: {tail[:200]}"}
    res = json.loads(lines[-1])
    res["child_wall_s"] = time.perf_counter() - t0
    return res


def run_treesim(tree: Tree, out: Path, timeout_s: float) -> dict[str, Any]:
    """treesim's defaults on ``tree`` in a child; writes the model into ``out``."""
    code = _TREESIM_CHILD.format(root=str(ROOT), cloud=str(tree.cloud), out=str(out))
    res = _child([sys.executable, "-c", code], timeout_s)
    if "error" not in res:
        from treesim.models.cylinders import read_cylinders

        t = read_cylinders(out / "cylinders.csv")
        res["stem"] = _stem_arrays(t.start, t.end, t.radius_m, t.end_radius_m, t.branch_order == 0)
    return res


def ensure_pytlidar(venv: Path = VENV) -> Path:
    """The virtualenv's python with PyTLidar 1.1.2, created on first use.

    Raises
    ------
    SystemExit
        When the virtualenv cannot be made, with the commands to make it by hand.
    """
    py = venv / "bin" / "python"
    check = [
        str(py),
        "-c",
        "import PyTLidar, importlib.metadata as m; print(m.version('PyTLidar'))",
    ]
    if (
        py.exists()
        and subprocess.run(check, capture_output=True, text=True).stdout.strip()
        == (PYTLIDAR.split("==")[1])
    ):
        return py
    how = (
        f"python3.11 -m venv {venv} && {venv}/bin/pip install {PYTLIDAR} "
        "(PyTLidar needs Python 3.8-3.12), or run with --skip-pytlidar"
    )
    print(f"creating {venv} with {PYTLIDAR} (once) ...", flush=True)
    try:
        subprocess.run(["python3", "-m", "venv", str(venv)], check=True)
        subprocess.run([str(py), "-m", "pip", "install", "-q", PYTLIDAR], check=True)
    except (OSError, subprocess.CalledProcessError) as e:
        raise SystemExit(
            f"could not make PyTLidar's virtualenv ({e}); make it by hand: {how}"
        ) from e
    return py


def run_pytlidar(tree: Tree, points: np.ndarray, out: Path, py: Path, timeout_s: float):
    """PyTLidar 1.1.2 on ``tree`` in a child (xy shifted to the cloud's median)."""
    out.mkdir(parents=True, exist_ok=True)
    shift = np.array([*np.median(points[:, :2], axis=0), 0.0])
    npy = out / "points.npy"
    np.save(npy, points - shift)
    code = _PYTLIDAR_CHILD.format(npy=str(npy), out=str(out))
    res = _child([str(py), "-c", code], timeout_s)
    npy.unlink(missing_ok=True)
    if "error" not in res:
        z = np.load(out / "cylinders.npz")
        start = z["start"] + shift
        end = start + z["length"][:, None] * z["axis"]
        res["stem"] = _stem_arrays(start, end, z["radius"], z["radius"], z["branch"] == 0)
    return res


def run_peer(path: Path) -> dict[str, Any]:
    """A peer model's figures from its cylinder table."""
    from treesim.models.cylinders import read_cylinders

    try:
        t = read_cylinders(path)
    except Exception as e:  # reported in the table
        return {"error": f"{type(e).__name__}: {e}"}
    s = t.summary()
    return {
        "dbh_m": s["dbh_m"],
        "height_m": s["height_m"],
        "volume_stem_m3": s["volume_stem_m3"],
        "volume_total_m3": s["volume_total_m3"],
        "stem": _stem_arrays(t.start, t.end, t.radius_m, t.end_radius_m, t.branch_order == 0),
    }


def _stem_arrays(start, end, r0, r1, stem) -> dict[str, list]:
    return {
        "start": np.asarray(start)[stem].tolist(),
        "end": np.asarray(end)[stem].tolist(),
        "r0": np.asarray(r0)[stem].tolist(),
        "r1": np.asarray(r1)[stem].tolist(),
    }


# ---------------------------------------------------------------------- comparison


def radius_error(stem: dict[str, list], ref: sr.TreeReference) -> dict[str, Any]:
    """Max relative stem radius error over the clean slabs, and where."""
    worst, where, missing = 0.0, None, []
    for s in ref.slabs:
        if not s.clean:
            continue
        r = sr.stem_radius_at(
            stem["start"], stem["end"], stem["r0"], stem["r1"], s.z_m, s.centre_xy_m
        )
        if r is None:
            missing.append(s.height_m)
            continue
        err = (r - s.diameter_m / 2) / (s.diameter_m / 2)
        if abs(err) >= abs(worst):
            worst, where = err, s.height_m
    return {"max_rel": worst if where is not None else None, "at_m": where, "no_stem_at": missing}


def form_factor(r: dict[str, Any]) -> float | None:
    d, h, v = r.get("dbh_m"), r.get("height_m"), r.get("volume_stem_m3")
    if not d or not h or v is None:
        return None
    return float(v / (np.pi / 4 * d * d * h))


# ---------------------------------------------------------------------- table


def _f(x: Any, spec: str, unit: str = "") -> str:
    return "-" if x is None else f"{x:{spec}}{unit}"


def rows_for(tree: Tree, ref: sr.TreeReference, results: dict[str, dict]) -> list[list[str]]:
    s = ref.dbh_slab
    d_ref = s.diameter_m if s.clean else None
    verdict = s.verdict + (f": {s.reason}" if s.reason else "")
    h_t, d_t = ref.taper()
    taper = (
        f"{len(h_t)} clean slabs {h_t.min():.1f}-{h_t.max():.1f} m" if len(h_t) else "no clean slab"
    )
    rows = [
        [
            tree.name,
            "slab reference",
            "",
            "",
            _f(None if s.diameter_m is None else s.diameter_m * 100, ".1f", " cm"),
            "",
            f"{ref.height_m:.1f} m",
            "",
            "",
            "",
            "",
            f"1.3 m {verdict}; {taper}; base: {ref.base_source}",
        ]
    ]
    for tool, r in results.items():
        if "error" in r:
            rows.append([tree.name, tool, *[""] * 9, f"error: {r['error']}"])
            continue
        dbh = r.get("dbh_m")
        derr = None if (d_ref is None or not dbh) else (dbh - d_ref) / d_ref * 100
        rerr = r.get("radius_error", {})
        note = []
        if rerr.get("no_stem_at"):
            note.append(
                f"no stem cylinder at {', '.join(f'{h:.1f}' for h in rerr['no_stem_at'])} m"
            )
        if r.get("warnings"):
            codes = [
                w.get("code", str(w)) if isinstance(w, dict) else str(w) for w in r["warnings"]
            ]
            note.append("warnings: " + ", ".join(codes))
        rows.append(
            [
                tree.name,
                tool,
                _f(r.get("time_s"), ".1f", " s"),
                _f(r.get("peak_rss_mib"), ".0f", " MiB"),
                _f(None if not dbh else dbh * 100, ".1f", " cm"),
                _f(derr, "+.1f", " %"),
                _f(r.get("height_m"), ".1f", " m"),
                _f(
                    None if r.get("volume_stem_m3") is None else r["volume_stem_m3"] * 1000,
                    ",.0f",
                    " L",
                ),
                _f(
                    None if r.get("volume_total_m3") is None else r["volume_total_m3"] * 1000,
                    ",.0f",
                    " L",
                ),
                _f(form_factor(r), ".2f"),
                _f(
                    None if rerr.get("max_rel") is None else rerr["max_rel"] * 100,
                    "+.0f",
                    f" % at {rerr['at_m']:.1f} m" if rerr.get("at_m") is not None else "",
                ),
                "; ".join(note),
            ]
        )
    return rows


HEADER = [
    "tree",
    "tool",
    "time",
    "peak RSS",
    "DBH",
    "DBH vs slab",
    "height",
    "stem",
    "total",
    "form factor",
    "stem radius vs slabs (max)",
    "notes",
]


def markdown(rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(HEADER) + " |", "|" + "---|" * len(HEADER)]
    lines += ["| " + " | ".join(c.replace("|", "/") for c in r) + " |" for r in rows]
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--shared", type=Path, default=SHARED_TREES, help="shared trees folder")
    ap.add_argument("--repo-trees", type=Path, default=REPO_TREES)
    ap.add_argument("--trees", default="", help="comma-separated substrings of tree names")
    ap.add_argument("--skip-pytlidar", action="store_true")
    ap.add_argument("--skip-treesim", action="store_true", help="(with --reuse: table only)")
    ap.add_argument("--timeout-s", type=float, default=1800.0, help="per tree and tool")
    ap.add_argument("--out", type=Path, default=ROOT / "out" / "bench_real_trees")
    ap.add_argument("--reuse", action="store_true", help="keep results already in --out")
    ap.add_argument(
        "--docs",
        "--readme",
        dest="docs",
        action="store_true",
        help="write the table into docs/validation.md",
    )
    a = ap.parse_args()

    from treesim.io import read_cloud

    trees, notes = find_trees(a.shared, a.repo_trees)
    for n in notes:
        print(n)
    if a.trees:
        want = [w.strip() for w in a.trees.split(",") if w.strip()]
        trees = [t for t in trees if any(w in t.name for w in want)]
    if not trees:
        print("no trees to measure")
        return
    py = None if a.skip_pytlidar else ensure_pytlidar()
    a.out.mkdir(parents=True, exist_ok=True)
    all_rows: list[list[str]] = []
    for tree in trees:
        slug = tree.name.replace("/", "_")
        cache = a.out / f"{slug}.json"
        results: dict[str, dict] = (
            json.loads(cache.read_text()) if a.reuse and cache.exists() else {}
        )
        pts = read_cloud(tree.cloud).points
        ref = sr.reference(pts)
        sr.render_slab(ref.dbh_slab, IMG_DIR / f"{slug}.png", title=tree.name)
        print(
            f"\n{tree.name} ({tree.cloud}, {len(pts):,} points): base {ref.base_source}, "
            f"height {ref.height_m:.2f} m"
        )
        for s in ref.slabs:
            print("   slab", s.describe())
        if not a.skip_treesim and "treesim" not in results:
            print("   treesim ...", flush=True)
            results["treesim"] = run_treesim(tree, a.out / slug / "treesim", a.timeout_s)
        if py is not None and "PyTLidar 1.1.2" not in results:
            print("   PyTLidar ...", flush=True)
            results["PyTLidar 1.1.2"] = run_pytlidar(
                tree, pts, a.out / slug / "pytlidar", py, a.timeout_s
            )
        for label, path in tree.peers:
            results[label] = run_peer(path)
        for r in results.values():
            if "stem" in r:
                r["radius_error"] = radius_error(r["stem"], ref)
        cache.write_text(json.dumps(results, default=str))
        rows = rows_for(tree, ref, results)
        for r in rows:
            print("   " + " | ".join(c for c in r[1:] if c))
        all_rows += rows
    table = markdown(all_rows)
    print("\n" + table)
    if a.docs:
        command = " ".join(["python benchmarks/bench_real_trees.py", *sys.argv[1:]])
        head = (
            f"`{command}` measured these on {date.today()}, {platform.machine()} with "
            f"{os.cpu_count()} cores, Python {platform.python_version()} (a shared host: times "
            "±15 %); each tool in a fresh child process per tree; the 1.3 m slabs are drawn in "
            "`docs/img/real_trees/` and shown below."
        )
        docs_part.write_part(DOCS_PART, head + "\n\n" + table)
        print(f"wrote the table into {docs_part.VALIDATION.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
