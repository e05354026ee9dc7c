"""The trade, measured: a grid of settings run on trees, timed, and scored.

``treesim sweep CONFIG -o OUTDIR`` (:func:`run_sweep`) runs every design of a grid (or a
list) of settings on one or more trees and records, per **point** (one tree × one design,
one cached run of :func:`treesim.run_tree`):

* cost: wall time of the loop and of each stage (imports and first use of open3d and
  matplotlib excluded), peak resident memory of the process that ran it (a fresh process
  per point, so the peak is the point's own), simulated points and rays cast;
* accuracy: AVOHD both ways (accuracy: simulated → reference; completeness: reference →
  simulated; mean and p95) and coverage against the scanned mesh (``vs_mesh``), the field
  cloud (``vs_field``) and, for procedural trees, the truth mesh (``vs_truth``), all at one
  τ for the whole sweep; DBH, height and volume of the reconstruction against the truth;
* the Pareto front, per tree, of time against each accuracy figure.

A sweep file (TOML)::

    description = "what this sweep asks"
    preset = "standard"            # the run preset every design starts from
    repeat = 1                     # timings per point (--repeat overrides)
    tolerance_m = 0.01             # τ of every coverage figure, or
    # tolerance_factor = 3.0       # τ = 3 × the coarsest reference cloud's point spacing

    [base]                         # settings every design gets
    "compare.max_samples" = 500000

    [reference]                    # how procedural trees are scanned into field clouds
    n_stations = 3                 # ScanParams fields; resolution_deg sets both steps
    resolution_deg = 0.04
    [reference.scanner]
    range_noise_sd_m = 0.002

    [[tree]]
    species = "sapling"            # a procedural species (exact truth); seed, leaves, facets
    [[tree]]
    bundled = "coffee_tree"        # the tree bundled with treesim
    [[tree]]
    cloud = "clouds/oak.laz"       # a field cloud, relative to this file; id = "..." renames

    [grid]                         # the cartesian product of these lists
    resolution_deg = [0.02, 0.04, 0.08]
    facets = [16, 32]
    scan.scanner.beam_divergence_mrad = [0.0, 0.35]

    [[point]]                      # and/or single designs
    preset = "draft"               # a design may start from another preset
    label = "draft"

Names are the flat settings (``resolution_deg``, ``stations``, ``distance_m``,
``facets``, ``voxel_m``, ``depth``, ``method``, ...) or dotted paths of the parameter
model (``scan.scanner.subrays``, ``reconstruct.qsm.slice_m``); every name and value is
checked before anything runs. Designs with the same effective settings are one design
(their labels merged).

The output folder::

    sweep.csv, sweep.json     one row per point: every swept parameter and every figure;
                              sweep.json also holds the config, τ, the trees, every
                              design's full settings, the machine and the Pareto fronts
    sweep.html                self-contained page: accuracy against time with the fronts,
                              each parameter alone, timing noise, the table
    points/<tree>-<key>/      each point's run_tree outputs, vs_truth/, result.json (last)
    points/<id>.failed/       a failed point's error.json and point.log
    trees/<tree>/             the trees made ready: field.ply, truth.ply, tree.json

**Resumable.** A point's hash covers its tree's content (a field cloud's SHA-256; a
procedural tree's species, seed, facets and reference design), its effective settings
(τ included) and treesim's version; a point whose ``result.json`` holds the same hash is
not run again. Point folders are named by tree and design key, so editing the grid keeps
the points that stay. Failed points are tried again. ``--fresh`` runs everything again
(treesim's version does not change with every edit of the code).

**Repeats.** ``--repeat N`` times each point N times, each in a fresh process; the first
run's outputs are kept, the others give timings only (and are checked to give the same
figures: ``repeatable``). A finished point with fewer than N timings gets only the
missing ones, so raising ``--repeat`` re-times without re-scoring; time is the mean of
the repeats, with min, max and standard deviation beside it.
"""

from __future__ import annotations

from .config import Design, SweepConfig, TreeSpec, known_names, load_sweep, parse_sweep
from .engine import FIGURES, SweepResult, fronts_of, machine, run_sweep, sweep_columns
from .pareto import dominates, pareto_front

__all__ = [
    "FIGURES",
    "Design",
    "SweepConfig",
    "SweepResult",
    "TreeSpec",
    "dominates",
    "fronts_of",
    "known_names",
    "load_sweep",
    "machine",
    "parse_sweep",
    "pareto_front",
    "run_sweep",
    "sweep_columns",
]
