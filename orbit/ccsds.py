"""What CCSDS navigation data messages (AEM, OEM) need from imcsim's frames and time scales.

imcsim's ECI frame is true-of-date equator, mean equinox (SGP4's TEME; docs/conventions.md).
A CCSDS message is usually in EME2000 (J2000 mean equator and equinox; GCRF / ICRF differ
from it by the 23 mas frame bias, 0.1 urad, which is included here). The rotation from
EME2000 to imcsim's ECI at an epoch is

    r_eci = R3(eqeq) N P B r_eme2000,

``N P B`` the IAU 2006/2000A bias-precession-nutation matrix (GCRS -> true of date) and
``eqeq`` the equation of the equinoxes (true -> mean equinox on the true equator), both from
ERFA (pyerfa). It turns by ~1e-11 rad/s (precession), so one matrix at the epoch of t = 0
serves a run (2e-9 rad over 600 s). Without it a 2026 attitude would be off by 0.36 deg.

Time scales: UTC, TAI, TT and GPS are converted to UTC with ERFA's leap-second table
(TAI - UTC), TT = TAI + 32.184 s, GPS = TAI - 19 s.
"""

from __future__ import annotations

import warnings

import numpy as np

#: names of the inertial frame a CCSDS message may use that imcsim converts (EME2000 family)
EME2000_NAMES = {"EME2000", "J2000", "GCRF", "ICRF", "ICRF2", "ICRF3"}
#: names of imcsim's own ECI frame (no conversion)
TEME_NAMES = {"TEME"}
#: Earth-fixed frame names (imcsim's ECEF: rotated from ECI by GMST)
ECEF_NAMES = {"ITRF", "ITRF93", "ITRF97", "ITRF2000", "ITRF2005", "ITRF2008", "ITRF2014",
              "ITRF2020", "ITRF-93", "ITRF-97", "ECEF", "WGS84"}
_TT_TAI_S = 32.184
_GPS_TAI_S = -19.0


def _calendar(epoch_utc: np.datetime64) -> tuple[int, int, int, float]:
    """(year, month, day, fraction of the day) of a UTC instant."""
    e = np.datetime64(epoch_utc, "ns")
    day = e.astype("datetime64[D]")
    y, m, d = (int(v) for v in str(day).split("-"))
    frac = float((e - day.astype("datetime64[ns]")) / np.timedelta64(1, "s")) / 86400.0
    return y, m, d, frac


def tai_minus_utc_s(epoch_utc: np.datetime64) -> float:
    """TAI - UTC at a UTC instant, s (ERFA's leap-second table)."""
    import erfa

    y, m, d, frac = _calendar(epoch_utc)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # ERFA calls years after its table 'dubious'
        return float(erfa.dat(y, m, d, frac))


def scale_to_utc_s(time_system: str, epoch: np.datetime64) -> float:
    """Seconds to add to an instant in ``time_system`` (UTC, TAI, TT, GPS) to get UTC.

    Raises
    ------
    ValueError
        For another time system.
    """
    ts = str(time_system).upper()
    if ts == "UTC":
        return 0.0
    offset = {"TAI": 0.0, "TT": _TT_TAI_S, "GPS": _GPS_TAI_S}.get(ts)
    if offset is None:
        raise ValueError(f"TIME_SYSTEM {time_system} is not one imcsim converts (UTC, TAI, TT, "
                         "GPS)")
    # TAI - UTC at the instant (read as UTC: a leap second's neighbourhood aside, the same)
    return -(offset + tai_minus_utc_s(epoch))


def eci_from_eme2000(epoch_utc: np.datetime64) -> np.ndarray:
    """Rotation (3, 3) taking EME2000 (GCRF) vectors to imcsim's ECI at ``epoch_utc``."""
    import erfa

    y, m, d, frac = _calendar(epoch_utc)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        utc1, utc2 = erfa.dtf2d("UTC", y, m, d, 0, 0, 0.0)
        utc2 = utc2 + frac
        tai1, tai2 = erfa.utctai(utc1, utc2)
        tt1, tt2 = erfa.taitt(tai1, tai2)
        npb = erfa.pnm06a(tt1, tt2)
        eqeq = erfa.ee06a(tt1, tt2)
    return erfa.rz(eqeq, npb)


def to_datetime64(text: str) -> np.datetime64:
    """A CCSDS epoch (ISO ``YYYY-MM-DDThh:mm:ss.d`` or day-of-year ``YYYY-DDDThh:mm:ss``) as
    numpy datetime64[ns].

    Raises
    ------
    ValueError
        If it is neither form.
    """
    s = str(text).strip().rstrip("Z")
    date, _, clock = s.partition("T")
    parts = date.split("-")
    if len(parts) == 2:  # day of year
        day = np.datetime64(f"{parts[0]}-01-01", "D") + np.timedelta64(int(parts[1]) - 1, "D")
        s = f"{day}T{clock or '00:00:00'}"
    try:
        return np.datetime64(s, "ns")
    except ValueError:
        raise ValueError(f"epoch {text!r} is not a CCSDS time (YYYY-MM-DDThh:mm:ss)") from None
