"""Scenario schema: one YAML describes orbit, attitude, scene, camera, correlator and loop.

Every field has a unit in its name or description; unknown fields are errors (typos must not
silently fall back to defaults). :func:`load_scenario` turns any problem into a
:class:`ScenarioError` whose one-line message names the field and the fix.
"""

from __future__ import annotations

import dataclasses
import hashlib
from datetime import date, datetime, timezone
from functools import lru_cache
from pathlib import Path
from typing import Annotated, ClassVar, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from camera.imager import IMAGERS
from compensation.registry import (
    MAX_MAGNITUDE,
    bool_at,
    check_params,
    expects_number,
    short,
)
from correlator.optical import EFFECTS, JtocModel, SensorSpec, SlmSpec
from imc.yamlload import YamlInputError, load_yaml, read_text
from scene import SCENE_KINDS


class ScenarioError(ValueError):
    """A scenario file that cannot be used; the message is one line naming the field."""


def error_line(e: BaseException) -> str:
    """One line for an exception: a ScenarioError's own message, else the type and the
    message's first line (a point or scenario that could not run)."""
    text = str(e).strip().splitlines()
    head = text[0] if text else ""
    return head if isinstance(e, ScenarioError) else f"{type(e).__name__}: {head}".rstrip(": ")


#: the epochs imcsim can propagate: its orbit, sun and time models count nanoseconds in
#: int64 (numpy datetime64[ns]: 1678-09-21 .. 2262-04-11), less a day for the run itself
EPOCH_MIN = datetime(1678, 9, 22)
EPOCH_MAX = datetime(2262, 4, 10)


def _finite_magnitude(v):
    """v, if every float in it (a number or a tuple of numbers) is at most MAX_MAGNITUDE."""
    many = isinstance(v, tuple | list)
    for i, x in enumerate(v if many else (v,)):
        if isinstance(x, float) and not abs(x) <= MAX_MAGNITUDE:
            where = f"@{i}@ " if many else ""  # the element, named in the error's field
            raise ValueError(f"{where}must be a finite number of magnitude <= {MAX_MAGNITUDE:g}")
    return v


