"""Sweep files: every name and value checked up front (one-line errors), the grid expanded
into designs, equal designs merged, trees read."""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest

from treesim.errors import InputFormatError, InvalidParameterError
from treesim.params import SETTINGS, run_preset
from treesim.sweep import known_names, load_sweep, parse_sweep

SAPLING = [{"species": "sapling", "leaves": False}]


def parse(**data):
    data.setdefault("tree", SAPLING)
    return parse_sweep(data, where="s.toml: ")


def one_line(exc) -> str:
    text = str(exc.value)
    assert "\n" not in text, text
    return text


# -- the grid ---------------------------------------------------------------------------------
def test_the_grid_is_the_cartesian_product_in_file_order():
    cfg = parse(grid={"resolution_deg": [0.1, 0.2], "facets": [8, 16, 32]})
    assert len(cfg.designs) == 6
    assert cfg.parameters == ("resolution_deg", "facets")
    got = [cfg.values_of(d) for d in cfg.designs]
    assert got[0] == {"resolution_deg": 0.1, "facets": 8}
    assert got[2] == {"resolution_deg": 0.1, "facets": 32}
    assert got[3] == {"resolution_deg": 0.2, "facets": 8}
    assert [d.index for d in cfg.designs] == list(range(6))
    # the flat setting sets both angular steps
    s = cfg.designs[3].params.scan.scanner
    assert s.horizontal_resolution_deg == s.vertical_resolution_deg == 0.2
    assert len({d.key for d in cfg.designs}) == 6


def test_dotted_names_nested_tables_and_quoted_keys_are_one_thing():
    a = parse(grid={"scan": {"scanner": {"beam_divergence_mrad": [0.0, 0.35]}}})
    b = parse(grid={"scan.scanner.beam_divergence_mrad": [0.0, 0.35]})
    assert a.parameters == b.parameters == ("scan.scanner.beam_divergence_mrad",)
    assert [d.key for d in a.designs] == [d.key for d in b.designs]
    assert a.designs[1].params.scan.scanner.beam_divergence_mrad == 0.35


def test_points_are_added_to_the_grid_and_equal_designs_merged():
    cfg = parse(
        preset="standard",
        grid={"resolution_deg": [0.04, 0.08]},
        point=[
            {"preset": "standard"},  # = the grid's 0.04 design
            {"preset": "draft", "label": "quick"},
            {"stations": 4},  # a name only a point sets is a parameter too
        ],
    )
    assert cfg.parameters == ("resolution_deg", "stations")
    assert len(cfg.designs) == 4
    assert cfg.designs[0].labels == ("standard",)
    assert cfg.designs[2].labels == ("quick",)
    draft = cfg.designs[2].params
    assert draft.compare.max_samples == run_preset("draft").compare.max_samples
    assert cfg.values_of(cfg.designs[2]) == {"resolution_deg": 0.08, "stations": 3}
    assert cfg.values_of(cfg.designs[3])["stations"] == 4


def test_base_applies_to_every_design_and_the_design_wins():
    cfg = parse(base={"facets": 12, "scan.height_m": 1.2}, grid={"facets": [8, 16]})
    assert [d.params.reconstruct.facets for d in cfg.designs] == [8, 16]
    assert all(d.params.scan.height_m == 1.2 for d in cfg.designs)


def test_speed_only_fields_can_be_swept_and_name_distinct_designs():
    cfg = parse(grid={"scan.chunk_rays": [1000, 2000]})
    assert len(cfg.designs) == 2
    assert cfg.designs[0].key != cfg.designs[1].key


def test_every_flat_setting_is_a_known_name():
    names = known_names()
    assert set(SETTINGS) - {"tolerance_m"} <= set(names)
    assert "scan.scanner.subrays" in names and "reconstruct.qsm.slice_m" in names
    assert "threads" not in names and "compare.tolerance_m" not in names
    # the flat setting --tolerance-m names the reserved τ too: a sweep refuses it
    assert "tolerance_m" not in names
    with pytest.raises(InvalidParameterError, match="tolerance_m cannot be swept: τ is the"):
        parse(grid={"tolerance_m": [0.01, 0.02]})


# -- errors -----------------------------------------------------------------------------------
def test_an_unknown_name_lists_the_known_ones():
    with pytest.raises(InvalidParameterError) as exc:
        parse(grid={"resolution": [0.1]})
    text = one_line(exc)
    assert text.startswith("s.toml: [grid] unknown parameter 'resolution'")
    assert "did you mean resolution_deg" in text
    assert "scan.scanner.beam_divergence_mrad" in text and "voxel_m" in text


