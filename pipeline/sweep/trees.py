"""A sweep's trees, made ready once: field clouds, truth meshes and truth figures.

* A **field cloud** (``cloud = ...``, ``bundled = ...``) is used as it is; its key is the
  SHA-256 of its content.
* A **procedural tree** (``species = ...``) is generated (:func:`treesim.models.generate_tree`),
  meshed with its ``facets`` (the truth mesh, wood and leaves labelled) and scanned with the
  sweep's reference field design (``[reference]``, seeded) into its field cloud. Its truth
  figures are those of its exact cylinder table (:meth:`ProceduralTree.truth`). Its key is
  the SHA-256 of what decides all that (species parameters, seed, leaves, facets, the
  reference design, treesim's version), so the files are made once and reused.

Each tree's files live in ``OUTDIR/trees/<id>/`` (``field.ply``, ``truth.ply``,
``tree.json`` written last).
"""

from __future__ import annotations

import hashlib
import json
import shutil
import uuid
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from ..jsonio import json_ready, write_json
from ..params import ScanParams, walk
from ..run import file_sha256, run_wind
from .config import TreeSpec

__all__ = ["PreparedTree", "derive_tolerance", "prepare_tree"]


@dataclass(frozen=True, kw_only=True)
class PreparedTree:
    """A tree ready for its points.

    Attributes
    ----------
    spec : TreeSpec
    key : str
        SHA-256 of its content (see the module doc).
    cloud : Path
        Its field cloud.
    truth_mesh : Path or None
        The truth mesh (procedural trees).
    truth : dict or None
        The truth figures (``dbh_m``, ``height_m``, ``volume_total_m3``, ...).
    field_points : int
    point_spacing_m : float
        The field cloud's median nearest-neighbour spacing (what τ may be derived from).
    info : dict
        ``tree.json``'s content.
    """

    spec: TreeSpec
    key: str
    cloud: Path
    truth_mesh: Path | None
    truth: dict[str, Any] | None
    field_points: int
    point_spacing_m: float
    info: dict[str, Any]


def _scan_settings(reference: ScanParams) -> dict[str, Any]:
    """The reference design's settings less those that decide only how fast it scans (the
    model's ``execution_only`` fields, as :func:`treesim.params.params_hash` leaves out)."""
    d = json_ready(asdict(reference))
    for info in walk(ScanParams):
        if info.execution_only:
            node = d
            for k in info.path[:-1]:
                node = node.get(k, {})
            node.pop(info.path[-1], None)
    return d


def tree_key(spec: TreeSpec, reference: ScanParams) -> str:
    """The key of a tree's content (see the module doc)."""
    from .._version import __version__

    if spec.kind == "cloud":
        assert spec.path is not None
        return file_sha256(spec.path)
    from ..models import species_preset

    assert spec.model is not None
    m = spec.model
    text = json.dumps(
        {
            "species": species_preset(str(m.species)).to_dict(),
            "seed": m.seed,
            "leaves": m.leaves,
            "facets": m.facets,
            "reference": _scan_settings(reference),
            "treesim": __version__,
        },
        sort_keys=True,
        default=str,
    )
    return hashlib.sha256(text.encode()).hexdigest()


def _spacing(cloud: Any, threads: int) -> float:
    from ..geometry import point_spacing

    return float(point_spacing(cloud.points, subsample=50_000, seed=0, workers=threads or -1))


