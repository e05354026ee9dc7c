"""LocalFrame: the one place where coordinate precision is handled.

Open3D casts rays and measures distances in float32. At georeferenced coordinates
(x ~ 5e5, y ~ 5e6) float32 has a spacing of 0.03-0.5 m, which collapses triangles and
makes rays miss. Every geometry therefore enters the heavy numerical code through a
:class:`LocalFrame`: a float64 origin near the data is subtracted (in float64) before
anything is converted to float32, and results are shifted back in float64.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import EmptyInputError, InvalidGeometryError


@dataclass(frozen=True)
class LocalFrame:
    """A float64 origin shift.

    Parameters
    ----------
    origin : (3,) float
        The point, in input coordinates (m), that becomes (0, 0, 0) locally.

    Examples
    --------
    >>> import numpy as np
    >>> import treesim as ts
    >>> frame = ts.LocalFrame((500000.0, 4000000.0, 250.0))
    >>> frame.to_local(np.array([[500001.0, 4000002.0, 251.5]]))
    array([[1. , 2. , 1.5]])
    """

    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @classmethod
    def around(cls, points: np.ndarray) -> LocalFrame:
        """A frame whose origin is the centre of the axis-aligned bounds of ``points``.

        The origin is rounded to whole millimetres so that it prints and serialises
        exactly; the rounding moves it by at most 0.5 mm, which is immaterial.
        """
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if len(pts) == 0:
            raise EmptyInputError("cannot build a local frame around zero points")
        if not np.isfinite(pts).all():
            raise InvalidGeometryError("coordinates contain NaN or infinite values")
        centre = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
        centre = np.round(centre, 3)
        return cls(origin=(float(centre[0]), float(centre[1]), float(centre[2])))

    @property
    def origin_array(self) -> np.ndarray:
        """The origin as a (3,) float64 array."""
        return np.asarray(self.origin, dtype=np.float64)

    def to_local(self, points: np.ndarray) -> np.ndarray:
        """Input coordinates -> local coordinates, (n, 3) float64."""
        return np.asarray(points, dtype=np.float64) - self.origin_array

    def to_global(self, points: np.ndarray) -> np.ndarray:
        """Local coordinates -> input coordinates, (n, 3) float64."""
        return np.asarray(points, dtype=np.float64) + self.origin_array
