"""Named random streams: every random draw of a run comes from one of these, by name.

A stream is ``numpy.random.default_rng([seed, id, *index])`` with a fixed id per name, so two
uses never share a stream and a resumed run draws exactly what the uninterrupted one did
(per-frame streams take the frame index). The ids of the first five are those of earlier
versions, so their draws are unchanged.
"""

from __future__ import annotations

import numpy as np

#: name -> stream id (never reuse or renumber an id)
STREAM_IDS = {
    "terrain": 0,  # procedural terrain
    "sensor": 1,  # tracker sensor noise, per frame
    "render": 2,  # Mitsuba's sampler seed, per frame
    "jitter": 3,  # jitter realisation (random phases, PSD)
    "clouds": 4,  # cloud layer
    "link": 5,  # serial-link faults (loop)
    "device_emulator": 6,  # serial-link faults (imc device-emulator)
    "optical": 7,  # optical correlator noise, per frame
    "analytic": 8,  # analytic plant noise, per frame
    "drops": 9,  # transport losses, per frame
    "texture": 10,  # texture plant (sensor noise), per frame
    "flight_sensor": 11,  # flight test: the second tracker sensor's noise, per frame
    "flight_render": 12,  # flight test: the second tracker sensor's render seed, per frame
    "texture_map": 13,  # texture-robustness map: shifts, blur and noise, per block
    "product": 14,  # the main imager's product: detector noise, per scene (scene, target)
    "links": 15,  # the ground's extra baselines (optical correlator noise), per (frame, j)
    "gyro": 16,  # the ground's gyro readings
    "ground_control": 17,  # the ground control points' errors
    "reference": 18,  # the reference orthoimage's detector noise (ground control)
}


def key(seed: int, name: str, *index: int) -> list[int]:
    """The entropy of stream ``name`` (and its per-frame member ``index``)."""
    try:
        sid = STREAM_IDS[name]
    except KeyError:
        raise ValueError(f"unknown random stream {name!r}; add it to STREAM_IDS") from None
    return [int(seed), sid, *(int(i) for i in index)]


def rng(seed: int, name: str, *index: int) -> np.random.Generator:
    """The generator of stream ``name`` (member ``index``)."""
    return np.random.default_rng(key(seed, name, *index))


def render_seed(seed: int, k: int, name: str = "render") -> int:
    """Mitsuba's sampler seed of frame k (from stream ``name``)."""
    return int(np.random.SeedSequence(key(seed, name, k)).generate_state(1)[0] & 0x7FFFFFFF)
