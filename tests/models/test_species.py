"""The species presets as data (``treesim/data/species.toml``) and the reader of species
files: the presets read back exactly the parameters the code held before they moved to
the file, agree with what their sources say was changed, and a bad file is refused with
the species and the field named."""

from __future__ import annotations

import hashlib
import json
from importlib import resources

import pytest

from treesim.errors import InvalidParameterError
from treesim.models import SPECIES, LeafParams, StemLevel, TreeParams, generate_tree
from treesim.models.species import read_species_toml

#: sha256 of each preset's parameters (``json.dumps(to_dict(), sort_keys=True)``), taken
#: from the presets as Python literals before they became data (procedural.py at
#: 4d40b08): the file must read back the same numbers, bit for bit, with the same types.
PINNED = {
    "aspen": "0ccb5a901529eb3edf16a0f9a12a41e64261288ce82df6d5a663eef4081ef7b5",
    "aspen-leafon": "d3b2944f2cc10338f8ae6fc81131ca8bd0a6f39e9d0463fc30e47abc2f7c9a1c",
    "balsam-fir": "c5c800b6b84129f7f31ce448bbbd00e1434ba37d8acbc4fa4a9f3019fcf09bf6",
    "sapling": "72a9fdf7fe78560dabae851fff72332af024d76b972b72d5265a828f9fd59b46",
    "old-tupelo": "4be6ab068d245b1ba04cd62d29f2294c3f5797db6245f348bc0c6739c62ffb26",
    # added as data (issue #21), pinned from the file itself
    "palm": "60e599b90e51a8b1473a77134796041866a8b121f158c6fab2cff237e3714b67",
}


#: Fields added after the pins, with the default that leaves a tree as it was: left out
#: of the digest where they hold it, so the pins keep meaning "the same numbers".
ADDED_LATER = {"leaves": {"droop": 0.0}}


def _digest(params: TreeParams) -> str:
    d = params.to_dict()
    for part, fields in ADDED_LATER.items():
        for name, default in fields.items():
            if d.get(part) and d[part].get(name) == default:
                del d[part][name]
    return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()


def test_the_presets_read_back_the_parameters_they_had_as_code():
    assert list(SPECIES) == list(PINNED)  # the order `treesim model list` shows
    assert {name: _digest(p) for name, p in SPECIES.items()} == PINNED


def test_the_presets_agree_with_what_their_sources_say_was_changed():
    """Numbers read from each preset's ``source`` sentence, against the parameters."""
    aspen = SPECIES["aspen"]
    assert (aspen.trunk_length_m, aspen.trunk_length_var_m) == (14.0, 1.0)  # 14 +- 1 m
    assert (aspen.radius_ratio, aspen.ratio_power) == (0.011, 1.7)
    assert [lev.branches for lev in aspen.levels[1:]] == [50, 14]  # 2Branches 30 -> 14
    assert aspen.leaves.length_m == 0.07 and aspen.leaves.shape == "ovate"  # 7 cm ovate
    fir = SPECIES["balsam-fir"]
    assert (fir.radius_ratio, fir.ratio_power, fir.base_size) == (0.009, 2.0, 0.1)
    one = fir.levels[1]
    assert (one.branches, one.length_ratio, one.down_angle_var_deg, one.curve_deg) == (
        70,
        0.35,
        -35.0,
        10.0,
    )
    assert fir.levels[2].branches == 8 and len(fir.levels) == 3  # the third level dropped
    assert (fir.leaves.shape, fir.leaves.length_m, fir.leaves.width_ratio) == (
        "rectangle",
        0.10,
        0.4,
    )  # 10 x 4 cm sprays
    sapling = SPECIES["sapling"]
    assert (sapling.trunk_length_m, sapling.trunk_length_var_m) == (3.5, 0.3)
    assert (sapling.radius_ratio, sapling.flare) == (0.006, 0.0)
    assert [lev.branches for lev in sapling.levels[1:]] == [20, 5]  # 20 stems, 5 twigs each
    tupelo = SPECIES["old-tupelo"]
    assert (tupelo.trunk_length_m, tupelo.trunk_length_var_m) == (24.0, 2.0)
    assert (tupelo.radius_ratio, tupelo.ratio_power) == (0.014, 1.5)
    assert (tupelo.levels[1].branches, tupelo.levels[1].seg_splits) == (32, 0.3)
    assert tupelo.levels[2].branches == 9 and len(tupelo.levels) == 3
    palm = SPECIES["palm"]
    assert (palm.trunk_length_m, palm.trunk_length_var_m) == (9.0, 0.5)  # 9 +- 0.5 m
    assert (palm.radius_ratio, palm.levels[0].taper, palm.flare) == (0.0135, 0.15, 0.3)
    assert len(palm.levels) == 2 and palm.levels[1].branches == 28  # one level: 28 fronds
    fronds = palm.levels[1]
    assert (fronds.down_angle_deg, fronds.down_angle_var_deg, fronds.curve_deg) == (
        45.0,
        -80.0,
        110.0,
    )
    leaflets = palm.leaves
    assert (leaflets.leaves_per_stem, leaflets.shape, leaflets.down_angle_deg) == (
        240,
        "rectangle",
        60.0,
    )
    assert (leaflets.length_m, leaflets.length_m * leaflets.width_ratio) == pytest.approx(
        (0.8, 0.04)
    )  # 80 x 4 cm strips
    assert (leaflets.rotate_deg, leaflets.droop) == (180.0, 0.7)  # two ranks, in a V
    # the leaf-on aspen is the aspen with its leaves on, nothing else changed
    on = SPECIES["aspen-leafon"]
    assert on.leaves_on and not aspen.leaves_on
    assert (on.levels, on.leaves, on.source) == (aspen.levels, aspen.leaves, aspen.source)


