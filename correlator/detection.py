"""Validity as a detection decision: the probability that a correlation peak is a noise peak.

The detection surface (the SNR-whitened band surface of :mod:`correlator.core`) is, away from
the true peak, a sum of many bins of bounded magnitude and (for a wrong lag) unrelated phase,
so by the central limit theorem its samples are Gaussian; the peak-to-sidelobe ratio (PSR)
z = (peak - mean) / std is the peak in units of that noise. The chosen peak is the largest of
the searched samples; were it a noise sample, it would be the maximum of ``cells`` Gaussian
variables, whose exceedance probability (the extreme-value, Bonferroni-exact form for
independent cells) is

    P_fa(z) = 1 - (1 - Q(z))^M,  Q(z) = erfc(z / sqrt 2) / 2,

with M the number of independent cells of the search area: the band surface is whitened
(a flat spectrum up to its own Nyquist frequency), so its samples are uncorrelated and M is
the number of samples searched (33^2 for the default quarter-block search of 64^2-256^2
blocks, 17^2 at 32^2). A result is valid when P_fa is at most the
stated false-alarm rate: a noise-only pair, or a textured pair whose true peak is weaker than
the noise's largest, is then flagged valid with that probability at most.

Measured on noise-only pairs (10,000 each), the share with P_fa <= 0.001 is 0.0007-0.0012 at
64^2-128^2 and 0.003 at 32^2 (a heavier tail of the 32^2 surface); at 0.05 it is 0.045-0.06
at 64^2-256^2 and 0.087 at 32^2 (``benchmarks/bench_validity.py``).
P_fa models the choice of a noise peak only: at low SNR the errors of textured pairs beyond
0.5 px are mostly sub-pixel tails of the true peak's estimate (0.5-1.6 px with a predicted
error of 0.15-0.3 px), which :mod:`correlator.tail` models; a result's ``p_wrong`` combines
the two.

References
----------
Kay, "Fundamentals of Statistical Signal Processing, Vol. II: Detection Theory", Prentice Hall
(1998), ch. 2 and 7 (false-alarm probability of a maximum over cells).
Gumbel, "Statistics of Extremes", Columbia University Press (1958).
"""

from __future__ import annotations

import numpy as np
from scipy import special


def false_alarm_probability(z: np.ndarray, cells: np.ndarray | float) -> np.ndarray:
    """P(the largest of ``cells`` independent standard normal samples >= z).

    1 - (1 - Q(z))^M, computed as -expm1(M log1p(-Q(z))) (no cancellation for small Q);
    1 where z is NaN.
    """
    z = np.asarray(z, dtype=np.float64)
    q = special.ndtr(-np.where(np.isnan(z), -np.inf, z))
    return -np.expm1(np.asarray(cells, dtype=np.float64) * np.log1p(-np.minimum(q, 1.0 - 1e-16)))


def psr_for_rate(rate: float, cells: np.ndarray | float) -> np.ndarray:
    """The PSR z at which :func:`false_alarm_probability` (z, cells) equals ``rate``."""
    if not 0.0 < rate < 1.0:
        raise ValueError(f"rate must be within (0, 1), got {rate}")
    q = -np.expm1(np.log1p(-rate) / np.asarray(cells, dtype=np.float64))
    return -special.ndtri(q)