class _Model(BaseModel):
    """Every section: unknown keys are errors, and every float is finite (no NaN, no inf)
    and of magnitude <= MAX_MAGNITUDE; true / false is not a number."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    @field_validator("*", mode="before")
    @classmethod
    def _no_bool_numbers(cls, v, info):
        at = bool_at(v)
        if at is not None:
            field = cls.model_fields.get(info.field_name)
            if field is not None and expects_number(field.annotation):
                where = f"@{at}@ " if isinstance(v, list | tuple) else ""  # the element
                raise ValueError(f"{where}give a number, not true / false")
        return v

    @field_validator("*", mode="after")
    @classmethod
    def _numbers(cls, v):
        return _finite_magnitude(v)


#: a pixel offset on the focal plane, px
_OffsetPx = Annotated[float, Field(ge=-1e5, le=1e5)]
#: an angle that is not taken modulo 360 silently, deg
_AngleDeg = Annotated[float, Field(ge=-360.0, le=360.0)]


def _epoch_input(v):
    """A date-time from YAML (a timestamp), a string (ISO 8601) or a date; not a number."""
    if isinstance(v, bool | int | float):
        raise ValueError("give a UTC date and time (ISO 8601, e.g. 2026-06-21T10:30:00Z), "
                         "not a number")
    if isinstance(v, str):
        try:
            return datetime.fromisoformat(v.strip())
        except ValueError:
            raise ValueError(f"{short(v, 40)} is not an ISO 8601 date and time (e.g. "
                             "2026-06-21T10:30:00Z)") from None
    if isinstance(v, date) and not isinstance(v, datetime):
        return datetime(v.year, v.month, v.day)
    return v


def _epoch_utc(v: datetime) -> datetime:
    """Naive UTC: an offset (Z, +02:00) is applied; no offset means UTC. Within the range
    imcsim can propagate (EPOCH_MIN .. EPOCH_MAX)."""
    if v.tzinfo is not None and v.utcoffset() is not None:
        naive = v.replace(tzinfo=None)
        if not EPOCH_MIN <= naive <= EPOCH_MAX:  # before converting (no overflow near 1 / 9999)
            raise ValueError(_EPOCH_RANGE)
        v = v.astimezone(timezone.utc).replace(tzinfo=None)
    v = v.replace(tzinfo=None)
    if not EPOCH_MIN <= v <= EPOCH_MAX:
        raise ValueError(_EPOCH_RANGE)
    return v


_EPOCH_RANGE = (f"must lie between {EPOCH_MIN:%Y-%m-%d} and {EPOCH_MAX:%Y-%m-%d} (UTC), the "
                "range imcsim's orbit and sun models can propagate")


def _usable_file(v: Path | None, what: str = "file") -> Path | None:
    """A path the schema accepts (not empty, no NUL, at most 4096 characters)."""
    if v is None:
        return v
    text = str(v)
    if "\x00" in text or not text.strip() or text == ".":
        raise ValueError(f"give the path of a {what}")
    if len(text) > 4096:
        raise ValueError(f"path of {len(text)} characters; the system takes at most 4096")
    return v


class OrbitConfig(_Model):
    """The platform's path. ``circular`` and ``sun_synchronous`` orbits are placed so that the
    line of sight (attitude.roll_deg / pitch_deg) meets the scene centre at t = 0 (mode
    target) or half-way through the run (scanning modes); ``elements``,
    ``tle`` and ``oem`` (a CCSDS orbit ephemeris file) orbits are taken as given and need
    attitude.mode 'target'. ``aircraft``: straight,
    level flight height_m above the scene's ground at ground_speed_mps along heading_deg,
    over the scene centre half-way through the run (attitude.mode nadir or off_nadir)."""

    kind: Literal["sun_synchronous", "circular", "elements", "tle", "oem", "aircraft"] = Field(
        "sun_synchronous", description="sun_synchronous (inclination from the altitude), "
        "circular, elements (Keplerian), tle (SGP4), oem (a CCSDS orbit ephemeris file) or "
        "aircraft (straight, level flight)")
    altitude_m: float = Field(681_000.0, gt=150_000.0, lt=50_000_000.0,
                              description="circular / sun_synchronous: altitude above the "
                              "WGS84 equatorial radius, m")
    inclination_deg: float = Field(98.1, ge=0.0, le=180.0,
                                   description="circular: inclination, deg")
    epoch_utc: datetime = Field(datetime(2026, 6, 21, 10, 30),
                                description="UTC time of t = 0 (ISO 8601: 2026-06-21T10:30:00Z,"
                                " an offset such as +02:00, or none: UTC); from "
                                f"{EPOCH_MIN:%Y-%m-%d} to {EPOCH_MAX:%Y-%m-%d}")
    pass_direction: Literal["descending", "ascending"] = Field(
        "descending", description="circular / sun_synchronous: which pass crosses the scene")
    j2: bool = Field(True, description="apply the J2 secular drift (node, perigee, anomaly)")
    semi_major_axis_m: float | None = Field(None, gt=6_478_137.0,
                                            description="elements: semi-major axis, m")
    eccentricity: float = Field(0.0, ge=0.0, lt=1.0, description="elements: eccentricity")
    raan_deg: _AngleDeg = Field(0.0, description="elements: right ascension of the node, deg")
    arg_perigee_deg: _AngleDeg = Field(0.0, description="elements: argument of perigee, deg")
    mean_anomaly_deg: _AngleDeg = Field(0.0, description="elements: mean anomaly at epoch, deg")
    tle_line1: str | None = Field(None, max_length=80, description="tle: line 1")
    tle_line2: str | None = Field(None, max_length=80, description="tle: line 2")
    oem_file: Path | None = Field(None, description="oem: CCSDS OEM file (KVN or XML; path "
                                  "relative to the scenario file) whose states span the run")
    height_m: float | None = Field(None, gt=0.0, le=30_000.0, description="aircraft: flight "
                                   "height above the scene's ground level (the DEM's median), m")
    ground_speed_mps: float | None = Field(None, gt=0.0, le=1000.0,
                                           description="aircraft: ground speed, m/s")
    heading_deg: float = Field(0.0, ge=0.0, lt=360.0, description="aircraft: direction of "
                               "flight from north toward east, deg")

    @field_validator("epoch_utc", mode="before")
    @classmethod
    def _epoch_in(cls, v):
        return _epoch_input(v)

    @field_validator("epoch_utc", mode="after")
    @classmethod
    def _epoch(cls, v: datetime) -> datetime:
        return _epoch_utc(v)

    @model_validator(mode="after")
    def _kind_fields(self) -> OrbitConfig:
        if self.kind == "elements" and self.semi_major_axis_m is None:
            raise ValueError("kind 'elements' needs semi_major_axis_m (m)")
        if self.kind == "tle" and not (self.tle_line1 and self.tle_line2):
            raise ValueError("kind 'tle' needs tle_line1 and tle_line2")
        if (self.kind == "oem") != (self.oem_file is not None):
            raise ValueError("kind 'oem' needs oem_file (a CCSDS OEM), and oem_file needs kind "
                             "'oem'")
        return self

    @field_validator("oem_file", mode="after")
    @classmethod
    def _oem_path(cls, v: Path | None) -> Path | None:
        return _usable_file(v, "CCSDS OEM file")

    @model_validator(mode="after")
    def _aircraft_fields(self) -> OrbitConfig:
        flight = ("height_m", "ground_speed_mps")
        if self.kind == "aircraft":
            missing = [f for f in flight if getattr(self, f) is None]
            if missing:
                raise ValueError(f"kind 'aircraft' needs {' and '.join(missing)} (height above "
                                 "the ground in m, ground speed in m/s)")
        elif any(getattr(self, f) is not None for f in flight) or self.heading_deg:
            raise ValueError("height_m, ground_speed_mps and heading_deg describe a flight: "
                             "set kind 'aircraft' or leave them out")
        return self


def _exactly_one(model: _Model, a: str, b: str):
    """The model, if exactly one of the fields a, b (the same quantity in two units) is set."""
    if (getattr(model, a) is None) == (getattr(model, b) is None):
        raise ValueError(f"give exactly one of {a} or {b}")
    return model


class SinusoidConfig(_Model):
    """One sinusoidal attitude-jitter term; give the amplitude in urad or in px (IFOVs)."""

    axis: Literal["roll", "pitch", "yaw"] = Field(
        description="body axis: roll moves the image along columns, pitch along rows")
    frequency_hz: float = Field(gt=0.0, description="frequency, Hz")
    amplitude_urad: float | None = Field(None, ge=0.0, description="amplitude, urad")
    amplitude_px: float | None = Field(None, ge=0.0,
                                       description="amplitude in pixels (IFOVs) of the camera")
    phase_deg: _AngleDeg = Field(0.0, description="phase at t = 0, deg")

    @model_validator(mode="after")
    def _one_amplitude(self) -> SinusoidConfig:
        return _exactly_one(self, "amplitude_urad", "amplitude_px")



class RandomJitterConfig(_Model):
    """Band-limited random jitter, PSD ~ f**slope on [f_min_hz, f_max_hz], seeded."""

    axis: Literal["roll", "pitch", "yaw"] = Field(description="body axis")
    rms_urad: float | None = Field(None, ge=0.0, description="RMS over the band, urad")
    rms_px: float | None = Field(None, ge=0.0, description="RMS over the band, px (IFOVs)")
    f_min_hz: float = Field(gt=0.0, description="lowest frequency, Hz")
    f_max_hz: float = Field(gt=0.0, description="highest frequency, Hz")
    slope: float = Field(0.0, ge=-4.0, le=4.0,
                         description="PSD power-law exponent (0: white, -2: random walk)")

    @model_validator(mode="after")
    def _check(self) -> RandomJitterConfig:
        _exactly_one(self, "rms_urad", "rms_px")
        if self.f_max_hz <= self.f_min_hz:
            raise ValueError("f_max_hz must exceed f_min_hz")
        return self


class HarmonicConfig(_Model):
    number: float = Field(gt=0.0, description="harmonic number (multiple of the wheel speed)")
    amplitude_urad: float | None = Field(None, ge=0.0, description="amplitude, urad")
    amplitude_px: float | None = Field(None, ge=0.0, description="amplitude, px (IFOVs)")

    @model_validator(mode="after")
    def _one_amplitude(self) -> HarmonicConfig:
        return _exactly_one(self, "amplitude_urad", "amplitude_px")


class WheelConfig(_Model):
    """Reaction-wheel harmonics; amplitudes grow with (speed / speed_hz)**2; random phases."""

    axis: Literal["roll", "pitch", "yaw"] = Field(description="body axis")
    speed_hz: float = Field(gt=0.0, description="wheel speed at t = 0, rev/s (Hz)")
    speed_rate_hz_per_s: float = Field(0.0, description="wheel speed ramp, Hz/s")
    harmonics: tuple[HarmonicConfig, ...] = Field(min_length=1,
                                                  description="harmonics at speed_hz")


class JitterSeriesConfig(_Model):
    """Measured attitude as the true jitter (orbit.attitude_series): a CSV of time (t_s: s
    since orbit.epoch_utc, or utc) and roll_<unit>, pitch_<unit>, yaw_<unit> offsets (unit:
    rad, mrad, urad, deg, arcsec or px), or a CCSDS AEM (EME2000 <-> body quaternions) whose
    jitter is taken against the nominal pointing of attitude.mode. Cubic-spline interpolated;
    the samples must cover the run at the tracker's frame rate or faster."""

    file: Path = Field(description="CSV or CCSDS AEM file (path relative to the scenario file)")
    format: Literal["csv", "aem"] | None = Field(None, description="csv or aem (none: from "
                                                 "the file's suffix, .csv or .aem)")

    @field_validator("file", mode="after")
    @classmethod
    def _path(cls, v: Path) -> Path:
        return _usable_file(v, "CSV or CCSDS AEM file")

    @model_validator(mode="after")
    def _format(self) -> JitterSeriesConfig:
        if self.format is None:
            suffix = self.file.suffix.lower()
            if suffix not in (".csv", ".aem"):
                raise ValueError(f"cannot tell the format from the suffix {suffix or '(none)'}"
                                 " of file: set format (csv or aem)")
            object.__setattr__(self, "format", suffix[1:])
        return self


class JitterProfileConfig(_Model):
    """Attitude jitter: lists of sinusoidal, random (PSD) and reaction-wheel terms. Lists left
    out are empty. Leaving out the whole section gives the default profile (DEFAULT_JITTER):
    roll 0.65 Hz at 1 px, pitch 4.3 Hz at 0.1 px, and a 35 Hz reaction wheel's 1st and 2nd
    harmonics on pitch at 0.02 px each."""

    sinusoids: tuple[SinusoidConfig, ...] = Field((), description="sinusoidal terms")
    random: tuple[RandomJitterConfig, ...] = Field((), description="random (PSD) terms")
    wheels: tuple[WheelConfig, ...] = Field((), description="reaction-wheel harmonic series")
    series: JitterSeriesConfig | None = Field(None, description="measured attitude (a CSV or "
                                              "a CCSDS AEM) as the jitter, instead of the "
                                              "modelled terms")

    @model_validator(mode="after")
    def _series_alone(self) -> JitterProfileConfig:
        if self.series is not None and (self.sinusoids or self.random or self.wheels):
            raise ValueError("series is the measured jitter: leave out sinusoids, random and "
                             "wheels (or drop series)")
        return self


