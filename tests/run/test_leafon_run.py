"""``treesim run`` end to end on a leaf-on field cloud (issue 13 §4).

The procedural ``aspen-leafon`` (seed 0) scanned at 0.12° with the RIEGL VZ-400 noise
model is written as a plain XYZ cloud (no labels: a field cloud) and run through the
command line with the draft preset, plots off. The run must find the leaves itself
(``--separate-leaves auto``), write ``labels.laz``, model a leaf layer, scan the model
leaf-on and compare it by label.
"""

from __future__ import annotations

import json

import laspy
import numpy as np
import pytest

from tests.reconstruct.leafon import scan_preset
from treesim.cli import main
from treesim.cloud import LABEL_CODES, Cloud
from treesim.io import write_cloud
from treesim.params import to_toml


@pytest.mark.slow
def test_run_on_a_leaf_on_cloud_separates_models_and_compares_leaves(quick, tmp_path, capsys):
    _, scanned = scan_preset("aspen-leafon", 0.12)
    field = write_cloud(tmp_path / "aspen_leafon.xyz", Cloud(scanned.points))
    cfg = tmp_path / "quick.toml"
    cfg.write_text(to_toml(quick))
    out = tmp_path / "out"
    rc = main(["run", str(field), "-o", str(out), "--config", str(cfg), "--resolution-deg", "0.12"])
    assert rc == 0, capsys.readouterr().err
    fig = json.loads((out / "tree.json").read_text())
    assert fig["leaf_separation"] == "auto" and fig["leaves_present"] is True
    assert fig["n_leaves"] > 1000 and fig["leaf_area_m2"] > 1.0
    # labels.laz: every prepared point labelled wood or leaf, both present
    labels = laspy.read(out / "labels.laz")
    codes = np.unique(np.asarray(labels["label"]))
    assert set(codes.tolist()) == {LABEL_CODES["wood"], LABEL_CODES["leaf"]}
    # the model was scanned leaf-on and the comparisons split by label
    run = json.loads((out / "run.json").read_text())
    scan = json.loads((out / "scan.json").read_text())
    assert "leaf" in scan["labels_in_scene"] and "wood" in scan["labels_in_scene"]
    by_label = json.loads((out / "vs_mesh" / "comparison.json").read_text())["by_label"]
    assert by_label["leaf"]["accuracy"]["n"] > 1000 and by_label["wood"]["accuracy"]["n"] > 1000
    assert by_label["leaf"]["coverage"] > 0.5
    assert set(run["vs_mesh"]["by_label"]) == {"wood", "leaf"}
