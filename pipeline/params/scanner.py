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
    "ScannerSpec",
    "instrument",
    "model_fields",
    "resolution_fields",
]

ReturnMode = Literal["first", "last", "strongest", "all"]
RETURN_MODES: tuple[str, ...] = ("first", "last", "strongest", "all")
BeamSampling = Literal["adaptive", "full"]
BEAM_SAMPLINGS: tuple[str, ...] = ("adaptive", "full")

#: Near-infrared reflectance per hit label used by the intensity proxy (1550 nm-ish
#: figures: bark ~0.45, leaves ~0.25 because water absorbs at 1550 nm, soil ~0.3).
DEFAULT_REFLECTANCE: dict[str, float] = {"wood": 0.45, "leaf": 0.25, "ground": 0.30, "other": 0.5}


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
    beam_sampling : {"adaptive", "full"}
        ``"adaptive"`` (default) casts each pulse's central ray and gives the sub-rays
        only to pulses whose footprint can straddle an edge; ``"full"`` casts every
        sub-ray of every pulse (brute force). See :mod:`treesim.scan.beam`.
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
        "full: sub-rays for every pulse (brute force)",
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
        }


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

    def scan_time_s(self, spec: ScannerSpec) -> float:
        """Seconds one scan takes: the pulses in ``spec``'s full field of view (at its
        resolution, :attr:`ScannerSpec.n_azimuth` × :attr:`ScannerSpec.n_elevation`)
        over :attr:`measurement_rate_hz`."""
        return spec.n_azimuth * spec.n_elevation / float(self.measurement_rate_hz)

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
        )
        kw.update(model_fields(beam=beam, noise=noise, figures=vars(self)))
        kw.update(overrides)
        return ScannerSpec(**kw)  # type: ignore[arg-type]


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
#: Field time (``measurement_rate_hz``, ``setup_time_min``; :meth:`InstrumentPreset.
#: station_time_s`): one station costs its set-up plus the pulses of the full field of view
#: at the chosen resolution over the measurement rate.
#:
#: - ``riegl-vz400``: effective measurement rate 122,000 measurements/s at the 300 kHz pulse
#:   repetition rate (high-speed mode, range up to 350 m at 90 % reflectance; the long-range
#:   mode's 600 m above comes with 42,000 meas./s at 100 kHz) -- same data sheet. At 0.04°
#:   the 360° × 100° field is 9,000 × 2,501 pulses: 184 s, within the 1-3 min per scan
#:   forest teams report for it (Wilkes et al. 2017, RSE 196; treesim's planning notes).
#:   Set-up 4 min per position (carry, level, place targets; makers publish none): with the
#:   scan, 7.1 min per station, inside the 5-10 min per position reported for it.
#: - ``faro-focus3d-x330``: measurement speed 122,000 points/s, the lowest of the tech
#:   sheet's four (122k/244k/488k/976k; the higher-quality settings forest scans use run
#:   at the low speeds). At 0.036° the 360° × 150° field is 10,000 × 4,167 pulses: 342 s,
#:   within the 3-8 min per scan reported for FARO Focus scanners. Set-up 3 min (a lighter
#:   instrument, no tilt mount; an assumption like the RIEGL's).
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