#: An IKONOS-class default from measured missions: ZY-3's dominant 0.65 Hz at 1 px
#: (cross-track), QuickBird's 4.3 Hz at 0.1 px, and reaction-wheel harmonics (35 Hz wheel,
#: 1st and 2nd harmonic) at 0.02 px (../shared/notes/domain-facts.md).
DEFAULT_JITTER = JitterProfileConfig(
    sinusoids=(SinusoidConfig(axis="roll", frequency_hz=0.65, amplitude_px=1.0),
               SinusoidConfig(axis="pitch", frequency_hz=4.3, amplitude_px=0.1)),
    wheels=(WheelConfig(axis="pitch", speed_hz=35.0,
                        harmonics=(HarmonicConfig(number=1.0, amplitude_px=0.02),
                                   HarmonicConfig(number=2.0, amplitude_px=0.02))),),
)


class SuspensionConfig(_Model):
    """The camera suspension: a second-order low-pass between the platform's attitude jitter
    and the camera (gain 1 / (2 damping) at the cut-off, falling as (cutoff / f)^2 above)."""

    cutoff_hz: float = Field(gt=0.0, le=10_000.0, description="cut-off (natural) frequency, Hz")
    damping: float = Field(0.3, gt=0.0, le=10.0, description="damping ratio")


class AttitudeConfig(_Model):
    mode: Literal["target", "nadir", "off_nadir"] = Field(
        "target",
        description="'target': line of sight held on the scene centre (staring frame camera);"
        " 'nadir': geocentric nadir (the image then flows ~8,300 px/s along the rows);"
        " 'off_nadir': fixed roll_deg / pitch_deg from nadir (scanning)")
    roll_deg: float = Field(0.0, ge=-60.0, le=60.0,
                            description="look angle at t = 0 about the flight axis, deg "
                            "(+: left of the track); off_nadir / target")
    pitch_deg: float = Field(0.0, ge=-60.0, le=60.0,
                             description="look angle at t = 0 about the cross axis, deg "
                             "(+: ahead); off_nadir / target")
    yaw_steering: bool = Field(False, description="turn about the line of sight so the ground "
                               "flows exactly along the rows (nadir / off_nadir; TDI needs it)")
    jitter: JitterProfileConfig = Field(DEFAULT_JITTER, description="jitter profile (a list: "
                                        "sinusoids only; [] for none)")
    suspension: SuspensionConfig | None = Field(None, description="camera suspension the "
                                                "jitter passes through (none: rigid mount)")

    @field_validator("jitter", mode="before")
    @classmethod
    def _list_is_sinusoids(cls, v):
        return {"sinusoids": v} if isinstance(v, list | tuple) else v

    @model_validator(mode="after")
    def _check(self) -> AttitudeConfig:
        if self.mode == "nadir" and (self.roll_deg or self.pitch_deg):
            raise ValueError("mode 'nadir' looks straight down: use mode 'off_nadir' for "
                             "roll_deg / pitch_deg")
        if self.mode == "target" and self.yaw_steering:
            raise ValueError("yaw_steering needs a scanning mode (nadir or off_nadir)")
        if self.jitter.series is not None and self.suspension is not None:
            raise ValueError("suspension filters modelled jitter; a measured jitter.series is "
                             "taken as the camera's motion: drop suspension")
        return self


class CloudsConfig(_Model):
    """A cloud layer above the terrain (its own surface: parallax and cloud shadows)."""

    cover: float = Field(0.2, ge=0.0, lt=1.0, description="fraction of the sky covered, 0..1")
    base_height_m: float = Field(1000.0, gt=0.0, le=15_000.0,
                                 description="cloud base above the highest terrain point, m")
    thickness_m: float = Field(100.0, ge=0.0, le=2000.0,
                               description="height of the cloud tops above the base, m")
    albedo: float = Field(0.8, gt=0.0, le=1.0, description="mean cloud-top reflectance")
    cell_m: float = Field(2.0, gt=0.0, description="grid cell of the cloud surface, m")


class GeoTiffConfig(_Model):
    """User terrain: a north-up GeoTIFF orthophoto and an optional GeoTIFF DEM, each in any
    CRS with an EPSG code or WKT (read by rasterio, placed by pyproj; see scene.geotiff)."""

    ortho: Path = Field(description="orthophoto GeoTIFF (path relative to the scenario file)")
    dem: Path | None = Field(None, description="DEM GeoTIFF in m covering the orthophoto "
                             "(none: flat)")
    albedo_scale: float | None = Field(None, gt=0.0, description="albedo per pixel value "
                                       "(default: 1 / dtype max for integers, 1 for floats)")
    band: int | None = Field(None, ge=1, le=65535, description="the orthophoto's band to "
                             "use, 1-based (none: the bands averaged, alpha left out)")

    @field_validator("ortho", "dem", mode="after")
    @classmethod
    def _usable_path(cls, v: Path | None) -> Path | None:
        if v is None:
            return v
        text = str(v)
        if "\x00" in text or not text.strip() or text == ".":
            raise ValueError("give the path of a GeoTIFF file")
        if len(text) > 4096:
            raise ValueError(f"path of {len(text)} characters; the system takes at most 4096")
        return v


class SceneConfig(_Model):
    """The terrain tile centred on (lat, lon), rendered by Mitsuba."""

    kind: Literal[SCENE_KINDS] = Field(
        "procedural", description="procedural (generic rural/suburban tile), one of the seed "
        "paper's classes (urban, rural, mountain with snow and clouds, waves, calm_water), "
        "or geotiff (user data)")
    center_lat_deg: float = Field(35.0, ge=-89.0, le=89.0, description="scene centre lat, "
                                  "deg (geotiff: the file's centre instead)")
    center_lon_deg: float = Field(10.0, ge=-180.0, le=360.0, description="scene centre lon, "
                                  "deg (geotiff: the file's centre instead)")
    size_m: float = Field(512.0, gt=0.0, description="tile side (square), m; geotiff: the "
                          "image's extent")
    texel_m: float = Field(0.4, gt=0.0, description="albedo texel size, m; geotiff: its pixel")
    dem_spacing_m: float = Field(4.0, gt=0.0, description="DEM grid spacing, m")
    relief_rms_m: float | None = Field(None, ge=0.0, description="RMS terrain height, m "
                                       "(default per kind: procedural 15, urban 2 plus "
                                       "buildings, rural 8, mountain 4 % of size_m, water 0)")
    sun_elevation_deg: float | None = Field(None, gt=0.0, le=90.0, description="sun elevation, "
                                            "deg (none: from orbit.epoch_utc at the centre)")
    sun_azimuth_deg: _AngleDeg | None = Field(None, description="sun azimuth from north to east, "
                                          "deg (none: from orbit.epoch_utc at the centre)")
    clouds: CloudsConfig | None = Field(None, description="cloud layer (mountain: cover 0.2 "
                                        "by default; set cover 0 to remove)")
    geotiff: GeoTiffConfig | None = Field(None, description="kind geotiff: the files")
    spp: int = Field(4, ge=1, le=4096, description="samples per pixel (also sample time)")
    quadrature: bool = Field(True, description="integrate each pixel and exposure with a fixed "
                             "quadrature, the same every frame (false: Monte Carlo, with noise "
                             "falling as 1 / sqrt(spp))")

    @model_validator(mode="after")
    def _sizes(self) -> SceneConfig:
        if (self.sun_elevation_deg is None) != (self.sun_azimuth_deg is None):
            raise ValueError("give both sun_elevation_deg and sun_azimuth_deg, or neither "
                             "(the sun then follows orbit.epoch_utc)")
        c = self.clouds
        if c is not None and c.cell_m > 1.5 * c.base_height_m:
            raise ValueError("clouds.cell_m exceeds 1.5 x clouds.base_height_m: the cloud layer "
                             "would be less than 2 cells wide; lower clouds.cell_m")
        if (self.kind == "geotiff") != (self.geotiff is not None):
            raise ValueError("kind 'geotiff' needs the geotiff section (ortho, dem), and the "
                             "geotiff section needs kind 'geotiff'")
        if self.kind == "geotiff":
            return self
        if self.size_m / self.texel_m > 16384:
            raise ValueError("size_m / texel_m exceeds 16384 texels; raise texel_m")
        if self.size_m / self.dem_spacing_m > 4096:
            raise ValueError("size_m / dem_spacing_m exceeds 4096 DEM cells; raise dem_spacing_m")
        if abs(round(self.size_m / self.dem_spacing_m) * self.dem_spacing_m - self.size_m) > 1e-6:
            raise ValueError("size_m must be a whole number of dem_spacing_m")
        return self


