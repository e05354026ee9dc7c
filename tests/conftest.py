"""Shared fixtures: analytic shapes with exact answers, and the path to shared data."""

from __future__ import annotations

import re
import signal
from pathlib import Path

import numpy as np
import pytest

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
#: The sample data the repository bundles (``pipeline/data``): in every clone, never skipped.
#: Its coffee_tree/cloud.txt and QSM_treeqsm_v2.4.1_cylinders.csv are byte-identical to
#: ../shared/data/trees/coffee_tree's (checked with cmp when the tests switched to them).
BUNDLED_DATA = Path(__file__).resolve().parents[1] / "pipeline" / "data"


def pytest_configure(config: pytest.Config) -> None:
    """Ctrl-C reaches the tests however the suite was started: a shell starts a background
    job (``make test &``, nohup) with SIGINT ignored, which every test process inherits
    and passes on to the commands it starts, and the tests of what Ctrl-C does then saw
    commands run to their end (exit 0 for 130). Python's own handler is put back (the
    pytest-xdist workers run this too)."""
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


#: A progress line a command writes per stage when stderr is not a terminal
#: (``treesim scan: station 2/3 (1.4 s)``); messages start ``treesim: error:`` or
#: ``treesim: warning:``.
PROGRESS_LINE = re.compile(r"^treesim [a-z-]+: .*(\(\d+\.\d s\)|done in \d+\.\d s)$")


def messages(stderr: str) -> list[str]:
    """The non-empty lines of a command's stderr less its progress lines."""
    return [ln for ln in stderr.splitlines() if ln.strip() and not PROGRESS_LINE.match(ln)]


def shared_path(*parts: str) -> Path:
    """A file in ../shared/data, or skip the test with the reason when it is absent."""
    p = SHARED_DATA.joinpath(*parts)
    if not p.exists():
        pytest.skip(f"needs {p} (the project's shared data, not part of a user's clone)")
    return p


def bundled_path(*parts: str) -> Path:
    """A file the repository bundles in pipeline/data (its absence is a failure, not a skip)."""
    p = BUNDLED_DATA.joinpath(*parts)
    assert p.is_file(), f"{p} is part of the repository and missing"
    return p


def cylinder_arrays(
    radius: float = 0.15,
    height: float = 2.0,
    sections: int = 2048,
    base: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> tuple[np.ndarray, np.ndarray]:
    """A closed vertical cylinder (float64 vertices, triangles) standing on ``base``."""
    import trimesh

    m = trimesh.creation.cylinder(radius=radius, height=height, sections=sections)
    v = np.asarray(m.vertices, dtype=np.float64) + np.array([0.0, 0.0, height / 2])
    v = v + np.asarray(base, dtype=np.float64)
    return v, np.asarray(m.faces, dtype=np.int64)


def box_arrays(lo: tuple[float, float, float], hi: tuple[float, float, float]):
    """A closed axis-aligned box (float64 vertices, outward triangles)."""
    import trimesh

    lo_a, hi_a = np.asarray(lo, float), np.asarray(hi, float)
    m = trimesh.creation.box(extents=hi_a - lo_a)
    v = np.asarray(m.vertices, dtype=np.float64) + (lo_a + hi_a) / 2
    return v, np.asarray(m.faces, dtype=np.int64)


@pytest.fixture(scope="session")
def tube_xyz(tmp_path_factory) -> Path:
    """An XYZ cloud of a 5 m tube of constant radius 12 cm: a cylinder (stem form factor
    1.0), never a real stem, so its reconstruction always raises plausibility warnings."""
    from tests.reconstruct.shapes import tube

    pts, _ = tube(radius=0.12, height=5.0, n=20000, noise_m=0.001, seed=0)
    path = tmp_path_factory.mktemp("tube") / "tube.xyz"
    np.savetxt(path, pts, fmt="%.6f")
    return path


def pytest_collection_modifyitems(config, items) -> None:
    """On a pytest-xdist worker, run the test files with slow tests first (most slow tests
    first), then the others (most tests first, as xdist orders files by itself).

    ``make test`` hands out whole files (``--dist loadfile``) in this order
    (``--no-loadscope-reorder``): the long files start early and the many short ones fill
    in at the end, so that no worker idles while the other finishes a long file. Every
    worker collects the same order; a run without xdist keeps the files' own order."""
    if not hasattr(config, "workerinput"):
        return
    n_tests: dict[str, int] = {}
    n_slow: dict[str, int] = {}
    for item in items:
        f = item.nodeid.split("::", 1)[0]
        n_tests[f] = n_tests.get(f, 0) + 1
        n_slow[f] = n_slow.get(f, 0) + (item.get_closest_marker("slow") is not None)
    # sorted() and list.sort() are stable: ties keep the collection's order
    files = sorted(n_tests, key=lambda f: (-n_slow[f], -n_tests[f]))
    rank = {f: k for k, f in enumerate(files)}
    items.sort(key=lambda item: rank[item.nodeid.split("::", 1)[0]])
