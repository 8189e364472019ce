"""The event builder, alignment and sensor plan (estimators.inputs) on small in-memory logs."""


from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from estimators.config import EstimatorConfig
from estimators.inputs import alignment, build, records
from ingest.errors import InputError
from ingest.flightlog import FlightLog, LogMetadata

# ----------------------------------------------------------------------------------------------------------------
# events


def _still_log(duration_s=10.0, imu_hz=250.0, *, gps=True, mag=True, mav_type=2, params=None):
    """A vehicle at rest, level, heading north-east, at 47 N 8 E, with clean sensors."""
    t = np.arange(0.0, duration_s, 1.0 / imu_hz) + 100.0
    g = 9.80
    imu = pd.DataFrame({"gyro_x_rad_s": 0.01, "gyro_y_rad_s": -0.02, "gyro_z_rad_s": 0.0, "accel_x_m_s2": 0.0,
                        "accel_y_m_s2": 0.0, "accel_z_m_s2": -g}, index=pd.Index(t, name="time_s"))
    streams = {"imu": imu}
    t_baro = np.arange(t[0], t[-1], 0.05)
    streams["baro"] = pd.DataFrame({"alt_m": 502.0, "pressure_pa": np.nan, "temp_c": np.nan},
                                   index=pd.Index(t_baro, name="time_s"))
    if gps:
        t_gps = np.arange(t[0] + 0.5, t[-1], 0.1)
        streams["gps"] = pd.DataFrame({"lat_deg": 47.0, "lon_deg": 8.0, "alt_m": 500.0, "vn_m_s": 0.0,
                                       "ve_m_s": 0.0, "vd_m_s": 0.0, "eph_m": 1.0, "epv_m": 1.5, "fix_type": 3,
                                       "time_utc_s": 1.7e9 + t_gps}, index=pd.Index(t_gps, name="time_s"))
    if mag:
        t_mag = np.arange(t[0], t[-1], 0.02)
        yaw = math.radians(45.0)
        field = np.array([0.21, 0.0, 0.43])  # declination ~0 for the test; rotated into the body by -yaw
        m_b = np.array([math.cos(yaw) * field[0], -math.sin(yaw) * field[0], field[2]])
        streams["mag"] = pd.DataFrame({"mag_x_gauss": m_b[0], "mag_y_gauss": m_b[1], "mag_z_gauss": m_b[2]},
                                      index=pd.Index(t_mag, name="time_s"))
    meta = LogMetadata(source="still.ulg", vehicle_type=mav_type, parameters=dict(params or {}),
                       utc_offset_s=1.7e9 if gps else None)
    return FlightLog(streams=streams, meta=meta)


def test_events_sorted_with_imu_interval_index():
    inputs = build.build_replay_inputs(_still_log(), rate_hz=50.0)
    ev, t_imu = inputs.events, inputs.imu.time_s
    assert np.all(np.diff(ev.time_s) >= 0)
    # each event lies in the interval (t[k-1], t[k]] of its IMU row
    k = ev.imu_index
    assert np.all(ev.time_s <= t_imu[k])
    assert np.all(ev.time_s[k > 0] > t_imu[k[k > 0] - 1])
    # equal times: kinds in processing order, output last
    same = np.diff(ev.time_s) == 0
    assert np.all(np.diff(ev.kind)[same] > 0)
    out = ev.time_s[ev.kind == records.OUTPUT]
    np.testing.assert_allclose(out, inputs.output_time_s)
    np.testing.assert_allclose(np.diff(out), 0.02, atol=1e-9)
    assert set(inputs.plan.used) == {"baro", "gps_pos", "gps_vel", "mag"}
    assert inputs.plan.skipped["sideslip"].startswith("not a fixed-wing")
    assert inputs.plan.skipped["airspeed"] == "not in the log"