class TrackerSensorConfig(_Model):
    """The tracking matrix sensor on the focal plane."""

    rows: int = Field(256, ge=16, le=4096, description="sensor rows, px")
    cols: int = Field(256, ge=16, le=4096, description="sensor columns, px")
    center_offset_px: tuple[_OffsetPx, _OffsetPx] = Field(
        (0.0, 0.0), description="sensor centre relative to the principal point, (row, col) px")
    frame_rate_hz: float = Field(100.0, gt=0.0, le=100_000.0, description="frame rate, Hz")
    exposure_s: float | None = Field(None, gt=0.0,
                                     description="exposure, s (default: the frame period)")
    signal: Literal["mean_level", "radiometric"] = Field(
        "mean_level", description="mean_level: frame 0 scaled to mean_signal_dn; "
        "radiometric: electrons from the rendered radiance, camera.optics and camera.radiometry")
    mean_signal_dn: float = Field(100.0, gt=0.0, description="mean_level: mean signal, DN")
    noise_model: Literal["additive", "physical"] = Field(
        "physical", description="physical: shot + dark + read + quantisation (+ "
        "noise_sigma_dn); additive: Gaussian noise_sigma_dn only (the paper's protocol)")
    noise_sigma_dn: float = Field(0.0, ge=0.0, description="additive Gaussian noise sigma, DN")
    gain_e_per_dn: float = Field(4.0, gt=0.0, description="conversion gain, e-/DN")
    full_well_e: float = Field(20_000.0, gt=0.0, description="full-well capacity, e-")
    read_noise_e: float = Field(10.0, ge=0.0, description="read noise, e- rms")
    dark_current_e_per_s: float = Field(50.0, ge=0.0, description="dark current, e-/s/pixel")
    adc_bits: int = Field(12, ge=1, le=16, description="ADC depth, bits")

    @model_validator(mode="after")
    def _exposure(self) -> TrackerSensorConfig:
        if self.exposure_s is not None and self.exposure_s > 1.0 / self.frame_rate_hz + 1e-12:
            raise ValueError("exposure_s cannot exceed the frame period 1 / frame_rate_hz")
        return self


class OpticsConfig(_Model):
    aperture_m: float = Field(0.70, gt=0.0, description="entrance-pupil diameter, m")
    wavelength_m: float = Field(0.675e-6, gt=1e-7, lt=2e-5,
                                description="effective wavelength of the band, m")
    blur_sigma_px: float = Field(0.0, ge=0.0, le=10.0,
                                 description="extra Gaussian blur (aberrations), px")
    transmission: float = Field(0.8, gt=0.0, le=1.0, description="optical transmission")
    diffraction: bool = Field(True, description="apply the diffraction MTF to tracker frames")


class RadiometryConfig(_Model):
    solar_irradiance_w_m2_um: float = Field(1500.0, gt=0.0,
                                            description="band solar spectral irradiance "
                                            "at the top of the atmosphere, W m^-2 um^-1")
    atmosphere_transmittance: float = Field(0.7, gt=0.0, le=1.0,
                                            description="two-way atmospheric transmittance")
    bandwidth_m: float = Field(0.45e-6, gt=0.0, description="spectral bandwidth, m")
    quantum_efficiency: float = Field(0.5, gt=0.0, le=1.0, description="detector QE")


class MainImagerConfig(_Model):
    """The main imager whose residual blur the metrics report."""

    kind: Literal["frame", "tdi"] = Field("frame", description="frame camera or TDI pushbroom")
    center_offset_px: tuple[_OffsetPx, _OffsetPx] = Field(
        (0.0, 0.0), description="imager centre relative to the principal point, (row, col) px")
    exposure_s: float = Field(0.1, gt=0.0, description="frame: exposure, s")
    stages: int = Field(32, ge=1, le=256, description="tdi: number of TDI stages")
    line_rate_hz: float | None = Field(None, gt=0.0, description="tdi: line rate, Hz "
                                       "(default: synchronous with the predicted image motion)")
    clock_phases: int = Field(0, ge=0, le=8, description="tdi: charge steps per line "
                              "(0: continuous transfer)")
    start_s: float = Field(0.0, ge=0.0, description="when the main imager starts exposing, "
                           "s; the compensation loop acquires lock before (the metrics cover "
                           "the imager's exposures from start_s on)")


#: the tracker's widest field of view, rad (its corner rays must still meet the ground)
MAX_TRACKER_FOV_RAD = 0.5


class CameraConfig(_Model):
    focal_length_m: float = Field(10.0, ge=1e-3, le=1e3, description="focal length, m")
    pixel_pitch_m: float = Field(12e-6, ge=1e-7, lt=1e-3, description="pixel pitch, m")
    optics: OpticsConfig = OpticsConfig()
    radiometry: RadiometryConfig = RadiometryConfig()
    tracker: TrackerSensorConfig = TrackerSensorConfig()
    main_imager: MainImagerConfig = MainImagerConfig()

    @model_validator(mode="after")
    def _field_of_view(self) -> CameraConfig:
        t = self.tracker
        fov = max(t.rows, t.cols) * self.pixel_pitch_m / self.focal_length_m
        if fov > MAX_TRACKER_FOV_RAD:
            raise ValueError(f"the tracker sees {fov:.3g} rad across (max(tracker.rows, cols) "
                             "x pixel_pitch_m / focal_length_m); at most "
                             f"{MAX_TRACKER_FOV_RAD} rad: raise focal_length_m or lower "
                             "pixel_pitch_m")
        return self


class SlmConfig(_Model):
    rows: int = Field(ge=1, le=8192, description="pixels down")
    cols: int = Field(ge=1, le=8192, description="pixels across")
    pitch_m: float = Field(gt=0.0, lt=1e-3, description="pixel pitch, m")
    bits: int = Field(8, ge=1, le=16, description="drive levels 2^bits")
    fill_factor: float = Field(0.6, gt=0.0, le=1.0, description="aperture area / pixel area")
    contrast: float = Field(100.0, ge=1.0, description="intensity contrast ratio (on / off)")


class OpticalSensorConfig(_Model):
    rows: int = Field(ge=1, le=8192, description="pixels down")
    cols: int = Field(ge=1, le=8192, description="pixels across")
    pitch_m: float = Field(gt=0.0, lt=1e-3, description="pixel pitch, m")
    bits: int = Field(8, ge=1, le=16, description="ADC bits")
    full_well_e: float = Field(20000.0, gt=0.0, description="full well, electrons")
    read_noise_e: float = Field(15.0, ge=0.0, description="read noise, electrons rms")
    gamma: float = Field(1.0, gt=0.0, le=3.0, description="response curve exponent")
    saturated_fraction: float = Field(0.0, ge=0.0, lt=0.5, description="auto-exposure: "
                                      "fraction of pixels allowed to reach full well")


