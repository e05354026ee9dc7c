"""Shared fixtures for the tree-model tests: the coffee tree's QSM tables, the presets."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.conftest import bundled_path

SHARED_DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"
COFFEE = SHARED_DATA / "trees" / "coffee_tree"


def _need(path: Path) -> Path:
    if not path.is_file():
        pytest.skip(f"needs the shared data set ({path} is absent; it lives in ../shared/data)")
    return path


@pytest.fixture(scope="session")
def treeqsm_csv() -> Path:
    """The coffee tree's TreeQSM 2.4.1 flat cylinder table (bundled with the package)."""
    return bundled_path("coffee_tree", "QSM_treeqsm_v2.4.1_cylinders.csv")


@pytest.fixture(scope="session")
def simpleforest_csv() -> Path:
    """The coffee tree's SimpleForest cylinder table."""
    return _need(COFFEE / "QSM_simpleforest.csv")


@pytest.fixture(scope="session")
def preset_trees():
    """Every species preset generated with seed 0 (and its default leaves), generated once."""
    from treesim.models import SPECIES as PRESETS
    from treesim.models import generate_tree

    return {name: generate_tree(name, seed=0) for name in PRESETS}
