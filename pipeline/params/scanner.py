"""The scanner's settings (:class:`ScannerSpec`) and the instruments it can imitate.

Angles are in degrees, distances in metres. The scanner frame has x along the station's
heading, z up; azimuth is measured counter-clockwise from x in the horizontal plane,
elevation up from the horizontal plane.

*Instruments* (:data:`INSTRUMENTS`) are one of treesim's three kinds of preset: a real
scanner's published figures. The others are run presets (:data:`treesim.params.RUN_PRESETS`)
and tree species (:data:`treesim.models.SPECIES`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Literal

from ..errors import InvalidParameterError
from ._fields import check_bounds, finite, param

__all__ = [
    "BEAM_SAMPLINGS",
    "DEFAULT_REFLECTANCE",
    "GENERIC_TLS",
    "INSTRUMENTS",
    "InstrumentPreset",
    "RETURN_MODES",
    "ScanMechanics",
    "ScannerSpec",
    "instrument",
    "model_fields",
    "resolution_fields",
]

ReturnMode = Literal["first", "last", "strongest", "all"]
RETURN_MODES: tuple[str, ...] = ("first", "last", "strongest", "all")
BeamSampling = Literal["adaptive", "full", "edge"]
BEAM_SAMPLINGS: tuple[str, ...] = ("adaptive", "full", "edge")

#: Near-infrared reflectance per hit label used by the intensity proxy (1550 nm-ish
#: figures: bark ~0.45, leaves ~0.25 because water absorbs at 1550 nm, soil ~0.3).
DEFAULT_REFLECTANCE: dict[str, float] = {"wood": 0.45, "leaf": 0.25, "ground": 0.30, "other": 0.5}


@dataclass(frozen=True)
class ScanMechanics:
    """How a scanner moves at given settings (:meth:`ScannerSpec.mechanics`).

    Attributes
    ----------
    cycle_pulses : float
        Pulse intervals in one mirror cycle: the scan line's pulses and the unused arc.
    line_period_s : float
        Seconds per mirror cycle (one scan line; with a two-sided mirror, a column and
        the one opposite).
    pulse_period_s : float
        Seconds between two pulses (``line_period_s / cycle_pulses``).
    n_lines : int
        Mirror cycles in one scan (the head's steps).
    duration_s : float
        The scan of one station, ``n_lines × line_period_s``.
    head_rate_deg_s : float
        How fast the head turns.
    two_sided : bool
        Whether each cycle scans a column and the one opposite (half a head turn).
    back_offset_pulses : float
        Two-sided: pulse intervals from the cycle's start (line 0 of the front column) to
        line 0 of the back column; 0 otherwise.
    """

    cycle_pulses: float
    line_period_s: float
    pulse_period_s: float
    n_lines: int
    duration_s: float
    head_rate_deg_s: float
    two_sided: bool
    back_offset_pulses: float

    @property
    def line_rate_hz(self) -> float:
        """Mirror cycles (scan lines) per second."""
        return 1.0 / self.line_period_s

    def to_dict(self) -> dict[str, object]:
        """Plain-JSON form, with the line rate."""
        return {
            "duration_s": self.duration_s,
            "line_period_s": self.line_period_s,
            "line_rate_hz": self.line_rate_hz,
            "pulse_period_s": self.pulse_period_s,
            "cycle_pulses": self.cycle_pulses,
            "n_lines": self.n_lines,
            "head_rate_deg_s": self.head_rate_deg_s,
            "two_sided": self.two_sided,
        }


@dataclass(frozen=True, kw_only=True)
class ScannerSpec:
    """A terrestrial laser scanner's settings.

    Parameters
    ----------
    horizontal_resolution_deg, vertical_resolution_deg : float
        Angular step between neighbouring pulses (> 0).
    horizontal_fov_deg : (2,) float
        Azimuth range swept, relative to the station heading; ``(0, 360)`` is a full turn.
    vertical_fov_deg : (2,) float
        Elevation range swept, within [-90, 90]; e.g. ``(-40, 60)`` for a RIEGL VZ-400.
    min_range_m, max_range_m : float
        Echoes nearer than ``min_range_m`` or farther than ``max_range_m`` are not recorded.
    beam_divergence_mrad : float
        Full-angle beam divergence. 0 (the default) casts one ray per pulse; > 0 samples
        the beam cone with ``subrays`` rays, which can give several returns per pulse.
        ``beam=True`` without an instrument sets :data:`GENERIC_TLS`'s 0.3 mrad.
    subrays : int
        Rays per pulse when the beam model is on (>= 2; a centre ray and rings).
    beam_sampling : {"adaptive", "full", "edge"}
        ``"adaptive"`` (default) casts each pulse's central ray and gives the sub-rays
        only to pulses whose footprint can straddle an edge; ``"full"`` casts every
        sub-ray of every pulse (brute force); ``"edge"`` casts the central ray and finds
        the silhouette edges inside the footprint from the mesh, the covered energy share
        analytic, one ray beyond each edge (sub-rays only where that cannot settle a
        pulse). See :mod:`treesim.scan.beam`.
    range_resolution_m : float
        Two echoes of one pulse closer than this merge into one return (beam model only).
    range_noise_sd_m : float
        Standard deviation of Gaussian range noise; 0 (the default) is off.
        ``noise=True`` without an instrument sets :data:`GENERIC_TLS`'s 1 mm.
    angular_jitter_sd_deg : float
        Standard deviation of Gaussian pointing noise per axis; 0 (the default) is off.
        ``noise=True`` without an instrument sets :data:`GENERIC_TLS`'s 0.001°.
    return_mode : {"first", "last", "strongest", "all"}
        Which returns of a pulse are recorded.
    seed : int
        Seed of every random model; outputs are reproducible for a given seed.
    reflectance : dict of str -> float
        Reflectance per hit label, used by the intensity proxy only.
    wind_speed_m_s, wind_direction_deg, wind_turbulence_intensity, wind_seed, wind_cylinders
        The wind the tree sways in while it is scanned (:mod:`treesim.scan.wind`); 0 m/s
        (the default) scans a still scene.
    pulse_rate_hz, mirror_cycle_deg, two_sided_mirror, max_line_rate_hz
        The scanner's mechanics (:meth:`mechanics`): when each pulse leaves, never where
        it goes. The defaults are a generic scanner firing 122 kHz with no unused mirror
        arc and no line-rate limit; instruments set their data sheets' figures
        (:data:`INSTRUMENTS`).

    Examples
    --------
    >>> import treesim as ts
    >>> spec = ts.ScannerSpec(horizontal_resolution_deg=0.02, vertical_resolution_deg=0.02)
    >>> spec.max_range_m
    400.0
    """

    horizontal_resolution_deg: float = param(
        0.04,
        help="horizontal angular step between pulses",
        unit="deg",
        flag="--h-resolution-deg",
        gt=0,
        le=45,
    )
    vertical_resolution_deg: float = param(
        0.04,
        help="vertical angular step between pulses",
        unit="deg",
        flag="--v-resolution-deg",
        gt=0,
        le=45,
    )
    horizontal_fov_deg: tuple[float, float] = param(
        (0.0, 360.0),
        help="azimuth range swept, START,END from the heading",
        unit="deg",
        flag="--hfov-deg",
    )
    vertical_fov_deg: tuple[float, float] = param(
        (-40.0, 90.0), help="elevation range swept, LOW,HIGH", unit="deg", flag="--vfov-deg"
    )
    min_range_m: float = param(0.5, help="nearest echo recorded", unit="m", ge=0)
    max_range_m: float = param(400.0, help="farthest echo recorded", unit="m", gt=0)
    beam_divergence_mrad: float = param(
        0.0,
        help="full-angle beam divergence; > 0 turns the beam model on",
        unit="mrad",
        ge=0,
        le=100,
    )
    subrays: int = param(7, help="rays per pulse with the beam model", ge=2, le=256)
    beam_sampling: BeamSampling = param(
        "adaptive",
        help="adaptive: sub-rays only for pulses whose footprint can straddle an edge; "
        "full: sub-rays for every pulse (brute force); edge: the footprint's silhouette "
        "edges from the mesh, analytic energy shares, a ray beyond each edge",
        choices=BEAM_SAMPLINGS,
    )
    range_resolution_m: float = param(
        0.3, help="echo separation for multiple returns (beam model)", unit="m", ge=0
    )
    range_noise_sd_m: float = param(0.0, help="Gaussian range noise σ (0: off)", unit="m", ge=0)
    angular_jitter_sd_deg: float = param(0.0, help="pointing noise σ (0: off)", unit="deg", ge=0)
    return_mode: ReturnMode = param(
        "first", help="which returns of a pulse are recorded", choices=RETURN_MODES
    )
    seed: int = param(0, help="seed of the noise models", ge=0)
    reflectance: dict[str, float] = param(
        help="reflectance per hit label (intensity proxy only)",
        factory=lambda: dict(DEFAULT_REFLECTANCE),
    )
    pulse_rate_hz: float = param(
        122_000.0,
        help="pulses the laser fires per second along the mirror's whole turn (pulse "
        "repetition rate; the pulse times only, never the points)",
        unit="Hz",
        gt=0,
        le=1e8,
    )
    mirror_cycle_deg: float = param(
        0.0,
        help="beam sweep of one mirror cycle: a scan line and the mirror's unused arc "
        "(0: no unused arc, a cycle is the vertical field of view)",
        unit="deg",
        ge=0,
        le=720,
    )
    two_sided_mirror: bool = param(
        False,
        help="one mirror turn scans both sides of the head through the zenith, so the "
        "head turns half the full turn (a rotating flat mirror, e.g. FARO Focus)",
    )
    max_line_rate_hz: float | None = param(
        None,
        help="most mirror cycles (scan lines) per second",
        unit="Hz",
        none_means="no limit",
        gt=0,
    )

    wind_speed_m_s: float = param(
        0.0,
        help="mean wind speed at the tree; > 0 sways a tree whose cylinder table is known "
        "(0: a still scene, today's scan bit for bit)",
        unit="m/s",
        ge=0,
        le=40,
    )
    wind_direction_deg: float = param(
        0.0, help="where the wind blows to, counter-clockwise from +x", unit="deg"
    )
    wind_turbulence_intensity: float = param(
        0.3, help="turbulence intensity σ_u / U of the wind (canopies: 0.2-0.5)", ge=0, le=2
    )
    wind_seed: int = param(0, help="seed of the wind's gusts", ge=0)
    wind_cylinders: str | None = param(
        None,
        help="the swaying tree's cylinder table (any table treesim reads: its own CSV "
        "from treesim model or reconstruct, TreeQSM's CSV or text export, SimpleForest's)",
        none_means="found beside the mesh by treesim scan, else the scene stays still",
    )

    def __post_init__(self) -> None:
        check_bounds(self)
        for label, r in self.reflectance.items():
            if isinstance(r, bool) or not isinstance(r, (int, float)) or not 0 <= r <= 1:
                raise InvalidParameterError(
                    f"reflectance[{label!r}] must be a number in [0, 1], got {r!r}"
                )
        h0, h1 = (finite("horizontal_fov_deg", a) for a in self.horizontal_fov_deg)
        if not 0 < h1 - h0 <= 360:
            raise InvalidParameterError(
                f"horizontal_fov_deg must span (0, 360] degrees, got ({h0}, {h1})"
            )
        v0, v1 = (finite("vertical_fov_deg", a) for a in self.vertical_fov_deg)
        if not -90 <= v0 < v1 <= 90:
            raise InvalidParameterError(
                f"vertical_fov_deg must satisfy -90 <= low < high <= 90, got ({v0}, {v1})"
            )
        if self.max_range_m <= self.min_range_m:
            raise InvalidParameterError(
                "ranges must satisfy 0 <= min_range_m < max_range_m, got "
                f"{self.min_range_m}, {self.max_range_m}"
            )

    # -- derived -----------------------------------------------------------------------
    @property
    def beam_model(self) -> bool:
        """True when the beam-divergence model (sub-rays, multiple returns) is on."""
        return self.beam_divergence_mrad > 0

    @property
    def full_turn(self) -> bool:
        """True when the horizontal field of view is a full 360 degree turn."""
        return abs(self.horizontal_fov_deg[1] - self.horizontal_fov_deg[0] - 360.0) < 1e-9

    @property
    def n_azimuth(self) -> int:
        """Number of azimuth steps (scan columns) in the full field of view."""
        span = self.horizontal_fov_deg[1] - self.horizontal_fov_deg[0]
        if self.full_turn:
            return max(1, int(round(360.0 / self.horizontal_resolution_deg)))
        return int(math.floor(span / self.horizontal_resolution_deg + 1e-9)) + 1

    @property
    def n_elevation(self) -> int:
        """Number of elevation steps (scan lines) in the full field of view."""
        span = self.vertical_fov_deg[1] - self.vertical_fov_deg[0]
        return int(math.floor(span / self.vertical_resolution_deg + 1e-9)) + 1

    @property
    def rays_per_pulse(self) -> int:
        """Rays cast per pulse: ``subrays`` with the beam model, else 1."""
        return self.subrays if self.beam_model else 1

    def active_models(self) -> list[str]:
        """Names of the optional models that are on (for reports)."""
        out = []
        if self.beam_model:
            out.append(
                f"beam divergence {self.beam_divergence_mrad} mrad × {self.subrays} sub-rays "
                f"({self.beam_sampling} sampling)"
            )
        if self.range_noise_sd_m > 0:
            out.append(f"range noise σ {self.range_noise_sd_m} m")
        if self.angular_jitter_sd_deg > 0:
            out.append(f"angular jitter σ {self.angular_jitter_sd_deg}°")
        if self.wind_speed_m_s > 0:
            out.append(
                f"wind {self.wind_speed_m_s:g} m/s towards {self.wind_direction_deg:g}°, "
                f"turbulence intensity {self.wind_turbulence_intensity:g}"
            )
        return out

    def with_(self, **changes: object) -> ScannerSpec:
        """A copy with some fields changed (validated again)."""
        return replace(self, **changes)  # type: ignore[arg-type]

    def to_dict(self) -> dict[str, object]:
        """Plain-JSON form of every setting."""
        return {
            "horizontal_resolution_deg": self.horizontal_resolution_deg,
            "vertical_resolution_deg": self.vertical_resolution_deg,
            "horizontal_fov_deg": list(self.horizontal_fov_deg),
            "vertical_fov_deg": list(self.vertical_fov_deg),
            "min_range_m": self.min_range_m,
            "max_range_m": self.max_range_m,
            "beam_divergence_mrad": self.beam_divergence_mrad,
            "subrays": self.subrays,
            "beam_sampling": self.beam_sampling,
            "range_resolution_m": self.range_resolution_m,
            "range_noise_sd_m": self.range_noise_sd_m,
            "angular_jitter_sd_deg": self.angular_jitter_sd_deg,
            "return_mode": self.return_mode,
            "seed": self.seed,
            "reflectance": dict(self.reflectance),
            "pulse_rate_hz": self.pulse_rate_hz,
            "mirror_cycle_deg": self.mirror_cycle_deg,
            "two_sided_mirror": self.two_sided_mirror,
            "max_line_rate_hz": self.max_line_rate_hz,
            "wind_speed_m_s": self.wind_speed_m_s,
            "wind_direction_deg": self.wind_direction_deg,
            "wind_turbulence_intensity": self.wind_turbulence_intensity,
            "wind_seed": self.wind_seed,
            "wind_cylinders": self.wind_cylinders,
        }

    def mechanics(self) -> ScanMechanics:
        """How the scanner moves for these settings: the one time model.

        A head turning about the vertical axis carries a mirror that sweeps the beam
        through the vertical field of view, one scan line (one grid column) per mirror
        cycle. The laser fires evenly along the cycle, ``pulse_rate_hz`` pulses a second;
        the cycle is ``mirror_cycle_deg`` (at least the arc the lines need), so the
        unused arc is dead time. A cycle lasts ``cycle pulses / pulse_rate_hz``, or
        ``1 / max_line_rate_hz`` where the mirror cannot spin faster (the pulses then
        spread evenly over the longer cycle). The head turns one horizontal step per
        cycle; with ``two_sided_mirror`` over a full turn each cycle scans the column
        and the one opposite, and the head turns half a turn.
        :func:`treesim.scan.timing.pulse_times_s` gives each pulse its time from this,
        and :meth:`InstrumentPreset.scan_time_s` (``treesim plan``'s field time) the
        scan's duration.

        Returns
        -------
        ScanMechanics

        Examples
        --------
        >>> spec = ScannerSpec(
        ...     horizontal_resolution_deg=10.0, vertical_resolution_deg=10.0,
        ...     vertical_fov_deg=(0.0, 40.0), pulse_rate_hz=1000.0,
        ... )
        >>> m = spec.mechanics()
        >>> (m.cycle_pulses, m.line_period_s, m.n_lines, round(m.duration_s, 9))
        (5.0, 0.005, 36, 0.18)
        """
        vres = self.vertical_resolution_deg
        two_sided = bool(self.two_sided_mirror and self.full_turn)
        v0 = self.vertical_fov_deg[0]
        # mirror positions (in pulses from the cycle's first) of the back side's line 0
        back = (180.0 - 2.0 * v0) / vres if two_sided else 0.0
        used = back + 1.0 if two_sided else float(self.n_elevation)
        cycle = max(self.mirror_cycle_deg / vres, used)
        period = cycle / self.pulse_rate_hz
        if self.max_line_rate_hz is not None:
            period = max(period, 1.0 / self.max_line_rate_hz)
        n_az = self.n_azimuth
        n_lines = n_az - n_az // 2 if two_sided else n_az
        return ScanMechanics(
            cycle_pulses=cycle,
            line_period_s=period,
            pulse_period_s=period / cycle,
            n_lines=n_lines,
            duration_s=n_lines * period,
            head_rate_deg_s=self.horizontal_resolution_deg / period,
            two_sided=two_sided,
            back_offset_pulses=back,
        )


def resolution_fields(resolution_deg: float) -> dict[str, float]:
    """One angular step for both axes: the ``ScannerSpec`` fields it sets.

    The single place where a square grid's step is expanded to the horizontal and
    vertical resolutions (instruments; the ``resolution_deg`` setting and run presets).

    Parameters
    ----------
    resolution_deg : float
        Step between neighbouring pulses, horizontally and vertically (degrees).

    Returns
    -------
    dict of str -> float
        ``horizontal_resolution_deg`` and ``vertical_resolution_deg``, for
        ``ScannerSpec(**resolution_fields(r), ...)`` or ``spec.with_(**...)``.
    """
    return {"horizontal_resolution_deg": resolution_deg, "vertical_resolution_deg": resolution_deg}


@dataclass(frozen=True, kw_only=True)
class InstrumentPreset:
    """Published figures of a real instrument.

    ``spec(beam=False, noise=False)`` gives a geometric-only ``ScannerSpec`` with the
    instrument's field of view, ranges and a typical resolution; ``beam=True`` turns on
    its beam divergence and ``noise=True`` its ranging noise and angular jitter: treesim
    models only what it is asked for.
    """

    name: str
    description: str
    resolution_deg: float
    horizontal_fov_deg: tuple[float, float]
    vertical_fov_deg: tuple[float, float]
    min_range_m: float
    max_range_m: float
    beam_divergence_mrad: float
    range_noise_sd_m: float
    angular_jitter_sd_deg: float
    wavelength_nm: float
    source: str
    measurement_rate_hz: float
    setup_time_min: float
    timing_source: str
    pulse_rate_hz: float
    mirror_cycle_deg: float
    two_sided_mirror: bool
    max_line_rate_hz: float | None
    mechanics_source: str

    def mechanics_fields(self) -> dict[str, object]:
        """The :class:`ScannerSpec` fields of this instrument's mechanics."""
        return {k: getattr(self, k) for k in MECHANICS_FIELDS}

    def scan_time_s(self, spec: ScannerSpec) -> float:
        """Seconds one scan takes: ``spec``'s field of view and resolution scanned with
        this instrument's mechanics (:meth:`ScannerSpec.mechanics`, the model that also
        times each pulse, :func:`treesim.scan.timing.pulse_times_s`)."""
        return spec.with_(**self.mechanics_fields()).mechanics().duration_s

    def station_time_s(self, spec: ScannerSpec) -> float:
        """Field time of one station (s): :attr:`setup_time_min` (carry, level, target
        and move) plus :meth:`scan_time_s`."""
        return 60.0 * float(self.setup_time_min) + self.scan_time_s(spec)

    def spec(self, *, beam: bool = False, noise: bool = False, **overrides: object) -> ScannerSpec:
        """A ``ScannerSpec`` from these figures; ``overrides`` replace any field."""
        kw: dict[str, object] = dict(
            **resolution_fields(self.resolution_deg),
            horizontal_fov_deg=self.horizontal_fov_deg,
            vertical_fov_deg=self.vertical_fov_deg,
            min_range_m=self.min_range_m,
            max_range_m=self.max_range_m,
            **self.mechanics_fields(),
        )
        kw.update(model_fields(beam=beam, noise=noise, figures=vars(self)))
        kw.update(overrides)
        return ScannerSpec(**kw)  # type: ignore[arg-type]


#: The :class:`ScannerSpec` fields that say how an instrument moves (its mechanics).
MECHANICS_FIELDS = ("pulse_rate_hz", "mirror_cycle_deg", "two_sided_mirror", "max_line_rate_hz")

#: Instrument presets. Figures from the makers' data sheets:
#:
#: - ``riegl-vz400``: RIEGL VZ-400 data sheet (RIEGL Laser Measurement Systems,
#:   "Datasheet VZ-400", 2014-09-19): FOV 100° vertical (+60°/-40°) × 360°, beam divergence
#:   0.35 mrad, range 1.5-600 m (long-range mode), precision 3 mm (1σ at 100 m), angle
#:   measurement resolution better than 0.0005°, laser wavelength near infrared (1550 nm).
#:   0.04° is the resolution most forest TLS studies used with it (e.g. Calders et al. 2015,
#:   Methods Ecol. Evol. 6:198).
#: - ``faro-focus3d-x330``: FARO Focus3D X 330 tech sheet (FARO, 2013): FOV 300° vertical
#:   (-60°/+90°) × 360°, beam divergence 0.19 mrad (0.011°), range 0.6-330 m, ranging noise
#:   0.3 mm at 10 m on 90 % reflectance (raw), wavelength 1550 nm; step 0.009° at full
#:   resolution, 0.036° at the common 1/4 resolution setting used here.
#:
#: Field time (:meth:`InstrumentPreset.station_time_s`): one station costs its set-up plus
#: the scan's duration from the instrument's mechanics (:meth:`ScannerSpec.mechanics`,
#: the model that also times every pulse, :mod:`treesim.scan.timing`).
#:
#: - ``riegl-vz400``, same data sheet, "Scanner Performance" and "Laser Product"
#:   tables: vertical (line) scan by a rotating multi-facet mirror at 3 to 120 lines/s,
#:   angle step 0.0024° <= Δθ <= 0.288°; horizontal (frame) scan by the rotating head,
#:   0 to 60°/s, 0.0024° <= Δφ <= 0.5°; laser pulse repetition rate (PRR) 300 kHz
#:   (high-speed mode, range up to 350 m at 90 % reflectance) or 100 kHz (long-range,
#:   600 m), effective measurement rate 122,000 and 42,000 meas./s. The mirror cycle is
#:   not published; 240° follows from the step limits, a step being cycle × lines/s /
#:   PRR: the finest, 0.0024°, at the slowest 3 lines/s and 300 kHz, and the coarsest,
#:   0.288°, at the fastest 120 lines/s and 100 kHz, both give 240° (a three-facet
#:   polygon, 720°/3). The 100° field of view is then 41.7 % of each cycle: 125,000
#:   meas./s at 300 kHz (the sheet says 122,000, 2.4 % fewer) and 41,700 at 100 kHz
#:   (the sheet: 42,000). At 0.04°: 6,000 pulses per cycle, 50 lines/s, the head at
#:   2°/s, 9,000 lines: 180.0 s (the sheet's effective rate over the 9,000 × 2,501
#:   pulses gives 184.5 s). Lines assumed swept upward (not published). Set-up 4 min
#:   per position (carry, level, place targets; makers publish none): with the scan,
#:   7.0 min per station, inside the 5-10 min per position reported for it (Wilkes et
#:   al. 2017, RSE 196).
#: - ``faro-focus3d-x330``, same tech sheet: measurement speed 122,000 / 244,000 /
#:   488,000 / 976,000 points/s (the lowest is used: the higher-quality settings forest
#:   scans use run at the low speeds); step 0.009° = 40,960 3D-pixels on 360°, both
#:   axes; max. vertical scan speed 5,820 rpm or 97 Hz; field of view 300° × 360°. The
#:   mechanics: one flat mirror turning a full turn per cycle (the pixel count is per
#:   360° of mirror turn), the 60° below the head blind (300° field of view), each turn
#:   measuring a column and the one opposite through the zenith, so the head turns half
#:   a turn for a full scan. Assumed (the sheet does not say): the measurement speed is
#:   the sampling rate along the whole mirror turn, the blind arc included; the sheet
#:   publishes no scan duration. At 0.036°: 10,000 pulses per turn, 12.2 turns/s
#:   (under the 97 Hz limit), 5,000 turns: 409.8 s, within the 3-8 min per scan
#:   reported for FARO Focus scanners. Set-up 3 min (a lighter instrument, no tilt
#:   mount; an assumption like the RIEGL's).
INSTRUMENTS: dict[str, InstrumentPreset] = {
    "riegl-vz400": InstrumentPreset(
        name="riegl-vz400",
        description="RIEGL VZ-400 (pulsed, 1550 nm, waveform returns)",
        resolution_deg=0.04,
        horizontal_fov_deg=(0.0, 360.0),
        vertical_fov_deg=(-40.0, 60.0),
        min_range_m=1.5,
        max_range_m=600.0,
        beam_divergence_mrad=0.35,
        range_noise_sd_m=0.003,
        angular_jitter_sd_deg=0.0005,
        wavelength_nm=1550.0,
        source="RIEGL VZ-400 data sheet, 2014-09-19",
        measurement_rate_hz=122_000.0,
        setup_time_min=4.0,
        timing_source="RIEGL VZ-400 data sheet, 2014-09-19 (effective measurement rate at "
        "300 kHz PRR); set-up: typical field practice (5-10 min per position with the scan)",
        pulse_rate_hz=300_000.0,
        mirror_cycle_deg=240.0,
        two_sided_mirror=False,
        max_line_rate_hz=120.0,
        mechanics_source="RIEGL VZ-400 data sheet, 2014-09-19: PRR 300 kHz, line scan "
        "3-120 lines/s by a multi-facet mirror; the 240° mirror cycle from the angle step "
        "limits 0.0024° (3 lines/s, 300 kHz) and 0.288° (120 lines/s, 100 kHz)",
    ),
    "faro-focus3d-x330": InstrumentPreset(
        name="faro-focus3d-x330",
        description="FARO Focus3D X 330 (phase shift, 1550 nm)",
        resolution_deg=0.036,
        horizontal_fov_deg=(0.0, 360.0),
        vertical_fov_deg=(-60.0, 90.0),
        min_range_m=0.6,
        max_range_m=330.0,
        beam_divergence_mrad=0.19,
        range_noise_sd_m=0.0003,
        angular_jitter_sd_deg=0.0005,
        wavelength_nm=1550.0,
        source="FARO Focus3D X 330 tech sheet, 2013",
        measurement_rate_hz=122_000.0,
        setup_time_min=3.0,
        timing_source="FARO Focus3D X 330 tech sheet, 2013 (lowest measurement speed); "
        "set-up: typical field practice (3-8 min per scan reported)",
        pulse_rate_hz=122_000.0,
        mirror_cycle_deg=360.0,
        two_sided_mirror=True,
        max_line_rate_hz=97.0,
        mechanics_source="FARO Focus3D X 330 tech sheet, 2013: 122,000 points/s, 40,960 "
        "3D-pixels per 360° of mirror turn, max. vertical scan speed 97 Hz; assumed: the "
        "speed counts the blind 60° arc, one turn scans both sides (the head turns 180°)",
    ),
}


#: The figures ``beam=True`` and ``noise=True`` turn on when no instrument is named
#: (``treesim scan --beam`` / ``--noise``, :func:`treesim.params.scan_params`): a generic
#: current terrestrial laser scanner, with the model's own ``subrays`` (7) and
#: ``range_resolution_m`` (0.3 m).
#:
#: - ``beam_divergence_mrad`` 0.3: between the bundled instruments' data sheets, 0.19
#:   (FARO Focus3D X 330) and 0.35 (RIEGL VZ-400) mrad;
#: - ``range_noise_sd_m`` 1 mm: the geometric mean (0.95 mm) of the bundled instruments'
#:   figures, 0.3 mm (FARO, phase shift, 10 m) and 3 mm (RIEGL, pulsed, 100 m); bark at
#:   forest ranges (5-30 m, ~45 % reflectance) sits between the two;
#: - ``angular_jitter_sd_deg`` 0.001 (3.6"): twice the bundled instruments' 0.0005°, a
#:   conservative pointing noise.
#: Only the two bundled instruments' sheets (sources in :data:`INSTRUMENTS`) were read for
#: these figures.
GENERIC_TLS: dict[str, float] = {
    "beam_divergence_mrad": 0.3,
    "range_noise_sd_m": 0.001,
    "angular_jitter_sd_deg": 0.001,
}


def model_fields(
    *, beam: bool, noise: bool, figures: Mapping[str, object] = GENERIC_TLS
) -> dict[str, object]:
    """The :class:`ScannerSpec` fields that turn on the beam model (``beam``) and the
    range noise and angular jitter (``noise``), with ``figures``' values (default
    :data:`GENERIC_TLS`; an instrument passes its own). The one place that says which
    fields each switch sets."""
    names = (("beam_divergence_mrad",) if beam else ()) + (
        ("range_noise_sd_m", "angular_jitter_sd_deg") if noise else ()
    )
    return {k: figures[k] for k in names}


def instrument(name: str) -> InstrumentPreset:
    """The scanner instrument called ``name`` (see :data:`INSTRUMENTS`)."""
    try:
        return INSTRUMENTS[name]
    except KeyError:
        raise InvalidParameterError(
            f"unknown scanner instrument {name!r}; choose one of {', '.join(sorted(INSTRUMENTS))}"
        ) from None
