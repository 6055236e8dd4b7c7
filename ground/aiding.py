"""Aiding for the motion-record network: a gyro's relative angles and absolute fixes.

Everything here is in pixels of the main imager (1 px = 1 IFOV); the caller maps the body
angles onto the image axes (+pitch -> +row, +roll -> +col, docs/conventions.md) and gives
the IFOV in radians. The measurements are consumed by :func:`ground.network.solve_network`,
which fuses them with the tracker's links in one sparse least-squares solve.

Gyro (:class:`GyroModel`). Its output is the body angle integrated from its rate samples,
read every ``1 / rate_hz`` s:

    g(t_j) = s_body(t_j) + beta (t_j - t_0) + W(t_j) + w_j,

``W`` the angle random walk (ARW: the integral of white rate noise, variance
``N^2 (t - t_0)``), ``beta`` the residual rate bias, ``w_j`` white angle noise per reading
(readout, quantisation). The gyro sits on the body: it sees attitude, never the focal plane's
own motion (thermal drift, the stage); :func:`gyro_aiding` can carry that as a per-frame
noise ``los_sigma_px`` the solve then separates from the tracker's view.

Between two frame times the reading's increment is a relative-angle measurement of
``s(t_{k+1}) - s(t_k)``: its ARW part is independent from interval to interval (variance
``N^2 dt``), its white part is shared by the two intervals that meet at a frame (a per-frame
noise, solved as an augmented unknown), and the bias enters every interval as ``beta dt``
with ``beta`` one extra unknown per axis whose prior is the bias instability (a gyro
calibrated on orbit keeps its bias within its instability; its wander within a strip of
seconds, far below the instability's correlation time of ~100 s, is neglected).

Absolute fixes (:class:`Absolute`): ground control points (or a reference orthoimage
correlated at sparse points) measure ``s`` itself at some times with a stated accuracy. A
star tracker is the same kind of measurement, but an arcsecond-class one is ~4 px at a
1.2 urad IFOV (:data:`STAR_TRACKER_SIGMA_PX`): m fixes anchor the record's constant to
``4 / sqrt(m)`` px and a trend over the strip to about ``4 sqrt(12 / m) / T`` px/s. Over a
strip of seconds (tens of fixes) that is ~1 px: it can anchor the absolute pointing of long
(minutes) records and keep a gyro's bias honest over an orbit, it cannot anchor the 0.02 px
geometry of a strip; only ground control does that.

References
----------
Sehn & Miller, AIAA 84-2046 (Landsat 4/5 gyro + angular displacement sensor blending);
IEEE Std 952-1997 (gyro error model: angle random walk, bias instability);
../shared/notes/product-facts.md, "Restitution" (Astrix 200 specification, star trackers).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

#: an arcsecond-class star tracker at the 1.2 urad IFOV, px (1 arcsec = 4.85 urad)
STAR_TRACKER_SIGMA_PX = 4.0
_DEG = np.pi / 180.0


@dataclass(frozen=True)
class GyroModel:
    """A rate-integrating gyro's error specification (one axis; both image axes alike).

    Parameters
    ----------
    arw_deg_rthr : float
        Angle random walk N, deg/sqrt(h) (Astrix 200: 0.0002).
    bias_instability_deg_h : float
        Bias instability B, deg/h (Astrix 200: 0.002); the prior sigma of the residual
        rate bias.
    rate_hz : float
        Output rate of the integrated angle, Hz.
    white_noise_urad : float
        White angle noise of each reading (readout, quantisation), urad.
    """

    arw_deg_rthr: float
    bias_instability_deg_h: float
    rate_hz: float
    white_noise_urad: float = 0.0

    def __post_init__(self) -> None:
        for name in ("arw_deg_rthr", "bias_instability_deg_h", "white_noise_urad"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be finite and >= 0, got {v}")
        if not (np.isfinite(self.rate_hz) and self.rate_hz > 0):
            raise ValueError(f"rate_hz must be finite and > 0, got {self.rate_hz}")

    @classmethod
    def pleiades_class(cls, rate_hz: float = 200.0) -> GyroModel:
        """A Pleiades-class fibre-optic gyro (Astrix 200: ARW 0.0002 deg/sqrt(h), bias
        stability 0.002 deg/h); ``rate_hz`` is an assumption (200 Hz, the tracker's)."""
        return cls(0.0002, 0.002, rate_hz)

    def arw_px_rts(self, ifov_rad: float) -> float:
        """ARW in px/sqrt(s) at ``ifov_rad`` (rad/px): N pi/180 / 60 / IFOV."""
        return self.arw_deg_rthr * _DEG / 60.0 / _check_ifov(ifov_rad)

    def bias_px_s(self, ifov_rad: float) -> float:
        """Bias instability in px/s at ``ifov_rad`` (rad/px): B pi/180 / 3600 / IFOV."""
        return self.bias_instability_deg_h * _DEG / 3600.0 / _check_ifov(ifov_rad)

    def white_px(self, ifov_rad: float) -> float:
        """White angle noise per reading in px at ``ifov_rad`` (rad/px)."""
        return self.white_noise_urad * 1e-6 / _check_ifov(ifov_rad)


def _check_ifov(ifov_rad: float) -> float:
    if not (np.isfinite(ifov_rad) and ifov_rad > 0):
        raise ValueError(f"ifov_rad must be finite and > 0 (rad per px, e.g. 1.2e-6), "
                         f"got {ifov_rad}")
    return float(ifov_rad)


def _check_times(t_s: ArrayLike, name: str) -> np.ndarray:
    t = np.asarray(t_s, dtype=np.float64)
    if t.ndim != 1 or t.size < 2 or not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise ValueError(f"{name} must be a finite, strictly increasing 1-D array of at least "
                         f"2 times (s), got shape {t.shape}")
    return t


def _check_series(t_s: ArrayLike, v_px: ArrayLike, t_name: str,
                  v_name: str) -> tuple[np.ndarray, np.ndarray]:
    t = _check_times(t_s, t_name)
    v = np.asarray(v_px, dtype=np.float64)
    if v.shape != (t.size, 2) or not np.all(np.isfinite(v)):
        raise ValueError(f"{v_name} must be finite with shape ({t.size}, 2) to match "
                         f"{t_name}, got {v.shape}")
    return t, v


@dataclass(frozen=True, eq=False)  # holds arrays
class GyroReadings:
    """A gyro's integrated angle as read: ``t_s`` (m,) s, strictly increasing, and
    ``angle_px`` (m, 2) (row, col) px, its arbitrary constant included."""

    t_s: np.ndarray
    angle_px: np.ndarray

    def __post_init__(self) -> None:
        t, a = _check_series(self.t_s, self.angle_px, "t_s", "angle_px")
        object.__setattr__(self, "t_s", t)
        object.__setattr__(self, "angle_px", a)


def simulate_gyro(gyro: GyroModel, t_s: ArrayLike, body_px: ArrayLike, ifov_rad: float,
                  rng: np.random.Generator) -> GyroReadings:
    """Simulate a gyro's readings of a true body motion.

    Readings every ``1 / gyro.rate_hz`` over the span of ``t_s``; the truth is linearly
    interpolated from the dense samples. The residual bias is drawn once per axis from
    N(0, B^2), the ARW as the cumulative sum of N(0, N^2 dt) increments, the white noise per
    reading.

    Parameters
    ----------
    gyro : GyroModel
        The error specification.
    t_s : array_like, (n,)
        Times of the true body motion, s, strictly increasing.
    body_px : array_like, (n, 2)
        True body (attitude) motion in image px (row, col); not the focal plane's own motion.
    ifov_rad : float
        Instantaneous field of view, rad per px.
    rng : numpy.random.Generator
        The caller's named random stream (one per use; docs/conventions.md).

    Returns
    -------
    GyroReadings
        Reading times (s) and integrated angles (px).

    References
    ----------
    IEEE Std 952-1997, annex C (angle random walk, bias instability).
    """
    if not isinstance(rng, np.random.Generator):
        raise ValueError("rng must be a numpy.random.Generator from a named stream "
                         "(e.g. np.random.default_rng([seed, stream_id]))")
    t, body = _check_series(t_s, body_px, "t_s", "body_px")
    dt = 1.0 / gyro.rate_hz
    m = int(np.floor((t[-1] - t[0]) / dt * (1 + 1e-12))) + 1
    if m < 2:
        raise ValueError(f"t_s spans {t[-1] - t[0]:.3g} s: less than one gyro period "
                         f"({dt:.3g} s); give a longer truth or a faster gyro")
    tg = t[0] + dt * np.arange(m)
    truth = np.stack([np.interp(tg, t, body[:, k]) for k in range(2)], axis=1)
    bias = rng.normal(0.0, 1.0, 2) * gyro.bias_px_s(ifov_rad)
    steps = rng.normal(0.0, 1.0, (m - 1, 2)) * (gyro.arw_px_rts(ifov_rad) * np.sqrt(dt))
    walk = np.concatenate([np.zeros((1, 2)), np.cumsum(steps, axis=0)])
    white = rng.normal(0.0, 1.0, (m, 2)) * gyro.white_px(ifov_rad)
    return GyroReadings(tg, truth + bias * (tg - tg[0])[:, None] + walk + white)


@dataclass(frozen=True, eq=False)  # holds arrays
class GyroAiding:
    """A gyro's readings at the frame times, ready for the network solve.

    ``t_s`` (N,) frame times s; ``angle_px`` (N, 2) the reading at each frame; ``step_sigma_px``
    (N - 1,) the independent (ARW) sigma of each interval's increment; ``frame_sigma_px``
    (N,) the per-frame noise shared by the two intervals meeting at a frame (white noise,
    interpolation, the line of sight's own motion); ``bias_sigma_px_s`` the bias prior, px/s.
    """

    t_s: np.ndarray
    angle_px: np.ndarray
    step_sigma_px: np.ndarray
    frame_sigma_px: np.ndarray
    bias_sigma_px_s: float

    def __post_init__(self) -> None:
        t, a = _check_series(self.t_s, self.angle_px, "t_s", "angle_px")
        st = np.asarray(self.step_sigma_px, dtype=np.float64)
        fr = np.asarray(self.frame_sigma_px, dtype=np.float64)
        if st.shape != (t.size - 1,) or not np.all(np.isfinite(st) & (st >= 0)):
            raise ValueError(f"step_sigma_px must be finite, >= 0, shape ({t.size - 1},)")
        if fr.shape != t.shape or not np.all(np.isfinite(fr) & (fr >= 0)):
            raise ValueError(f"frame_sigma_px must be finite, >= 0, shape {t.shape}")
        b = float(self.bias_sigma_px_s)
        if not (np.isfinite(b) and b >= 0):
            raise ValueError(f"bias_sigma_px_s must be finite and >= 0, got {b}")
        for name, v in (("t_s", t), ("angle_px", a), ("step_sigma_px", st),
                        ("frame_sigma_px", fr), ("bias_sigma_px_s", b)):
            object.__setattr__(self, name, v)


def gyro_aiding(gyro: GyroModel, readings: GyroReadings, t_frame_s: ArrayLike, ifov_rad: float, *,
                los_sigma_px: float = 0.0) -> GyroAiding:
    """The gyro's relative-angle measurements between frames, with their covariance.

    The readings are linearly interpolated to the frame times. Per interval the ARW gives an
    independent sigma ``N sqrt(dt_k)``; per frame, the white noise of the two readings it is
    interpolated from (``sigma_w sqrt(u^2 + (1 - u)^2)``, u its fraction of the gyro
    period), the random walk's Brownian-bridge error inside the gyro period
    (``N sqrt(u (1 - u) / rate)``) and ``los_sigma_px`` (the focal plane's own motion the
    body-mounted gyro cannot see) add in quadrature. The model is exact when the gyro
    reads at least as fast as the frames; a slower gyro interpolates neighbouring frames
    from the same pair of readings, and the white noise they then share is not carried
    (the ARW dominates at Astrix-class specifications).

    Parameters
    ----------
    gyro : GyroModel
        The error specification.
    readings : GyroReadings
        What the gyro delivered.
    t_frame_s : array_like, (N,)
        The network's frame times, s, strictly increasing, inside the readings' span.
    ifov_rad : float
        Instantaneous field of view, rad per px.
    los_sigma_px : float
        RMS of the line of sight's motion the gyro does not see, px (0: none).

    Returns
    -------
    GyroAiding
        Readings at the frame times and their error model, px.

    References
    ----------
    IEEE Std 952-1997 (gyro error model).
    """
    t = _check_times(t_frame_s, "t_frame_s")
    tg = readings.t_s
    if t[0] < tg[0] - 1e-12 or t[-1] > tg[-1] + 1e-12:
        raise ValueError(f"t_frame_s spans [{t[0]:.6g}, {t[-1]:.6g}] s, outside the gyro's "
                         f"readings [{tg[0]:.6g}, {tg[-1]:.6g}] s: trim the frames or read "
                         "the gyro longer")
    if not (np.isfinite(los_sigma_px) and los_sigma_px >= 0):
        raise ValueError(f"los_sigma_px must be finite and >= 0, got {los_sigma_px}")
    angle = np.stack([np.interp(t, tg, readings.angle_px[:, k]) for k in range(2)], axis=1)
    j = np.clip(np.searchsorted(tg, t, side="right") - 1, 0, tg.size - 2)
    u = np.clip((t - tg[j]) / (tg[j + 1] - tg[j]), 0.0, 1.0)
    n_arw = gyro.arw_px_rts(ifov_rad)
    sw = gyro.white_px(ifov_rad)
    frame = np.sqrt(sw**2 * (u**2 + (1 - u) ** 2) + n_arw**2 * u * (1 - u) / gyro.rate_hz
                    + los_sigma_px**2)
    return GyroAiding(t, angle, n_arw * np.sqrt(np.diff(t)), frame, gyro.bias_px_s(ifov_rad))


@dataclass(frozen=True, eq=False)  # holds arrays
class Absolute:
    """Absolute measurements of the motion s (ground control, orthoimage points, a star
    tracker): at fractional frame positions ``frame`` (m,) (s linearly interpolated between
    the two frames around it), values ``s_px`` (m, 2) and accuracies ``sigma_px`` (m, 2)."""

    frame: np.ndarray
    s_px: np.ndarray
    sigma_px: np.ndarray

    def __post_init__(self) -> None:
        f = np.atleast_1d(np.asarray(self.frame, dtype=np.float64))
        s = np.asarray(self.s_px, dtype=np.float64)
        if f.ndim != 1 or f.size == 0 or not np.all(np.isfinite(f) & (f >= 0)):
            raise ValueError("frame must be a non-empty 1-D array of finite frame positions "
                             ">= 0")
        if s.shape != (f.size, 2) or not np.all(np.isfinite(s)):
            raise ValueError(f"s_px must be finite with shape ({f.size}, 2), got {s.shape}")
        try:
            sg = np.broadcast_to(np.asarray(self.sigma_px, dtype=np.float64), s.shape).copy()
        except ValueError:
            sg = np.full(s.shape, np.nan)
        if sg.shape != s.shape or not np.all(np.isfinite(sg) & (sg > 0)):
            raise ValueError("sigma_px must be finite, > 0 and broadcast to s_px's shape "
                             "(a stated accuracy per point, px)")
        object.__setattr__(self, "frame", f)
        object.__setattr__(self, "s_px", s)
        object.__setattr__(self, "sigma_px", sg)


def frame_position(t_s: ArrayLike, t_frame_s: ArrayLike) -> np.ndarray:
    """Fractional frame positions of times on the frame times (linear between frames).

    Parameters
    ----------
    t_s : array_like, (m,)
        Times, s, inside the frames' span (a ValueError otherwise).
    t_frame_s : array_like, (N,)
        Frame times, s, strictly increasing.

    Returns
    -------
    numpy.ndarray, (m,)
        Positions in frames (3.5: half-way between frames 3 and 4).

    References
    ----------
    docs/conventions.md, "Time".
    """
    tf = _check_times(t_frame_s, "t_frame_s")
    t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
    if not np.all(np.isfinite(t)) or t.min() < tf[0] or t.max() > tf[-1]:
        raise ValueError(f"t_s must be finite and inside the frames' span [{tf[0]:.6g}, "
                         f"{tf[-1]:.6g}] s")
    return np.interp(t, tf, np.arange(tf.size, dtype=np.float64))


def simulate_absolute(t_s: ArrayLike, truth_t_s: ArrayLike, truth_px: ArrayLike,
                      sigma_px: ArrayLike, t_frame_s: ArrayLike,
                      rng: np.random.Generator) -> Absolute:
    """Simulated absolute fixes (ground control, a star tracker: ``sigma_px`` =
    :data:`STAR_TRACKER_SIGMA_PX`) of the true motion at times ``t_s`` (m,) s.

    Parameters
    ----------
    t_s : array_like, (m,)
        Times of the fixes, s, inside the frames' span.
    truth_t_s, truth_px : array_like, (n,), (n, 2)
        The true motion, densely sampled (s, px), linearly interpolated.
    sigma_px : float or array_like, broadcast to (m, 2)
        Accuracy of each fix, px.
    t_frame_s : array_like, (N,)
        The network's frame times, s.
    rng : numpy.random.Generator
        The caller's named random stream.

    Returns
    -------
    Absolute
        The fixes at their fractional frame positions.

    References
    ----------
    ../shared/notes/product-facts.md, "Restitution" (ground control, star trackers).
    """
    if not isinstance(rng, np.random.Generator):
        raise ValueError("rng must be a numpy.random.Generator from a named stream")
    tt, tp = _check_series(truth_t_s, truth_px, "truth_t_s", "truth_px")
    frame = frame_position(t_s, t_frame_s)
    t = np.interp(frame, np.arange(np.size(t_frame_s)), np.asarray(t_frame_s, float))
    sig = np.broadcast_to(np.asarray(sigma_px, dtype=np.float64), (frame.size, 2))
    s = np.stack([np.interp(t, tt, tp[:, k]) for k in range(2)], axis=1)
    return Absolute(frame, s + sig * rng.normal(0.0, 1.0, sig.shape), sig)
