"""A plan's verification scans on an executor (``treesim plan --executor local``): each
verification station a task, the same verified figures as inline, bit for bit.

The oracle is the inline verification: one process, one station after another, which
tests/plot holds against the whole plot scanned at once."""

from __future__ import annotations

import json

import pytest

from treesim.cli import main
from treesim.errors import InvalidParameterError
from treesim.params import instrument
from treesim.plan import PlanParams, plan_scans
from treesim.plot.generate import generate_stand
from treesim.plot.io import read_plot, write_plot

VZ400 = instrument("riegl-vz400")
RESOLUTION_DEG = 0.5
#: the smallest verified plan of tests/plot/test_plot_tasks.py (three saplings on a 4 m
#: plot at 0.5°), verified this time
PARAMS = {
    "goal_coverage": 0.5,
    "samples_per_tree": 100,
    "band_samples": 36,
    "candidate_spacing_m": 2.0,
    "threads": 1,
}
CLI = [
    "--resolution-deg", str(RESOLUTION_DEG), "--goal-coverage", "0.5",
    "--samples-per-tree", "100", "--band-samples", "36", "--candidate-spacing-m", "2",
    "--threads", "1",
]  # fmt: skip


def _spec():
    return VZ400.spec(
        horizontal_resolution_deg=RESOLUTION_DEG, vertical_resolution_deg=RESOLUTION_DEG
    )


def _verified(ver):
    """A verification's figures without its timings (as JSON writes them)."""
    return json.loads(json.dumps({k: v for k, v in ver.items() if k != "timings_s"}))


@pytest.fixture(scope="module")
def stand(tmp_path_factory):
    """The plot file and the plan made from it inline."""
    path = tmp_path_factory.mktemp("plan-exec") / "plot.toml"
    plot, _ = generate_stand("sapling", 600, 4.0, seed=1, facets=8)
    write_plot(path, plot)
    inline = plan_scans(
        read_plot(path), spec=_spec(), instrument=VZ400, params=PlanParams(**PARAMS)
    )
    assert len(inline.stations) >= 2  # more than one task
    assert inline.verification["points"] > 1000
    assert inline.baseline_verification is not None
    return path, inline


def test_verification_on_local_workers_gives_the_inline_figures(stand):
    path, inline = stand
    local = plan_scans(
        read_plot(path),
        spec=_spec(),
        instrument=VZ400,
        params=PlanParams(**PARAMS),
        executor="local",
        workers=2,
    )
    assert [s.position_m for s in local.stations] == [s.position_m for s in inline.stations]
    assert _verified(local.verification) == _verified(inline.verification)
    assert _verified(local.baseline_verification) == _verified(inline.baseline_verification)
    assert local.comparison["verdict"] == inline.comparison["verdict"]


def test_treesim_plan_executor_local_writes_the_inline_verification(stand, tmp_path, capsys):
    path, inline = stand
    out = tmp_path / "p"
    argv = ["plan", "--plot", str(path), *CLI, "--executor", "local", "--workers", "2"]
    assert main([*argv, "-o", str(out)]) == 0, capsys.readouterr().err
    d = json.loads((out / "plan.json").read_text())
    want = _verified(inline.verification)
    assert {k: v for k, v in d["verification"].items() if k != "timings_s"} == {
        k: v for k, v in want.items() if k != "trees"
    }
    assert {str(t["tree_id"]): t["verified"] for t in d["trees"]} == want["trees"]
    assert _verified(d["baseline_verification"]) == _verified(inline.baseline_verification)


def test_a_remote_scheduler_without_a_shared_folder_is_refused_before_planning(tmp_path):
    from treesim.plot import Plot, PlotTree

    plot = Plot([PlotTree(tree_id=1, x_m=0.0, y_m=0.0, species="sapling")], radius_m=3)
    with pytest.raises(InvalidParameterError, match="cache_dir"):
        plan_scans(plot, spec=_spec(), instrument=VZ400, executor="dask", scheduler="tcp://x:8786")
    with pytest.raises(InvalidParameterError, match="inline"):
        plan_scans(plot, spec=_spec(), instrument=VZ400, executor="inline", workers=2)
