"""Measured attitude as the true jitter: a CSV of roll / pitch / yaw offsets, or a CCSDS AEM.

A mission team hands over attitude as it measured it (gyro or star-tracker telemetry, a
microvibration test, a flight dynamics attitude ephemeris). imcsim uses it as the true motion
of the body against its nominal pointing (``attitude.mode``), in the same form as modelled
jitter: a rotation vector (roll about x_b, pitch about y_b, yaw about z_b, rad) applied in the
body frame, R_eci_body = R_nominal R(jitter) (docs/conventions.md).

* CSV: a header line naming the columns, then one sample a line. Time is ``t_s`` (seconds
  since orbit.epoch_utc) or ``utc`` (ISO 8601, UTC); the angles are ``roll_<unit>``,
  ``pitch_<unit>``, ``yaw_<unit>`` with the unit one of rad, mrad, urad, deg, arcsec or px
  (IFOVs of the camera). Lines starting with ``#`` are comments.
* CCSDS AEM (Attitude Ephemeris Message, KVN; CCSDS 504.0-B): quaternions between EME2000
  (or GCRF / ICRF) and the body, read here (:func:`read_aem`; ``ccsds-ndm``, the maintained
  reader on PyPI, is GPL-3.0 and imcsim MIT, so the tests only cross-check against it). The
  jitter is the measured attitude against the scenario's nominal one:
  phi(t) = log(R_nominal(t)^T R_eci_from_eme2000 R_eme2000_from_body(t)), the EME2000 -> ECI
  rotation from :mod:`orbit.ccsds`.

Between samples the rotation vector is a cubic spline (not-a-knot) per axis, so its rate is
continuous and analytic; outside the samples it is held at the end values (the run is
refused unless the samples cover it: :meth:`SampledJitter.check_covers`).
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from orbit.ccsds import EME2000_NAMES, eci_from_eme2000, scale_to_utc_s, to_datetime64
from orbit.jitter import JitterSeries

#: radians per unit of a CSV column suffix (px: set from the camera's IFOV)
ANGLE_UNITS_RAD = {"rad": 1.0, "mrad": 1e-3, "urad": 1e-6, "deg": np.pi / 180.0,
                   "arcsec": np.pi / 180.0 / 3600.0}
_AXES = ("roll", "pitch", "yaw")


class AttitudeSeriesError(ValueError):
    """A measured attitude file that cannot be used (the message names the file and fix)."""


@dataclass(frozen=True, eq=False)
class SampledJitter(JitterSeries):
    """Jitter sampled at times ``t_s`` (N,) as rotation vectors ``rotvec_samples_rad`` (N, 3),
    a cubic spline in between.

    The inherited component arrays (axis, frequency_hz, amplitude_rad, phase_rad) hold the
    samples' discrete Fourier components (detrended, one-sided): what code that asks about
    the jitter's spectrum (e.g. how many pose keyframes an exposure needs) reads. Evaluation
    uses the spline, never those components.
    """

    t_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    rotvec_samples_rad: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    source: str = ""

    def __post_init__(self) -> None:
        from scipy.interpolate import CubicSpline

        t = np.asarray(self.t_s, np.float64)
        v = np.asarray(self.rotvec_samples_rad, np.float64)
        if t.ndim != 1 or v.shape != (len(t), 3) or len(t) < 4:
            raise AttitudeSeriesError(f"{self.source}: needs at least 4 samples of (roll, "
                                      "pitch, yaw)")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(v))):
            raise AttitudeSeriesError(f"{self.source}: holds a value that is not a number")
        if np.any(np.diff(t) <= 0.0):
            i = int(np.argmax(np.diff(t) <= 0.0))
            raise AttitudeSeriesError(f"{self.source}: its times do not increase (sample "
                                      f"{i + 1}: {t[i + 1]!r} s after {t[i]!r} s); sort them")
        spline = CubicSpline(t, v, axis=0)
        object.__setattr__(self, "t_s", t)
        object.__setattr__(self, "rotvec_samples_rad", v)
        object.__setattr__(self, "_spline", spline)
        object.__setattr__(self, "_rate", spline.derivative())
        ax, f, a, ph = _spectrum(t, v)
        object.__setattr__(self, "axis", ax)
        object.__setattr__(self, "frequency_hz", f)
        object.__setattr__(self, "amplitude_rad", a)
        object.__setattr__(self, "phase_rad", ph)
        object.__setattr__(self, "chirp_hz_s", np.zeros(len(f)))
        object.__setattr__(self, "growth_per_s", np.zeros(len(f)))

    def __len__(self) -> int:
        return len(self.t_s)

    @property
    def interval_s(self) -> float:
        """The longest interval between samples, s."""
        return float(np.max(np.diff(self.t_s)))

    def _clamped(self, t_s) -> np.ndarray:
        return np.clip(np.asarray(t_s, np.float64), self.t_s[0], self.t_s[-1])

    def rotvec_rad(self, t_s) -> np.ndarray:
        """Jitter rotation vectors (..., 3) = (roll, pitch, yaw) in rad at times t_s."""
        return self._spline(self._clamped(t_s))

    def rate_rad_s(self, t_s) -> np.ndarray:
        """Time derivative (..., 3) of :meth:`rotvec_rad`, rad/s (0 outside the samples)."""
        t = np.asarray(t_s, np.float64)
        inside = (t >= self.t_s[0]) & (t <= self.t_s[-1])
        return self._rate(self._clamped(t)) * inside[..., None]

    def check_covers(self, start_s: float, stop_s: float, frame_rate_hz: float,
                     field_name: str) -> None:
        """Refuse (one line naming ``field_name``) samples that do not cover [start_s, stop_s]
        or are spaced more than a tracker frame period apart within it."""
        t = self.t_s
        tol = 1e-9 * max(1.0, abs(stop_s))
        if t[0] > start_s + tol or t[-1] < stop_s - tol:
            raise AttitudeSeriesError(
                f"{field_name}: {self.source} covers t = {t[0]:.6g} .. {t[-1]:.6g} s, not the "
                f"run's {start_s:g} .. {stop_s:g} s (t = 0 at orbit.epoch_utc); give samples "
                "over the whole run or shorten duration_s")
        lo = max(int(np.searchsorted(t, start_s, side="right")) - 1, 0)
        hi = min(int(np.searchsorted(t, stop_s, side="left")) + 1, len(t))
        dt = float(np.max(np.diff(t[lo:hi])))
        period = 1.0 / frame_rate_hz
        if dt > period * (1.0 + 1e-6):
            raise AttitudeSeriesError(
                f"{field_name}: {self.source} is sampled every {dt * 1e3:.4g} ms "
                f"({1.0 / dt:.4g} Hz), slower than the tracker's {frame_rate_hz:g} Hz frames; "
                f"give samples at >= {frame_rate_hz:g} Hz or lower "
                "camera.tracker.frame_rate_hz")


def _spectrum(t: np.ndarray, v: np.ndarray):
    """(axis, frequency_hz, amplitude_rad, phase_rad) of the samples' detrended DFT on a
    uniform grid of their mean spacing (components above 1e-3 of the largest per axis)."""
    n = len(t)
    tu = np.linspace(t[0], t[-1], n)
    dt = (t[-1] - t[0]) / (n - 1)
    axes, freqs, amps, phases = [], [], [], []
    for k in range(3):
        y = np.interp(tu, t, v[:, k])
        y = y - np.polyval(np.polyfit(tu - tu[0], y, 1), tu - tu[0])
        spec = np.fft.rfft(y) * 2.0 / n
        f = np.fft.rfftfreq(n, dt)
        a = np.abs(spec)
        keep = (f > 0) & (a > 1e-3 * max(float(a.max()), 1e-300))
        axes.append(np.full(int(keep.sum()), k))
        freqs.append(f[keep])
        amps.append(a[keep])
        phases.append(np.angle(spec[keep]) + np.pi / 2.0)
    return (np.concatenate(axes).astype(int), np.concatenate(freqs), np.concatenate(amps),
            np.concatenate(phases))


# ----- CSV --------------------------------------------------------------------------------

def _read_series_text(path: str | Path, what: str) -> tuple[str, str]:
    """(the name errors use: ``what`` and the path, the file's text); one line naming both
    when it cannot be read."""
    p = Path(path)
    name = f"{what} {p}"
    try:
        return name, p.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as e:
        raise AttitudeSeriesError(f"{name}: cannot read it "
                                  f"({getattr(e, 'strerror', None) or e})") from None


def read_jitter_csv(path: str | Path, epoch_utc: np.datetime64, ifov_rad: float,
                    what: str = "attitude.jitter.series.file") -> SampledJitter:
    """Jitter samples from a CSV (module docstring) with t = 0 at ``epoch_utc``.

    Raises
    ------
    AttitudeSeriesError
        One line naming ``what``, the file and the fix.
    """
    name, text = _read_series_text(path, what)
    rows = [r for r in csv.reader(line for line in text.splitlines()
                                  if line.strip() and not line.lstrip().startswith("#"))]
    if len(rows) < 2:
        raise AttitudeSeriesError(f"{name}: needs a header line and samples")
    head = [h.strip().lower() for h in rows[0]]
    tcol = next((i for i, h in enumerate(head) if h in ("t_s", "utc")), None)
    if tcol is None:
        raise AttitudeSeriesError(f"{name}: no time column; name it t_s (s since "
                                  "orbit.epoch_utc) or utc (ISO 8601)")
    cols, scale = [], []
    for ax in _AXES:
        hit = [(i, h[len(ax) + 1:]) for i, h in enumerate(head) if h.startswith(ax + "_")]
        if len(hit) != 1:
            raise AttitudeSeriesError(
                f"{name}: needs one column {ax}_<unit> (unit: "
                f"{', '.join([*ANGLE_UNITS_RAD, 'px'])}), got header {','.join(head)}")
        i, unit = hit[0]
        if unit == "px":
            s = ifov_rad
        elif unit in ANGLE_UNITS_RAD:
            s = ANGLE_UNITS_RAD[unit]
        else:
            raise AttitudeSeriesError(f"{name}: column {head[i]}: unit {unit!r} is not one of "
                                      f"{', '.join([*ANGLE_UNITS_RAD, 'px'])}")
        cols.append(i)
        scale.append(s)
    t, vals = [], []
    for k, r in enumerate(rows[1:], start=2):
        try:
            if head[tcol] == "t_s":
                t.append(float(r[tcol]))
            else:
                dt = to_datetime64(r[tcol].strip()) - np.datetime64(epoch_utc, "ns")
                t.append(float(dt / np.timedelta64(1, "ns")) * 1e-9)
            vals.append([float(r[i]) for i in cols])
        except (ValueError, IndexError):
            raise AttitudeSeriesError(f"{name}: line {k} ({','.join(r)[:60]}) is not "
                                      f"{len(head)} numbers") from None
    return SampledJitter(t_s=np.array(t), rotvec_samples_rad=np.array(vals) * np.array(scale),
                         source=str(path))


def write_jitter_csv(path: str | Path, t_s: np.ndarray, rotvec_rad: np.ndarray,
                     comment: str = "") -> None:
    """Write jitter samples as the CSV :func:`read_jitter_csv` reads (angles in urad)."""
    lines = [f"# {c}" for c in comment.splitlines()] + ["t_s,roll_urad,pitch_urad,yaw_urad"]
    lines += [f"{t:.9f},{v[0] * 1e6:.9f},{v[1] * 1e6:.9f},{v[2] * 1e6:.9f}"
              for t, v in zip(np.asarray(t_s), np.asarray(rotvec_rad) * 1.0, strict=True)]
    Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")


# ----- CCSDS AEM --------------------------------------------------------------------------

@dataclass(frozen=True)
class AttitudeEphemeris:
    """Measured attitude: times ``t_s`` (N,) since the run's epoch and rotations
    ``eme2000_from_body`` (N, 3, 3) (columns: the body axes in EME2000)."""

    t_s: np.ndarray
    eme2000_from_body: np.ndarray
    source: str


def _kvn_segments(lines: list[str], name: str) -> list[tuple[dict, list[list[str]]]]:
    """(metadata, data rows) of each segment of a KVN message: ``KEY = value`` lines between
    META_START and META_STOP, whitespace-separated rows between DATA_START and DATA_STOP;
    COMMENT lines and blank lines skipped (CCSDS 504.0-B, 7.x: KVN)."""
    segs: list[tuple[dict, list[list[str]]]] = []
    state, meta, rows = "header", {}, []
    for k, raw in enumerate(lines, start=1):
        line = raw.strip()
        if not line or line.startswith("COMMENT"):
            continue
        if line == "META_START":
            if state == "meta":
                raise AttitudeSeriesError(f"{name}: line {k}: META_START inside a metadata block")
            state, meta, rows = "meta", {}, []
        elif line == "META_STOP":
            state = "between"
        elif line == "DATA_START":
            if state != "between":
                raise AttitudeSeriesError(f"{name}: line {k}: DATA_START without metadata")
            state = "data"
        elif line == "DATA_STOP":
            segs.append((meta, rows))
            state = "header"
        elif state == "data":
            rows.append(line.split())
        elif "=" in line:
            key, _, value = line.partition("=")
            if state == "meta":
                meta[key.strip().upper()] = value.strip()
            elif state == "header" and key.strip().upper() == "CCSDS_AEM_VERS":
                meta["CCSDS_AEM_VERS"] = value.strip()
        else:
            raise AttitudeSeriesError(f"{name}: line {k} ({line[:40]}) is neither KEY = value "
                                      "nor a data line")
    if state == "data":  # a file that ends without DATA_STOP (some writers omit it)
        segs.append((meta, rows))
    return segs


def read_aem(path: str | Path, epoch_utc: np.datetime64,
             what: str = "attitude.jitter.series.file") -> AttitudeEphemeris:
    """The quaternion segments of a CCSDS AEM in KVN (CCSDS 504.0-B, versions 1 and 2), with
    t = 0 at ``epoch_utc``.

    Quaternions follow the standard (Shuster's convention): ATTITUDE_DIR A2B's quaternion
    gives the matrix taking frame-A components to frame B; QUATERNION_TYPE FIRST or LAST
    places the scalar (version 2: always last). One frame must be EME2000 (or GCRF / ICRF),
    the other the body.

    Raises
    ------
    AttitudeSeriesError
        One line naming ``what``, the file and the fix.
    """
    from scipy.spatial.transform import Rotation

    name, text = _read_series_text(path, what)
    if text.lstrip().startswith("<"):
        raise AttitudeSeriesError(f"{name}: an XML message; imcsim reads AEMs in KVN (convert "
                                  "it, or give the attitude as a CSV)")
    if "CCSDS_AEM_VERS" not in text:
        raise AttitudeSeriesError(f"{name}: no CCSDS_AEM_VERS line: not an attitude "
                                  "ephemeris message (AEM)")
    segments = _kvn_segments(text.splitlines(), name)
    t_all, m_all = [], []
    for meta, rows in segments:
        kind = meta.get("ATTITUDE_TYPE", "").upper()
        if kind != "QUATERNION":
            raise AttitudeSeriesError(f"{name}: ATTITUDE_TYPE {kind or '(none)'}; imcsim reads "
                                      "QUATERNION segments")
        fa = meta.get("REF_FRAME_A", "").upper()
        fb = meta.get("REF_FRAME_B", "").upper()
        if fa in EME2000_NAMES and fb not in EME2000_NAMES:
            inertial_is_a = True
        elif fb in EME2000_NAMES and fa not in EME2000_NAMES:
            inertial_is_a = False
        else:
            raise AttitudeSeriesError(f"{name}: REF_FRAME_A {fa}, REF_FRAME_B {fb}: imcsim needs "
                                      f"one of them inertial ({', '.join(sorted(EME2000_NAMES))})"
                                      " and the other the body")
        direction = meta.get("ATTITUDE_DIR", "A2B").upper()
        if direction not in ("A2B", "B2A"):
            raise AttitudeSeriesError(f"{name}: ATTITUDE_DIR {direction} is not A2B or B2A")
        first = meta.get("QUATERNION_TYPE", "LAST").upper() == "FIRST"
        q, t = [], []
        for r in rows:
            if len(r) != 5:
                raise AttitudeSeriesError(f"{name}: data line '{' '.join(r)[:60]}' is not an "
                                          "epoch and 4 quaternion components")
            try:
                v = [float(x) for x in r[1:]]
                t.append(to_datetime64(r[0]))
            except ValueError:
                raise AttitudeSeriesError(f"{name}: data line '{' '.join(r)[:60]}' is not an "
                                          "epoch and 4 numbers") from None
            q.append(v[1:] + v[:1] if first else v)  # scalar last
        if not t:
            continue
        try:
            shift = scale_to_utc_s(meta.get("TIME_SYSTEM", "UTC"), t[0])
        except ValueError as e:
            raise AttitudeSeriesError(f"{name}: {e}") from None
        ep = np.array(t, "datetime64[ns]") + np.timedelta64(int(round(shift * 1e9)), "ns")
        t_all.append((ep - np.datetime64(epoch_utc, "ns")) / np.timedelta64(1, "ns") * 1e-9)
        qa = np.array(q)
        if np.any(np.abs(np.linalg.norm(qa, axis=1) - 1.0) > 1e-2):
            raise AttitudeSeriesError(f"{name}: quaternions of norm other than 1 (by more than "
                                      "1 %); check the columns")
        # Shuster: q_A2B's attitude matrix A (v_B = A v_A) is the transpose of scipy's active
        # rotation of the same components, so scipy's matrix is A's inverse: a_from_b
        rot = Rotation.from_quat(qa).as_matrix()
        a_from_b = rot if direction == "A2B" else np.swapaxes(rot, -1, -2)
        m_all.append(a_from_b if inertial_is_a else np.swapaxes(a_from_b, -1, -2))
    if not t_all:
        raise AttitudeSeriesError(f"{name}: holds no attitude states (DATA_START .. DATA_STOP)")
    t = np.concatenate(t_all)
    m = np.concatenate(m_all)
    order = np.argsort(t, kind="stable")
    t, m = t[order], m[order]
    keep = np.r_[True, np.diff(t) > 0]  # segments that share a boundary epoch
    return AttitudeEphemeris(t[keep], m[keep], str(path))


def rotvec_of(r: np.ndarray) -> np.ndarray:
    """Rotation vectors (..., 3), rad, of rotation matrices (..., 3, 3)."""
    from scipy.spatial.transform import Rotation

    flat = np.asarray(r, np.float64).reshape(-1, 3, 3)
    return Rotation.from_matrix(flat).as_rotvec().reshape(r.shape[:-2] + (3,))


def jitter_from_attitude(aem: AttitudeEphemeris, nominal_eci_from_body, epoch_utc,
                         ) -> SampledJitter:
    """The jitter of a measured attitude against the nominal one: samples of
    log(N(t)^T R_eci_from_eme2000 R_eme2000_from_body(t)) at the ephemeris' times.

    ``nominal_eci_from_body``: a function of t_s (N,) giving (N, 3, 3) rotations (e.g.
    ``lambda t: attitude.eci_from_body(orbit, t, nominal=True)``).
    """
    m = eci_from_eme2000(np.datetime64(epoch_utc, "ns"))
    n = nominal_eci_from_body(aem.t_s)
    rel = np.swapaxes(n, -1, -2) @ (m @ aem.eme2000_from_body)
    return SampledJitter(t_s=aem.t_s, rotvec_samples_rad=rotvec_of(rel), source=aem.source)


def aem_text(epoch_utc: np.datetime64, t_s: np.ndarray, eme2000_from_body: np.ndarray,
             object_name: str = "IMCSIM", comment: str = "") -> str:
    """A CCSDS AEM (KVN, version 1.0; UTC; EME2000 -> body quaternions, scalar last) of
    rotations ``eme2000_from_body`` (N, 3, 3) at ``epoch_utc`` + ``t_s``."""
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(np.asarray(eme2000_from_body)).as_quat()  # x, y, z, w (active)
    q *= np.where(q[:, 3:] < 0, -1.0, 1.0)
    ep = (np.datetime64(epoch_utc, "ns")
          + np.round(np.asarray(t_s) * 1e9).astype("timedelta64[ns]"))
    stamp = [str(e)[:26] for e in ep]
    head = ["CCSDS_AEM_VERS = 1.0", f"CREATION_DATE = {stamp[0][:19]}",
            "ORIGINATOR = IMCSIM", "", "META_START"]
    head += [f"COMMENT {c}" for c in comment.splitlines()]
    head += [f"OBJECT_NAME = {object_name}", "OBJECT_ID = 2026-000A", "CENTER_NAME = EARTH",
             "REF_FRAME_A = EME2000", "REF_FRAME_B = SC_BODY_1", "ATTITUDE_DIR = A2B",
             "TIME_SYSTEM = UTC", f"START_TIME = {stamp[0]}", f"STOP_TIME = {stamp[-1]}",
             "ATTITUDE_TYPE = QUATERNION", "QUATERNION_TYPE = LAST",
             "INTERPOLATION_METHOD = HERMITE", "INTERPOLATION_DEGREE = 3", "META_STOP", "",
             "DATA_START"]
    body = [f"{s} {a:.15f} {b:.15f} {c:.15f} {d:.15f}" for s, (a, b, c, d) in zip(stamp, q,
                                                                                   strict=True)]
    return "\n".join(head + body + ["DATA_STOP", ""])


def measured_attitude(jitter_rad: np.ndarray, t_s: np.ndarray, nominal_eci_from_body,
                      epoch_utc) -> np.ndarray:
    """The EME2000 <- body rotations (N, 3, 3) of a body that moves by ``jitter_rad`` (N, 3)
    about its nominal attitude: what an attitude ephemeris of that motion holds (the inverse
    of :func:`jitter_from_attitude`)."""
    from orbit.attitude import rotation_matrices

    m = eci_from_eme2000(np.datetime64(epoch_utc, "ns"))
    return m.T @ nominal_eci_from_body(np.asarray(t_s)) @ rotation_matrices(jitter_rad)
