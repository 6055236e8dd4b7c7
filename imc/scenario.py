"""Scenario schema: one YAML describes orbit, attitude, scene, camera, correlator and loop.

Every field has a unit in its name or description; unknown fields are errors (typos must not
silently fall back to defaults). :func:`load_scenario` turns any problem into a
:class:`ScenarioError` whose one-line message names the field and the fix.
"""

from __future__ import annotations

import hashlib
from datetime import datetime
from pathlib import Path
from typing import Literal

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator


class ScenarioError(ValueError):
    """A scenario file that cannot be used; the message is one line naming the field."""


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class OrbitConfig(_Model):
    """Circular orbit placed so that the satellite is over the scene centre at t = 0."""

    altitude_m: float = Field(681_000.0, gt=150_000.0, lt=50_000_000.0,
                              description="altitude above the WGS84 equatorial radius, m")
    inclination_deg: float = Field(98.1, ge=0.0, le=180.0, description="inclination, deg")
    epoch_utc: datetime = Field(datetime(2026, 6, 21, 10, 30),
                                description="UTC time of t = 0 (ISO 8601)")
    pass_direction: Literal["descending", "ascending"] = Field(
        "descending", description="which pass crosses the scene at t = 0")


class JitterConfig(_Model):
    """One sinusoidal attitude-jitter term; give the amplitude in urad or in px (IFOVs)."""

    axis: Literal["roll", "pitch", "yaw"] = Field(
        description="body axis: roll moves the image along columns, pitch along rows")
    frequency_hz: float = Field(gt=0.0, description="frequency, Hz")
    amplitude_urad: float | None = Field(None, ge=0.0, description="amplitude, urad")
    amplitude_px: float | None = Field(None, ge=0.0,
                                       description="amplitude in pixels (IFOVs) of the camera")
    phase_deg: float = Field(0.0, description="phase at t = 0, deg")

    @model_validator(mode="after")
    def _one_amplitude(self) -> JitterConfig:
        if (self.amplitude_urad is None) == (self.amplitude_px is None):
            raise ValueError("give exactly one of amplitude_urad or amplitude_px")
        return self


class AttitudeConfig(_Model):
    mode: Literal["target", "nadir"] = Field(
        "target",
        description="'target': line of sight held on the scene centre (staring frame camera);"
        " 'nadir': geocentric nadir (the image then flows ~8,300 px/s along the rows)")
    jitter: tuple[JitterConfig, ...] = Field((), description="sinusoidal jitter terms")


class SceneConfig(_Model):
    """Procedural terrain tile centred on (lat, lon), rendered by Mitsuba."""

    center_lat_deg: float = Field(35.0, ge=-89.0, le=89.0, description="scene centre lat, deg")
    center_lon_deg: float = Field(10.0, ge=-180.0, le=360.0, description="scene centre lon, deg")
    size_m: float = Field(512.0, gt=0.0, description="tile side (square), m")
    texel_m: float = Field(0.4, gt=0.0, description="albedo texel size, m")
    dem_spacing_m: float = Field(4.0, gt=0.0, description="DEM grid spacing, m")
    relief_rms_m: float = Field(15.0, ge=0.0, description="RMS terrain height, m")
    sun_elevation_deg: float = Field(50.0, gt=0.0, le=90.0, description="sun elevation, deg")
    sun_azimuth_deg: float = Field(140.0, description="sun azimuth from north to east, deg")
    spp: int = Field(4, ge=1, le=4096, description="samples per pixel (also sample time)")

    @model_validator(mode="after")
    def _sizes(self) -> SceneConfig:
        if self.size_m / self.texel_m > 16384:
            raise ValueError("size_m / texel_m exceeds 16384 texels; raise texel_m")
        if self.size_m / self.dem_spacing_m > 4096:
            raise ValueError("size_m / dem_spacing_m exceeds 4096 DEM cells; raise dem_spacing_m")
        if abs(round(self.size_m / self.dem_spacing_m) * self.dem_spacing_m - self.size_m) > 1e-6:
            raise ValueError("size_m must be a whole number of dem_spacing_m")
        return self


class TrackerSensorConfig(_Model):
    """The tracking matrix sensor on the focal plane (centred on the principal point)."""

    rows: int = Field(256, ge=16, le=4096, description="sensor rows, px")
    cols: int = Field(256, ge=16, le=4096, description="sensor columns, px")
    frame_rate_hz: float = Field(100.0, gt=0.0, le=100_000.0, description="frame rate, Hz")
    exposure_s: float | None = Field(None, gt=0.0,
                                     description="exposure, s (default: the frame period)")
    mean_signal_dn: float = Field(100.0, gt=0.0, description="mean signal, DN")
    noise_sigma_dn: float = Field(5.0, ge=0.0, description="additive noise sigma, DN")
    adc_bits: int = Field(12, ge=1, le=16, description="ADC depth, bits")

    @model_validator(mode="after")
    def _exposure(self) -> TrackerSensorConfig:
        if self.exposure_s is not None and self.exposure_s > 1.0 / self.frame_rate_hz + 1e-12:
            raise ValueError("exposure_s cannot exceed the frame period 1 / frame_rate_hz")
        return self


