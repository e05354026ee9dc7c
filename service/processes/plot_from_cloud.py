"""``plot-from-cloud``: a field plot's cloud becomes a digital twin (as ``treesim plot
from-cloud``)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from treesim.params import merge
from treesim.twin import TwinParams

from .base import CLOUD, Process, Progress, job_schema


def _parse_from_cloud(parameters: Mapping[str, Any]) -> TwinParams:
    return merge(TwinParams(), dict(parameters))


def _execute_from_cloud(
    inputs: Mapping[str, Path],
    params: TwinParams,
    out: Path,
    threads: int,
    progress: Progress,
    name: str,
) -> dict[str, Any]:
    from treesim.twin import plot_from_cloud

    # the job is one process already: its trees are reconstructed in it, one after another
    result = plot_from_cloud(inputs["cloud"], out, params, executor="inline", progress=progress)
    _hide_server_path(out, name)
    _zip_twin(out, result)
    # "input" is the upload's path in the data folder: a client's job says nothing of it
    return {k: v for k, v in result.figures.items() if k not in ("params", "input")}


def _hide_server_path(out: Path, name: str) -> None:
    """``from_cloud.json`` (a result a client downloads) names the upload as the client
    named it, not by its path in the server's data folder."""
    import json

    from treesim.jsonio import write_json

    path = out / "from_cloud.json"
    figures = json.loads(path.read_text(encoding="utf-8"))
    figures["input"] = name or "the uploaded cloud"
    write_json(path, figures)


def _zip_twin(out: Path, result: Any) -> Path:
    """``twin.zip``: the plot file and every file it names, as a plot-scan or validate job
    takes a plot (``{"job": ID, "result": "twin.zip"}``)."""
    import zipfile

    from treesim.atomic import atomic_path

    names = ["plot.toml", "trees.csv", "dtm.asc"]
    if (out / "stations.csv").is_file():  # the field's stations, from an E57's poses
        names.append("stations.csv")
    for r in result.trees:
        names += [r["twin_table"], r["field_cloud"]]
    path = out / "twin.zip"
    with atomic_path(path) as tmp, zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as z:
        for name in names:
            z.write(out / name, name)
    return path


PROCESS = Process(
    id="plot-from-cloud",
    title="A digital twin of a field plot",
    description="A field plot's cloud (LAS/LAZ, or E57 with the scans' poses) becomes a "
    "twin: ground and DTM (cloth simulation filter), stems and DBH (slab circles), every "
    "point given to its tree, a QSM per tree; trees that fail are listed and left out (as "
    "treesim plot from-cloud).",
    inputs=(CLOUD,),
    outputs=(
        ("plot.toml", "the twin: the DTM as terrain, each tree as its QSM"),
        ("trees.csv", "the twin's trees"),
        ("dtm.asc", "the DTM (ESRI ASCII grid)"),
        ("plot_labelled.laz", "the plot's cloud with tree_id (0: none) and ground"),
        ("from_cloud.json", "stems, per-tree figures, what was left out and why, warnings"),
        ("report.html", "the map, DBH and height distributions, per-tree figures"),
        ("twin.zip", "the twin as a plot archive (input plot of plot-scan and validate)"),
    ),
    extra_schema=dict,
    base_schema=lambda: job_schema(TwinParams),
    parse=_parse_from_cloud,
    execute=_execute_from_cloud,
)
