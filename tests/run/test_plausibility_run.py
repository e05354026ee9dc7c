"""A run's report carries the reconstruction's plausibility warnings: ``run.json``, the
run page (``report.html``) and the lines ``treesim run`` prints on stderr."""

from __future__ import annotations

import html
import json

from treesim.cli.run import print_run_summary
from treesim.run import run_tree


def test_run_report_and_stderr_show_the_warnings(tube_xyz, tmp_path, quick, capsys):
    result = run_tree(tube_xyz, quick, tmp_path / "run")
    run = json.loads((tmp_path / "run" / "run.json").read_text())
    warns = run["reconstruction"]["warnings"]
    assert "form_factor_high" in [w["code"] for w in warns]
    page = (tmp_path / "run" / "report.html").read_text()
    assert 'id="plausibility"' in page
    for w in warns:
        assert html.escape(w["message"]) in page
    capsys.readouterr()
    print_run_summary(result)
    err = capsys.readouterr().err
    for w in warns:
        assert f"treesim: warning: {w['message']}" in err.splitlines()