class CameraConfig(_Model):
    focal_length_m: float = Field(10.0, gt=0.0, description="focal length, m")
    pixel_pitch_m: float = Field(12e-6, gt=0.0, lt=1e-3, description="pixel pitch, m")
    tracker: TrackerSensorConfig = TrackerSensorConfig()


class CorrelatorConfig(_Model):
    method: Literal["jtc", "xcorr", "phase"] = Field("jtc", description="correlation method")
    subpixel: Literal["fourier", "gradient", "parabolic", "gaussian", "com"] = Field(
        "fourier", description="sub-pixel estimator (fourier: Newton on the spectrum)")
    block_px: int = Field(64, ge=16, le=1024, description="block side, px")
    n_blocks: int = Field(4, ge=1, le=1024, description="number of tracked blocks")
    psr_threshold: float = Field(7.0, ge=0.0, description="peak-to-sidelobe threshold")
    max_crlb_px: float = Field(0.15, gt=0.0, description="largest predicted 1-sigma error "
                               "of a valid measurement, px")
    rewindow: bool = Field(True, description="second pass with windows on the common content "
                           "(about 2x the cost; false: one FFT per block)")


class CompensationConfig(_Model):
    enabled: bool = Field(True, description="close the loop (false: open loop)")
    gain: float = Field(0.8, gt=0.0, le=2.0, description="first-order loop gain per frame")
    latency_frames: int = Field(0, ge=0, le=100,
                                description="extra frames before a measurement acts")


class MetricsConfig(_Model):
    main_exposure_s: float = Field(0.1, gt=0.0, description="main-imager exposure for MTF, s")
    samples_per_frame: int = Field(8, ge=2, le=256,
                                   description="truth samples per tracker exposure")


class Scenario(_Model):
    name: str = Field("scenario", min_length=1, description="run name")
    seed: int = Field(0, ge=0, description="master seed of every random draw")
    duration_s: float = Field(1.0, gt=0.0, le=600.0, description="simulated time, s")
    orbit: OrbitConfig = OrbitConfig()
    attitude: AttitudeConfig = AttitudeConfig()
    scene: SceneConfig = SceneConfig()
    camera: CameraConfig = CameraConfig()
    correlator: CorrelatorConfig = CorrelatorConfig()
    compensation: CompensationConfig = CompensationConfig()
    metrics: MetricsConfig = MetricsConfig()

    @field_validator("name")
    @classmethod
    def _safe_name(cls, v: str) -> str:
        if any(c in v for c in "/\\\n"):
            raise ValueError("name may not contain slashes or newlines")
        return v

    @model_validator(mode="after")
    def _cross(self) -> Scenario:
        t = self.camera.tracker
        if self.correlator.block_px > min(t.rows, t.cols):
            raise ValueError(
                f"correlator.block_px ({self.correlator.block_px}) exceeds the tracker sensor "
                f"({t.rows} x {t.cols})")
        if self.n_frames < 2:
            raise ValueError("duration_s covers fewer than 2 tracker frames; raise it")
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
        e = self.orbit.epoch_utc
        if e.tzinfo is not None:
            e = e.replace(tzinfo=None) - (e.utcoffset() or 0)
        return np.datetime64(e, "ns")

    def digest(self) -> str:
        """Stable hash of the full (defaults filled) scenario and imcsim version, for resuming."""
        from importlib.metadata import PackageNotFoundError, version

        try:
            ver = version("imcsim")
        except PackageNotFoundError:
            ver = "unknown"
        return hashlib.sha256((ver + self.model_dump_json()).encode()).hexdigest()[:16]


def _format_validation_error(err: ValidationError, source: str) -> str:
    errors = err.errors()
    first = errors[0]
    loc = ".".join(str(p) for p in first["loc"]) or "(top level)"
    msg = first["msg"].removeprefix("Value error, ")
    if first["type"] == "extra_forbidden":
        msg = "unknown field (check the spelling; see docs/scenario.md)"
    got = ""
    if first["type"] not in ("missing", "extra_forbidden") and "input" in first:
        val = first["input"]
        if not isinstance(val, dict | list):
            got = f" (got {val!r})"
    more = f" [and {len(errors) - 1} more]" if len(errors) > 1 else ""
    return f"{source}: {loc}: {msg}{got}{more}"


def parse_scenario(data: object, source: str = "scenario") -> Scenario:
    """Validate a mapping (e.g. parsed YAML) into a Scenario, or raise ScenarioError."""
    if not isinstance(data, dict):
        raise ScenarioError(f"{source}: the top level must be a mapping of sections "
                            f"(orbit, attitude, scene, camera, ...), got {type(data).__name__}")
    try:
        return Scenario.model_validate(data)
    except ValidationError as e:
        raise ScenarioError(_format_validation_error(e, source)) from None


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario YAML file; every problem becomes a one-line ScenarioError."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ScenarioError(f"{p}: file not found") from None
    except (OSError, UnicodeDecodeError) as e:
        raise ScenarioError(f"{p}: cannot read the file ({e.__class__.__name__}: {e})") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(e, "problem", None) or str(e).splitlines()[0]
        raise ScenarioError(f"{p}: YAML syntax error{where}: {problem}") from None
    if data is None:
        raise ScenarioError(f"{p}: the file is empty")
    return parse_scenario(data, str(p))
