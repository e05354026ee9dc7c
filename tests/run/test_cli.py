"""``treesim run`` and ``treesim batch`` from the command line: figures and the report's
path on success, one line and a non-zero exit on bad input."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from treesim.cli import main
from treesim.params import to_toml


def one_line_error(capsys) -> str:
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("treesim: error: ") and "Traceback" not in err
    return lines[0]


def test_run_prints_the_figures_and_the_report_path(saplings, quick, tmp_path, capsys):
    cfg = tmp_path / "quick.toml"
    cfg.write_text(to_toml(quick))
    out = tmp_path / "out"
    args = ["run", str(saplings["sapling1"]), "-o", str(out), "--config", str(cfg)]
    rc = main([*args, "--stations", "4", "--tolerance-m", "0.004"])
    assert rc == 0
    printed = capsys.readouterr().out
    run = json.loads((out / "run.json").read_text())
    assert run["parameters"]["compare"]["tolerance_m"] == 0.004
    assert run["vs_mesh"]["tolerance_m"] == run["vs_field"]["tolerance_m"] == 0.004
    assert run["tolerance"]["rule"].startswith("given")
    assert "within 4 mm" in printed
    report = Path(printed.strip().splitlines()[-1].removeprefix("report: "))
    assert report == (out / "report.html").resolve() and report.is_file()
    assert "DBH" in printed and "vs mesh" in printed and "vs field" in printed
    assert "4 stations" in printed


def test_run_with_a_missing_file_says_so_in_one_line(tmp_path, capsys):
    rc = main(["run", str(tmp_path / "nope.laz"), "-o", str(tmp_path / "out")])
    assert rc == 1
    assert "nope.laz not found" in one_line_error(capsys)


@pytest.mark.parametrize(
    ("text", "words"),
    [("[scan\n", "not valid TOML"), ("[scan]\nspeed = 3\n", "unknown setting 'speed'")],
)
def test_run_with_a_bad_config_says_so_in_one_line(saplings, tmp_path, capsys, text, words):
    cfg = tmp_path / "bad.toml"
    cfg.write_text(text)
    rc = main(["run", str(saplings["sapling0"]), "-o", str(tmp_path / "o"), "--config", str(cfg)])
    assert rc == 1
    assert words in one_line_error(capsys)
    assert not (tmp_path / "o").exists()


def test_run_with_a_missing_config_and_bad_flags(saplings, tmp_path, capsys):
    rc = main(["run", str(saplings["sapling0"]), "-o", str(tmp_path), "--config", "none.toml"])
    assert rc == 1
    assert "none.toml not found" in one_line_error(capsys)
    with pytest.raises(SystemExit) as exc:  # out of the model's range: a usage error
        main(["run", str(saplings["sapling0"]), "-o", str(tmp_path), "--stations", "0"])
    assert exc.value.code == 2
    assert "--stations: expected a whole number in [1, 64]" in one_line_error(capsys)
    with pytest.raises(SystemExit) as exc:
        main(["run", str(saplings["sapling0"]), "--preset", "ultra"])
    assert exc.value.code == 2


def test_batch_with_a_missing_input_says_so_in_one_line(tmp_path, capsys):
    rc = main(["batch", str(tmp_path / "nothing"), "-o", str(tmp_path / "out")])
    assert rc == 1
    assert "not found" in one_line_error(capsys)
    rc = main(["batch", str(tmp_path), "-o", str(tmp_path / "out"), "--executor", "inline"])
    assert rc == 1
    assert "no point clouds found" in one_line_error(capsys)


def test_run_help_shows_the_measured_presets(capsys):
    with pytest.raises(SystemExit):
        main(["run", "--help"])
    text = capsys.readouterr().out
    for name in ("draft", "standard", "fine"):
        assert name in text
    assert "measured" in text
    assert "max(5 m, 1.5 x crown diameter, 0.5 x height)" in text


def test_print_params_is_a_config_file(tmp_path, capsys):
    assert main(["run", "--print-params", "--preset", "fine", "--method", "poisson"]) == 0
    cfg = tmp_path / "fine.toml"
    cfg.write_text(capsys.readouterr().out)
    from treesim.params import load_config

    p = load_config(cfg)
    assert p.preset == "fine" and p.reconstruct.method == "poisson"


def test_a_missing_reference_qsm_says_so_in_one_line(saplings, tmp_path, capsys):
    out = tmp_path / "out"
    rc = main(["run", str(saplings["sapling0"]), "-o", str(out), "--reference-qsm", "no.csv"])
    assert rc == 1
    assert "reference QSM no.csv not found" in one_line_error(capsys)
    assert not (out / "tree.ply").exists()


def test_the_demo_sets_the_bundled_treeqsm_model_beside_the_reconstruction(
    tmp_path, monkeypatch, capsys
):
    from treesim.cli.demo import SAMPLE_QSM
    from treesim.errors import ReconstructionError
    from treesim.models import read_cylinders

    given = {}

    def fake(cloud, params, outdir, **kwargs):
        given.update(kwargs)
        raise ReconstructionError("stopped here")

    monkeypatch.setattr("treesim.run.run_tree", fake)
    assert main(["demo", "-o", str(tmp_path / "o")]) == 1
    capsys.readouterr()
    assert given["reference_qsm"] == SAMPLE_QSM
    # the model PROVENANCE.md describes: 1,136 cylinders, DBH 7.35 cm, 21.6 L
    s = read_cylinders(SAMPLE_QSM).summary()
    assert s["n_cylinders"] == 1136
    assert round(s["dbh_m"] * 100, 2) == 7.35 and round(s["volume_total_m3"] * 1000, 1) == 21.6
