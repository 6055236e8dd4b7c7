"""Measured inputs: attitude as a CSV or a CCSDS AEM (the true jitter), orbit as a CCSDS OEM.

The runs are the quickstart on the analytic plant (conftest.tiny_base, ~1 s each). The AEM
of a motion is written from the scenario's own nominal attitude and that motion, through
EME2000 (orbit.ccsds): reading it back must give the motion again, so an AEM and a CSV of
the same motion, and the sinusoid the motion was sampled from, give the same run.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest
from conftest import ROOT, tiny_base

from imc.scenario import ScenarioError, load_scenario, parse_scenario
from imc.wiring.build import build_models
from orbit.attitude_series import (
    AttitudeSeriesError,
    aem_text,
    measured_attitude,
    read_aem,
    read_jitter_csv,
    write_jitter_csv,
)
from orbit.ccsds import eci_from_eme2000
from orbit.oem_orbit import oem_text, read_oem

EPOCH = np.datetime64("2026-06-21T10:30:00", "ns")

#: CCSDS 504.0-B-1 (Attitude Data Messages), the AEM example's layout (Mars Global Surveyor)
STANDARD_AEM = """CCSDS_AEM_VERS = 1.0
CREATION_DATE = 2002-11-04T17:22:31
ORIGINATOR = NASA/JPL

META_START
COMMENT This file was produced by M.R. Somebody, MSOO NAV/JPL, 2002 OCT 04.
COMMENT It is to be used for attitude reconstruction only.
OBJECT_NAME = MARS GLOBAL SURVEYOR
OBJECT_ID = 1996-062A
CENTER_NAME = mars barycenter
REF_FRAME_A = EME2000
REF_FRAME_B = SC_BODY_1
ATTITUDE_DIR = A2B
TIME_SYSTEM = UTC
START_TIME = 1996-11-28T21:29:07.2555
USEABLE_START_TIME = 1996-11-28T22:08:02.5555
USEABLE_STOP_TIME = 1996-11-30T01:18:02.5555
STOP_TIME = 1996-11-30T01:28:02.5555
ATTITUDE_TYPE = QUATERNION
QUATERNION_TYPE = {qtype}
INTERPOLATION_METHOD = hermite
INTERPOLATION_DEGREE = 7
META_STOP

