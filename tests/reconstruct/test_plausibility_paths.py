"""Plausibility warnings reach every place a reconstruction is read: ``tree.json``, the
CLI's stderr and a batch's summary row (the run page: tests/run/test_plausibility_run.py,
the service's job: tests/service/test_plausibility_job.py).

The trigger is deterministic: a 5 m tube of constant radius is a cylinder (form factor
1.0, radius held over its whole height), which no real stem is."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from treesim.cli import main


def test_cli_reconstruct_prints_each_warning_on_stderr(tube_xyz, tmp_path, capsys):
    assert main(["reconstruct", str(tube_xyz), "-o", str(tmp_path)]) == 0
    err = capsys.readouterr().err
    tree = json.loads((tmp_path / "tree.json").read_text())
    warns = tree["warnings"]
    assert "form_factor_high" in [w["code"] for w in warns]
    ff = tree["plausibility"]["stem_form_factor"]
    # the oracle: the tube's volume over basal area x height is 1 for any cylinder
    assert ff == pytest.approx(1.0, abs=0.08)
    lines = [ln for ln in err.splitlines() if "warning: " in ln]
    assert len(lines) == len(warns)
    for w, line in zip(warns, lines, strict=True):
        assert line.endswith("warning: " + w["message"])
    assert any(ln.startswith("treesim: warning: stem form factor") for ln in lines)


def test_coffee_tree_is_plausible_no_warning_on_stderr(tmp_path, capsys):
    """The bundled coffee tree (a real leaf-off cloud) raises none: no warning line."""
    cloud = Path(__file__).resolve().parents[2] / "pipeline/data/coffee_tree/cloud.txt"
    assert main(["reconstruct", str(cloud), "-o", str(tmp_path)]) == 0
    tree = json.loads((tmp_path / "tree.json").read_text())
    assert tree["warnings"] == [], tree["warnings"]
    assert "warning:" not in capsys.readouterr().err
    assert 0.3 < tree["plausibility"]["stem_form_factor"] < 1.0


def test_batch_row_and_cli_line_name_the_codes():
    from treesim.batch import SUMMARY_COLUMNS, _row_from_summary

    warns = [{"code": "form_factor_high", "message": "m"}, {"code": "stem_radius_held"}]
    row = _row_from_summary({"reconstruction": {"warnings": warns}})
    assert row["warnings"] == "form_factor_high;stem_radius_held"
    assert _row_from_summary({"reconstruction": {"warnings": []}})["warnings"] is None
    assert "warnings" in SUMMARY_COLUMNS
