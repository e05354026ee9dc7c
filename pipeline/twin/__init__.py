"""A field plot becomes a digital twin (``treesim plot from-cloud``); see :mod:`.core`.

:func:`plot_from_cloud` runs the stages (ground and DTM, stems, trees, a QSM per tree, the
twin); :func:`plots_from_clouds` (:mod:`.many`) makes the twins of many plots, one after
another, resumably; :mod:`.report` draws its report; :mod:`.result` holds what it writes.
"""

from __future__ import annotations

from .core import (
    UNITS,
    TwinParams,
    declared_units,
    finished_twin,
    plot_from_cloud,
    stand_on_ground,
)
from .many import PLOT_COLUMNS, PLOTS_FILES, PlotsResult, plots_from_clouds
from .result import TWIN_FILES, TwinResult

__all__ = [
    "PLOTS_FILES",
    "PLOT_COLUMNS",
    "TWIN_FILES",
    "UNITS",
    "PlotsResult",
    "TwinParams",
    "TwinResult",
    "declared_units",
    "finished_twin",
    "plot_from_cloud",
    "plots_from_clouds",
    "stand_on_ground",
]
