"""The parameter model: every field documented once, and what is generated from it."""

from __future__ import annotations

from dataclasses import fields

import pytest

from treesim.errors import InvalidParameterError
from treesim.params import (
    INSTRUMENTS,
    RUN_PRESETS,
    SETTINGS,
    RunParams,
    ScannerSpec,
    apply_settings,
    execution_only_paths,
    json_schema,
    params_from_dict,
    run_preset,
    to_toml,
    walk,
)
from treesim.params.models import ModelParams


def test_every_field_has_help_and_every_length_a_unit():
    leaves = list(walk(RunParams)) + list(walk(ModelParams))
    assert len(leaves) > 50
    for info in leaves:
        assert info.help and not info.help.endswith("."), info.path
        if info.name.endswith(("_m", "_deg", "_mrad", "_s")):
            assert info.unit, f"{info.path} has a unit in its name but none declared"


def test_execution_only_fields_are_the_ones_that_do_not_change_results():
    assert set(execution_only_paths()) == {
        ("threads",),
        ("preset",),
        ("reconstruct", "prepare", "threads"),
        ("reconstruct", "timeout_s"),
        ("compare", "nthreads"),
        ("scan", "chunk_rays"),
        ("scan", "max_rays"),
    }


@pytest.mark.parametrize("name", list(RUN_PRESETS))
def test_toml_round_trips_every_run_preset(tmp_path, name):
    from treesim.params import load_config

    p = tmp_path / "p.toml"
    p.write_text(to_toml(run_preset(name)))
    assert load_config(p) == run_preset(name)
    assert "# voxel size for downsampling the field cloud [m]" in p.read_text()


def test_json_schema_mirrors_the_dataclasses():
    s = json_schema(RunParams)
    assert s["additionalProperties"] is False
    scanner = s["properties"]["scan"]["properties"]["scanner"]["properties"]
    assert set(scanner) == {f.name for f in fields(ScannerSpec)}
    res = scanner["horizontal_resolution_deg"]
    assert res == {
        "type": "number",
        "exclusiveMinimum": 0,
        "maximum": 45,
        "description": "horizontal angular step between pulses",
        "x-unit": "deg",
        "default": 0.04,
    }
    assert scanner["vertical_fov_deg"]["minItems"] == scanner["vertical_fov_deg"]["maxItems"] == 2
    assert scanner["return_mode"]["enum"] == ["first", "last", "strongest", "all"]
    dist = s["properties"]["scan"]["properties"]["distance_m"]
    assert dist["anyOf"][1] == {"type": "null"} and "station rule" in dist["description"]
    assert dist["anyOf"][0] == {"type": "number", "exclusiveMinimum": 0, "maximum": 10_000}


def test_json_schema_states_every_declared_range():
    """The schema's ranges are the ones the model checks (``param(ge=...)``): a value on
    the wrong side of each bound is refused by both."""
    import jsonschema

    s = json_schema(RunParams)
    checked = 0
    for info in walk(RunParams):
        if info.base_type not in ("int", "float") or info.bounds == (None,) * 4:
            continue
        node = s
        for k in info.path:
            node = node["properties"][k]
        schema = node["anyOf"][0] if info.optional else node
        ge, gt, le, lt = info.bounds
        outside = [ge - 1 if ge is not None else None, gt, le + 1 if le is not None else None, lt]
        for bad in (b for b in outside if b is not None):
            with pytest.raises(jsonschema.ValidationError):
                jsonschema.validate(bad, schema)
            with pytest.raises(InvalidParameterError):
                info.owner(**{info.name: bad})
        jsonschema.validate(info.default, node)
        checked += 1
    assert checked >= 40


def test_one_resolution_setting_sets_both_axes():
    p = apply_settings(run_preset("draft"), {"resolution_deg": "0.5"})
    assert p.scan.scanner.horizontal_resolution_deg == p.scan.scanner.vertical_resolution_deg
    assert p.scan.scanner.vertical_resolution_deg == 0.5
    spec = INSTRUMENTS["riegl-vz400"].spec()
    assert spec.horizontal_resolution_deg == spec.vertical_resolution_deg == 0.04


def test_optional_settings_read_zero_as_the_rule():
    p = apply_settings(run_preset("standard"), {"distance_m": "0", "voxel_m": 0})
    assert p.scan.distance_m is None and p.reconstruct.prepare.voxel_size_m is None
    assert set(SETTINGS) >= {"method", "stations", "resolution_deg", "distance_m"}


def test_unknown_keys_and_bad_values_are_refused_with_their_place():
    with pytest.raises(InvalidParameterError, match=r"unknown setting 'colour' in \[scan\]"):
        params_from_dict({"scan": {"colour": 1}})
    with pytest.raises(InvalidParameterError, match="unknown preset 'ultra'"):
        run_preset("ultra")


def test_every_declared_choice_is_enforced_by_the_model():
    # every text field declared with choices refuses another value where the dataclass is
    # built (a TOML file, the service, Python), not only on the command line; CompareParams'
    # hidden_surface and ModelParams' joints had no check of their own
    from treesim.params import CompareParams, ReconstructParams, ScanParams, describe

    checked = []
    for cls in (CompareParams, ModelParams, ReconstructParams, ScannerSpec, ScanParams):
        for info in describe(cls):
            if info.choices:
                with pytest.raises(InvalidParameterError, match=f"{info.name} must be one of"):
                    cls(**{info.name: "no-such-choice"})
                checked.append(info.name)
    assert {"hidden_surface", "joints", "method", "lod", "return_mode"} <= set(checked)
