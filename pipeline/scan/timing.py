"""When each pulse leaves the scanner: the time of every pulse of a station's scan.

The scanner's mechanics (:meth:`treesim.params.ScannerSpec.mechanics`) are one model:
a head turning about the vertical axis carries a mirror that sweeps the beam through
the vertical field of view, one scan line per mirror cycle, the laser firing evenly
along the cycle (``pulse_rate_hz``); the mirror's unused arc (``mirror_cycle_deg``) is
dead time, and a line-rate limit (``max_line_rate_hz``) can stretch the cycle. The head
steps one column per cycle; a two-sided mirror (``two_sided_mirror``, a FARO Focus)
scans a column and the one opposite in one turn, so the head turns half a turn. The
instruments' figures and their data sheets are in :data:`treesim.params.INSTRUMENTS`.

The same model gives each pulse its time (:func:`pulse_times_s`, from the pulse's grid
line and column, so a windowed or culled scan gives the same pulses the same times) and
the scan's duration (:func:`station_duration_s`), which is also
:meth:`~treesim.params.InstrumentPreset.scan_time_s` and so ``treesim plan``'s field
time. Times never change where a pulse goes: points are the same, bit for bit.

Convention: ``time_s`` is seconds since the station's scan started (its first pulse at
0; every station starts at 0). LAS/LAZ files store the same value in the standard
``gps_time`` (point format 6) as GPS week time (global encoding bit 0 clear), as if
each scan started at the start of a GPS week: CloudCompare shows it as the ``GpsTime``
scalar field, seconds into the station's scan; the ``station`` field tells the stations
apart. All returns of one pulse (beam model) share its time.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..params import ScannerSpec

#: The per-point field that holds each pulse's time (float64 seconds).
TIME_FIELD = "time_s"

#: The time convention, as recorded in a scan's metadata and ``scan.json``.
TIME_CONVENTION = (
    "time_s: seconds since the station's scan started (first pulse at 0, each station "
    "from 0), from the scanner's mechanics; LAS/LAZ gps_time holds the same value as GPS "
    "week time (global encoding bit 0 clear)"
)


class PulseClock:
    """The time of any pulse of one scanner setting (the mechanics computed once).

    Parameters
    ----------
    spec : ScannerSpec
        The scanner's settings, its mechanics included.

    Examples
    --------
    >>> import numpy as np
    >>> from treesim.params import ScannerSpec
    >>> spec = ScannerSpec(
    ...     horizontal_resolution_deg=10.0, vertical_resolution_deg=10.0,
    ...     vertical_fov_deg=(0.0, 40.0), pulse_rate_hz=1000.0,
    ... )
    >>> clock = PulseClock(spec)
    >>> clock(np.array([0, 4, 0]), np.array([0, 0, 1])).tolist()
    [0.0, 0.004, 0.005]
    """

    def __init__(self, spec: ScannerSpec) -> None:
        self.mechanics = spec.mechanics()
        self._half = spec.n_azimuth // 2
        self._front = spec.n_azimuth - self._half

    def __call__(self, lines: np.ndarray, columns: np.ndarray) -> np.ndarray:
        """Seconds since the station's start of pulses (``lines``, ``columns``), float64."""
        m = self.mechanics
        lines = np.asarray(lines, dtype=np.int64)
        cycle = np.asarray(columns, dtype=np.int64)
        pos = lines.astype(np.float64)
        if m.two_sided:
            back = cycle >= self._front
            cycle = np.where(back, cycle - self._half, cycle)
            pos = np.where(back, m.back_offset_pulses - pos, pos)
        return cycle * m.line_period_s + pos * m.pulse_period_s


def pulse_times_s(spec: ScannerSpec, lines: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """The time of pulses, in seconds since the station's scan started.

    Pulse (``line``, ``column``) of a one-sided scanner leaves at
    ``column × line_period_s + line × pulse_period_s``; with a two-sided mirror over a
    full turn, the columns of the second half turn are the back of the first half's
    mirror turns, swept downward from the zenith (see :meth:`ScannerSpec.mechanics
    <treesim.params.ScannerSpec.mechanics>`).

    Parameters
    ----------
    spec : ScannerSpec
        The scanner's settings, its mechanics included.
    lines, columns : (n,) int
        Grid indices of the pulses (the ``scan_line`` and ``scan_column`` fields).

    Returns
    -------
    (n,) float64
        Seconds; the first pulse of the scan is at 0.

    Examples
    --------
    >>> import numpy as np
    >>> from treesim.params import instrument
    >>> spec = instrument("riegl-vz400").spec()
    >>> pulse_times_s(spec, np.array([0, 1, 0]), np.array([0, 0, 1])).round(7).tolist()
    [0.0, 3.3e-06, 0.02]
    """
    return PulseClock(spec)(lines, columns)


def station_duration_s(spec: ScannerSpec) -> float:
    """Seconds one station's scan takes: every line of the field of view, the mirror's
    dead time included (``spec.mechanics().duration_s``).

    Parameters
    ----------
    spec : ScannerSpec

    Returns
    -------
    float

    Examples
    --------
    >>> from treesim.params import instrument
    >>> station_duration_s(instrument("riegl-vz400").spec())
    180.0
    """
    return spec.mechanics().duration_s


def timing_summary(spec: ScannerSpec) -> dict[str, Any]:
    """What ``scan.json`` says of the scanner's time: its mechanics, the scan's duration
    per station and the convention of ``time_s`` and LAS ``gps_time``.

    Parameters
    ----------
    spec : ScannerSpec

    Returns
    -------
    dict
        JSON-ready: :meth:`ScanMechanics.to_dict <treesim.params.scanner.ScanMechanics.
        to_dict>` plus ``pulse_rate_hz`` and ``convention``.

    Examples
    --------
    >>> from treesim.params import ScannerSpec
    >>> timing_summary(ScannerSpec())["duration_s"] > 0
    True
    """
    return {
        **spec.mechanics().to_dict(),
        "pulse_rate_hz": spec.pulse_rate_hz,
        "convention": TIME_CONVENTION,
    }


__all__ = [
    "TIME_CONVENTION",
    "TIME_FIELD",
    "PulseClock",
    "pulse_times_s",
    "station_duration_s",
    "timing_summary",
]
