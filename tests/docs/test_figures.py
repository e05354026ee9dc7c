"""Figures typed into the manual agree with the code that produces them.

The preset table of ``docs/commands/model.md`` lists each species preset's figures (seed 0,
32 facets); the generator is deterministic, so the table must match what
``generate_tree(...).truth(32)`` gives today, or the page is stale.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from treesim.models import SPECIES, generate_tree

ROOT = Path(__file__).resolve().parents[2]
MODEL_PAGE = ROOT / "docs" / "commands" / "model.md"

_ROW = re.compile(r"^\| `(?P<name>[a-z-]+)` \| (?P<what>[^|]+) \| (?P<rest>.+) \|$")


def _number(text: str) -> float:
    return float(re.sub(r"[^0-9.]", "", text))


def _preset_rows() -> dict[str, dict[str, object]]:
    rows: dict[str, dict[str, object]] = {}
    for line in MODEL_PAGE.read_text(encoding="utf-8").splitlines():
        m = _ROW.match(line.strip())
        if m is None or m["name"] not in SPECIES:
            continue
        dbh, height, wood, cylinders, triangles = (c.strip() for c in m["rest"].split("|"))
        leaves = re.search(r"([\d,]+) leaves", m["what"])
        rows[m["name"]] = {
            "dbh_cm": _number(dbh),
            "height_m": _number(height),
            "wood_l": _number(wood),
            "cylinders": int(_number(cylinders)),
            "triangles": int(_number(triangles)),
            "leaves": int(_number(leaves[1])) if leaves else None,
        }
    return rows


def test_model_page_lists_every_preset() -> None:
    assert sorted(_preset_rows()) == sorted(SPECIES)


@pytest.mark.parametrize("name", sorted(SPECIES))
def test_model_page_preset_figures_match_the_generator(name: str) -> None:
    row = _preset_rows()[name]
    truth = generate_tree(SPECIES[name], seed=0).truth(32)
    # The page rounds to its printed digits: DBH 0.1 cm, height 0.1 m, wood to the litre
    # (one decimal below 10 L).
    assert row["dbh_cm"] == pytest.approx(truth["dbh_m"] * 100, abs=0.051)
    assert row["height_m"] == pytest.approx(truth["height_m"], abs=0.051)
    wood_l = truth["volume_total_m3"] * 1000
    assert row["wood_l"] == pytest.approx(wood_l, abs=0.051 if wood_l < 10 else 0.51)
    assert row["cylinders"] == truth["n_cylinders"]
    assert row["triangles"] == truth["n_triangles"]
    if row["leaves"] is not None:
        assert row["leaves"] == truth["n_leaves"]