@pytest.mark.parametrize(
    "data, match",
    [
        ({"grid": {"facets": 16}}, r"\[grid\] facets must be a non-empty list"),
        ({"grid": {"facets": []}}, r"\[grid\] facets must be a non-empty list"),
        (
            {"grid": {"facets": [16, 2]}},
            r"\[grid\] facets=2: .*facets must be a whole number in \[3, 512\]",
        ),
        ({"grid": {"resolution_deg": [0.1, "fine"]}}, r"resolution_deg='fine'"),
        ({"grid": {"threads": [1, 2]}}, r"threads cannot be swept: the executor sets threads"),
        ({"grid": {"compare.tolerance_m": [0.01]}}, r"τ is the sweep's own"),
        ({"point": [{"resolution_deg": -1}]}, r"\[\[point\]\] 1: .*resolution_deg must be a"),
        ({"point": [{"preset": "ultra"}]}, r"unknown preset 'ultra'"),
        ({"point": [{"label": 3}]}, r"label must be text"),
        ({}, r"nothing to sweep"),
        ({"grid": {"facets": [8]}, "colour": 1}, r"unknown key\(s\) colour at the top level"),
        ({"grid": {"facets": [8]}, "tolerance_m": 0.01, "tolerance_factor": 3}, r"not both"),
        ({"grid": {"facets": [8]}, "tolerance_m": -1}, r"tolerance_m must be > 0"),
        ({"grid": {"facets": [8]}, "repeat": 0}, r"repeat must be >= 1"),
        ({"grid": {"facets": [8]}, "preset": "ultra"}, r"unknown preset"),
        ({"grid": {"facets": [8]}, "base": {"bogus": 1}}, r"\[base\] unknown parameter 'bogus'"),
        ({"grid": {"facets": [8]}, "reference": {"n_stations": 0}}, r"\[reference\].*n_stations"),
        (
            {"grid": {"facets": [8]}, "reference": {"resolution": 1}},
            r"\[reference\].*unknown setting",
        ),
    ],
)
def test_bad_values_are_one_line_errors_naming_the_place(data, match):
    with pytest.raises(InvalidParameterError, match=match) as exc:
        parse(**data)
    one_line(exc)
    assert str(exc.value).startswith("s.toml: ")


@pytest.mark.parametrize(
    "trees, match",
    [
        (None, r"no trees"),
        ([{"species": "baobab"}], r"unknown species 'baobab'; the species are .*sapling"),
        ([{"species": "sapling", "cloud": "x.laz"}], r"exactly one of species, cloud or bundled"),
        ([{"bundled": "oak"}], r"no bundled tree 'oak'; the bundled trees are coffee_tree"),
        ([{"bundled": "coffee_tree", "seed": 2}], r"seed apply to procedural trees"),
        ([{"species": "sapling", "colour": "red"}], r"\[\[tree\]\] 1: unknown key\(s\) colour"),
        ([{"species": "sapling", "facets": 2}], r"\[\[tree\]\] 1: facets must be a whole number"),
        ([{"species": "sapling"}, {"species": "sapling"}], r"two trees are named 'sapling'"),
        ([{"species": "sapling", "id": "a b"}], r"tree id 'a b'"),
    ],
)
def test_bad_trees(trees, match):
    with pytest.raises(InvalidParameterError, match=match) as exc:
        parse_sweep(
            {"tree": trees, "grid": {"facets": [8]}} if trees else {"grid": {"facets": [8]}}
        )
    one_line(exc)


def test_a_missing_cloud_is_an_input_error(tmp_path):
    with pytest.raises(InputFormatError, match="relative to the config file"):
        parse_sweep({"tree": [{"cloud": "nope.laz"}], "grid": {"facets": [8]}}, base_dir=tmp_path)


# -- files ------------------------------------------------------------------------------------
def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "s.toml"
    p.write_text(textwrap.dedent(text), encoding="utf-8")
    return p


def test_a_file_with_trees_of_every_kind(tmp_path):
    (tmp_path / "clouds").mkdir()
    (tmp_path / "clouds" / "oak.xyz").write_text("0 0 0\n1 0 0\n0 1 0\n")
    cfg = load_sweep(
        write(
            tmp_path,
            """
            tolerance_m = 0.01
            [[tree]]
            species = "sapling"
            seed = 2
            facets = 12
            [[tree]]
            bundled = "coffee_tree"
            [[tree]]
            cloud = "clouds/oak.xyz"
            id = "oak"
            [grid]
            scan.scanner.subrays = [3, 5]
            """,
        )
    )
    assert cfg.name == "s" and cfg.path == (tmp_path / "s.toml").resolve()
    assert [t.id for t in cfg.trees] == ["sapling", "coffee_tree", "oak"]
    assert [t.kind for t in cfg.trees] == ["procedural", "cloud", "cloud"]
    assert cfg.trees[0].model.seed == 2 and cfg.trees[0].model.facets == 12
    assert cfg.trees[1].path.name == "cloud.txt" and cfg.trees[1].path.is_file()
    assert cfg.trees[2].path == (tmp_path / "clouds" / "oak.xyz").resolve()
    assert cfg.tolerance_m == 0.01 and cfg.tolerance_factor is None
    assert cfg.parameters == ("scan.scanner.subrays",)


def test_tau_defaults_to_three_times_the_reference_spacing(tmp_path):
    cfg = parse(grid={"facets": [8]})
    assert cfg.tolerance_m is None and cfg.tolerance_factor == 3.0


def test_files_that_cannot_be_read(tmp_path):
    with pytest.raises(InputFormatError, match="not found"):
        load_sweep(tmp_path / "none.toml")
    with pytest.raises(InputFormatError, match="not valid TOML"):
        load_sweep(write(tmp_path, "grid = [\n"))
    with pytest.raises(InvalidParameterError, match=r"^s.toml: \[grid\] unknown parameter"):
        load_sweep(write(tmp_path, '[[tree]]\nspecies = "sapling"\n[grid]\nfoo = [1]\n'))


def test_the_committed_sweep_is_valid_and_large_enough():
    root = Path(__file__).resolve().parents[2]
    cfg = load_sweep(root / "benchmarks" / "sweeps" / "presets.toml")
    kinds = [t.kind for t in cfg.trees]
    assert kinds.count("procedural") >= 2 and "cloud" in kinds
    assert len(cfg.parameters) >= 3
    assert len(cfg.trees) * len(cfg.designs) >= 30
    labels = {lab for d in cfg.designs for lab in d.labels}
    assert {"draft", "standard", "fine"} <= labels
    # each preset is a point of the sweep with exactly the preset's settings
    from treesim.params import params_hash

    for d in cfg.designs:
        for lab in d.labels:
            assert params_hash(d.params) == params_hash(run_preset(lab)), lab