def test_gps_delay_from_parameter_and_default():
    log = _still_log(params={"EKF2_GPS_DELAY": 200.0})
    inputs = build.build_replay_inputs(log)
    gps_t = inputs.events.time_s[inputs.events.kind == records.GPS_POS]
    assert inputs.gps_delay_s == pytest.approx(0.2)
    np.testing.assert_allclose(gps_t[:3], log["gps"].index[:3] - 0.2)
    default = build.build_replay_inputs(_still_log())
    assert default.gps_delay_s == pytest.approx(0.11)
    np.testing.assert_allclose(default.events.time_s[default.events.kind == records.GPS_POS][:3],
                               log["gps"].index[:3] - 0.11)
    config = EstimatorConfig(timing=EstimatorConfig().timing.__class__(gps_delay_s=0.0))
    assert build.build_replay_inputs(log, config).gps_delay_s == 0.0
    # without the parameter, a logged sample time is the measurement time
    sampled = _still_log()
    gps = sampled["gps"].copy()
    gps["sample_time_s"] = gps.index - 0.07
    sampled.streams["gps"] = gps
    inputs = build.build_replay_inputs(sampled)
    assert inputs.gps_time_rule == "sample_time_s"
    np.testing.assert_allclose(inputs.events.time_s[inputs.events.kind == records.GPS_VEL][:3], gps.index[:3] - 0.07)


def test_sample_time_and_duplicates():
    log = _still_log()
    baro = log["baro"].copy()
    # sample times 10 ms before the row time; rows 5 and 6 repeat one sample
    sample = baro.index.to_numpy() - 0.01
    sample[6] = sample[5]
    baro["sample_time_s"] = sample
    log.streams["baro"] = baro
    inputs = build.build_replay_inputs(log)
    baro_t = inputs.events.time_s[inputs.events.kind == records.BARO]
    assert len(baro_t) == len(baro) - 1 - np.count_nonzero(sample < inputs.imu.time_s[0])
    np.testing.assert_allclose(baro_t[:5], sample[sample >= inputs.imu.time_s[0]][:5])
    # duplicate IMU rows are dropped and counted
    imu = log["imu"]
    log.streams["imu"] = pd.concat([imu.iloc[:50], imu.iloc[49:]])
    assert build.build_replay_inputs(log).imu.n_dropped == 1
    # so are a non-finite row and a step back in time
    bad = imu.copy()
    bad.iloc[10, bad.columns.get_loc("accel_y_m_s2")] = np.nan
    time_s = bad.index.to_numpy(copy=True)
    time_s[20] = time_s[18]
    bad.index = pd.Index(time_s, name=imu.index.name)
    log.streams["imu"] = bad
    samples = build.build_replay_inputs(log).imu
    assert samples.n_dropped == 2 and len(samples.time_s) == len(bad) - 2
    assert np.all(np.diff(samples.time_s) > 0) and np.isfinite(samples.accel_m_s2).all()
    np.testing.assert_array_equal(samples.gyro_rad_s[10], bad.iloc[11][["gyro_x_rad_s", "gyro_y_rad_s",
                                                                         "gyro_z_rad_s"]].to_numpy(float))


def test_baro_offset_and_heights():
    inputs = build.build_replay_inputs(_still_log())
    assert inputs.baro_offset_m == pytest.approx(2.0)
    assert inputs.origin.source == "gps" and inputs.origin.alt_m == 500.0
    baro = inputs.events.values[inputs.events.kind == records.BARO, 0]
    np.testing.assert_allclose(baro, 0.0, atol=1e-9)


def test_alignment_from_still_window():
    inputs = build.build_replay_inputs(_still_log())
    a = inputs.alignment
    assert a.tilt_source == "still_window" and a.still_window_s is not None
    assert abs(a.roll_rad) < 1e-12 and abs(a.pitch_rad) < 1e-12
    np.testing.assert_allclose(a.gyro_bias_rad_s, [0.01, -0.02, 0.0], atol=1e-12)
    # field of the test log has ~zero declination only approximately (WMM at 47N 8E ~ +3 deg): compare to the WMM
    declination = math.degrees(math.atan2(inputs.mag_field_ned[1], inputs.mag_field_ned[0]))
    assert math.degrees(a.yaw_rad) == pytest.approx(45.0 + declination, abs=1.5)
    assert a.yaw_source == "mag"


