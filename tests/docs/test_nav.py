"""The manual's navigation (``mkdocs.yml``) and its pages agree: every page in the nav
exists, every page under ``docs/`` is in the nav, and the pages the two docs authors agreed
on are all there."""

from __future__ import annotations

from pathlib import Path

import pytest

yaml = pytest.importorskip("yaml", reason="pyyaml (the dev extra) reads mkdocs.yml")

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"

#: The site's pages, as agreed for issue 22 (paths under docs/).
AGREED = {
    "index.md",
    "install.md",
    "getting-started.md",
    "concepts.md",
    *(
        f"commands/{c}.md"
        for c in (
            "scan plot model reconstruct compare report run batch sweep plan demo serve".split()
        )
    ),
    *(
        f"guides/{g}.md"
        for g in "python plots-and-plans sweeps dask service reconstruction".split()
    ),
    "validation.md",
    *(
        f"api/{a}.md"
        for a in "index treesim scan reconstruct compare models plot plan sweep io params "
        "service".split()
    ),
    "changelog.md",
    "cite.md",
}


def _config() -> dict:
    return yaml.safe_load((ROOT / "mkdocs.yml").read_text(encoding="utf-8"))


def nav_pages(nav) -> list[str]:
    """Every page path in a MkDocs ``nav`` (titles and sections walked), in order."""
    if isinstance(nav, str):
        return [nav]
    if isinstance(nav, list):
        return [p for item in nav for p in nav_pages(item)]
    if isinstance(nav, dict):
        return [p for value in nav.values() for p in nav_pages(value)]
    raise TypeError(f"unexpected nav entry {nav!r}")


def test_nav_pages_walks_titles_and_sections():
    nav = [{"Home": "index.md"}, {"Part": [{"A": "a/x.md"}, "b.md"]}]
    assert nav_pages(nav) == ["index.md", "a/x.md", "b.md"]


def test_every_nav_page_exists():
    missing = [p for p in nav_pages(_config()["nav"]) if not (DOCS / p).is_file()]
    assert missing == [], f"in mkdocs.yml's nav but not under docs/: {missing}"


def test_every_page_is_in_the_nav_once():
    listed = nav_pages(_config()["nav"])
    assert len(listed) == len(set(listed)), "a page is in the nav twice"
    pages = {p.relative_to(DOCS).as_posix() for p in DOCS.rglob("*.md")}
    assert sorted(pages - set(listed)) == [], "pages under docs/ missing from mkdocs.yml's nav"


def test_the_agreed_pages_are_in_the_nav():
    assert sorted(AGREED - set(nav_pages(_config()["nav"]))) == []


def test_the_build_is_strict():
    # strict turns a broken link, anchor or API reference into a failed build (CI)
    config = _config()
    assert config["strict"] is True
    links = config["validation"]["links"]
    assert {links[k] for k in ("not_found", "anchors", "unrecognized_links")} == {"warn"}
