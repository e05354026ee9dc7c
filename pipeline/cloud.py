"""Point clouds as treesim passes them between stages."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .errors import EmptyInputError, InvalidGeometryError

#: Hit-part labels and their integer codes (the ``label`` field of simulated clouds).
LABEL_CODES: dict[str, int] = {"other": 0, "wood": 1, "leaf": 2, "ground": 3}
LABEL_NAMES: dict[int, str] = {v: k for k, v in LABEL_CODES.items()}


@dataclass
class Cloud:
    """A point cloud in input coordinates.

    Parameters
    ----------
    points : (n, 3) float64
        Coordinates in metres, in the coordinates of the input (georeferenced or not).
        Stages that hand the data to float32 code shift it through a ``LocalFrame``.
    fields : dict of str -> (n,) array
        Per-point scalar fields (``intensity``, ``station``, ``range_m``, ...).
    metadata : dict
        Anything that describes the cloud as a whole (label names, scanner, source path).

    Examples
    --------
    >>> import numpy as np
    >>> import treesim as ts
    >>> cloud = ts.Cloud(np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 2.0]]))
    >>> len(cloud), cloud.points.dtype
    (2, dtype('float64'))
    """

    points: np.ndarray
    fields: dict[str, np.ndarray] = field(default_factory=dict)
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        pts = np.asarray(self.points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise InvalidGeometryError(f"points must have shape (n, 3), got {pts.shape}")
        self.points = pts
        for name, values in self.fields.items():
            arr = np.asarray(values)
            if arr.shape[:1] != (len(pts),):
                raise InvalidGeometryError(
                    f"field {name!r} has {arr.shape[0] if arr.ndim else 0} values "
                    f"for {len(pts)} points"
                )
            self.fields[name] = arr

    def __len__(self) -> int:
        return len(self.points)

    def validate(self) -> Cloud:
        """Raise if the cloud is empty or has non-finite coordinates; return self."""
        if len(self.points) == 0:
            raise EmptyInputError("the point cloud has no points")
        bad = ~np.isfinite(self.points).all(axis=1)
        if bad.any():
            first = int(np.flatnonzero(bad)[0])
            raise InvalidGeometryError(
                f"{int(bad.sum())} points have NaN or infinite coordinates "
                f"(first at row {first}); clean the input or drop those rows"
            )
        return self

    def subset(self, mask: np.ndarray) -> Cloud:
        """The points selected by a boolean mask or index array, with their fields."""
        return Cloud(
            self.points[mask],
            {k: v[mask] for k, v in self.fields.items()},
            dict(self.metadata),
        )

    @staticmethod
    def concatenate(clouds: list[Cloud]) -> Cloud:
        """Merge clouds; fields present in every cloud are kept."""
        if not clouds:
            return Cloud(np.empty((0, 3)))
        names = set(clouds[0].fields)
        for c in clouds[1:]:
            names &= set(c.fields)
        return Cloud(
            np.concatenate([c.points for c in clouds]),
            {n: np.concatenate([c.fields[n] for c in clouds]) for n in sorted(names)},
            dict(clouds[0].metadata),
        )
