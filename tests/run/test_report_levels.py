"""``--report none|summary|full`` (issue 25): which files a run's report level writes, and
which links its page holds. Oracle: the files each level promises (report.level's
documentation), checked on disk."""

from __future__ import annotations

import json
import re
from dataclasses import replace
from pathlib import Path

import pytest

from treesim.cli import main
from treesim.params import ReportParams
from treesim.report import PNG_FILES
from treesim.run import run_tree


def _level_run(saplings, quick, tmp_path, level):
    out = tmp_path / level
    stale = out / "vs_mesh"  # an earlier full run's report, which must not stay
    stale.mkdir(parents=True)
    (stale / "report.html").write_text("old")
    (stale / "histograms.png").write_bytes(b"old")
    (out / "clouds.png").write_bytes(b"old")
    params = replace(quick, report=replace(quick.report, plots=True, level=level))
    return run_tree(saplings["sapling0"], params, out)


def _links(page: str) -> set[str]:
    return set(re.findall(r'(?:href|src)="([^"#]+)', page))


def test_report_none_writes_no_report_and_links_none(saplings, quick, tmp_path):
    res = _level_run(saplings, quick, tmp_path, "none")
    out = res.outdir
    assert res.summary["report_level"] == "none"
    for key in ("vs_mesh", "vs_field"):
        assert (out / key / "comparison.json").is_file()
        assert not (out / key / "report.html").exists() and not (out / key / "report.json").exists()
        assert not any((out / key / n).exists() for n in PNG_FILES.values())
        assert res.summary["summary_text"][key].startswith("The cloud")  # from comparison.json
    assert not (out / "clouds.png").exists()
    page = res.report_html.read_text(encoding="utf-8")
    assert all((out / link).is_file() for link in _links(page)), _links(page)
    assert 'id="viewer-data"' not in page and "--report none" in page
    assert "vs_mesh_report" not in res.summary["files"]


def test_report_summary_writes_pages_without_plots(saplings, quick, tmp_path):
    res = _level_run(saplings, quick, tmp_path, "summary")
    out = res.outdir
    assert res.summary["report_level"] == "summary"
    for key in ("vs_mesh", "vs_field"):
        assert (out / key / "report.html").read_text() != "old"
        assert not any((out / key / n).exists() for n in PNG_FILES.values())
    assert not (out / "clouds.png").exists()
    page = res.report_html.read_text(encoding="utf-8")
    assert all((out / link).is_file() for link in _links(page)), _links(page)
    assert "vs_mesh/report.html" in _links(page) and 'id="viewer-data"' in page


def test_auto_is_full_for_a_run_and_summary_for_a_batch_or_sweep():
    assert ReportParams().level == "auto"
    assert ReportParams().resolved() == "full"
    assert ReportParams().resolved("summary") == "summary"
    assert ReportParams(level="full").resolved("summary") == "full"
    assert ReportParams(level="full", plots=False).resolved() == "summary"
    assert ReportParams(level="none", plots=False).resolved() == "none"
    with pytest.raises(Exception, match="level must be one of"):
        ReportParams(level="some")


@pytest.mark.parametrize("command", [["run"], ["batch", "x.ply", "-o", "o"]])
def test_the_report_flag_sets_the_level(command, capsys):
    if command[0] == "batch":  # batch has no --print-params: the parser's value
        from treesim.cli import build_parser

        args = build_parser().parse_args([*command, "--report", "none"])
        assert getattr(args, "param:report.level") == "none"
        return
    assert main([*command, "--report", "summary", "--print-params"]) == 0
    toml = capsys.readouterr().out
    assert re.search(r'^level = "summary"', toml, re.M)
    assert main([*command, "--print-params"]) == 0
    assert re.search(r'^level = "auto"', capsys.readouterr().out, re.M)


def test_the_sweep_flag_sets_every_designs_level(tmp_path):
    from treesim.cli import build_parser
    from treesim.cli.sweep import _with_report_level
    from treesim.sweep import load_sweep

    cfg = load_sweep(Path(__file__).resolve().parents[2] / "benchmarks/sweeps/presets.toml")
    args = build_parser().parse_args(["sweep", "c.toml", "--report", "none"])
    got = _with_report_level(cfg, args)
    assert {d.params.report.level for d in got.designs} == {"none"}
    assert {d.params.report.level for d in cfg.designs} == {"auto"}
    json.dumps([d.params.to_dict() for d in got.designs])  # still plain settings
