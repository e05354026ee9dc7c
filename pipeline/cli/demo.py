"""``treesim demo``: the whole loop on the bundled sample tree."""

from __future__ import annotations

import argparse
from pathlib import Path

from ._outputs import output_folder
from .progress import progress_printer
from .run import print_run_summary

SAMPLE_DIR = Path(__file__).resolve().parent.parent / "data" / "coffee_tree"
#: The bundled tree's TreeQSM model, shown beside the reconstruction.
SAMPLE_QSM = SAMPLE_DIR / "QSM_treeqsm_v2.4.1_cylinders.csv"


def cmd_demo(args: argparse.Namespace) -> int:
    """Run the whole loop (``run_tree``) on the bundled coffee tree's field cloud."""
    from ..params import run_preset
    from ..run import run_tree

    output_folder(args.output)
    cloud = SAMPLE_DIR / "cloud.txt"
    print(
        "bundled sample: Kentucky coffee tree (rTwig), leaf-off TLS cloud; reconstruct, "
        "scan from three stations, compare with the mesh and the field cloud, report; "
        "its TreeQSM model is the reference the reconstruction is set beside"
    )
    result = run_tree(
        cloud,
        run_preset(),
        Path(args.output),
        name="coffee_tree",
        reference_qsm=SAMPLE_QSM,
        progress=progress_printer(label="demo"),
    )
    print_run_summary(result)
    print(f"\ndemo output is in {result.outdir.resolve()}/; open the report in a browser:")
    print(f"{result.report_html.resolve()}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``demo`` to ``treesim``'s parser."""
    dm = sub.add_parser(
        "demo",
        help="run the whole loop on the bundled sample tree and print the report's path",
    )
    dm.add_argument("-o", "--output", default="out/demo", help="output folder (default out/demo)")
    dm.set_defaults(func=cmd_demo)
