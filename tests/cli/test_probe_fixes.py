"""The command-line fixes of issue #12 (an independent probe of the CLI): each test fails
on the code before the fix."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import laspy
import pytest

from tests.architecture.test_cli_options import PARSERS
from tests.conftest import box_arrays, messages
from treesim.cli import build_parser, main
from treesim.cli._options import PARAM, SETTING
from treesim.io.mesh import write_mesh


def _usage_error(capsys, argv: list[str]) -> str:
    """Run ``treesim argv`` expecting a usage error (exit 2); its one stderr line."""
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("treesim: error:") and "\n" not in err, err
    assert "Traceback" not in err
    return err


@pytest.fixture()
def box_ply(tmp_path: Path) -> Path:
    """A 1 m box standing 5 m out on +x: a scene a coarse scan finishes in well under 1 s."""
    v, f = box_arrays((4.5, -0.5, 0.0), (5.5, 0.5, 1.0))
    return write_mesh(tmp_path / "box.ply", v, f)


# -- 1. numbers are checked while the flags are read, against the model's own ranges ----------
@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (
            ["scan", "m.ply", "-o", "o.laz", "--max-rays", "nan"],
            "--max-rays: expected a whole number >= 1, got 'nan'",
        ),
        (["scan", "m.ply", "-o", "o.laz", "--max-rays", "inf"], "got 'inf'"),
        (
            ["scan", "m.ply", "-o", "o.laz", "--max-rays", "0"],
            "--max-rays: expected a whole number >= 1, got '0'",
        ),
        (["scan", "m.ply", "-o", "o.laz", "--max-rays", "-5"], "got '-5'"),
        (["scan", "m.ply", "-o", "o.laz", "--max-rays", "2.5"], "whole number"),
        (
            ["scan", "m.ply", "-o", "o.laz", "--chunk-rays", "0"],
            "--chunk-rays: expected a whole number >= 1",
        ),
        (
            ["scan", "m.ply", "-o", "o.laz", "--threads", "-1"],
            "--threads: expected a whole number >= 0",
        ),
        (
            ["scan", "m.ply", "-o", "o.laz", "--stations", "100"],
            "--stations: expected a whole number in [1, 64]",
        ),
        (
            ["scan", "m.ply", "-o", "o.laz", "--resolution-deg", "0"],
            "--resolution-deg: expected a number in (0, 45]",
        ),
        (["scan", "m.ply", "-o", "o.laz", "--h-resolution-deg", "nan"], "in (0, 45]"),
        (
            ["scan", "m.ply", "-o", "o.laz", "--distance-m", "-3"],
            "--distance-m: expected a number in (0, 10000], or 0/none for the station rule",
        ),
        (
            ["scan", "m.ply", "-o", "o.laz", "--subrays", "1"],
            "--subrays: expected a whole number in [2, 256]",
        ),
        (["scan", "m.ply", "-o", "o.laz", "--range-noise-sd-m", "-0.001"], ">= 0"),
        (
            ["scan", "m.ply", "-o", "o.laz", "--station", "1,2"],
            "--station: expected 3 finite numbers",
        ),
        (
            ["scan", "m.ply", "-o", "o.laz", "--vfov-deg", "nan,60"],
            "--vfov-deg: expected 2 finite numbers",
        ),
        (["run", "c.txt", "-o", "o", "--resolution-deg", "nan"], "--resolution-deg: expected"),
        (["run", "c.txt", "-o", "o", "--stations", "0"], "--stations: expected a whole number"),
        (["run", "c.txt", "-o", "o", "--voxel-m", "-1"], "--voxel-m: expected a number > 0"),
        (
            ["batch", "c.txt", "-o", "o", "--workers", "0"],
            "--workers: expected a whole number >= 1",
        ),
        (["batch", "c.txt", "-o", "o", "--threads", "x"], "--threads: expected a whole number"),
        (["compare", "a", "b", "-o", "o", "--seed", "-1"], "--seed: expected a whole number >= 0"),
        (["compare", "a", "b", "-o", "o", "--max-samples", "0"], "--max-samples"),
        (
            ["reconstruct", "c.txt", "-o", "o", "--bpa-radius-m", "-0.1"],
            "--bpa-radius-m: expected a number > 0",
        ),
        (
            ["reconstruct", "c.txt", "-o", "o", "--depth", "40"],
            "--depth: expected a whole number in [4, 16]",
        ),
        (["report", "o", "--dpi", "0"], "--dpi: expected a whole number >= 1"),
        (
            ["model", "generate", "--species", "sapling", "--facets", "2", "-o", "t.obj"],
            "--facets: expected a whole number >= 3",
        ),
    ],
)
def test_numbers_out_of_range_are_usage_errors_that_say_the_range(argv, message, capsys):
    err = _usage_error(capsys, argv)
    assert message in err
    assert "invalid" not in err and "read_int" not in err


def _outside(info) -> list[float]:
    ge, gt, le, lt = info.bounds
    out = [float("nan"), float("inf")]
    out += [ge - 1] if ge is not None else []
    out += [gt] if gt is not None and not (info.optional and gt == 0) else []
    out += [le + 1] if le is not None else []
    out += [lt] if lt is not None else []
    return out


def test_every_number_option_refuses_what_its_parameter_refuses():
    """The range an option checks is the parameter model's (``param(ge=...)``), and the
    model refuses the same values: the flags cannot drift from the model."""
    from treesim.errors import InvalidParameterError

    checked = 0
    for name, parser in PARSERS:
        for a in parser._actions:
            info = getattr(a, PARAM, None) or getattr(getattr(a, SETTING, None), "info", None)
            if info is None or info.base_type not in ("int", "float") or info.choices:
                continue
            for bad in _outside(info):
                with pytest.raises(argparse.ArgumentTypeError):
                    a.type(repr(bad))
                with pytest.raises(InvalidParameterError, match=f"{info.name} must be"):
                    info.owner(**{info.name: bad})
            if info.default is not None:
                assert a.type(str(info.default)) == info.default, (name, a.dest)
            checked += 1
    assert checked >= 40


# -- 2. negative numbers and lists that start with one are values, not options ---------------
@pytest.mark.parametrize(
    ("flag", "value", "key", "expected"),
    [
        ("--station", "-3,0,0.5", "stations", [-3.0, 0.0, 0.5]),
        ("--hfov-deg", "-45,45", "horizontal_fov_deg", [-45.0, 45.0]),
        ("--vfov-deg", "-40,60", "vertical_fov_deg", [-40.0, 60.0]),
    ],
)
def test_scan_reads_negative_lists_without_equals(flag, value, key, expected, tmp_path, capsys):
    v, f = box_arrays((-0.5, 2.0, 0.0), (0.5, 3.0, 1.0))
    mesh = write_mesh(tmp_path / "box.ply", v, f)
    out = tmp_path / "s.laz"
    argv = ["scan", str(mesh), "-o", str(out), "--resolution-deg", "2", flag, value]
    if flag != "--station":
        argv += ["--station", "0,0,0.5"]
    assert main(argv) == 0, capsys.readouterr().err
    summary = json.loads(out.with_suffix(".json").read_text())
    if key == "stations":
        assert summary["stations"][0]["position_m"] == expected
    else:
        assert summary["scanner"][key] == expected


@pytest.mark.parametrize(
    ("argv", "dest", "expected"),
    [
        (["run", "c.txt", "-o", "o", "--height-m", "-0.5"], "setting:height_m", -0.5),
        (["run", "c.txt", "-o", "o", "--height-m", "-5e-1"], "setting:height_m", -0.5),
        (["batch", "c.txt", "-o", "o", "--height-m", "-1.5"], "setting:height_m", -1.5),
        (
            ["scan", "m.ply", "-o", "o.laz", "--start-angle-deg", "-90"],
            "param:start_angle_deg",
            -90.0,
        ),
        (
            ["scan", "m.ply", "-o", "o.laz", "--station", "-1e1,-2,0"],
            "station",
            [(-10.0, -2.0, 0.0)],
        ),
    ],
)
def test_every_command_reads_negative_numbers_as_values(argv, dest, expected):
    assert getattr(build_parser().parse_args(argv), dest) == expected


def test_a_negative_value_out_of_range_is_named_not_taken_for_an_option(capsys):
    err = _usage_error(capsys, ["compare", "a", "b", "-o", "o", "--tolerance-m", "-1e-3"])
    assert "--tolerance-m: expected a number > 0" in err and "expected one argument" not in err


# -- 3. outputs are checked first: a file where a folder must be is one line, nothing run ----
_STAGES = {
    "treesim.steps": ("scan_files", "compare_files", "reconstruct_files"),
    "treesim.run": ("run_tree",),
    "treesim.batch": ("run_batch",),
    "treesim.report": ("build_report",),
    "treesim.models": ("generate_tree", "read_cylinders"),
    "treesim.sweep": ("load_sweep", "run_sweep"),
}


@pytest.fixture()
def no_work(monkeypatch):
    """Every stage a command could start fails the test if it is called."""
    import importlib

    def forbidden(*args, **kwargs):
        raise AssertionError("work started before the output was checked")

    for module, names in _STAGES.items():
        for name in names:
            monkeypatch.setattr(importlib.import_module(module), name, forbidden)


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["scan", "{mesh}", "-o", "{file}/x.laz"], "afile is a file, not a folder"),
        (["scan", "{mesh}", "-o", "{dir}"], "it is a folder"),
        (["scan", "{mesh}", "-o", "{mesh}"], "it is an input of this command"),
        (["compare", "{cloud}", "{mesh}", "-o", "{file}"], "it is a file, not a folder"),
        (["compare", "{cloud}", "{mesh}", "-o", "{file}/sub"], "afile is a file, not a folder"),
        (["reconstruct", "{cloud}", "-o", "{file}"], "it is a file, not a folder"),
        (["reconstruct", "{cloud}", "-o", "{dir}"], "tree.ply: it is a folder"),
        (["run", "{cloud}", "-o", "{file}"], "it is a file, not a folder"),
        (["batch", "{cloud}", "-o", "{file}"], "it is a file, not a folder"),
        (["report", "{dir}", "-o", "{file}"], "it is a file, not a folder"),
        (["model", "generate", "--species", "sapling", "-o", "{file}/t.ply"], "afile is a file"),
        (["model", "from-qsm", "{table}", "-o", "{file}/t.ply"], "afile is a file"),
        (["model", "from-qsm", "{table}", "-o", "{file}.ply"], "it is an input"),
        (["demo", "-o", "{file}"], "it is a file, not a folder"),
        (["sweep", "{cloud}", "-o", "{file}"], "it is a file, not a folder"),
    ],
)
def test_an_output_that_cannot_be_written_is_refused_before_any_work(
    argv, words, tmp_path, capsys, no_work, box_ply
):
    afile = tmp_path / "afile"
    afile.write_text("not a folder\n")
    (tmp_path / "afile.ply").write_text("a table, by name\n")
    adir = tmp_path / "adir"
    adir.mkdir()
    (adir / "tree.ply").mkdir()  # where reconstruct writes its mesh
    cloud = tmp_path / "c.xyz"
    cloud.write_text("0 0 0\n1 0 0\n0 1 0\n0 0 1\n")
    names = {
        "mesh": box_ply,
        "file": afile,
        "dir": adir,
        "cloud": cloud,
        "table": tmp_path / ("afile.ply" if "{file}.ply" in argv else "t.csv"),
    }
    before = sorted(tmp_path.rglob("*"))
    rc = main([a.format(**names) for a in argv])
    err = capsys.readouterr().err.strip()
    assert rc == 1
    assert err.startswith("treesim: error: cannot write") and "\n" not in err, err
    assert words in err
    assert sorted(tmp_path.rglob("*")) == before  # nothing written


# -- 5. --beam and --noise work without --instrument: a generic TLS's documented figures -----
@pytest.mark.parametrize(
    ("extra", "expected"),
    [
        (["--noise"], {"range_noise_sd_m": 0.001, "angular_jitter_sd_deg": 0.001}),
        (["--beam"], {"beam_divergence_mrad": 0.3, "range_noise_sd_m": 0.0}),
        (["--beam", "--noise", "--range-noise-sd-m", "0.004"], {"range_noise_sd_m": 0.004}),
        (
            ["--noise", "--instrument", "faro-focus3d-x330"],
            {"range_noise_sd_m": 0.0003, "angular_jitter_sd_deg": 0.0005},
        ),
    ],
)
def test_beam_and_noise_alone_use_a_generic_scanner(extra, expected, box_ply, tmp_path, capsys):
    from treesim.params import GENERIC_TLS

    out = tmp_path / "s.laz"
    argv = ["scan", str(box_ply), "-o", str(out), "--resolution-deg", "2", "--station", "0,0,0.5"]
    assert main([*argv, *extra]) == 0, capsys.readouterr().err
    summary = json.loads(out.with_suffix(".json").read_text())
    for key, value in expected.items():
        assert summary["scanner"][key] == value
    if "--instrument" not in extra:
        assert summary["models_active"]
        on = {k: summary["scanner"][k] for k in GENERIC_TLS if summary["scanner"][k]}
        assert all(v in (GENERIC_TLS[k], 0.004) for k, v in on.items())


def test_the_help_states_the_generic_figures(capsys):
    from treesim.params import GENERIC_TLS

    with pytest.raises(SystemExit):
        main(["scan", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert f"{GENERIC_TLS['beam_divergence_mrad']:g} mrad" in text
    assert f"σ {GENERIC_TLS['range_noise_sd_m'] * 1000:g} mm" in text


# -- 6. long commands say what they are doing when stderr is no terminal (a log, a pipe) -----
def test_scan_and_compare_write_one_line_per_stage_to_a_log(box_ply, tmp_path, capsys):
    out = tmp_path / "s.laz"
    argv = ["scan", str(box_ply), "-o", str(out), "--resolution-deg", "1", "--stations", "2"]
    assert main(argv) == 0
    err = capsys.readouterr().err.splitlines()
    assert [ln.split(" (")[0] for ln in err[:5]] == [
        "treesim scan: loading the scene",
        "treesim scan: scanning",
        "treesim scan: station 1/2",
        "treesim scan: station 2/2",
        "treesim scan: writing the cloud",
    ]
    assert err[-1].startswith("treesim scan: done in ") and len(err) == 6
    assert main(["compare", str(out), str(box_ply), "-o", str(tmp_path / "c")]) == 0
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith("treesim compare: reading (") and "comparing" in err[1]
    assert err[-1].startswith("treesim compare: done in ")


@pytest.mark.parametrize(
    ("command", "target"),
    [
        ("run", "treesim.run.run_tree"),
        ("reconstruct", "treesim.steps.reconstruct_files"),
        ("demo", "treesim.run.run_tree"),
    ],
)
def test_run_reconstruct_and_demo_report_their_stages(
    command, target, tmp_path, capsys, monkeypatch
):
    from treesim.errors import ReconstructionError

    def fake(*args, progress=None, **kwargs):
        for fraction, message in [(0.0, "reading"), (0.1, "reading"), (0.3, "done"), (0.5, "x")]:
            progress(fraction, message)  # a stage's own "done" is not the command's
        progress(1.0, "done")
        raise ReconstructionError("stopped here")

    module, name = target.rsplit(".", 1)
    monkeypatch.setattr(module + "." + name, fake)
    cloud = tmp_path / "c.xyz"
    cloud.write_text("0 0 0\n")
    argv = {"run": ["run", str(cloud)], "reconstruct": ["reconstruct", str(cloud)]}
    rc = main([*argv.get(command, ["demo"]), "-o", str(tmp_path / "o")])
    assert rc == 1
    lines = capsys.readouterr().err.splitlines()
    assert [ln.split(" (")[0].split(" in ")[0] for ln in lines] == [
        f"treesim {command}: reading",
        f"treesim {command}: x",
        f"treesim {command}: done",
        "treesim: error: stopped here",
    ]


def test_the_terminal_form_is_unchanged(capsys):
    from treesim.cli.progress import progress_printer

    show = progress_printer(True, label="scan")
    show(0.5, "station 1/2")
    show(1.0, "done")
    err = capsys.readouterr().err
    assert err.startswith("\r  station 1/2:  50.0 %") and err.endswith("done: 100.0 %\n")
    assert progress_printer(False) is None


@pytest.mark.parametrize(
    ("kw", "first"),
    [
        ({}, "batch: 3 trees, 1 unchanged (not run again), 2 to run"),
        (
            {"name": "sweep", "noun": "points"},
            "sweep: 3 points, 1 unchanged (not run again), 2 to run",
        ),
    ],
)
def test_the_plain_bar_first_says_what_it_will_run_in_its_own_words(kw, first):
    import io

    from treesim.batch import BatchProgress
    from treesim.cli.progress import BatchProgressBar

    stream = io.StringIO()
    bar = BatchProgressBar(stream, tty=False, **kw)
    bar(BatchProgress(total=3, done=1, failed=0, reused=1, running=1, elapsed_s=0, eta_s=None))
    assert stream.getvalue().splitlines() == [first]


# -- 7. a scan that runs but may not be what was meant warns on stderr, not only in OUT.json --
@pytest.mark.parametrize(
    ("flip", "station", "words"),
    [
        (False, "1,0,1", "station 0 at (1.0, 0.0, 1.0) is on a wood surface"),
        (False, "1,1,2", "station 0 at (1.0, 1.0, 2.0) is on a wood surface"),
        (True, "0,0,1", "looks enclosed by the wood geometry"),
    ],
)
def test_a_doubtful_station_is_a_warning_on_stderr(flip, station, words, tmp_path, capsys):
    v, f = box_arrays((-1, -1, 0), (1, 1, 2))
    mesh = write_mesh(tmp_path / "box.ply", v, f[:, ::-1] if flip else f)
    out = tmp_path / "s.laz"
    rc = main(["scan", str(mesh), "-o", str(out), "--station", station, "--resolution-deg", "2"])
    assert rc == 0
    warnings = [ln for ln in messages(capsys.readouterr().err) if "warning" in ln]
    assert len(warnings) == 1 and warnings[0].startswith("treesim: warning: ")
    assert words in warnings[0]
    assert json.loads(out.with_suffix(".json").read_text())["warnings"] == [
        warnings[0].removeprefix("treesim: warning: ")
    ]


def test_an_ordinary_scan_warns_of_nothing(box_ply, tmp_path, capsys):
    out = tmp_path / "s.laz"
    assert main(["scan", str(box_ply), "-o", str(out), "--resolution-deg", "2"]) == 0
    assert "warning" not in capsys.readouterr().err
    assert json.loads(out.with_suffix(".json").read_text())["warnings"] == []


# -- 8. a scan that records nothing writes a valid empty cloud and says why -------------------
@pytest.mark.parametrize(
    ("extra", "azimuth_deg", "why"),
    [
        (["--max-range-m", "5", "--resolution-deg", "1"], 0.0, "64 beyond 5 m from every station"),
        (
            ["--hfov-deg", "90,180", "--resolution-deg", "1"],
            0.0,
            "64 outside every field of view",
        ),
        (
            ["--resolution-deg", "10"],
            5.0,  # a 10 cm pole 10 m out, halfway between two 10° columns
            "the scene lies between the pulses; use a finer resolution",
        ),
    ],
    ids=["beyond-range", "outside-fov", "between-pulses"],
)
def test_an_empty_scan_is_a_valid_empty_cloud_that_says_why(
    extra, azimuth_deg, why, tmp_path, capsys
):
    import math

    from tests.conftest import cylinder_arrays

    a = math.radians(azimuth_deg)
    v, f = cylinder_arrays(0.05, 1.0, 16, (10 * math.cos(a), 10 * math.sin(a), 0.0))
    mesh = write_mesh(tmp_path / "pole.ply", v, f)
    out = tmp_path / "none.laz"
    assert main(["scan", str(mesh), "-o", str(out), "--station", "0,0,0.5", *extra]) == 0
    err = " ".join(messages(capsys.readouterr().err))
    assert "no points were recorded" in err and why in err
    assert laspy.read(out).header.point_count == 0
    summary = json.loads(out.with_suffix(".json").read_text())
    assert summary["points"] == 0
    reasons = " ".join(entry["why"] for entry in summary["lod"].values() if isinstance(entry, dict))
    assert why in reasons
