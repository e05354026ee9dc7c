"""A field plot becomes a digital twin (``treesim plot from-cloud``); see :mod:`.core`.

:func:`plot_from_cloud` runs the stages (ground and DTM, stems, trees, a QSM per tree, the
twin); :mod:`.report` draws its report; :mod:`.result` holds what it writes.
"""

from __future__ import annotations

from .core import UNITS, TwinParams, declared_units, plot_from_cloud, stand_on_ground
from .result import TWIN_FILES, TwinResult

__all__ = [
    "TWIN_FILES",
    "UNITS",
    "TwinParams",
    "TwinResult",
    "declared_units",
    "plot_from_cloud",
    "stand_on_ground",
]
