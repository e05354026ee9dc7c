"""A run's report carries the reconstruction's plausibility warnings: ``run.json``, the
run page (``report.html``) and the lines ``treesim run`` prints on stderr."""

from __future__ import annotations

import html
import json

import numpy as np

from pipeline.cli.run import print_run_summary
from pipeline.run import run_tree
from tests.reconstruct.shapes import tube


def test_run_report_and_stderr_show_the_warnings(tmp_path, quick, capsys):
    # a 5 m tube of constant radius: a cylinder (form factor 1.0), never a real stem
    pts, _ = tube(radius=0.12, height=5.0, n=20000, noise_m=0.001, seed=0)
    cloud = tmp_path / "tube.xyz"
    np.savetxt(cloud, pts, fmt="%.6f")
    result = run_tree(cloud, quick, tmp_path / "run")
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
