"""Orbits from a two-line element set, propagated with SGP4 (the ``sgp4`` package).

SGP4 returns TEME (true equator, mean equinox) states. TEME turns into the Earth-fixed frame
by one rotation through GMST (IAU 1982), which is exactly how imcsim defines ECI -> ECEF, so
TEME *is* imcsim's ECI frame and no conversion is needed.

References
----------
.. [1] Vallado, Crawford, Hujsak, Kelso, "Revisiting Spacetrack Report #3", AIAA 2006-6753.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from orbit.frames import julian_date
from orbit.kepler import EarthOrbit

_UNIX_JD = 2440587.5
_SGP4_ERRORS = {
    1: "mean eccentricity out of range",
    2: "mean motion below zero",
    3: "perturbed eccentricity out of range",
    4: "semi-latus rectum below zero",
    6: "the satellite has decayed",
}


@dataclass(frozen=True)
class TleOrbit(EarthOrbit):
    """An orbit from TLE lines; t = 0 at ``epoch_utc`` (default: the TLE's own epoch).

    Raises
    ------
    ValueError
        For lines that sgp4 cannot parse (with the reason).
    """

    line1: str
    line2: str
    epoch_utc: np.datetime64 | None = None
    _sat: object = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        from sgp4.api import Satrec

        l1, l2 = self.line1.strip(), self.line2.strip()
        if not (l1.startswith("1 ") and l2.startswith("2 ")):
            raise ValueError("a TLE needs line 1 starting with '1 ' and line 2 with '2 '")
        try:
            sat = Satrec.twoline2rv(l1, l2)
        except Exception as e:  # sgp4 raises bare ValueError/IndexError on bad columns
            raise ValueError(f"cannot parse the TLE ({e})") from None
        if sat.error:
            raise ValueError(f"TLE rejected by sgp4: {_SGP4_ERRORS.get(sat.error, sat.error)}")
        object.__setattr__(self, "_sat", sat)
        epoch = self.tle_epoch_utc if self.epoch_utc is None else self.epoch_utc
        object.__setattr__(self, "epoch_utc", np.datetime64(epoch, "ns"))

    @property
    def tle_epoch_utc(self) -> np.datetime64:
        """The TLE's own epoch (UTC)."""
        days = self._sat.jdsatepoch - _UNIX_JD + self._sat.jdsatepochF
        return np.datetime64(0, "ns") + np.timedelta64(int(round(days * 86400e9)), "ns")

    @property
    def period_s(self) -> float:
        """Period from the TLE's mean motion (Kozai-Brouwer no_kozai), s."""
        return 2.0 * np.pi / (self._sat.no_kozai / 60.0)

    def state_eci(self, t_s: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """TEME (= imcsim ECI) position (..., 3) in m and velocity (..., 3) in m/s.

        Raises
        ------
        ValueError
            If SGP4 fails at any of the times (e.g. the satellite has decayed).
        """
        t = np.asarray(t_s, dtype=np.float64)
        jd0 = julian_date(self.epoch_utc)
        whole = np.floor(jd0)
        frac = (jd0 - whole) + t.ravel() / 86400.0
        err, r, v = self._sat.sgp4_array(np.full(frac.shape, whole), frac)
        if np.any(err):
            code = int(err[np.nonzero(err)[0][0]])
            raise ValueError(f"SGP4 failed: {_SGP4_ERRORS.get(code, code)}")
        return (r.reshape(t.shape + (3,)) * 1e3, v.reshape(t.shape + (3,)) * 1e3)
