"""Faults that must not be 500s nor leave work outside the data folder (issue 24, part 2).

Each test reproduces one fault the issue lists: a zip bomb, a full disk, ...; the oracle
is the limit or status the issue asks for, not anything the code computed.
"""

from __future__ import annotations

import io
import zipfile
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

import treesim.service.plots as plots
from treesim.errors import ResourceLimitError
from treesim.service.app import create_app
from treesim.service.settings import Settings

PROBLEM = "application/problem+json"
LIMIT = 200_000
_TOML = 'radius_m = 5.0\ntrees = "trees.csv"\n'
_CSV = "tree_id,x_m,y_m,species\n1,1.0,0.0,sapling\n"


def _bomb(inflated: int) -> bytes:
    """A small zip whose ``zeros.bin`` inflates to ``inflated`` bytes."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("plot.toml", _TOML)
        z.writestr("trees.csv", _CSV)
        z.writestr("zeros.bin", b"\0" * inflated)
    return buf.getvalue()


def _files(root: Path) -> list[Path]:
    return sorted(p for p in root.rglob("*") if p.exists()) if root.exists() else []


@pytest.fixture
def app_settings(tmp_path) -> Settings:
    return Settings(
        data_dir=tmp_path / "data",
        workers=0,
        api_token=None,
        database_url=None,
        poll_interval_s=0.2,
        max_upload_bytes=LIMIT,
    )


@pytest.fixture
def watched_tmp(tmp_path, monkeypatch) -> Path:
    """The system temp folder, as the app and its spawned inspector see it."""
    d = tmp_path / "systemp"
    d.mkdir()
    monkeypatch.setenv("TMPDIR", str(d))
    return d


def _problem(r, status: int) -> dict:
    assert r.status_code == status, r.text
    assert r.headers["content-type"].startswith(PROBLEM), r.headers
    body = r.json()
    assert body["status"] == status
    assert body["type"].startswith("/problems#"), body
    return body


# -- 1. plot archives inspected inside the data folder, streamed within the limit ---------------
def test_a_zip_bomb_is_refused_and_nothing_lands_outside_the_data_folder(app_settings, watched_tmp):
    bomb = _bomb(500 * LIMIT)  # 100 MB of zeros in a ~100 kB zip
    assert len(bomb) < LIMIT
    with TestClient(create_app(app_settings)) as client:
        body = _problem(client.post("/v1/uploads?filename=bomb.zip", content=bomb), 422)
    assert "unpacks to" in body["detail"]
    assert _files(watched_tmp) == []  # the system temp folder was never used
    data = app_settings.data_dir
    left = [p for p in _files(data) if p.is_file() and p.name != "treesim.db"]
    assert [p for p in left if "treesim-plot-" in str(p) or p.suffix == ".part"] == []


def test_a_plot_archive_is_unpacked_beside_it_not_in_the_system_temp_folder(tmp_path, monkeypatch):
    data = tmp_path / "data" / "tmp"
    data.mkdir(parents=True)
    archive = data / "x.part"
    archive.write_bytes(_bomb(10))
    where: list[Path] = []
    real = plots.tempfile.TemporaryDirectory

    def spy(*args, **kwargs):
        where.append(Path(kwargs["dir"]))
        return real(*args, **kwargs)

    monkeypatch.setattr(plots.tempfile, "TemporaryDirectory", spy)
    info = plots.inspect_plot_archive(archive, "x.zip", max_bytes=LIMIT)
    assert (info["kind"], info["n_trees"]) == ("plot", 1)
    assert where == [data.resolve()]
    assert sorted(p.name for p in data.iterdir()) == ["x.part"]  # removed after


def test_a_lying_archive_never_puts_more_than_the_limit_on_disk(tmp_path, monkeypatch):
    """An archive whose directory declares tiny sizes (so the declared total passes) but
    whose member inflates far beyond the limit: the streamed counter stops it, and the bytes
    on disk never exceed the limit (counted at every write, not timed)."""
    archive = tmp_path / "bomb.zip"
    archive.write_bytes(_bomb(50 * LIMIT))
    real_infolist = zipfile.ZipFile.infolist
    real_init = zipfile.ZipExtFile.__init__

    def lying_infolist(self):
        infos = real_infolist(self)
        for i in infos:
            i.file_size = 1  # what a lying (or zip64-confused) directory declares
        return infos

    def unbounded_init(self, *args, **kwargs):
        real_init(self, *args, **kwargs)
        self._left = 1 << 40  # a reader that trusts the stream, not the directory

    monkeypatch.setattr(zipfile.ZipFile, "infolist", lying_infolist)
    monkeypatch.setattr(zipfile.ZipExtFile, "__init__", unbounded_init)
    on_disk = [0]
    peak = [0]

    class Counting(io.FileIO):
        def write(self, b):
            n = super().write(b)
            on_disk[0] += n
            peak[0] = max(peak[0], on_disk[0])
            return n

    monkeypatch.setattr(plots, "open", lambda p, mode="r": Counting(p, mode[0]), raising=False)
    work = tmp_path / "work"
    work.mkdir()
    with pytest.raises(ResourceLimitError, match="unpacks to more than"):
        plots.inspect_plot_archive(archive, "bomb.zip", max_bytes=LIMIT, work_dir=work)
    assert 0 < peak[0] <= LIMIT
    assert list(work.iterdir()) == []
