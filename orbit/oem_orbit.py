"""An orbit from a CCSDS Orbit Ephemeris Message (OEM, CCSDS 502.0-B), read by the ``oem``
package.

The states (km, km/s, in EME2000 / GCRF / ICRF, TEME or an Earth-fixed ITRF frame; centre
EARTH; time system UTC, TAI, TT or GPS) are turned into imcsim's ECI frame (orbit.ccsds) and
interpolated by a cubic Hermite spline in position and velocity: its error is
~ omega^4 r h^4 / 384, 0.3 mm for LEO states every 10 s (0.3 m every 60 s), and the velocity
is the spline's derivative. More than :data:`EXTRAPOLATE_S` outside the states the orbit is
refused (ValueError); within it (the central differences of the nominal pointing, 1 ms) the
end polynomial is extended.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from orbit.ccsds import (
    ECEF_NAMES,
    EME2000_NAMES,
    TEME_NAMES,
    eci_from_eme2000,
    scale_to_utc_s,
    to_datetime64,
)
from orbit.frames import OMEGA_EARTH_RAD_S, eci_to_ecef_matrix, gmst_rad
from orbit.kepler import EarthOrbit

#: how far (s) beyond its first and last state an OEM orbit is evaluated
EXTRAPOLATE_S = 1.0


@dataclass(frozen=True)
class OemOrbit(EarthOrbit):
    """Orbit states ``t_s`` (N,) since ``epoch_utc``, ECI positions ``r_m`` (N, 3) and
    velocities ``v_mps`` (N, 3), Hermite-interpolated."""

    epoch_utc: np.datetime64
    t_s: np.ndarray
    r_m: np.ndarray
    v_mps: np.ndarray
    source: str = ""
    _spline: object = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        from scipy.interpolate import CubicHermiteSpline

        t = np.asarray(self.t_s, np.float64)
        if len(t) < 2 or np.any(np.diff(t) <= 0):
            raise ValueError(f"{self.source}: needs at least 2 states at increasing times")
        object.__setattr__(self, "epoch_utc", np.datetime64(self.epoch_utc, "ns"))
        object.__setattr__(self, "_spline", CubicHermiteSpline(t, self.r_m, self.v_mps, axis=0))

    @property
    def span_s(self) -> tuple[float, float]:
        """The times (s since epoch_utc) it can be evaluated at (EXTRAPOLATE_S past the
        states)."""
        return (float(self.t_s[0]) - EXTRAPOLATE_S, float(self.t_s[-1]) + EXTRAPOLATE_S)

    def covers(self, start_s: float, stop_s: float) -> bool:
        """Whether the states span [start_s, stop_s]."""
        return bool(self.t_s[0] <= start_s and self.t_s[-1] >= stop_s)

    def state_eci(self, t_s: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """ECI position (..., 3) in m and velocity (..., 3) in m/s.

        Raises
        ------
        ValueError
            At a time more than EXTRAPOLATE_S outside the states.
        """
        t = np.asarray(t_s, dtype=np.float64)
        lo, hi = self.span_s
        if t.size and (t.min() < lo or t.max() > hi):
            raise ValueError(f"{self.source} has states for t = {self.t_s[0]:.6g} .. "
                             f"{self.t_s[-1]:.6g} s only, asked for {t.min():.6g} .. "
                             f"{t.max():.6g} s")
        return self._spline(t), self._spline(t, 1)


def read_oem(path: str | Path, epoch_utc: np.datetime64, what: str = "orbit.oem_file"
             ) -> OemOrbit:
    """The states of a CCSDS OEM (KVN or XML) as an :class:`OemOrbit` with t = 0 at
    ``epoch_utc``.

    Raises
    ------
    ValueError
        One line naming ``what``, the file and the fix.
    """
    p = Path(path)
    name = f"{what} {p}"
    try:
        from oem import OrbitEphemerisMessage

        msg = OrbitEphemerisMessage.open(str(p))
    except OSError as e:
        raise ValueError(f"{name}: cannot read it ({e.strerror or e})") from None
    except Exception as e:  # the oem package raises several kinds on a malformed message
        text = " ".join(str(e).split())[:160]
        raise ValueError(f"{name}: not a CCSDS OEM the oem package can read ({text}); check "
                         "it against CCSDS 502.0-B") from None
    epoch = np.datetime64(epoch_utc, "ns")
    ts, rs, vs = [], [], []
    for seg in msg:
        md = seg.metadata
        centre, frame = str(md["CENTER_NAME"]).upper(), str(md["REF_FRAME"]).upper()
        if centre != "EARTH":
            raise ValueError(f"{name}: CENTER_NAME {centre}; imcsim needs EARTH")
        raw = seg._state_data  # (epochs, x, y, z, vx, vy, vz[, ax, ay, az]) as parsed
        ep = np.array([to_datetime64(e.isoformat() if hasattr(e, "isoformat") else str(e))
                       for e in raw[0]], "datetime64[ns]")
        shift = scale_to_utc_s(str(md["TIME_SYSTEM"]), ep[0])
        ep = ep + np.timedelta64(int(round(shift * 1e9)), "ns")
        t = (ep - epoch) / np.timedelta64(1, "ns") * 1e-9
        r = np.array(raw[1:4], np.float64).T * 1e3
        v = np.array(raw[4:7], np.float64).T * 1e3
        if frame in EME2000_NAMES:
            m = eci_from_eme2000(epoch)
            r, v = r @ m.T, v @ m.T
        elif frame in ECEF_NAMES:  # imcsim's ECEF: ECI turned by GMST (UT1 = UTC)
            e2i = np.swapaxes(eci_to_ecef_matrix(gmst_rad(epoch, t)), -1, -2)
            w = np.array([0.0, 0.0, OMEGA_EARTH_RAD_S])
            v = np.einsum("nij,nj->ni", e2i, v + np.cross(w, r))
            r = np.einsum("nij,nj->ni", e2i, r)
        elif frame not in TEME_NAMES:
            raise ValueError(f"{name}: REF_FRAME {frame} is not one imcsim converts (EME2000, "
                             "GCRF, ICRF, TEME, ITRF)")
        ts.append(t)
        rs.append(r)
        vs.append(v)
    if not ts:
        raise ValueError(f"{name}: holds no states")
    t, r, v = np.concatenate(ts), np.concatenate(rs), np.concatenate(vs)
    order = np.argsort(t, kind="stable")
    t, r, v = t[order], r[order], v[order]
    keep = np.r_[True, np.diff(t) > 0]
    return OemOrbit(epoch, t[keep], r[keep], v[keep], str(p))


def oem_text(epoch_utc: np.datetime64, t_s: np.ndarray, r_eme2000_m: np.ndarray,
             v_eme2000_mps: np.ndarray, object_name: str = "IMCSIM", comment: str = "") -> str:
    """A CCSDS OEM (KVN, version 2.0; UTC; EME2000; km, km/s) of states at ``epoch_utc`` +
    ``t_s``."""
    ep = (np.datetime64(epoch_utc, "ns")
          + np.round(np.asarray(t_s) * 1e9).astype("timedelta64[ns]"))
    stamp = [str(e)[:23] for e in ep]
    head = ["CCSDS_OEM_VERS = 2.0", f"CREATION_DATE = {stamp[0][:19]}",
            "ORIGINATOR = IMCSIM", "", "META_START", f"OBJECT_NAME = {object_name}",
            "OBJECT_ID = 2026-000A", "CENTER_NAME = EARTH", "REF_FRAME = EME2000",
            "TIME_SYSTEM = UTC", f"START_TIME = {stamp[0]}", f"STOP_TIME = {stamp[-1]}",
            "META_STOP", ""]
    head += [f"COMMENT {c}" for c in comment.splitlines()]
    rk, vk = np.asarray(r_eme2000_m) / 1e3, np.asarray(v_eme2000_mps) / 1e3
    body = [f"{s} {r[0]:.6f} {r[1]:.6f} {r[2]:.6f} {v[0]:.9f} {v[1]:.9f} {v[2]:.9f}"
            for s, r, v in zip(stamp, rk, vk, strict=True)]
    return "\n".join(head + body + [""])