_OPTICAL_EFFECTS = Literal[
    "slm_amplitude", "slm_quantisation", "slm_contrast", "slm_fill_factor",
    "fourier_sampling", "dc_stop", "jps_response", "jps_saturation", "jps_noise",
    "jps_quantisation", "slm2_quantisation", "slm2_contrast", "output_square_law",
    "output_noise", "output_quantisation"]


_JTOC = JtocModel()  # the defaults below are the hardware model's, written once there


class OpticalConfig(_Model):
    """The emulated optical correlator (method 'optical'); defaults: correlator.optical."""

    input_slm: SlmConfig = SlmConfig(**dataclasses.asdict(_JTOC.input_slm))
    wavelength_m: float = Field(_JTOC.wavelength_m, gt=1e-7, lt=2e-6,
                                description="laser wavelength, m")
    lens1_focal_m: float = Field(_JTOC.lens1_focal_m, gt=0.0,
                                 description="first Fourier lens focal length, m")
    jps_sensor: OpticalSensorConfig = OpticalSensorConfig(
        **dataclasses.asdict(_JTOC.jps_sensor))
    dc_stop_cycles: float = Field(_JTOC.dc_stop_cycles, ge=0.0,
                                  description="DC stop radius, cycles per block")
    slm2: SlmConfig = SlmConfig(**dataclasses.asdict(_JTOC.slm2))
    lens2_focal_m: float = Field(_JTOC.lens2_focal_m, gt=0.0,
                                 description="second lens focal length, m")
    output_sensor: OpticalSensorConfig = OpticalSensorConfig(
        **dataclasses.asdict(_JTOC.output_sensor))
    effects_off: list[_OPTICAL_EFFECTS] = Field(
        default_factory=list, description="hardware effects to switch off (all on by default)")


class TimingConfig(_Model):
    """When the correlator's results arrive (the seed's hardware model: 60 correlations/s)."""

    enabled: bool = Field(False, description="results act when the device would deliver them "
                          "(false: every block of every frame, one frame later)")
    transforms_per_s: float = Field(30.0, gt=0.0, description="Fourier transforms per second "
                                    "of one processor")
    processors: int = Field(2, ge=1, le=64, description="cascaded processors")
    transforms_per_correlation: int = Field(2, ge=1, le=8, description="transforms per "
                                            "correlation")
    pairs_per_transform: int = Field(2, ge=1, le=1024, description="image pairs per transform")
    input_latency_s: float = Field(1.0 / 30.0, ge=0.0, le=10.0, description="frame read-out "
                                   "to input SLM, s")
    output_latency_s: float = Field(0.005, ge=0.0, le=10.0, description="correlation plane to "
                                    "host, s")
    policy: Literal["latest", "fifo"] = Field("latest", description="latest: drop waiting "
                                              "pairs of older frames; fifo: keep all")


class LinkConfig(_Model):
    """How results reach the loop: in process, or as records through the serial driver and a
    device emulator on a pseudo-terminal (with injected faults)."""

    kind: Literal["direct", "emulator"] = Field("direct", description="direct or emulator")
    corrupt_probability: float = Field(0.0, ge=0.0, lt=1.0, description="emulator: chance a "
                                       "record has a flipped bit")
    drop_probability: float = Field(0.0, ge=0.0, lt=1.0, description="emulator: chance a "
                                    "record is lost")


class CorrelatorConfig(_Model):
    method: Literal["jtc", "xcorr", "phase", "optical"] = Field(
        "jtc", description="correlation method (optical: the emulated JTOC)")
    subpixel: Literal["fourier", "gradient", "parabolic", "gaussian", "com"] | None = Field(
        None, description="sub-pixel estimator (default fourier, Newton on the spectrum; "
        "com for optical, which allows com, parabolic, gaussian)")
    block_px: int = Field(64, ge=16, le=1024, description="block side, px")
    n_blocks: int = Field(4, ge=1, le=1024, description="number of tracked blocks")
    false_valid_rate: float = Field(0.005, gt=0.0, lt=1.0, description="largest probability "
                                    "that a valid result is 0.5 px or more off (a noise "
                                    "peak or the estimate's tail)")
    psr_threshold: float | None = Field(None, ge=0.0, description="peak-to-sidelobe floor "
                                        "(null: the correlator's safeguard, 5.5; 7 optical)")
    max_crlb_px: float | None = Field(None, gt=0.0, description="largest predicted 1-sigma "
                                      "error of a valid measurement, px (null: none besides "
                                      "false_valid_rate)")
    rewindow: bool | None = Field(None, description="passes with windows on the common "
                                  "content: null (default) only where a block's first pass "
                                  "needs them, true for every block (the precise path), "
                                  "false for none (one FFT per block)")
    trust_prediction_px: float | None = Field(
        None, gt=0.0, le=64.0, description="start the sub-pixel refinement from the "
        "orbit/attitude/DEM prediction, skipping the integer search, while prediction and "
        "measurement agree within this, px (null: always search)")
    optical: OpticalConfig = OpticalConfig()
    timing: TimingConfig = TimingConfig()
    link: LinkConfig = LinkConfig()

    @model_validator(mode="after")
    def _optical_subpixel(self):
        if self.method == "optical" and self.subpixel not in (None, "com", "parabolic",
                                                              "gaussian"):
            raise ValueError(f"subpixel '{self.subpixel}' needs the spectrum; the optical "
                             "correlator reads a correlation plane: use com, parabolic or "
                             "gaussian")
        if self.link.kind == "emulator" and self.method != "optical":
            raise ValueError("link.kind 'emulator' serves the optical emulation: set "
                             "correlator.method to 'optical'")
        return self

    def jtoc_model(self):
        """The optical correlator's hardware model (correlator.optical.JtocModel)."""
        o = self.optical
        return JtocModel(
            SlmSpec(**o.input_slm.model_dump()), o.wavelength_m, o.lens1_focal_m,
            SensorSpec(**o.jps_sensor.model_dump()), o.dc_stop_cycles,
            SlmSpec(**o.slm2.model_dump()), o.lens2_focal_m,
            SensorSpec(**o.output_sensor.model_dump()),
            frozenset(EFFECTS) - set(o.effects_off))

    def pipeline_timing(self):
        """The device's schedule model (correlator.timing.PipelineTiming), or None."""
        from correlator.timing import PipelineTiming

        t = self.timing
        if not t.enabled:
            return None
        return PipelineTiming(**t.model_dump(exclude={"enabled"}))


#: the packages whose source is imcsim's code (pyproject's top-level packages)
CODE_PACKAGES = ("orbit", "scene", "camera", "correlator", "compensation", "ground", "imc")


@lru_cache(maxsize=1)
def code_digest() -> str:
    """A hash of imcsim's source (every ``.py`` file of ``CODE_PACKAGES``, by path and content).

    The installed version does not change with each commit of an editable install, so a
    checkpoint or a sweep's point keyed by the version alone would be resumed by other code;
    keyed by this it is run again. Read once per process (~10 ms)."""
    import importlib.util

    h = hashlib.sha256()
    for name in CODE_PACKAGES:
        spec = importlib.util.find_spec(name)
        for root in (spec.submodule_search_locations or []) if spec else []:
            root = Path(root)
            for f in sorted(root.rglob("*.py")):
                h.update(f"{name}/{f.relative_to(root).as_posix()}\0".encode())
                h.update(f.read_bytes())
    return h.hexdigest()[:16]


