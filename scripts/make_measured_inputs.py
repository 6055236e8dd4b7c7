"""Write the bundled measured-input example: scenarios/data/measured/ (run: python
scripts/make_measured_inputs.py; deterministic, seed below).

* ``orbit.oem``: CCSDS OEM (EME2000, UTC, every 10 s from -60 s to +60 s) of the quickstart's
  sun-synchronous orbit placed over the scene (35 N, 10 E) at 2026-06-21T10:30:00Z;
* ``attitude.aem``: CCSDS AEM (EME2000 -> body quaternions at 200 Hz from -0.5 s to 2.5 s)
  of the staring attitude plus a jitter built from the lines of ZY-3's published attitude
  oscillation (Tong et al. 2014; ../shared/notes/domain-facts.md): 0.65 Hz at 1.0 px
  cross-track (roll) and 0.4 px along-track (pitch), 0.21 Hz at 0.5 px roll, 0.56 Hz at 0.3 px
  pitch, 1.12 Hz at 0.2 px roll, seeded random phases, plus a 0.01 px rms white measurement
  floor per axis (star-tracker / gyro noise, seeded);
* ``jitter.csv``: the same jitter as roll / pitch / yaw offsets in urad (what a CSV of the
  AEM's motion holds).

The px amplitudes are IFOVs of the scenario's IKONOS-class camera (12 um / 10 m = 1.2 urad).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "scenarios" / "data" / "measured"
SEED = 20261203
IFOV_RAD = 12e-6 / 10.0
#: (axis index, frequency Hz, amplitude px): ZY-3's lines
LINES = ((0, 0.65, 1.0), (1, 0.65, 0.4), (0, 0.21, 0.5), (1, 0.56, 0.3), (0, 1.12, 0.2))
FLOOR_PX = 0.01


def main() -> None:
    from imc.scenario import load_scenario
    from imc.wiring.build import build_models
    from orbit.attitude_series import aem_text, measured_attitude, write_jitter_csv
    from orbit.ccsds import eci_from_eme2000
    from orbit.oem_orbit import oem_text

    OUT.mkdir(parents=True, exist_ok=True)
    sc = load_scenario(ROOT / "scenarios" / "quickstart.yaml")
    sc = sc.model_copy(update={"attitude": sc.attitude.model_copy(
        update={"jitter": sc.attitude.jitter.model_copy(update={"sinusoids": ()})})})
    m = build_models(sc)
    cam = m.camera
    m_eci = eci_from_eme2000(sc.epoch)
    t_orb = np.arange(-60.0, 60.0 + 1e-9, 10.0)
    r, v = cam.orbit.state_eci(t_orb)
    (OUT / "orbit.oem").write_text(oem_text(
        sc.epoch, t_orb, r @ m_eci, v @ m_eci, "IMCSIM-EXAMPLE",
        "imcsim example: the quickstart's sun-synchronous orbit (681 km) placed over\n"
        "35 N 10 E at 2026-06-21T10:30:00Z (scripts/make_measured_inputs.py)"))
    rng = np.random.default_rng(SEED)
    t = np.arange(-0.5, 2.5 + 1e-9, 1.0 / 200.0)
    jit = np.zeros((len(t), 3))
    for axis, f, a in LINES:
        jit[:, axis] += a * IFOV_RAD * np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi))
    jit += rng.normal(0.0, FLOOR_PX * IFOV_RAD, jit.shape)
    nominal = cam.attitude  # jitter-free: the scenario above has none
    rot = measured_attitude(jit, t, lambda tt: nominal.eci_from_body(cam.orbit, tt, True),
                            sc.epoch)
    note = ("imcsim example: staring at 35 N 10 E with ZY-3's attitude oscillation lines\n"
            "(0.65 Hz 1.0 px roll and 0.4 px pitch, 0.21 Hz 0.5 px roll, 0.56 Hz 0.3 px pitch,\n"
            "1.12 Hz 0.2 px roll; 1 px = 1.2 urad) and a 0.01 px rms white floor, 200 Hz\n"
            "(scripts/make_measured_inputs.py)")
    (OUT / "attitude.aem").write_text(aem_text(sc.epoch, t, rot, "IMCSIM-EXAMPLE", note))
    write_jitter_csv(OUT / "jitter.csv", t, jit, note + "\nt_s: s since 2026-06-21T10:30:00Z")
    print(f"wrote {OUT}/orbit.oem, attitude.aem, jitter.csv")


if __name__ == "__main__":
    main()