DATA_START
{rows}
DATA_STOP
"""
_Q = [("1996-11-28T21:29:07.2555", (0.56748, 0.03146, 0.45689, 0.68427)),
      ("1996-11-28T22:08:03.5555", (0.42319, -0.45697, 0.23784, 0.74533)),
      ("1996-11-28T22:08:04.5555", (-0.84532, 0.26974, -0.06532, 0.45652)),
      ("1996-11-30T01:28:02.5555", (0.74563, -0.45375, 0.33845, 0.35842))]


def _shuster_a(q):
    """The attitude matrix A(q) of a CCSDS quaternion (q1, q2, q3, qc), v_B = A v_A
    (Shuster 1993, written out here independently of the reader)."""
    q = np.asarray(q, float) / np.linalg.norm(q)
    v, s = q[:3], q[3]
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return (s * s - v @ v) * np.eye(3) + 2 * np.outer(v, v) - 2 * s * k


@pytest.mark.parametrize("qtype", ["LAST", "FIRST"])
def test_the_standards_aem_example_reads_as_eme2000_from_body(tmp_path, qtype):
    rows = [f"{t} {' '.join(map(str, q))}" if qtype == "LAST" else
            f"{t} {q[3]} {q[0]} {q[1]} {q[2]}" for t, q in _Q]
    p = tmp_path / "mgs.aem"
    p.write_text(STANDARD_AEM.format(qtype=qtype, rows="\n".join(rows)))
    a = read_aem(p, np.datetime64("1996-11-28T21:29:07.2555", "ns"))
    assert a.t_s == pytest.approx([0.0, 2336.3, 2337.3, 100735.3], abs=1e-9)
    for k, (_, q) in enumerate(_Q):  # A2B with A = EME2000: eme2000_from_body = A(q)^T
        assert np.abs(a.eme2000_from_body[k] - _shuster_a(q).T).max() < 1e-12


def test_the_aem_reader_agrees_with_ccsds_ndm(tmp_path):
    """The maintained PyPI reader (GPL-3.0, so not a dependency) reads the same quaternions."""
    ndm = pytest.importorskip("ccsds_ndm.ndm_io", reason="ccsds-ndm is not installed")
    p = ROOT / "scenarios" / "data" / "measured" / "attitude.aem"
    ours = read_aem(p, EPOCH)
    seg = ndm.NdmIo().from_path(p).body.segment[0]
    qs = [s.quaternion_state.quaternion for s in seg.data.attitude_state]
    theirs = np.array([_shuster_a((q.q1, q.q2, q.q3, q.qc)).T for q in qs])
    assert len(theirs) == len(ours.t_s) == 601
    assert np.abs(theirs - ours.eme2000_from_body).max() < 1e-14


def test_eme2000_to_eci_agrees_with_astropy_teme():
    """0.37 deg of precession and nutation since J2000, against astropy's TEME to 1 urad
    (the IAU 1980 and 2000A nutations differ by ~0.3 urad)."""
    from astropy.coordinates import GCRS, TEME, CartesianRepresentation
    from astropy.time import Time
    from astropy.utils import iers

    m = eci_from_eme2000(EPOCH)
    angle = np.arccos((np.trace(m) - 1) / 2)
    assert 6.0e-3 < angle < 7.0e-3
    with iers.conf.set_temp("auto_download", False):
        t = Time(str(EPOCH)[:19], scale="utc")
        ref = np.array([GCRS(CartesianRepresentation(*e, unit="m"), obstime=t)
                        .transform_to(TEME(obstime=t)).cartesian.xyz.to_value("m")
                        for e in np.eye(3) * 7e6]).T / 7e6
    assert np.abs(ref - m).max() < 1e-6


def _series_files(tmp_path, sc, t):
    """CSV and AEM of the jitter of a built scenario, sampled at t."""
    cam = build_models(sc).camera
    rv = cam.attitude.jitter.rotvec_rad(t)
    write_jitter_csv(tmp_path / "j.csv", t, rv)
    rot = measured_attitude(rv, t, lambda tt: cam.attitude.eci_from_body(cam.orbit, tt, True),
                            sc.epoch)
    (tmp_path / "j.aem").write_text(aem_text(sc.epoch, t, rot))
    return rv


def _with_series(base, path):
    d = copy.deepcopy(base)
    d["attitude"]["jitter"] = {"series": {"file": str(path)}}
    return parse_scenario(d)


def test_aem_and_csv_of_the_same_motion_and_the_sinusoid_give_the_same_run(tmp_path):
    from imc.pipeline import run_scenario

    base = tiny_base()  # pitch 2 Hz at 1 px, 0.3 s
    sc = parse_scenario(base)
    t = np.arange(-0.01, 0.32, 1e-3)
    rv = _series_files(tmp_path, sc, t)
    got = {}
    for name, s in (("sinusoid", sc), ("csv", _with_series(base, tmp_path / "j.csv")),
                    ("aem", _with_series(base, tmp_path / "j.aem"))):
        got[name] = run_scenario(s, tmp_path / name, fresh=True, rerun=False)[0]
    # the AEM's jitter is the CSV's: its round trip through EME2000 quaternions
    aem = build_models(_with_series(base, tmp_path / "j.aem")).camera.attitude.jitter
    assert np.abs(aem.rotvec_samples_rad - rv).max() < 1e-12  # rad; 1 px = 1.2e-6 rad
    for key in ("rms_total_px", "mtf_nyquist_worst"):
        a, c = got["aem"]["with_compensation"][key], got["csv"]["with_compensation"][key]
        assert a == pytest.approx(c, rel=1e-6)
    res = {k: got[k]["with_compensation"]["rms_total_px"] for k in got}
    opened = {k: got[k]["without_compensation"]["rms_total_px"] for k in got}
    assert res["sinusoid"] > 0.05  # a residual worth comparing
    assert res["aem"] == pytest.approx(res["sinusoid"], rel=0.01)
    assert opened["aem"] == pytest.approx(opened["sinusoid"], rel=0.01)


def test_a_series_short_of_the_run_or_slower_than_the_tracker_is_refused_in_one_line(
        tmp_path):
    base = tiny_base()  # 0.3 s, 100 Hz tracker
    t = np.arange(0.0, 0.2, 1e-3)
    write_jitter_csv(tmp_path / "short.csv", t, np.zeros((len(t), 3)))
    with pytest.raises(ScenarioError) as e:
        build_models(_with_series(base, tmp_path / "short.csv"))
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith("attitude.jitter.series: ")
    assert "covers t = 0 .. 0.199 s, not the run's 0 .. 0.3 s" in msg
    t = np.arange(0.0, 0.4, 0.02)  # 50 Hz
    write_jitter_csv(tmp_path / "slow.csv", t, np.zeros((len(t), 3)))
    with pytest.raises(ScenarioError, match=r"^attitude\.jitter\.series: .* sampled every 20 ms "
                       r"\(50 Hz\), slower than the tracker's 100 Hz frames; give samples at >= "
                       r"100 Hz or lower camera\.tracker\.frame_rate_hz$"):
        build_models(_with_series(base, tmp_path / "slow.csv"))


def test_csv_units_and_utc_times(tmp_path):
    p = tmp_path / "deg.csv"
    p.write_text("# a gyro\nutc,yaw_arcsec,roll_deg,pitch_px\n"
                 "2026-06-21T10:30:00,3600,1,1\n2026-06-21T10:30:00.5,0,0,2\n"
                 "2026-06-21T10:30:01,0,0,0\n2026-06-21T10:30:01.5,0,0,0\n")
    s = read_jitter_csv(p, EPOCH, ifov_rad=1.2e-6)
    assert s.t_s == pytest.approx([0.0, 0.5, 1.0, 1.5])
    assert s.rotvec_samples_rad[0] == pytest.approx([np.pi / 180, 1.2e-6, np.pi / 180])
    assert s.rotvec_rad(0.5) == pytest.approx([0.0, 2.4e-6, 0.0])
    p.write_text("t_s,roll_furlong,pitch_rad,yaw_rad\n0,0,0,0\n")
    with pytest.raises(AttitudeSeriesError, match=r"column roll_furlong: unit 'furlong' is not"):
        read_jitter_csv(p, EPOCH, 1e-6)


def test_series_interpolates_a_sinusoid_and_its_rate():
    from orbit.attitude_series import SampledJitter

    t = np.arange(0.0, 1.0, 1e-3)
    f, a = 7.0, 1e-5
    s = SampledJitter(t_s=t, rotvec_samples_rad=np.stack(
        [a * np.sin(2 * np.pi * f * t), 0 * t, 0 * t], axis=1), source="x")
    tt = np.linspace(0.1, 0.9, 777)
    assert np.abs(s.rotvec_rad(tt)[:, 0] - a * np.sin(2 * np.pi * f * tt)).max() < 1e-6 * a
    rate = 2 * np.pi * f * a * np.cos(2 * np.pi * f * tt)
    assert np.abs(s.rate_rad_s(tt)[:, 0] - rate).max() < 1e-4 * 2 * np.pi * f * a
    big = s.amplitude_rad > 0.5 * a  # the spectrum code asks about: one line at 7 Hz
    assert s.frequency_hz[big] == pytest.approx([f], abs=1.0)


def test_oem_orbit_matches_the_orbit_it_was_written_from(tmp_path):
    """States every 10 s, Hermite-interpolated: within 1 mm and 1 mm/s."""
    from orbit.kepler import Orbit

    o = Orbit(7_059e3, 0.001, 98.1, 30.0, 0.0, 10.0, EPOCH, True)
    t = np.arange(-60.0, 121.0, 10.0)
    r, v = o.state_eci(t)
    m = eci_from_eme2000(EPOCH)
    (tmp_path / "o.oem").write_text(oem_text(EPOCH, t, r @ m, v @ m))
    got = read_oem(tmp_path / "o.oem", EPOCH)
    tt = np.linspace(-55.0, 115.0, 41)
    (r1, v1), (r2, v2) = o.state_eci(tt), got.state_eci(tt)
    assert np.abs(r1 - r2).max() < 1e-3 and np.abs(v1 - v2).max() < 1e-3
    with pytest.raises(ValueError, match="has states for t = -60 .. 120 s only"):
        got.state_eci(200.0)
    # the same states Earth-fixed (REF_FRAME ITRF): turned back through GMST
    r_e, v_e = o.state_ecef(t)
    text = oem_text(EPOCH, t, r_e, v_e).replace("REF_FRAME = EME2000", "REF_FRAME = ITRF")
    (tmp_path / "e.oem").write_text(text)
    r3, v3 = read_oem(tmp_path / "e.oem", EPOCH).state_eci(tt)
    assert np.abs(r1 - r3).max() < 1e-3 and np.abs(v1 - v3).max() < 1e-3


def test_the_bundled_measured_scenario_builds_and_its_files_agree():
    """scenarios/measured_attitude.yaml: OEM orbit, AEM attitude; the AEM's jitter is the
    bundled CSV's (the same motion, written against the propagated orbit) to 1e-8 rad
    (0.008 px): the OEM's Hermite interpolation of states every 10 s (1e-4 m/s) turns the
    nominal yaw by 6e-9 rad."""
    sc = load_scenario(ROOT / "scenarios" / "measured_attitude.yaml")
    assert sc.orbit.kind == "oem" and sc.attitude.jitter.series.format == "aem"
    jit = build_models(sc).camera.attitude.jitter
    csv = read_jitter_csv(ROOT / "scenarios" / "data" / "measured" / "jitter.csv", sc.epoch,
                          1.2e-6)
    assert np.abs(jit.rotvec_samples_rad - csv.rotvec_samples_rad).max() < 1e-8
    assert 0.5 < np.abs(jit.rotvec_samples_rad[:, 0]).max() / 1.2e-6 < 2.5  # px, ZY-3 roll


def test_schema_refusals_name_the_field():
    base = tiny_base()
    d = copy.deepcopy(base)
    d["attitude"]["jitter"]["series"] = {"file": "x.csv"}
    with pytest.raises(ScenarioError, match=r"attitude\.jitter: .*leave out sinusoids"):
        parse_scenario(d)
    d = copy.deepcopy(base)
    d["attitude"]["jitter"] = {"series": {"file": "x.txt"}}
    with pytest.raises(ScenarioError, match=r"series: .*set format \(csv or aem\)"):
        parse_scenario(d)
    d = copy.deepcopy(base)
    d["orbit"] = {"kind": "oem"}
    with pytest.raises(ScenarioError, match=r"orbit: .*kind 'oem' needs oem_file"):
        parse_scenario(d)
    d["orbit"] = {"kind": "oem", "oem_file": "/nonexistent/o.oem"}
    with pytest.raises(ScenarioError, match=r"^orbit\.oem_file /nonexistent/o\.oem: cannot read"):
        build_models(parse_scenario(d))