@lru_cache(maxsize=1)
def installed_version() -> str:
    """imcsim's installed version (read once: the metadata lookup costs ~3 ms)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("imcsim")
    except PackageNotFoundError:
        return "unknown"


class BlockConfig(_Model):
    """A loop block picked by ``kind`` from the registry (compensation.blocks); every other
    key is a parameter of that kind (see the kinds' tables below), checked here."""

    model_config = ConfigDict(extra="allow", frozen=True)
    ROLE: ClassVar[str] = ""
    #: schema-level options of a section that are not parameters of the block class
    OPTIONS: ClassVar[tuple[str, ...]] = ()

    kind: str = Field(description="the block's kind")

    @model_validator(mode="after")
    def _params(self):
        check_params(self.ROLE, self.kind, self.params())
        return self

    def params(self) -> dict:
        """The block's parameters as written (schema-level options left out)."""
        return {k: v for k, v in (self.model_extra or {}).items() if k not in self.OPTIONS}

    def option(self, name: str, default=None):
        return (self.model_extra or {}).get(name, default)


class ControllerConfig(BlockConfig):
    """The control law: integrator (today's first-order loop), pi, pii (type 2) with
    optional resonant ``lines`` and a ``notch``, or kalman (model-based predictor).
    ``feedforward: true`` (kalman) adds the orbit/attitude prediction as feed-forward."""

    ROLE: ClassVar[str] = "controller"
    OPTIONS: ClassVar[tuple[str, ...]] = ("feedforward",)
    kind: str = Field("integrator", description="integrator, pi, pii or kalman")

    @model_validator(mode="after")
    def _feedforward(self):
        ff = self.option("feedforward")
        if ff is not None and (self.kind != "kalman" or not isinstance(ff, bool)):
            raise ValueError("@feedforward@ is a true/false option of kind 'kalman'")
        return self


class ActuatorConfig(BlockConfig):
    """The focal-plane stage: ideal (zero-order hold) or piezo (second-order mode, stroke,
    slew, Bouc-Wen hysteresis, creep, DAC)."""

    ROLE: ClassVar[str] = "actuator"
    kind: str = Field("ideal", description="ideal or piezo")


class EstimatorConfig(BlockConfig):
    """How the blocks' shifts become one motion at the main imager: motion_field (weighted
    fit, outliers rejected, re-referencing) or mean (today's)."""

    ROLE: ClassVar[str] = "estimator"
    kind: str = Field("motion_field", description="motion_field or mean")


class SupervisorConfig(BlockConfig):
    """A watch on the loop (on by default; null: none): residual (the residual's running RMS
    against the pseudo-open-loop motion's, in total and within the main imager's exposures;
    when the loop amplifies what it should reject it holds the stage, opens the loop or
    de-rates the controller; its decisions go to metrics.json and are printed as warnings)."""

    ROLE: ClassVar[str] = "supervisor"
    kind: str = Field("residual", description="residual")


class TransportConfig(_Model):
    """Latency and losses between the tracker and the controller (the correlator device's
    own pipeline comes from correlator.timing)."""

    latency_s: float = Field(0.0, ge=0.0, le=10.0, description="extra latency after the "
                             "exposure ends (read-out, computing), s")
    latency_frames: int = Field(0, ge=0, le=100, description="extra latency in tracker "
                                "frames (added to latency_s)")
    drop_probability: float = Field(0.0, ge=0.0, lt=1.0, description="chance a frame's "
                                    "measurement is lost")


class CompensationConfig(_Model):
    """The loop: blocks picked by kind, the transport, and the stability a design must have.
    ``gain`` and ``latency_frames`` of earlier versions are still read (as
    controller.gain and transport.latency_frames)."""

    enabled: bool = Field(True, description="close the loop (false: open loop)")
    controller: ControllerConfig = ControllerConfig(kind="integrator", gain=0.8)
    actuator: ActuatorConfig = ActuatorConfig(kind="ideal")
    estimator: EstimatorConfig = EstimatorConfig(kind="motion_field")
    transport: TransportConfig = TransportConfig()
    supervisor: SupervisorConfig | None = Field(
        SupervisorConfig(kind="residual"), description="the supervisor block (default: "
        "residual, which holds the stage when the loop's measured residual, total or within "
        "an exposure, exceeds the open loop's; null: the loop is not watched)")
    min_phase_margin_deg: float = Field(20.0, ge=0.0, le=90.0, description="a design with "
                                        "less phase margin is refused, deg")
    min_modulus_margin: float = Field(0.25, ge=0.0, le=1.0, description="a design whose "
                                      "loop comes closer to -1 (least |1 + L|), or whose "
                                      "rejection |S| peaks above 1 / this, is refused")

    @model_validator(mode="before")
    @classmethod
    def _legacy(cls, data):
        if not isinstance(data, dict):
            return data
        data = dict(data)
        if "gain" in data:
            if "controller" in data:
                raise ValueError("give the loop gain as controller.gain (compensation.gain is "
                                 "the older spelling), not both")
            data["controller"] = {"kind": "integrator", "gain": data.pop("gain")}
        if "latency_frames" in data:
            tr = dict(data.get("transport") or {})
            if "latency_frames" in tr:
                raise ValueError("give transport.latency_frames (compensation.latency_frames "
                                 "is the older spelling), not both")
            tr["latency_frames"] = data.pop("latency_frames")
            data["transport"] = tr
        return data


class PlantConfig(_Model):
    """What stands for the world the tracker looks at: rendered (Mitsuba frames), texture
    (the scene's albedo, each pixel showing the ground point the camera model puts there;
    numpy; the real correlator) or
    analytic (no images in the loop: measurements = truth + noise of the correlator's
    predicted sigma, predicted on the albedo or on frame 0 rendered once: plant.noise).
    The loop is the same for all three."""

    fidelity: Literal["rendered", "texture", "analytic"] = Field(
        "rendered", description="rendered, texture or analytic")
    sigma_px: float | None = Field(None, gt=0.0, description="analytic: 1-sigma noise of "
                                   "each block's shift, px (default: the correlator's "
                                   "predicted error on the scene of plant.noise)")
    noise: Literal["albedo", "rendered"] = Field(
        "albedo", description="analytic, without sigma_px: the scene the noise is predicted "
        "on. 'albedo': the flat-shaded albedo (no renderer: fast). 'rendered': frame 0 "
        "rendered once (shading and sky), with the renderer's pixel-integration floor and "
        "the correlator's efficiency on it: the rendered tracker's noise (docs/product.md, "
        "issue 32: the record's RMS error after a constant or an affine within 1.5x of the "
        "rendered tracker's)")
    noise_texel_m: float | None = Field(
        None, gt=0.0, description="analytic, noise 'rendered': predict the noise on a tile of "
        "the tracker's footprint at frame 0 with texels of this size (the scene's kind, "
        "relief, DEM and sun), not on the scene itself: for a scene whose texels are coarser "
        "than the tracker's pixels so that it covers a long strip (default: the scene)")


class GyroConfig(_Model):
    """A gyro on the body fused with the record on the ground (product.gyro): it sees the
    attitude, not the focal plane's own effects. Defaults: a Pleiades-class fibre-optic gyro
    (Astrix 200)."""

    arw_deg_rt_h: float = Field(0.0002, gt=0.0, description="angle random walk, deg/sqrt(h)")
    bias_instability_deg_h: float = Field(0.002, ge=0.0, description="bias instability, deg/h")
    rate_hz: float = Field(200.0, gt=0.0, le=100000.0, description="sampling rate, Hz (at "
                           "least the tracker's frame rate)")
    white_noise_urad: float = Field(0.0, ge=0.0, description="white angle noise per sample, "
                                    "urad")


class GroundControlConfig(_Model):
    """Ground control on the strip (product.ground_control), fused with the record on the
    ground: ``kind`` 'points', the line of sight's absolute position at ``points`` instants
    spread evenly over the product, each to ``sigma_px``; or 'orthoimage', a reference
    orthoimage of the scene at ``gsd_factor`` times the product's GSD (its own noise) correlated
    against the corrected product in chips of ``chip_px`` reference pixels at ``points`` places
    along the strip, each fix's accuracy predicted from its correlation."""

    kind: Literal["points", "orthoimage"] = Field(
        "points", description="'points': control points of a stated accuracy; 'orthoimage': a "
        "coarser reference orthoimage correlated against the corrected product (needs "
        "product.render true)")
    points: int = Field(4, ge=1, le=10000, description="control points (orthoimage: chip rows) "
                        "along the strip")
    sigma_px: float = Field(0.02, gt=0.0, description="points: each point's accuracy, px "
                            "(1 sigma)")
    gsd_factor: int = Field(4, ge=2, le=16, description="orthoimage: the reference's GSD as a "
                            "multiple of the product's")
    chip_px: int = Field(32, ge=16, le=256, description="orthoimage: a correlation chip's side, "
                         "reference pixels")


class RestitutionConfig(_Model):
    """How the ground turns the record into the best motion it can know (product.restitution):
    a network of every link (multi-baseline), solved by weighted least squares, then a
    two-sided smoother whose prior is estimated from the record itself."""

    baselines: int | None = Field(None, ge=1, le=32, description="baselines K a chained "
                                  "tracker measures (frame k against k-1 .. k-K; default: "
                                  "what the sensor's overlap allows; 1: today's chain)")
    smoother: bool = Field(True, description="smooth the network's solution (a cubic "
                           "smoothing-spline prior of intensity estimated from the record)")


class ProductConfig(_Model):
    """The main imager's image product: rendered as the camera forms it (a TDI strip line by
    line, or a frame window), static / open loop / closed loop, corrected on the ground from
    the loop's motion record, restored, and judged (MTF, RER, NIIRS): product/ and
    metrics.json product."""

    enabled: bool = Field(False, description="render and process the product")
    render: bool = Field(True, description="render the product's images (false: the "
                         "geometry alone, the lines' offsets from the camera model and the "
                         "record, no image: for trade studies over long strips)")
    lines: int = Field(512, ge=128, le=65536, description="TDI: lines of the strip; frame: "
                       "rows of the window (centred on the imager)")
    cols: int = Field(512, ge=128, le=16384, description="detector columns (centred; the "
                      "quality target's edges need 128 at least)")
    samples: int = Field(8, ge=1, le=64, description="sampling instants per line (TDI: over "
                         "its N-stage integration) or per exposure (frame)")
    start_s: float | None = Field(None, ge=0.0, description="TDI: the first line's start; "
                                  "frame: the exposure's start, s (default: TDI strips "
                                  "centred on the scene centre, from main_imager.start_s on; "
                                  "a frame at main_imager.start_s)")
    run_lines: int = Field(128, ge=8, le=65536, description="lines per restoration PSF (the "
                           "PSF is estimated and deconvolved per run of lines)")
    restore: Literal["wiener", "richardson_lucy"] = Field(
        "wiener", description="deconvolution (scikit-image): wiener or richardson_lucy")
    restitution: RestitutionConfig = Field(default_factory=RestitutionConfig)
    gyro: GyroConfig | None = Field(None, description="a body gyro fused with the record "
                                    "(null: none)")
    ground_control: GroundControlConfig | None = Field(
        None, description="ground control points fused with the record (null: none)")

    @model_validator(mode="after")
    def _orthoimage_needs_images(self) -> ProductConfig:
        gc = self.ground_control
        if gc is not None and gc.kind == "orthoimage" and not self.render:
            raise ValueError("ground_control.kind 'orthoimage' correlates the rendered product: "
                             "set product.render true or use kind 'points'")
        return self


class MetricsConfig(_Model):
    samples_per_frame: int = Field(8, ge=2, le=256,
                                   description="truth samples per tracker exposure")
    blur_images: bool = Field(False, description="frame imager: its worst exposure as a small "
                              "frame product (192 px square of the scene and the slanted-square "
                              "target; static, open and closed loop; the product's own when "
                              "product.enabled) and the target's edge MTF without detector "
                              "noise against its prediction (main_imager.png); a TDI imager's "
                              "picture is its product")
    blur_spp: int = Field(64, ge=1, le=4096, description="samples a pixel (instants, each with "
                          "its footprint offset) of that small frame product; the edge MTF at "
                          "Nyquist scatters by about +-0.02 at 64 against the prediction "
                          "(+-0.01 at 256)")


#: the top-level keys of metrics.json (imc/outputs/report.py summarize and imc/pipeline.py); an
#: expectation's metric path starts with one of them
METRIC_SECTIONS = ("scenario", "frames", "blocks", "compensation_enabled",
                   "without_compensation", "with_compensation", "rms_reduction", "tracker",
                   "loop", "main_imager_start_s", "geometry", "correlator_device", "link",
                   "main_imager_blur", "exposures", "product")


class BoundConfig(_Model):
    """A bound on one metric of metrics.json: ``{max: 0.15}``, ``{min: 5}`` or
    ``{within: [lo, hi]}`` (min and max may be given together). A metric that is a list
    (row, col) must meet the bound in every element unless the path names one (``.0``)."""

    min: float | None = Field(None, description="the metric must be >= min")
    max: float | None = Field(None, description="the metric must be <= max")
    within: tuple[float, float] | None = Field(None, description="the metric must lie in "
                                               "[lo, hi]")

    @model_validator(mode="after")
    def _check(self) -> BoundConfig:
        if self.min is None and self.max is None and self.within is None:
            raise ValueError("give max, min or within [lo, hi]")
        if self.within is not None and (self.min is not None or self.max is not None):
            raise ValueError("give within [lo, hi], or min / max, not both")
        if self.within is not None and self.within[0] > self.within[1]:
            raise ValueError("within [lo, hi] needs lo <= hi")
        if self.min is not None and self.max is not None and self.min > self.max:
            raise ValueError("min exceeds max")
        return self

    @property
    def lo_hi(self) -> tuple[float, float]:
        """The bound as a closed interval (infinite where open)."""
        if self.within is not None:
            return self.within
        return (-np.inf if self.min is None else self.min,
                np.inf if self.max is None else self.max)

    def text(self) -> str:
        """The bound as written, e.g. '<= 0.15', '>= 5', 'in [0.1, 0.2]'."""
        if self.within is not None:
            return f"in [{self.within[0]:g}, {self.within[1]:g}]"
        parts = ([f">= {self.min:g}"] if self.min is not None else []) + (
            [f"<= {self.max:g}"] if self.max is not None else [])
        return " and ".join(parts)


def check_metric_path(path: str) -> str:
    parts = path.split(".")
    if not path or any(not p for p in parts):
        raise ValueError(f"metric path {path!r} is empty or has an empty part; write "
                         "e.g. with_compensation.rms_total_px")
    if parts[0] not in METRIC_SECTIONS:
        raise ValueError(f"metric path {path!r}: metrics.json has no {parts[0]!r}; it "
                         f"starts with one of {', '.join(METRIC_SECTIONS)}")
    return path


class Scenario(_Model):
    name: str = Field("scenario", min_length=1, max_length=200, description="run name")
    seed: int = Field(0, ge=0, lt=2**64, description="master seed of every random draw")
    duration_s: float = Field(1.0, gt=0.0, le=600.0, description="simulated time, s")
    orbit: OrbitConfig = OrbitConfig()
    attitude: AttitudeConfig = AttitudeConfig()
    scene: SceneConfig = SceneConfig()
    camera: CameraConfig = CameraConfig()
    correlator: CorrelatorConfig = CorrelatorConfig()
    compensation: CompensationConfig = CompensationConfig()
    plant: PlantConfig = PlantConfig()
    metrics: MetricsConfig = MetricsConfig()
    product: ProductConfig = ProductConfig()
    expect: dict[str, BoundConfig] = Field(
        {}, description="expectations: metric path of metrics.json (e.g. "
        "with_compensation.rms_total_px, tracker.rms_error_px.0) -> bound; `imc run` prints "
        "a pass/fail table and exits 1 when one fails, `imc check` runs them in CI")

    @field_validator("expect")
    @classmethod
    def _metric_paths(cls, v: dict) -> dict:
        for path in v:
            check_metric_path(path)
        return v

    @field_validator("name")
    @classmethod
    def _safe_name(cls, v: str) -> str:
        if any(c in v for c in "/\\\n"):
            raise ValueError("name may not contain slashes or newlines")
        return v

    @model_validator(mode="after")
    def _cross(self) -> Scenario:
        t = self.camera.tracker
        if self.orbit.kind in ("elements", "tle", "oem") and self.attitude.mode != "target":
            raise ValueError(f"orbit.kind '{self.orbit.kind}' is not placed over the scene: "
                             "use attitude.mode 'target' (stare at the scene centre)")
        if IMAGERS[self.camera.main_imager.kind].scanning and self.attitude.mode == "target":
            raise ValueError("camera.main_imager.kind 'tdi' needs a scanning attitude: set "
                             "attitude.mode to 'nadir' or 'off_nadir' (with yaw_steering)")
        if self.correlator.block_px > min(t.rows, t.cols):
            raise ValueError(
                f"correlator.block_px ({self.correlator.block_px}) exceeds the tracker sensor "
                f"({t.rows} x {t.cols})")
        if self.n_frames < 2:
            raise ValueError("duration_s covers fewer than 2 tracker frames; raise it")
        if self.camera.main_imager.start_s >= self.duration_s:
            raise ValueError("camera.main_imager.start_s must lie within duration_s")
        return self

    @model_validator(mode="after")
    def _aircraft(self) -> Scenario:
        if self.orbit.kind == "aircraft" and self.attitude.mode == "target":
            raise ValueError("attitude.mode: an aircraft's camera looks 'nadir' or 'off_nadir' "
                             "(the flight passes over the scene centre half-way through the run)")
        return self

    @property
    def n_frames(self) -> int:
        return int(round(self.duration_s * self.camera.tracker.frame_rate_hz))

    @property
    def exposure_s(self) -> float:
        t = self.camera.tracker
        return t.exposure_s if t.exposure_s is not None else 1.0 / t.frame_rate_hz

    @property
    def epoch(self) -> np.datetime64:
        """orbit.epoch_utc as numpy datetime64[ns] (UTC); never wraps (range checked)."""
        return np.datetime64(_epoch_utc(self.orbit.epoch_utc), "ns")

    def digest(self) -> str:
        """Stable hash of the full (defaults filled) scenario, imcsim's version and its source
        (`code_digest`), for resuming: a run or a sweep's point is resumed only by the code
        that started it."""
        ver = installed_version() + code_digest()
        # expectations judge a run's metrics, they do not change the run
        return hashlib.sha256((ver + self.model_dump_json(exclude={"expect"})).encode()
                              ).hexdigest()[:16]


#: fields the schema moves from an older spelling: (where the schema checks it, where an
#: older file wrote it)
_LEGACY_PATHS = ((("compensation", "controller", "gain"), ("compensation", "gain")),
                 (("compensation", "transport", "latency_frames"),
                  ("compensation", "latency_frames")))


def _has(data, path) -> bool:
    node = data
    for key in path:
        if not isinstance(node, dict) or key not in node:
            return False
        node = node[key]
    return True


def user_path(loc: tuple, data: object) -> tuple:
    """The location of a validation error as the user wrote it: older spellings
    (compensation.gain) and the list form of attitude.jitter keep their own path."""
    loc = tuple(loc)
    for schema, written in _LEGACY_PATHS:
        if loc[:len(schema)] == schema and not _has(data, schema) and _has(data, written):
            return written + loc[len(schema):]
    if (loc[:3] == ("attitude", "jitter", "sinusoids") and isinstance(data, dict)
            and isinstance(data.get("attitude"), dict)
            and isinstance(data["attitude"].get("jitter"), list)):
        return ("attitude", "jitter") + loc[3:]
    return loc


def format_validation_error(err: ValidationError, source: str, data: object = None) -> str:
    errors = err.errors()
    first = errors[0]
    loc = tuple(first["loc"])
    msg = first["msg"].removeprefix("Value error, ")
    if msg.startswith("@") and "@" in msg[1:]:  # a block parameter names its own field
        name, msg = msg[1:].split("@", 1)
        loc, msg = loc + tuple(name.split(".")), msg.strip()
    loc = ".".join(str(p) for p in user_path(loc, data)) or "(top level)"
    if first["type"] == "extra_forbidden":
        msg = "unknown field (check the spelling; see docs/scenario.md)"
    got = ""
    if first["type"] not in ("missing", "extra_forbidden") and "input" in first:
        val = first["input"]
        if isinstance(val, date):
            got = f" (got {val.isoformat()})"
        elif not isinstance(val, dict | list):
            got = f" (got {short(val)})"
    more = f" [and {len(errors) - 1} more]" if len(errors) > 1 else ""
    return f"{source}: {short(loc, 120)}: {short(msg, 300)}{got}{more}"


def parse_scenario(data: object, source: str = "scenario") -> Scenario:
    """Validate a mapping (e.g. parsed YAML) into a Scenario, or raise ScenarioError."""
    if not isinstance(data, dict):
        raise ScenarioError(f"{source}: the top level must be a mapping of sections "
                            f"(orbit, attitude, scene, camera, ...), got {type(data).__name__}")
    try:
        return Scenario.model_validate(data)
    except ValidationError as e:
        raise ScenarioError(format_validation_error(e, source, data)) from None
    except RecursionError:
        raise ScenarioError(f"{source}: nested deeper than the schema") from None


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario YAML file; every problem becomes a one-line ScenarioError
    (strict YAML: see imc.yamlload)."""
    p = Path(path)
    name = short(str(p), 200)
    try:
        data = load_yaml(read_text(p))
    except YamlInputError as e:
        raise ScenarioError(f"{name}: {e}") from None
    if data is None:
        raise ScenarioError(f"{name}: the file is empty")
    sc = parse_scenario(data, name)
    g = sc.scene.geotiff
    if g is not None:  # files next to the scenario, wherever it is run from
        g = g.model_copy(update={
            "ortho": g.ortho if g.ortho.is_absolute() else p.parent / g.ortho,
            "dem": g.dem if g.dem is None or g.dem.is_absolute() else p.parent / g.dem})
        sc = sc.model_copy(update={"scene": sc.scene.model_copy(update={"geotiff": g})})
    return _files_next_to(sc, p.parent)


def _files_next_to(sc: Scenario, folder: Path) -> Scenario:
    """The scenario with its measured-input files (attitude.jitter.series.file,
    orbit.oem_file) taken relative to ``folder`` unless absolute."""
    s = sc.attitude.jitter.series
    if s is not None and not s.file.is_absolute():
        jit = sc.attitude.jitter.model_copy(update={
            "series": s.model_copy(update={"file": folder / s.file})})
        sc = sc.model_copy(update={"attitude": sc.attitude.model_copy(update={"jitter": jit})})
    o = sc.orbit
    if o.oem_file is not None and not o.oem_file.is_absolute():
        sc = sc.model_copy(update={"orbit": o.model_copy(update={"oem_file":
                                                                 folder / o.oem_file})})
    return sc