def prepare_tree(
    spec: TreeSpec,
    reference: ScanParams,
    trees_dir: Path,
    *,
    threads: int = 0,
    fresh: bool = False,
) -> PreparedTree:
    """Make a tree ready (or find it ready from an earlier run, unless ``fresh``): see
    the module doc."""
    from ..io import read_cloud

    key = tree_key(spec, reference)
    folder = trees_dir / spec.id
    done = None if fresh else _finished(folder, key)
    if done is not None:
        return _prepared(spec, key, folder, done)
    tmp = trees_dir / f".{spec.id}-{uuid.uuid4().hex[:8]}"
    tmp.mkdir(parents=True)
    try:
        if spec.kind == "cloud":
            assert spec.path is not None
            cloud = read_cloud(spec.path)
            info: dict[str, Any] = {
                "kind": "cloud",
                "cloud": str(spec.path),
                "truth": None,
                "truth_mesh": None,
            }
        else:
            cloud, info = _procedural(spec, reference, tmp, threads)
        info.update(
            {
                "id": spec.id,
                "source": spec.source,
                "key": key,
                "field_points": len(cloud),
                "point_spacing_m": _spacing(cloud, threads),
            }
        )
        write_json(tmp / "tree.json", info)  # last: a folder without it is not a tree
        if folder.exists():
            shutil.rmtree(folder)
        tmp.rename(folder)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return _prepared(spec, key, folder, info)


def _procedural(
    spec: TreeSpec, reference: ScanParams, out: Path, threads: int
) -> tuple[Any, dict[str, Any]]:
    from ..io import write_cloud, write_mesh
    from ..models import generate_tree
    from ..scan import stations_for
    from ..scene import Scene
    from ..steps import scan_scene

    m = spec.model
    assert m is not None
    tree = generate_tree(str(m.species), seed=int(m.seed), leaves=m.leaves)
    v, f, label = tree.mesh(int(m.facets))
    write_mesh(out / "truth.ply", v, f, face_label=label)
    scene = Scene.from_labelled_mesh(v, f, label, name_prefix="truth:")
    stations, rule = stations_for(scene.bounds, reference)
    # a wind in the reference design sways the tree by its exact cylinder table
    wind = run_wind(reference.scanner, tree.cylinders)
    res = scan_scene(scene, stations, reference, threads=threads, wind=wind)
    cloud = res.cloud
    write_cloud(out / "field.ply", cloud)
    truth = tree.truth(int(m.facets))
    truth.pop("params", None)
    info = {
        "kind": "procedural",
        "cloud": "field.ply",
        "truth_mesh": "truth.ply",
        "truth": truth,
        "reference_scan": {
            "settings": _scan_settings(reference),
            "station_rule": rule,
            "rays_cast": res.rays_cast,
            "models_active": res.models,
            **({"wind": res.wind} if res.wind is not None else {}),
        },
    }
    return cloud, info


def _finished(folder: Path, key: str) -> dict[str, Any] | None:
    try:
        info = json.loads((folder / "tree.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(info, dict) or info.get("key") != key:
        return None
    for name in ("cloud", "truth_mesh"):
        f = info.get(name)
        if f and not (folder / f).is_file() and not Path(f).is_file():
            return None
    return info


def _prepared(spec: TreeSpec, key: str, folder: Path, info: dict[str, Any]) -> PreparedTree:
    cloud = spec.path if spec.kind == "cloud" else folder / info["cloud"]
    assert cloud is not None
    return PreparedTree(
        spec=spec,
        key=key,
        cloud=cloud,
        truth_mesh=folder / info["truth_mesh"] if info.get("truth_mesh") else None,
        truth=info.get("truth"),
        field_points=int(info["field_points"]),
        point_spacing_m=float(info["point_spacing_m"]),
        info=info,
    )


def derive_tolerance(trees: list[PreparedTree], factor: float) -> dict[str, Any]:
    """τ for the whole sweep from the reference clouds: ``factor`` × the largest median
    point spacing among the trees' field clouds (so no tree's reference is sampled more
    sparsely than τ / factor). Computed once, from the references, never from a scan."""
    worst = max(trees, key=lambda t: t.point_spacing_m)
    return {
        "tolerance_m": factor * worst.point_spacing_m,
        "rule": f"{factor:g} × the median point spacing of tree {worst.spec.id}'s field "
        f"cloud ({worst.point_spacing_m * 1000:.3g} mm), the coarsest of the references",
        "factor": factor,
        "from_tree": worst.spec.id,
        "spacings_m": {t.spec.id: t.point_spacing_m for t in trees},
    }
