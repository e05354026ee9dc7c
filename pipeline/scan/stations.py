"""Where the scanner stands: :class:`Station`, ring layouts and the station rule.

Angles are in degrees, distances in metres. The scanner frame has x along the
station's heading, z up; azimuth is measured counter-clockwise from x in the
horizontal plane, elevation up from the horizontal plane.

**The station rule** (:func:`stations_for`). Unless ``ScanParams.distance_m`` is given,
the ``n_stations`` stations stand evenly on a circle around the centre of the scene's
bounding box, the first on +x, at the horizontal distance
``max(min_distance_m, 1.5 × crown diameter, 0.5 × height)`` (default ``min_distance_m``
5 m), ``height_m`` (1.5 m) above the scene's lowest point. The crown diameter is the mean
of the scene's x and y extents and the height its z extent: 1.5 crown diameters from the
centre keeps the whole crown in front of the scanner at about one crown diameter from its
edge, and half the height keeps the top below ~63° elevation (the vertical field of view
reaches 90°, but resolution on the crown top falls with range); 5 m is a usual minimum for
small trees.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import InvalidParameterError
from ..params import ScanParams
from ..params._fields import finite


@dataclass(frozen=True, kw_only=True)
class Station:
    """A scanner position and orientation.

    Parameters
    ----------
    position_m : (3,) float
        The scanner's optical centre in the scene's coordinates (may be georeferenced).
    heading_deg : float
        Rotation of the scanner frame about z (azimuth 0 points along it).
    pitch_deg, roll_deg : float
        Tilt of the scanner about its y and x axes (0 for a levelled instrument).

    Examples
    --------
    >>> import treesim as ts
    >>> ts.Station(position_m=(0.0, -10.0, 1.5), heading_deg=90.0).position_m
    (0.0, -10.0, 1.5)
    """

    position_m: tuple[float, float, float]
    heading_deg: float = 0.0
    pitch_deg: float = 0.0
    roll_deg: float = 0.0

    def __post_init__(self) -> None:
        pos = tuple(float(v) for v in self.position_m)
        if len(pos) != 3 or not all(math.isfinite(v) for v in pos):
            raise InvalidParameterError(
                f"station position must be three finite numbers, got {self.position_m!r}"
            )
        object.__setattr__(self, "position_m", pos)
        for name in ("heading_deg", "pitch_deg", "roll_deg"):
            finite(name, getattr(self, name))

    @property
    def position(self) -> np.ndarray:
        """Position as a (3,) float64 array."""
        return np.asarray(self.position_m, dtype=np.float64)

    @property
    def rotation(self) -> np.ndarray:
        """(3, 3) float64 matrix taking scanner-frame vectors to scene-frame vectors."""
        h, p, r = (math.radians(a) for a in (self.heading_deg, self.pitch_deg, self.roll_deg))
        rz = np.array([[math.cos(h), -math.sin(h), 0], [math.sin(h), math.cos(h), 0], [0, 0, 1]])
        ry = np.array([[math.cos(p), 0, math.sin(p)], [0, 1, 0], [-math.sin(p), 0, math.cos(p)]])
        rx = np.array([[1, 0, 0], [0, math.cos(r), -math.sin(r)], [0, math.sin(r), math.cos(r)]])
        return rz @ ry @ rx

    def to_dict(self) -> dict[str, object]:
        return {
            "position_m": list(self.position_m),
            "heading_deg": self.heading_deg,
            "pitch_deg": self.pitch_deg,
            "roll_deg": self.roll_deg,
        }


def ring_layout(
    n: int,
    *,
    distance_m: float,
    height_m: float,
    centre_xy: Sequence[float],
    base_z_m: float = 0.0,
    start_angle_deg: float = 0.0,
) -> list[Station]:
    """``n`` stations evenly spaced on a circle around a centre.

    Parameters
    ----------
    n : int
        Number of stations (3 gives the classic three scans 120° apart).
    distance_m : float
        Horizontal distance from the centre to each station.
    height_m : float
        Instrument height above ``base_z_m`` (the scene's ground or stem base).
    centre_xy : (2,) float
        Centre of the ring, in scene coordinates.
    base_z_m : float
        Height of the ground (or stem base) the instrument stands on.
    start_angle_deg : float
        Polar angle of the first station, counter-clockwise from +x.

    Examples
    --------
    >>> import treesim as ts
    >>> stations = ts.ring_layout(3, distance_m=10.0, height_m=1.5, centre_xy=(0.0, 0.0))
    >>> [tuple(round(v, 2) for v in s.position_m) for s in stations]
    [(10.0, 0.0, 1.5), (-5.0, 8.66, 1.5), (-5.0, -8.66, 1.5)]
    """
    if int(n) != n or n < 1:
        raise InvalidParameterError(f"the number of stations must be a positive integer, got {n}")
    if not math.isfinite(distance_m) or distance_m <= 0:
        raise InvalidParameterError(f"distance_m must be > 0, got {distance_m}")
    finite("height_m", height_m)
    cx, cy = (float(v) for v in centre_xy)
    out = []
    for k in range(int(n)):
        a = math.radians(start_angle_deg + 360.0 * k / n)
        out.append(
            Station(
                position_m=(
                    cx + distance_m * math.cos(a),
                    cy + distance_m * math.sin(a),
                    base_z_m + height_m,
                )
            )
        )
    return out


def ring_around(
    bounds: np.ndarray,
    n: int,
    *,
    distance_m: float,
    height_m: float,
    start_angle_deg: float = 0.0,
) -> list[Station]:
    """``n`` stations on a ring around a scene: centred on its bounds in x and y, at
    ``height_m`` above its lowest point (the usual field layout).

    Parameters
    ----------
    bounds : (2, 3) float
        Min and max corners of the scene (``Scene.bounds``).
    """
    lo, hi = np.asarray(bounds, dtype=np.float64)
    return ring_layout(
        n,
        distance_m=distance_m,
        height_m=height_m,
        centre_xy=(0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1])),
        base_z_m=float(lo[2]),
        start_angle_deg=start_angle_deg,
    )


def station_distance_m(
    crown_diameter_m: float, height_m: float, *, min_distance_m: float = 5.0
) -> float:
    """The rule's station distance: ``max(min_distance_m, 1.5 × crown diameter,
    0.5 × height)``."""
    return float(max(min_distance_m, 1.5 * crown_diameter_m, 0.5 * height_m))


def stations_for(bounds: np.ndarray, params: ScanParams) -> tuple[list[Station], dict[str, Any]]:
    """The ring of stations ``params`` asks for around a scene, and how it was chosen.

    Parameters
    ----------
    bounds : (2, 3) float
        Min and max corners of the scene (``Scene.bounds``).
    params : ScanParams
        ``n_stations``, ``distance_m`` (``None``: the station rule), ``min_distance_m``,
        ``height_m`` and ``start_angle_deg``.

    Returns
    -------
    stations : list of Station
    rule : dict
        ``distance_m``, ``rule`` (in words), ``crown_diameter_m``, ``height_m``,
        ``n_stations`` and ``height_above_base_m``: written into ``scan.json``.
    """
    lo, hi = np.asarray(bounds, dtype=np.float64)
    ext = hi - lo
    crown_d = float(0.5 * (ext[0] + ext[1]))
    height = float(ext[2])
    if params.distance_m is not None:
        distance, rule = float(params.distance_m), "given"
    else:
        distance = station_distance_m(crown_d, height, min_distance_m=params.min_distance_m)
        rule = (
            f"max({params.min_distance_m:g} m, 1.5 × crown diameter {crown_d:.3g} m, "
            f"0.5 × height {height:.3g} m)"
        )
    stations = ring_around(
        bounds,
        params.n_stations,
        distance_m=distance,
        height_m=params.height_m,
        start_angle_deg=params.start_angle_deg,
    )
    return stations, {
        "distance_m": distance,
        "rule": rule,
        "crown_diameter_m": crown_d,
        "height_m": height,
        "n_stations": params.n_stations,
        "height_above_base_m": params.height_m,
    }