def test_the_presets_file_ships_inside_the_package():
    text = (resources.files("treesim") / "data" / "species.toml").read_text("utf-8")
    assert read_species_toml(text) == SPECIES


_SMALL = """
[[species]]
name = "stick"
description = "a test tree"
source = "Weber & Penn (1995), made small for a test"
trunk_length_m = 4
radius_ratio = 0.02

[[species.levels]]
segments = 3

[[species.levels]]
branches = 6
length_ratio = 0.4
down_angle_deg = 45

[species.leaves]
leaves_per_stem = 3

[[species]]
name = "stick-leafon"
based_on = "stick"
description = "the test tree with leaves"
leaves_on = true
"""


def test_a_species_file_reads_into_the_dataclasses_with_their_defaults():
    got = read_species_toml(_SMALL)
    want = TreeParams(
        name="stick",
        description="a test tree",
        source="Weber & Penn (1995), made small for a test",
        trunk_length_m=4.0,
        radius_ratio=0.02,
        levels=(
            StemLevel(segments=3),
            StemLevel(branches=6, length_ratio=0.4, down_angle_deg=45.0),
        ),
        leaves=LeafParams(leaves_per_stem=3),
    )
    assert list(got) == ["stick", "stick-leafon"]
    assert got["stick"] == want
    # a whole number for a float field reads as a float (the JSON of the truth says 4.0)
    assert type(got["stick"].trunk_length_m) is float
    assert type(got["stick"].levels[1].down_angle_deg) is float
    assert got["stick"].to_dict()["trunk_length_m"] == 4.0
    # based_on: the same tree, only the fields given changed
    on = got["stick-leafon"]
    assert on.leaves_on and on.description == "the test tree with leaves"
    assert (on.levels, on.leaves, on.trunk_length_m) == (want.levels, want.leaves, 4.0)
    a = generate_tree(got["stick"], seed=2)
    b = generate_tree(want, seed=2)
    assert (a.cylinders.start == b.cylinders.start).all()


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("[[species]\nname = 'x'", r"species\.toml: not a valid TOML file"),
        ("species = 3", r"species must be \[\[species\]\] tables"),
        (
            _SMALL.replace("radius_ratio = 0.02", "radius_ratio = 0.02\nratio = 1"),
            r"species 'stick': unknown TreeParams parameter 'ratio'; known: name, description",
        ),
        (
            _SMALL.replace("segments = 3", "segments = 3\ncurl = 2"),
            r"species 'stick', level 0: unknown StemLevel parameter 'curl'",
        ),
        (
            _SMALL.replace("leaves_per_stem = 3", "leaves_per_stem = 3\nsize = 1"),
            r"species 'stick', leaves: unknown LeafParams parameter 'size'",
        ),
        (
            _SMALL.replace("length_ratio = 0.4", "length_ratio = -0.4"),
            r"species 'stick': length_ratio must be a number > 0",
        ),
        (
            _SMALL.replace("radius_ratio = 0.02", "radius_ratio = 0.5"),
            r"species 'stick': radius_ratio must be a number > 0 and <= 0.2, got 0.5",
        ),
        (
            _SMALL.replace('based_on = "stick"', 'based_on = "tree"'),
            r"species 'stick-leafon': based_on 'tree' names no species above it",
        ),
        (
            _SMALL.replace('name = "stick-leafon"', 'name = "stick"'),
            r"species 'stick': a second species of that name",
        ),
        (
            _SMALL.replace('description = "a test tree"\n', ""),
            r"species 'stick': .*missing 1 required keyword-only argument: 'description'",
        ),
    ],
)
def test_a_bad_species_file_is_refused_naming_the_species_and_field(text, match):
    with pytest.raises(InvalidParameterError, match=match):
        read_species_toml(text)
