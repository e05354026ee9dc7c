"""What a twin is made of on disk (:data:`TWIN_FILES`) and in memory (:class:`TwinResult`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = ["TWIN_FILES", "TwinResult"]

#: The files a twin folder holds.
TWIN_FILES = {
    "plot": "plot.toml",
    "trees": "trees.csv",
    "dtm": "dtm.asc",
    "labelled": "plot_labelled.laz",
    "json": "from_cloud.json",
    "report": "report.html",
    "map": "map.png",
    "distributions": "dbh_height.png",
}


@dataclass
class TwinResult:
    """What :func:`plot_from_cloud` made.

    Attributes
    ----------
    outdir : Path
    plot_file : Path
        The twin's ``plot.toml``.
    trees : list of dict
        One row per tree in the twin: ``tree_id``, position, slab DBH, QSM figures.
    left_out : list of dict
        ``tree_id`` (or the stem's index), ``reason``.
    warnings : list of str
    figures : dict
        ``from_cloud.json``'s content.

    Examples
    --------
    >>> import treesim as ts
    >>> twin = ts.plot_from_cloud("plot.laz", "twin/")  # doctest: +SKIP
    >>> print(twin.summary_line())  # doctest: +SKIP
    14 trees in the twin, 1 left out
    """

    outdir: Path
    plot_file: Path
    trees: list[dict[str, Any]]
    left_out: list[dict[str, Any]]
    warnings: list[str] = field(default_factory=list)
    figures: dict[str, Any] = field(default_factory=dict)

    def summary_line(self) -> str:
        """One line: trees in the twin, left out, warnings."""
        n = len(self.trees)
        out = len(self.left_out)
        return f"{n} tree{'s' * (n != 1)} in the twin, {out} left out" + (
            f", {len(self.warnings)} warnings" if self.warnings else ""
        )
