"""Write issue 21's generated plot-column tree (``tests/reconstruct/fieldcolumn.py``) as a
point cloud file with its truth beside it, to run ``treesim reconstruct`` on it by hand.

Run from the repository root:

    python scripts/field_column.py conifer /tmp/fieldcolumn/conifer
    python scripts/field_column.py broadleaf /tmp/fieldcolumn/broadleaf --format ply
    treesim reconstruct /tmp/fieldcolumn/conifer/column.laz -o /tmp/fieldcolumn/conifer/rec

The folder gets ``column.laz`` (or ``.ply``; per point the field ``part``: the index into
``part_names`` of the metadata / truth: ground, litter, shrub, neighbour, target_wood,
target_leaf) and ``truth.json`` (the target's exact figures: ``dbh_m``, ``height_m``,
``volume_stem_m3``, ``volume_total_m3``, ...; and how the scene was made). About a minute
per kind on 2 cores.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.reconstruct.fieldcolumn import (  # noqa: E402
    DEFAULT_STEP_DEG,
    KINDS,
    PARTS,
    field_column,
)
from treesim.cloud import Cloud  # noqa: E402
from treesim.errors import TreesimError  # noqa: E402
from treesim.io import write_cloud  # noqa: E402
from treesim.jsonio import write_json  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("kind", choices=list(KINDS), help="the stand and its target tree")
    ap.add_argument("out_dir", type=Path, help="folder for the cloud and truth.json")
    ap.add_argument("--seed", type=int, default=0, help="seed of the whole scene (default 0)")
    ap.add_argument(
        "--step-deg",
        type=float,
        default=DEFAULT_STEP_DEG,
        help=f"scanner angular step in degrees (default {DEFAULT_STEP_DEG})",
    )
    ap.add_argument("--format", choices=("laz", "ply"), default="laz", help="cloud format")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    try:
        truth, points, labels = field_column(args.kind, args.seed, args.step_deg)
        args.out_dir.mkdir(parents=True, exist_ok=True)
        truth = {**truth, "part_names": list(PARTS)}
        cloud = Cloud(
            points,
            fields={"part": labels.astype(np.uint8)},
            metadata={"source": "tests/reconstruct/fieldcolumn.py", "part_names": list(PARTS)},
        )
        path = write_cloud(args.out_dir / f"column.{args.format}", cloud)
        write_json(args.out_dir / "truth.json", truth)
    except (TreesimError, ValueError, RuntimeError, OSError) as exc:
        print(f"field_column: {exc}", file=sys.stderr)
        return 1
    print(
        f"{path} ({len(points)} points, {time.perf_counter() - t0:.0f} s); truth: "
        f"DBH {truth['dbh_m'] * 100:.2f} cm, height {truth['height_m']:.2f} m, stem "
        f"{truth['volume_stem_m3'] * 1e3:.1f} L, total {truth['volume_total_m3'] * 1e3:.1f} L"
    )
    print("points per part:", truth["part_points"])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
