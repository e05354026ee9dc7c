"""Work done ahead so that no scan pays it: the edge beam model's compiled kernels.

:func:`warm_edge_model` runs one coarse edge scan, which compiles numba's kernels
(:mod:`treesim.scan._edge_jit`) into its cache, or loads them from it.
"""

from __future__ import annotations

import time

import numpy as np

from ..models import generate_tree
from ..params import ScannerSpec
from ..scene import MeshPart, Scene
from .stations import ring_around
from .trace import scan

__all__ = ["warm_edge_model"]


def warm_edge_model() -> float:
    """Compile the edge model's kernels (:mod:`treesim.scan._edge_jit`), or load them
    from numba's cache, with one coarse edge scan of a generated aspen: numba compiles
    each kernel the first time a process calls it and caches it (in ``NUMBA_CACHE_DIR``
    where it is set, else beside the package, else in numba's user-wide cache: the first
    of them that the user can write), once per install; a process that finds them cached
    loads them in about half a second (``benchmarks/bench_scan.py`` measures both: the
    compilation's figure is in ``docs/validation.md``). The docker image and
    ``scripts/setup.sh`` call it so that no scan pays the compilation.

    Returns
    -------
    float
        The seconds it took.

    Examples
    --------
    >>> warm_edge_model() > 0
    True
    """
    t0 = time.perf_counter()
    v, f, _ = generate_tree("aspen", seed=0).mesh(facets=8)
    scene = Scene([MeshPart(vertices=v, faces=f, label="wood", name="aspen")])
    stations = ring_around(np.asarray(scene.bounds), 1, distance_m=15.0, height_m=0.0)
    spec = ScannerSpec(
        horizontal_resolution_deg=0.1,
        vertical_resolution_deg=0.1,
        beam_divergence_mrad=3.0,
        subrays=19,
        return_mode="all",
        beam_sampling="edge",
    )
    scan(scene, stations, spec)
    return time.perf_counter() - t0
