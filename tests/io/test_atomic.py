"""``treesim.atomic.atomic_path`` and the JSON writer on it: concurrent writers of one path
never tear or lose the file, every writer has a temporary file of its own, and nothing is
left behind."""

from __future__ import annotations

import json
import os
import stat
import threading
from pathlib import Path

import pytest

from treesim.atomic import atomic_path, write_text
from treesim.errors import InputFormatError
from treesim.jsonio import write_json

#: Writers, rounds each, and the lines of one payload (written a line at a time, flushed,
#: so that two writers sharing a temporary file would interleave).
WRITERS, ROUNDS, LINES = 4, 25, 400


def payload(writer: int, round_: int) -> str:
    """A file only this writer's round writes, with its own last line as a checksum."""
    body = "".join(f"writer {writer} round {round_} line {i:04d}\n" for i in range(LINES))
    return body + f"end {writer} {round_} {len(body)}\n"


def is_whole(text: str) -> bool:
    lines = text.splitlines(keepends=True)
    if not lines or not lines[-1].startswith("end "):
        return False
    _, w, r, n = lines[-1].split()
    return text == payload(int(w), int(r)) and len(text) - len(lines[-1]) == int(n)


def temporaries(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.endswith(".tmp"))


def _run_concurrently(path: Path, write_one) -> list[str]:
    """Start the writers and a reader; return what went wrong (torn or missing reads,
    writers' exceptions)."""
    problems: list[str] = []
    start = threading.Barrier(WRITERS + 1)
    done = threading.Event()

    def writer(w: int) -> None:
        start.wait()
        try:
            for r in range(ROUNDS):
                write_one(w, r)
        except Exception as exc:  # reported below, the test fails on it
            problems.append(f"writer {w}: {type(exc).__name__}: {exc}")

    def reader() -> None:
        start.wait()
        while not done.is_set():
            try:
                text = path.read_text(encoding="utf-8")
            except FileNotFoundError:
                problems.append("the file went missing between two writes")
                continue
            if not is_whole(text):
                problems.append(f"a torn file of {len(text)} characters")

    path.write_text(payload(-1, -1), encoding="utf-8")  # a whole file from the start
    threads = [threading.Thread(target=writer, args=(w,)) for w in range(WRITERS)]
    watcher = threading.Thread(target=reader)
    for t in [*threads, watcher]:
        t.start()
    for t in threads:
        t.join(120)
    done.set()
    watcher.join(120)
    return problems


def test_concurrent_writers_of_one_path_never_tear_or_lose_it(tmp_path):
    path = tmp_path / "summary.txt"

    def write_one(w: int, r: int) -> None:
        with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8") as fh:
            for line in payload(w, r).splitlines(keepends=True):
                fh.write(line)
                fh.flush()  # a system call per line: writers sharing a file would mix

    problems = _run_concurrently(path, write_one)
    assert problems == [], problems[:5]
    final = path.read_text(encoding="utf-8")
    assert is_whole(final) and not final.startswith("writer -1")  # a writer's, whole
    assert temporaries(tmp_path) == []


def test_concurrent_json_writers_of_one_path(tmp_path):
    path = tmp_path / "result.json"
    seen: set[tuple[int, int]] = set()

    def write_one(w: int, r: int) -> None:
        write_json(path, {"writer": w, "round": r, "text": payload(w, r)})
        data = json.loads(path.read_text(encoding="utf-8"))  # whatever is there is whole
        assert data["text"] == payload(data["writer"], data["round"])
        seen.add((data["writer"], data["round"]))

    path.write_text("{}", encoding="utf-8")
    problems: list[str] = []
    threads = []
    for w in range(WRITERS):

        def run(w: int = w) -> None:
            try:
                for r in range(ROUNDS):
                    write_one(w, r)
            except Exception as exc:
                problems.append(f"{type(exc).__name__}: {exc}")

        threads.append(threading.Thread(target=run))
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    assert problems == [], problems[:5]
    data = json.loads(path.read_text(encoding="utf-8"))
    assert data["text"] == payload(data["writer"], data["round"])
    assert seen and temporaries(tmp_path) == []


def test_each_writer_gets_a_temporary_file_of_its_own(tmp_path):
    path = tmp_path / "a.csv"
    with atomic_path(path) as first, atomic_path(path) as second:
        assert first != second and first.parent == second.parent == tmp_path
        for tmp in (first, second):
            assert tmp.is_file() and tmp.stat().st_size == 0  # reserved, empty
            assert tmp.name.startswith(".a.csv.") and tmp.suffix == ".tmp"
        first.write_text("first\n")
        second.write_text("second\n")
    assert path.read_text() == "first\n"  # the outer block finished last
    assert temporaries(tmp_path) == []


def test_a_failed_write_leaves_the_destination_and_no_temporary(tmp_path):
    path = write_text(tmp_path / "keep.txt", "old\n")
    with pytest.raises(RuntimeError, match="half way"):
        with atomic_path(path) as tmp:
            tmp.write_text("new, partial")
            raise RuntimeError("half way")
    assert path.read_text() == "old\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.txt"]


def test_a_missing_folder_is_an_os_error_and_a_clear_json_error(tmp_path):
    with pytest.raises(FileNotFoundError):
        with atomic_path(tmp_path / "nowhere" / "x.txt"):
            pytest.fail("yielded a temporary file in a folder that does not exist")
    with pytest.raises(InputFormatError, match=r"could not write .*nowhere"):
        write_json(tmp_path / "nowhere" / "x.json", {"a": 1})


@pytest.mark.skipif(os.name != "posix", reason="POSIX permission bits")
def test_the_output_has_the_permissions_of_an_ordinary_file(tmp_path):
    # not mkstemp's 0o600: the temporary file becomes the output, which others may read
    plain = tmp_path / "plain.txt"
    plain.write_text("x")
    made = write_text(tmp_path / "made.txt", "x")
    assert stat.S_IMODE(made.stat().st_mode) == stat.S_IMODE(plain.stat().st_mode)


def test_json_writer_options(tmp_path):
    import numpy as np

    p = write_json(tmp_path / "a.json", {"x": np.float64(1.5), "n": float("nan"), "p": Path("q")})
    assert json.loads(p.read_text()) == {"x": 1.5, "n": None, "p": "q"}
    assert p.read_text().endswith("\n") and "\n  " in p.read_text()  # indented
    with pytest.raises(TypeError):
        write_json(tmp_path / "b.json", {"s": {1, 2}})
    assert not (tmp_path / "b.json").exists() and temporaries(tmp_path) == []
    q = write_json(tmp_path / "c.json", {"s": {1}}, default=str)
    assert json.loads(q.read_text()) == {"s": "{1}"}
