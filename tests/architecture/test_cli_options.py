"""Every command-line option that sets a model parameter takes its default and help from
the parameter model (:mod:`treesim.params`): no literal default is typed twice."""

from __future__ import annotations

import argparse
import ast
from pathlib import Path

from treesim.cli import build_parser
from treesim.cli._options import PARAM, SETTING
from treesim.params import RUN_PRESETS, SETTINGS, RunParams, walk
from treesim.params.models import ModelParams

CLI = Path(__file__).resolve().parents[2] / "pipeline" / "cli"

#: Options that share a parameter's name but are not the parameter, and why.
NOT_PARAMETERS = {
    ("batch", "--threads"): "threads per tree chosen by the executor (cores // workers)",
    ("sweep", "--threads"): "threads per point chosen by the executor (cores // workers)",
    ("plot from-cloud", "--threads"): "threads per tree chosen by the executor (cores // workers)",
    ("scan", "--resolution-deg"): "the flat setting resolution_deg: sets both steps",
    ("plan", "--resolution-deg"): "the flat setting resolution_deg: sets both steps",
    ("plot scan", "--resolution-deg"): "the flat setting resolution_deg: sets both steps",
    ("plot scan", "--facets"): "overrides the plot file's facets (Plot.facets) for its trees",
    ("run", "--preset"): "picks the run preset to start from (RunParams.preset records it)",
    ("batch", "--preset"): "picks the run preset to start from (RunParams.preset records it)",
}


def _parsers() -> list[tuple[str, argparse.ArgumentParser]]:
    out, todo = [], [("", build_parser())]
    while todo:
        name, p = todo.pop()
        out.append((name, p))
        for a in p._actions:
            if isinstance(a, argparse._SubParsersAction):
                todo.extend((f"{name} {k}".strip(), sp) for k, sp in a.choices.items())
    return out


PARSERS = _parsers()
PARAM_FLAGS = (
    {i.cli_flag for i in walk(RunParams)}
    | {i.cli_flag for i in walk(ModelParams)}
    | {s.flag for s in SETTINGS.values()}
)


def test_every_command_is_walked():
    names = {n for n, _ in PARSERS}
    assert {"scan", "reconstruct", "compare", "report", "run", "batch", "model generate"} <= names


def test_generated_options_carry_the_models_help_and_default():
    checked = 0
    for name, parser in PARSERS:
        for a in parser._actions:
            info = getattr(a, PARAM, None)
            if info is None:
                continue
            checked += 1
            assert a.default is argparse.SUPPRESS, f"{name} {a.option_strings}: a default typed"
            assert info.help in a.help, f"{name} {a.option_strings}: help not the model's"
            if not a.required:
                shown = f"default {info.default_text(with_unit=False)}"
                assert shown in a.help, (name, a.option_strings)
    assert checked >= 40


def test_setting_options_carry_the_models_help():
    standard = RUN_PRESETS["standard"]
    seen = 0
    for name, parser in PARSERS:
        for a in parser._actions:
            setting = getattr(a, SETTING, None)
            if setting is None:
                continue
            seen += 1
            assert a.default is None
            assert (setting.help or setting.info.help) in a.help, (name, a.option_strings)
            node = standard
            for k in setting.paths[0]:
                node = getattr(node, k)
            shown = f"default {setting.info.default_text(with_unit=False)}"
            assert f"standard {node}" in a.help or shown in a.help, (name, a.help)
    assert seen == 2 * len(SETTINGS)  # run and batch


def test_no_hand_made_option_sets_a_parameter():
    bad = []
    for name, parser in PARSERS:
        for a in parser._actions:
            if getattr(a, PARAM, None) or getattr(a, SETTING, None):
                continue
            for flag in a.option_strings:
                if flag in PARAM_FLAGS and (name, flag) not in NOT_PARAMETERS:
                    bad.append(f"{name} {flag}")
            d = a.default
            if isinstance(d, (int, float)) and not isinstance(d, bool) and d is not None:
                bad.append(f"{name} {a.option_strings}: literal default {d!r}")
    assert not bad, bad


def test_the_cli_sources_type_no_numeric_default():
    """``add_argument(..., default=<number>)`` appears nowhere in ``pipeline/cli``."""
    bad = []
    for path in CLI.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Call) and getattr(node.func, "attr", "") == "add_argument":
                for kw in node.keywords:
                    if kw.arg == "default" and isinstance(kw.value, ast.Constant):
                        if isinstance(kw.value.value, (int, float)) and not isinstance(
                            kw.value.value, bool
                        ):
                            bad.append(f"{path.name}:{node.lineno}")
    assert not bad, bad


def test_a_parameter_on_by_default_can_be_turned_off():
    """A bool parameter whose default is True gets ``--no-NAME`` beside ``--NAME``: the
    bare flag alone could only set what is already set."""
    from treesim.cli._options import collect

    seen = set()
    for name, parser in PARSERS:
        for a in parser._actions:
            info = getattr(a, PARAM, None)
            if info is None or info.base_type != "bool" or info.default is not True:
                continue
            seen.add(info.path[-1])
            off = "--no-" + info.cli_flag.removeprefix("--")
            assert off in a.option_strings, (name, a.option_strings)
    assert {"plots", "leaf_layer"} <= seen
    args = build_parser().parse_args(["report", "OUT", "--no-plots"])
    assert collect(args) == {"plots": False}
    args = build_parser().parse_args(["reconstruct", "c.ply", "-o", "o", "--no-leaf-layer"])
    assert collect(args)["leaf_layer"] is False
