"""The committed sweep (``benchmarks/sweeps/presets``): it is the committed config's, it
finished, its page shows the fronts, and the preset tables are generated from it."""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import pytest

from benchmarks import preset_table
from treesim.sweep import load_sweep
from treesim.sweep.engine import _csv_value

ROOT = Path(__file__).resolve().parents[2]
OUT = ROOT / "benchmarks" / "sweeps" / "presets"


@pytest.fixture(scope="module")
def doc() -> dict:
    return json.loads((OUT / "sweep.json").read_text(encoding="utf-8"))


def _holds(recorded: dict, now: dict, where: str = "") -> list[str]:
    """Where the settings ``now`` differ from those ``recorded`` (keys the record lacks, a
    parameter added since with its default, are not differences)."""
    diffs = []
    for k, v in recorded.items():
        if isinstance(v, dict) and isinstance(now.get(k), dict):
            diffs += _holds(v, now[k], f"{where}{k}.")
        elif now.get(k) != v:
            diffs.append(f"{where}{k}: {v!r} then, {now.get(k)!r} now")
    return diffs


def test_it_is_the_committed_config_and_every_point_finished(doc):
    from treesim.jsonio import json_ready

    cfg = load_sweep(ROOT / "benchmarks" / "sweeps" / "presets.toml")
    # the designs are the config's, setting for setting (no stale sweep under a changed
    # file); compared by settings, not by key, since a parameter added later with a
    # default that keeps the old behaviour changes every key
    assert len(doc["designs"]) == len(cfg.designs)
    for old, d in zip(doc["designs"], cfg.designs, strict=True):
        assert old["given"] == json_ready(d.given) and old["labels"] == list(d.labels)
        assert _holds(old["parameters"], json_ready(d.params.to_dict())) == [], old["index"]
    rows = doc["rows"]
    want = {(t.id, d.index) for t in cfg.trees for d in cfg.designs}
    assert {(r["tree"], r["design"]) for r in rows} == want
    assert len(rows) >= 30 and len(doc["parameters"]) >= 3
    assert all(r["status"] == "ok" for r in rows), [r["id"] for r in rows if r["status"] != "ok"]
    kinds = [t["kind"] for t in doc["trees"]]
    assert kinds.count("procedural") >= 2 and "cloud" in kinds
    assert doc["tolerance"]["tolerance_m"] == cfg.tolerance_m


def test_its_table_is_its_rows(doc):
    # sweep.csv and sweep.json are written from the same rows: neither was edited apart
    with open(OUT / "sweep.csv", newline="", encoding="utf-8") as fh:
        table = list(csv.DictReader(fh))
    assert list(table[0]) == doc["columns"]
    want = [{c: str(_csv_value(r.get(c))) for c in doc["columns"]} for r in doc["rows"]]
    assert table == want


def test_its_page_shows_the_fronts(doc):
    page = (OUT / "sweep.html").read_text(encoding="utf-8")
    assert "Pareto front" in page
    assert len(re.findall(r'src="data:image/png;base64,', page)) >= 5
    assert not re.search(r"""(src|href)=["'](https?:|//)""", page)
    assert all(doc["fronts"][f["key"]] for f in doc["figures"])


def test_the_preset_tables_are_generated_from_it(doc):
    page = preset_table.PAGE.read_text(encoding="utf-8")
    assert preset_table.replace_between(page, preset_table.markdown(doc)) == page, (
        "docs/validation.md's preset table is not the committed sweep's: "
        "run python benchmarks/preset_table.py"
    )
    txt = (ROOT / "pipeline" / "data" / "preset_measurements.txt").read_text(encoding="utf-8")
    assert txt == preset_table.text(doc)
    for name in ("draft", "standard", "fine"):
        assert f"| `{name}` |" in page