def _still_window_whole_log(imu, gravity_m_s2, config):
    """Oracle for alignment.still_window: 0.2 s moving averages of the whole log by np.convolve."""
    n_avg = round(0.2 / imu.median_dt_s)
    kernel = np.ones(n_avg) / n_avg
    gyro = np.column_stack([np.convolve(imu.gyro_rad_s[:, i], kernel, mode="same") for i in range(3)])
    accel = np.column_stack([np.convolve(imu.accel_m_s2[:, i], kernel, mode="same") for i in range(3)])
    half = n_avg // 2
    gyro[:half], accel[:half] = gyro[half], accel[half]  # the edges see zero padding
    gyro[len(gyro) - half:], accel[len(accel) - half:] = gyro[-half - 1], accel[-half - 1]
    t = imu.time_s
    norm = np.linalg.norm(accel, axis=1)
    reference = float(np.median(norm[t <= t[0] + 1.0]))
    still = ((np.linalg.norm(gyro, axis=1) < config.timing.still_gyro_rad_s)
             & (np.abs(norm - reference) < config.timing.still_accel_m_s2))
    i0 = int(np.flatnonzero(still & (t <= t[0] + 1.0))[0])
    moving = np.flatnonzero(~still[i0:])
    return i0, i0 + int(moving[0]) if len(moving) else len(t)


@pytest.mark.parametrize("still_s", [5.0, 37.3, 200.0, None])
def test_still_window_ends_at_the_first_motion(still_s):
    """The window found on growing prefixes of the log is the one the whole log's moving averages give."""
    rng = np.random.default_rng(3)
    time_s = 10.0 + np.arange(0, 120.0, 0.004)
    gyro = rng.normal(0.0, 0.002, (len(time_s), 3)) + np.array([0.01, -0.02, 0.0])
    accel = rng.normal(0.0, 0.02, (len(time_s), 3)) + np.array([0.0, 0.0, -9.81])
    if still_s is not None:
        gyro[time_s >= 10.0 + still_s, 2] += 0.5
    imu = records.ImuSamples(time_s=time_s, gyro_rad_s=gyro, accel_m_s2=accel, median_dt_s=0.004, gaps=(),
                            n_dropped=0)
    config = EstimatorConfig()
    window = alignment.still_window(imu, 9.81, config)
    assert window == _still_window_whole_log(imu, 9.81, config)
    expected_end_s = 120.0 if still_s is None or still_s > 120.0 else still_s
    assert time_s[window[1] - 1] - 10.0 == pytest.approx(expected_end_s, abs=0.15)


def test_degraded_plans():
    no_gps = build.build_replay_inputs(_still_log(gps=False))
    assert not no_gps.plan.has_gps and no_gps.events.count(records.ZERO_VELOCITY) > 0
    assert no_gps.mag_field_source == "declination_parameter"
    no_mag = build.build_replay_inputs(_still_log(mag=False))
    assert any("yaw dead-reckoned" in d for d in no_mag.plan.degradations)
    fixed_wing_on_ground = build.build_replay_inputs(_still_log(mav_type=1))
    assert fixed_wing_on_ground.plan.fixed_wing and fixed_wing_on_ground.events.count(records.SIDESLIP) == 0
    with pytest.raises(InputError, match="sun"):
        build.build_replay_inputs(_still_log(), heading="sun")
    with pytest.raises(InputError, match="heading"):
        build.build_replay_inputs(_still_log(), heading="compass")
    with pytest.raises(InputError, match="rate"):
        build.build_replay_inputs(_still_log(), rate_hz=0.0)
    empty = _still_log()
    del empty.streams["imu"]
    with pytest.raises(InputError, match="IMU"):
        build.build_replay_inputs(empty)
