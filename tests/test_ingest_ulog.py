"""ingest.ulog_reader: PX4 ULog -> canonical FlightLog, on the five public PX4 logs (PX4 1.6 .. 1.15) and on
copies of them with injected faults. Expected values come from plain pyulog reads of the same files."""

from __future__ import annotations

import copy
import hashlib
import io
import re

import numpy as np
import pytest
from pyulog import ULog

from ingest.errors import FileTooLargeError, InputError
from ingest.flightlog import OPTIONAL_COLUMNS, STREAM_COLUMNS
from ingest.frames import euler_to_quat
from ingest.log_formats import load_flight_log
from ingest.px4_topics import ALL_TOPICS, RELATIVE_TIMESTAMP_INVALID, TRUTH_WIND_TOPIC
from ingest.ulog_reader import firmware_version, flightlog_from_ulog

REAL_LOGS = ("sample.ulg", "sample_appended_multiple.ulg", "sample_log_small.ulg",
             "sample_logging_tagged_and_default_params.ulg", "sample_px4_events.ulg")
SITL_GROUND = "sample_logging_tagged_and_default_params.ulg"  # SITL, PX4 1.13, on the ground, ground truth
SITL_FLIGHT = "sample_px4_events.ulg"  # SITL, PX4 1.15, float64 GPS lat/lon
VTOL = "sample_log_small.ulg"  # Cube Orange, PX4 1.11, airspeed, int32 GPS

STANDARD_GRAVITY_M_S2 = 9.80665
#: ISA barometric formula with the textbook constants (not the reader's): h = 44330.77 (1 - (p/p0)^0.190263).
ISA_ALT_SCALE_M, ISA_EXPONENT = 44330.77, 0.190263

#: Streams and source topics of each real log. Rates are checked against the raw topic (below); the comments
#: give the rates the shared README lists.
EXPECTED_STREAMS = {
    "sample.ulg": {  # PX4 ~1.6 bench log: mag inside sensor_combined, baro there but never valid, no GPS
        "imu": "sensor_combined", "mag": "sensor_combined", "onboard_attitude": "vehicle_attitude",
        "onboard_local_position": "vehicle_local_position"},
    "sample_appended_multiple.ulg": {  # PX4 1.6: mag and baro inside sensor_combined, wind_estimate
        "imu": "sensor_combined", "mag": "sensor_combined", "baro": "sensor_combined",
        "onboard_attitude": "vehicle_attitude", "onboard_local_position": "vehicle_local_position",
        "onboard_wind": "wind_estimate"},
    VTOL: {"imu": "sensor_combined", "mag": "vehicle_magnetometer", "baro": "vehicle_air_data",
           "gps": "vehicle_gps_position", "airspeed": "airspeed", "onboard_attitude": "vehicle_attitude",
           "onboard_local_position": "vehicle_local_position", "onboard_wind": "wind_estimate[0]"},
    SITL_GROUND: {"imu": "sensor_combined", "mag": "vehicle_magnetometer", "baro": "vehicle_air_data",
                  "gps": "vehicle_gps_position", "onboard_attitude": "vehicle_attitude",
                  "onboard_local_position": "vehicle_local_position", "onboard_wind": "estimator_states[0]",
                  "truth_attitude": "vehicle_attitude_groundtruth",
                  "truth_local_position": "vehicle_local_position_groundtruth",
                  "truth_global_position": "vehicle_global_position_groundtruth"},
    SITL_FLIGHT: {"imu": "sensor_combined", "mag": "vehicle_magnetometer", "baro": "vehicle_air_data",
                  "gps": "vehicle_gps_position", "onboard_attitude": "vehicle_attitude",
                  "onboard_local_position": "vehicle_local_position",
                  "onboard_global_position": "vehicle_global_position", "onboard_wind": "estimator_states"},
}
#: Rates the shared README states [Hz].
README_RATES_HZ = {(name, "imu"): 250.0 for name in REAL_LOGS if name != VTOL} | {
    (SITL_FLIGHT, "gps"): 19.0, (SITL_FLIGHT, "mag"): 15.0, (SITL_FLIGHT, "baro"): 20.0}


@pytest.fixture(scope="module")
def logs(real_logs_dir):
    """Every real log read once."""
    return {name: load_flight_log(real_logs_dir / name) for name in REAL_LOGS}


@pytest.fixture(scope="module")
def raw(real_logs_dir):
    """Every real log read once with plain pyulog (the reference; do not mutate)."""
    return {name: ULog(str(real_logs_dir / name), message_name_filter_list=list(ALL_TOPICS)) for name in REAL_LOGS}


def parse(real_logs_dir, name: str) -> ULog:
    """A fresh pyulog parse (tests mutate it)."""
    return ULog(str(real_logs_dir / name), message_name_filter_list=list(ALL_TOPICS))


def dataset(ulog: ULog, topic: str, multi_id: int = 0):
    return next(d for d in ulog.data_list if d.name == topic and d.multi_id == multi_id)


def raw_median_rate_hz(ulog: ULog, topic_label: str, stream: str) -> float:
    """Median sample rate of a topic straight from pyulog: the sensor's sample times (``timestamp_sample`` where
    set, else ``timestamp``; for a sensor embedded in sensor_combined, timestamp + its relative time on rows
    where that is valid), from the log start on, in order, without repeats."""
    topic, _, instance = topic_label.partition("[")
    data = dataset(ulog, topic, int(instance.rstrip("]") or 0)).data
    time_us = data["timestamp"].astype(np.int64)
    relative = {("sensor_combined", "mag"): "magnetometer_timestamp_relative",
                ("sensor_combined", "baro"): "baro_timestamp_relative"}.get((topic, stream))
    if relative is not None:
        valid = data[relative].astype(np.int64) != RELATIVE_TIMESTAMP_INVALID
        time_us = time_us[valid] + data[relative].astype(np.int64)[valid]
    elif "timestamp_sample" in data and np.all(data["timestamp_sample"] > 0):
        time_us = time_us + (data["timestamp_sample"].astype(np.int64) - time_us)
    time_us = np.unique(time_us[data["timestamp"].astype(np.int64) >= ulog.start_timestamp]
                        if relative is None else time_us)
    return 1e6 / np.median(np.diff(time_us))


@pytest.mark.parametrize("name", REAL_LOGS)
def test_expected_streams_topics_and_rates(logs, raw, name):
    log = logs[name]
    assert {stream: info.topic for stream, info in log.meta.streams.items()} == EXPECTED_STREAMS[name]
    for stream, info in log.meta.streams.items():
        expected_hz = README_RATES_HZ.get((name, stream), raw_median_rate_hz(raw[name], info.topic, stream))
        assert info.rate_hz == pytest.approx(expected_hz, rel=0.10), stream


@pytest.mark.parametrize("name", REAL_LOGS)
def test_streams_follow_the_contract(logs, name):
    log = logs[name]
    assert set(log.meta.streams) == set(log.streams)
    for stream, frame in log.streams.items():
        required = STREAM_COLUMNS[stream]
        assert list(frame.columns[:len(required)]) == list(required), stream
        assert set(frame.columns) <= set(required + OPTIONAL_COLUMNS.get(stream, ())), stream
        assert frame.index.name == "time_s"
        time_s = frame.index.to_numpy()
        assert time_s.dtype == np.float64
        assert np.all(np.diff(time_s) > 0), f"{stream}: time not strictly increasing"
        assert all(dtype == np.float64 for dtype in frame.dtypes), stream
        assert log.meta.streams[stream].n_samples == len(frame)
    assert log.meta.start_time_s == log["imu"].index[0]
    assert log.meta.duration_s == pytest.approx(log.meta.end_time_s - log.meta.start_time_s)


@pytest.mark.parametrize("name", REAL_LOGS)
def test_imu_is_specific_force_in_frd(logs, name):
    """Every log starts on the bench or the ground: |specific force| ~ g (within what a hand-held or idling
    vehicle allows), pointing up, i.e. accel_z ~ -g in FRD."""
    accel = logs[name]["imu"][["accel_x_m_s2", "accel_y_m_s2", "accel_z_m_s2"]].to_numpy()[:200]
    assert np.median(np.linalg.norm(accel, axis=1)) == pytest.approx(STANDARD_GRAVITY_M_S2, abs=0.5)
    assert np.median(accel[:, 2]) < -0.9 * STANDARD_GRAVITY_M_S2


def test_imu_values_are_the_logged_ones(logs, raw):
    imu, data = logs[SITL_FLIGHT]["imu"], dataset(raw[SITL_FLIGHT], "sensor_combined").data
    np.testing.assert_array_equal(imu.index.to_numpy(), data["timestamp"].astype(np.int64) * 1e-6)
    for axis, i in zip("xyz", range(3), strict=True):
        np.testing.assert_array_equal(imu[f"gyro_{axis}_rad_s"], data[f"gyro_rad[{i}]"].astype(np.float64))
        np.testing.assert_array_equal(imu[f"accel_{axis}_m_s2"], data[f"accelerometer_m_s2[{i}]"])


@pytest.mark.parametrize(("name", "scale"), [("sample.ulg", 1.0), (SITL_FLIGHT, 1e-6)])
def test_imu_dt_seconds_from_float_seconds_and_uint_microseconds(logs, raw, name, scale):
    """gyro_integral_dt: float32 seconds in PX4 1.6, uint32 microseconds in 1.15."""
    raw_dt = dataset(raw[name], "sensor_combined").data["gyro_integral_dt"]
    assert raw_dt.dtype.kind == ("f" if scale == 1.0 else "u")
    np.testing.assert_allclose(logs[name]["imu"]["dt_s"].to_numpy(), raw_dt.astype(np.float64) * scale)
    assert logs[name]["imu"]["dt_s"].median() == pytest.approx(0.004, rel=1e-3)  # 250 Hz


def test_sitl_at_rest_has_no_rotation_and_level_gravity(logs):
    imu = logs[SITL_GROUND]["imu"].iloc[:200]
    gyro = imu[["gyro_x_rad_s", "gyro_y_rad_s", "gyro_z_rad_s"]].to_numpy()
    accel = imu[["accel_x_m_s2", "accel_y_m_s2", "accel_z_m_s2"]].to_numpy()
    np.testing.assert_allclose(gyro.mean(axis=0), 0.0, atol=0.005)  # SITL gyro noise/bias << 0.005 rad/s
    np.testing.assert_allclose(accel.mean(axis=0), [0.0, 0.0, -STANDARD_GRAVITY_M_S2], atol=0.15)


def test_embedded_magnetometer_collapses_repeated_rows(logs, raw):
    """sample.ulg (PX4 ~1.6) logs the magnetometer inside the 250 Hz sensor_combined: each sample repeats on
    2-3 rows; collapsed on its own sample time (timestamp + magnetometer_timestamp_relative) it runs at ~100 Hz."""
    mag = logs["sample.ulg"]["mag"]
    data = dataset(raw["sample.ulg"], "sensor_combined").data
    sample_us = data["timestamp"].astype(np.int64) + data["magnetometer_timestamp_relative"].astype(np.int64)
    first = np.flatnonzero(np.r_[True, np.diff(sample_us) != 0])
    np.testing.assert_array_equal(mag.index.to_numpy(), sample_us[first] * 1e-6)
    np.testing.assert_array_equal(mag["mag_x_gauss"].to_numpy(), data["magnetometer_ga[0]"][first])
    field_gauss = np.linalg.norm(mag[["mag_x_gauss", "mag_y_gauss", "mag_z_gauss"]].to_numpy(), axis=1)
    assert 0.25 < np.median(field_gauss) < 0.65  # Earth's field strength


def test_embedded_baro_and_its_pressure(logs, raw):
    """PX4 1.6 sensor_combined carries baro_alt_meter (no pressure): the pressure is the ISA inverse with the
    log's QNH, so the textbook ISA formula gives the altitude back."""
    log = logs["sample_appended_multiple.ulg"]
    baro = log["baro"]
    data = dataset(raw["sample_appended_multiple.ulg"], "sensor_combined").data
    assert set(np.round(baro["alt_m"].to_numpy(), 3)) <= set(np.round(data["baro_alt_meter"].astype(float), 3))
    qnh_pa = 100.0 * log.meta.parameters["SENS_BARO_QNH"]
    isa_alt_m = ISA_ALT_SCALE_M * (1.0 - (baro["pressure_pa"].to_numpy() / qnh_pa) ** ISA_EXPONENT)
    # PX4 uses R = 287.1 J/(kg K), the textbook exponent R = 287.05: 0.02 % of the altitude apart
    np.testing.assert_allclose(isa_alt_m, baro["alt_m"].to_numpy(), atol=0.2)
    assert baro["temp_c"].median() == pytest.approx(float(np.median(data["baro_temp_celcius"])), abs=0.5)
    assert any("pressure derived from the altitude" in w for w in log.meta.warnings)


def test_missing_sensors_are_absent_and_reported(logs):
    log = logs["sample.ulg"]  # bench log: no GPS, baro fields present but never valid, multicopter
    assert "gps" not in log.streams and "baro" not in log.streams and "airspeed" not in log.streams
    warnings = log.meta.warnings
    assert any(w.startswith("no barometer: vehicle_air_data: not in the log; sensor_combined: no valid samples "
                            "(baro_timestamp_relative marks every row invalid)") for w in warnings)
    assert any(w.startswith("no GPS: vehicle_gps_position: not in the log; sensor_gps: not in the log")
               for w in warnings)
    assert any(w.startswith("no airspeed sensor (normal for a vehicle that is not fixed-wing): ")
               for w in warnings)
    assert not any(w.startswith("no magnetometer") for w in warnings)


def test_fixed_wing_without_airspeed_is_reported(real_logs_dir):
    ulog = parse(real_logs_dir, SITL_FLIGHT)
    ulog.initial_parameters["MAV_TYPE"] = 1  # fixed wing
    log = flightlog_from_ulog(ulog, source="x.ulg")
    assert ("no airspeed sensor: airspeed: not in the log; differential_pressure: not in the log; "
            "airspeed_validated: not in the log") in log.meta.warnings


@pytest.mark.parametrize("name", [SITL_GROUND, SITL_FLIGHT, VTOL])
def test_baro_pressure_is_pascal(logs, name):
    """PX4's baro_alt_meter is the ISA altitude of the static pressure for QNH = SENS_BARO_QNH [hPa]."""
    log = logs[name]
    baro = log["baro"]
    qnh_pa = 100.0 * log.meta.parameters.get("SENS_BARO_QNH", 1013.25)
    isa_alt_m = ISA_ALT_SCALE_M * (1.0 - (baro["pressure_pa"].to_numpy() / qnh_pa) ** ISA_EXPONENT)
    np.testing.assert_allclose(isa_alt_m, baro["alt_m"].to_numpy(), atol=0.5)


@pytest.mark.parametrize(("name", "mbar"), [(VTOL, True), (SITL_GROUND, False)])
def test_raw_sensor_baro_in_mbar_and_pascal(real_logs_dir, raw, name, mbar):
    """Without vehicle_air_data the raw sensor_baro is used: PX4 1.11 logs millibar, 1.13 pascal."""
    ulog = parse(real_logs_dir, name)
    ulog.data_list[:] = [d for d in ulog.data_list if d.name != "vehicle_air_data"]
    log = flightlog_from_ulog(ulog, source="x.ulg")
    assert log.meta.streams["baro"].topic == "sensor_baro[0]"
    pressure = dataset(raw[name], "sensor_baro").data["pressure"].astype(np.float64)
    np.testing.assert_allclose(log["baro"]["pressure_pa"].to_numpy(), pressure * (100.0 if mbar else 1.0))
    air_data = dataset(raw[name], "vehicle_air_data").data
    np.testing.assert_allclose(log["baro"]["alt_m"].median(), np.median(air_data["baro_alt_meter"]), atol=2.0)
    assert any(w.startswith("baro from sensor_baro[0]: raw driver output") for w in log.meta.warnings)


@pytest.mark.parametrize("name", [VTOL, SITL_GROUND, SITL_FLIGHT])
def test_gps_units_against_pyulog(logs, raw, name):
    """int32 lat/lon [1e-7 deg] and alt [mm] up to PX4 1.13; float64 degrees and metres from 1.14."""
    gps = logs[name]["gps"]
    data = dataset(raw[name], "vehicle_gps_position").data
    new_format = "latitude_deg" in data
    assert new_format == (logs[name].meta.ver_data_format == 2)
    lat = data["latitude_deg"] if new_format else data["lat"].astype(np.float64) * 1e-7
    lon = data["longitude_deg"] if new_format else data["lon"].astype(np.float64) * 1e-7
    alt = data["altitude_msl_m"] if new_format else data["alt"].astype(np.float64) * 1e-3
    rows = np.searchsorted(data["timestamp"].astype(np.int64) * 1e-6, gps.index.to_numpy())
    with_fix = gps["fix_type"].to_numpy() >= 2
    assert with_fix.sum() > 10
    np.testing.assert_allclose(gps["lat_deg"].to_numpy()[with_fix], lat[rows][with_fix], rtol=1e-15)
    np.testing.assert_allclose(gps["lon_deg"].to_numpy()[with_fix], lon[rows][with_fix], rtol=1e-15)
    np.testing.assert_allclose(gps["alt_m"].to_numpy()[with_fix], alt[rows][with_fix], rtol=1e-12)
    np.testing.assert_allclose(gps["vn_m_s"].to_numpy()[with_fix], data["vel_n_m_s"][rows][with_fix])
    np.testing.assert_allclose(gps["eph_m"].to_numpy(), data["eph"][rows])


def test_gps_int_degrees_match_ground_truth(logs):
    """Cross-check of the 1e-7 deg scale: PX4 1.13 SITL GPS agrees with the simulator's float64 truth."""
    log = logs[SITL_GROUND]
    gps, truth = log["gps"], log["truth_global_position"]
    at = np.searchsorted(truth.index, gps.index[-1])
    assert gps["lat_deg"].iloc[-1] == pytest.approx(truth["lat_deg"].iloc[at - 1], abs=2e-5)  # ~2 m
    assert gps["lon_deg"].iloc[-1] == pytest.approx(truth["lon_deg"].iloc[at - 1], abs=3e-5)
    assert 400.0 < gps["alt_m"].iloc[-1] < 600.0  # PX4 SITL home (Zurich) is at 488 m MSL


def test_gps_utc_and_sample_time(logs, raw):
    """time_utc_usec -> time_utc_s; timestamp_sample is 0 (unset) in the 1.15 SITL GPS, so no sample_time_s."""
    gps = logs[VTOL]["gps"]
    data = dataset(raw[VTOL], "vehicle_gps_position").data
    np.testing.assert_allclose(gps["time_utc_s"].to_numpy(), data["time_utc_usec"].astype(np.int64) * 1e-6)
    assert "sample_time_s" not in logs[SITL_FLIGHT]["gps"].columns
    assert "sample_time_s" in logs[SITL_FLIGHT]["mag"].columns


def test_utc_offset_matches_pyulog(logs, raw):
    data = dataset(raw[VTOL], "vehicle_gps_position").data
    offset_us = data["time_utc_usec"].astype(np.int64) - data["timestamp"].astype(np.int64)
    assert logs[VTOL].meta.utc_offset_s == pytest.approx(np.median(offset_us) * 1e-6, abs=1e-6)
    assert logs["sample.ulg"].meta.utc_offset_s is None


def test_utc_offset_is_the_robust_median_and_ignores_missing_utc(real_logs_dir):
    ulog = parse(real_logs_dir, SITL_FLIGHT)
    gps = dataset(ulog, "vehicle_gps_position").data
    offset_us = 1_600_000_000_123_456 - int(gps["timestamp"][0])
    utc = gps["timestamp"].astype(np.int64) + offset_us
    utc[:50] = 0  # no UTC yet
    utc[60:63] += 18_000_000  # a few rows in GPS time (18 leap seconds): outliers for the median
    gps["time_utc_usec"] = utc.astype(np.uint64)
    log = flightlog_from_ulog(ulog, source="x.ulg")
    assert log.meta.utc_offset_s == pytest.approx(offset_us * 1e-6, abs=1e-6)
    assert np.isnan(log["gps"]["time_utc_s"].to_numpy()[:50]).all()
    assert log.utc(log.meta.start_time_s)[0].year == 2020  # 1.6e9 s after 1970


def test_gps_without_fix_has_no_position(real_logs_dir):
    ulog = parse(real_logs_dir, SITL_FLIGHT)
    gps = dataset(ulog, "vehicle_gps_position").data
    fix_type = gps["fix_type"].copy()
    had_fix = fix_type >= 2
    lost = np.flatnonzero(had_fix)[100:110]
    fix_type[lost] = 1  # "dead reckoning only": no position
    gps["fix_type"] = fix_type
    frame = flightlog_from_ulog(ulog, source="x.ulg")["gps"]
    position = frame[["lat_deg", "lon_deg", "alt_m", "vn_m_s", "ve_m_s", "vd_m_s"]].to_numpy()
    with_fix = frame["fix_type"].to_numpy() >= 2
    assert np.isnan(position[~with_fix]).all()
    assert np.isfinite(position[with_fix]).all()
    assert np.count_nonzero(with_fix) == np.count_nonzero(had_fix) - len(lost)


def test_airspeed_from_the_sensor_topic(logs, raw, real_logs_dir):
    airspeed = logs[VTOL]["airspeed"]
    data = dataset(raw[VTOL], "airspeed").data
    np.testing.assert_array_equal(airspeed["ias_m_s"].to_numpy(), data["indicated_airspeed_m_s"])
    np.testing.assert_array_equal(airspeed["tas_m_s"].to_numpy(), data["true_airspeed_m_s"])
    everything = ULog(str(real_logs_dir / VTOL))
    header_span_s = (everything.last_timestamp - everything.start_timestamp) * 1e-6
    assert header_span_s == pytest.approx(1174.0, abs=1.0)  # a late `mission` message
    assert logs[VTOL].meta.duration_s == pytest.approx(6.5, abs=0.1)  # the sensor data


def test_airspeed_from_differential_pressure(real_logs_dir, raw):
    """IAS = sign(q) sqrt(2 |q| / 1.225); TAS / IAS = sqrt(1.225 / rho) with rho the ISA density at the
    barometer's static pressure."""
    ulog = parse(real_logs_dir, VTOL)
    ulog.data_list[:] = [d for d in ulog.data_list if d.name != "airspeed"]
    log = flightlog_from_ulog(ulog, source="x.ulg")
    assert log.meta.streams["airspeed"].topic == "differential_pressure[0]"
    dp_pa = dataset(raw[VTOL], "differential_pressure").data["differential_pressure_raw_pa"].astype(np.float64)
    airspeed = log["airspeed"]
    np.testing.assert_allclose(airspeed["ias_m_s"].to_numpy(), np.sign(dp_pa) * np.sqrt(2 * np.abs(dp_pa) / 1.225))
    static_pa = log["baro"]["pressure_pa"].median()
    isa_temp_k = 288.15 - 0.0065 * ISA_ALT_SCALE_M * (1.0 - (static_pa / 101325.0) ** ISA_EXPONENT)
    density = static_pa / (287.05 * isa_temp_k)
    np.testing.assert_allclose(airspeed["tas_m_s"] / airspeed["ias_m_s"], np.sqrt(1.225 / density), rtol=2e-4)
    assert any(w.startswith("airspeed from differential_pressure[0]: IAS with the sea-level density")
               for w in log.meta.warnings)


def test_airspeed_validated_is_the_flagged_last_resort(real_logs_dir):
    ulog = parse(real_logs_dir, VTOL)
    ulog.data_list[:] = [d for d in ulog.data_list if d.name not in ("airspeed", "differential_pressure")]
    log = flightlog_from_ulog(ulog, source="x.ulg")
    assert log.meta.streams["airspeed"].topic == "airspeed_validated"
    assert any(w.startswith("airspeed from airspeed_validated: PX4's validated airspeed, which may be synthetic")
               for w in log.meta.warnings)


def test_onboard_attitude_matches_ground_truth(logs):
    log = logs[SITL_GROUND]
    onboard, truth = log["onboard_attitude"], log["truth_attitude"]
    at = np.searchsorted(onboard.index, truth.index[-1]) - 1
    for angle, tol_deg in (("roll_deg", 1.0), ("pitch_deg", 1.0), ("yaw_deg", 3.0)):
        assert onboard[angle].iloc[at] == pytest.approx(truth[angle].iloc[-1], abs=tol_deg), angle


@pytest.mark.parametrize("name", REAL_LOGS)
def test_euler_angles_reproduce_the_quaternion(logs, name):
    attitude = logs[name]["onboard_attitude"]
    q = attitude[["qw", "qx", "qy", "qz"]].to_numpy()
    q_back = euler_to_quat(*np.radians(attitude[["roll_deg", "pitch_deg", "yaw_deg"]].to_numpy().T))
    np.testing.assert_allclose(np.abs(np.sum(q * q_back, axis=1)), 1.0, atol=1e-6)  # same rotation (q ~ -q)
    assert np.all((attitude["yaw_deg"] >= -180.0) & (attitude["yaw_deg"] < 180.0))


def test_wind_variance_names_of_both_px4_generations(logs, raw):
    for name, field in (("sample_appended_multiple.ulg", "covariance_north"), (VTOL, "variance_north")):
        wind = logs[name]["onboard_wind"]
        data = dataset(raw[name], "wind_estimate").data
        keep = data["timestamp"].astype(np.int64) >= raw[name].start_timestamp
        np.testing.assert_array_equal(wind["wind_n_var_m2_s2"].to_numpy(), data[field][keep])
        np.testing.assert_array_equal(wind["wind_e_m_s"].to_numpy(), data["windspeed_east"][keep])


def test_wind_from_estimator_states(logs, raw):
    wind = logs[SITL_GROUND]["onboard_wind"]
    data = dataset(raw[SITL_GROUND], "estimator_states").data
    np.testing.assert_array_equal(wind["wind_n_m_s"].to_numpy(), data["states[22]"])
    np.testing.assert_array_equal(wind["wind_e_m_s"].to_numpy(), data["states[23]"])


def test_truth_wind_from_the_simulator_topic(real_logs_dir):
    ulog = parse(real_logs_dir, "sample_appended_multiple.ulg")
    truth = copy.deepcopy(dataset(ulog, "wind_estimate"))
    truth.name = TRUTH_WIND_TOPIC
    truth.data = {key: truth.data[key] for key in ("timestamp", "windspeed_north", "windspeed_east")}
    ulog.data_list.append(truth)
    log = flightlog_from_ulog(ulog, source="x.ulg")
    assert log.meta.streams["truth_wind"].topic == TRUTH_WIND_TOPIC
    np.testing.assert_array_equal(log["truth_wind"]["wind_n_m_s"].to_numpy(), truth.data["windspeed_north"])
    assert list(log["truth_wind"].columns) == ["wind_n_m_s", "wind_e_m_s"]


def test_secondary_instance_is_used_and_named_when_instance_0_is_missing(real_logs_dir):
    ulog = parse(real_logs_dir, SITL_GROUND)
    ulog.data_list[:] = [d for d in ulog.data_list if d.name != "vehicle_gps_position"]
    dataset(ulog, "sensor_gps").multi_id = 2
    log = flightlog_from_ulog(ulog, source="x.ulg")
    assert log.meta.streams["gps"].topic == "sensor_gps[2]"
    assert "sensor_gps: instance 0 has no data; using instance 2 (most samples)" in log.meta.warnings


def test_all_zero_timestamp_topic_is_skipped(real_logs_dir):
    ulog = parse(real_logs_dir, SITL_GROUND)
    mag = dataset(ulog, "vehicle_magnetometer").data
    mag["timestamp"] = np.zeros_like(mag["timestamp"])
    log = flightlog_from_ulog(ulog, source="x.ulg")
    assert "vehicle_magnetometer: every timestamp is zero; topic skipped" in log.meta.warnings
    assert log.meta.streams["mag"].topic == "sensor_mag[0]"  # the raw fallback
    assert any(w.startswith("mag from sensor_mag[0]: raw driver output") for w in log.meta.warnings)


def test_rows_before_the_log_start_are_dropped_and_counted(logs, raw):
    data = dataset(raw[SITL_GROUND], "vehicle_magnetometer").data
    n_early = int(np.count_nonzero(data["timestamp"].astype(np.int64) < raw[SITL_GROUND].start_timestamp))
    assert n_early == 1
    assert len(logs[SITL_GROUND]["mag"]) == len(data["timestamp"]) - n_early
    assert "vehicle_magnetometer: dropped 1 rows timed before the log start (0.280000 s)" in \
        logs[SITL_GROUND].meta.warnings


def test_time_axis_cleaning(real_logs_dir):
    ulog = parse(real_logs_dir, SITL_FLIGHT)
    imu = dataset(ulog, "sensor_combined").data
    n_rows = len(imu["timestamp"])
    timestamp = imu["timestamp"].copy()
    timestamp[5] = 0  # not set
    timestamp[11] = timestamp[10]  # repeated
    timestamp[20], timestamp[21] = timestamp[21], timestamp[20]  # out of order
    imu["timestamp"] = timestamp
    log = flightlog_from_ulog(ulog, source="x.ulg")
    time_s = log["imu"].index.to_numpy()
    assert len(time_s) == n_rows - 2
    assert np.all(np.diff(time_s) > 0)
    warnings = log.meta.warnings
    assert "sensor_combined: dropped 1 rows with timestamp 0" in warnings
    assert "sensor_combined: dropped 1 rows repeating an earlier timestamp" in warnings
    assert "sensor_combined: 1 rows were out of time order and have been sorted" in warnings
    # the swapped rows keep their values: the row logged at the later time still carries its own gyro sample
    later = timestamp[20] * 1e-6
    assert log["imu"].loc[later, "gyro_x_rad_s"] == pytest.approx(float(imu["gyro_rad[0]"][20]))


def test_nonfinite_imu_rows_are_dropped(real_logs_dir):
    ulog = parse(real_logs_dir, SITL_FLIGHT)
    imu = dataset(ulog, "sensor_combined").data
    gyro = imu["gyro_rad[1]"].copy()
    gyro[[7, 8, 9]] = np.nan
    imu["gyro_rad[1]"] = gyro
    log = flightlog_from_ulog(ulog, source="x.ulg")
    assert len(log["imu"]) == len(gyro) - 3
    assert np.isfinite(log["imu"].to_numpy()).all()
    assert "sensor_combined: dropped 3 rows with non-finite gyro/accel values" in log.meta.warnings


@pytest.mark.parametrize(("name", "expected"), [
    ("sample_appended_multiple.ulg", "v1.6.0 dev (f54a6c29)"),  # ver_sw_release 0x01060000
    (VTOL, "v1.11.2 dev (8583f1da)"),  # 0x010B0200
    (SITL_FLIGHT, "v1.15.0 dev (cb09dde6)"),  # 0x010F0000
    ("sample.ulg", "fd483321"),  # no ver_sw_release: git hash only
])
def test_firmware_version(logs, name, expected):
    assert logs[name].meta.px4_version == expected


def test_firmware_release_tag_and_zero_release(real_logs_dir):
    ulog = parse(real_logs_dir, SITL_FLIGHT)
    ulog.msg_info_dict["ver_sw_release"] = 0x010E02FF  # v1.14.2, type 0xFF = release
    assert firmware_version(ulog) == "v1.14.2"
    ulog.msg_info_dict["ver_sw_release"] = 0  # not set: the git hash says more
    assert firmware_version(ulog) == "cb09dde6"


def test_metadata(logs, real_logs_dir):
    log = logs[VTOL]
    assert log.meta.vehicle_type == 22 and log.meta.is_fixed_wing  # standard VTOL
    assert log.meta.hardware == "CUBEPILOT_CUBEORANGE"
    assert log.meta.ver_data_format == 1 and logs[SITL_FLIGHT].meta.ver_data_format == 2
    assert logs["sample.ulg"].meta.ver_data_format is None
    assert log.meta.sha256 == hashlib.sha256((real_logs_dir / VTOL).read_bytes()).hexdigest()
    assert log.meta.parameters["MAV_TYPE"] == 22.0
    assert "1 logger dropouts, 30 ms of data lost in total (longest 30 ms at 20.328 s)" in log.meta.warnings


def test_log_without_imu_is_refused(real_logs_dir):
    ulog = parse(real_logs_dir, SITL_FLIGHT)
    ulog.data_list[:] = [d for d in ulog.data_list if d.name != "sensor_combined"]
    with pytest.raises(InputError, match="sensor_combined") as caught:
        flightlog_from_ulog(ulog, source="x.ulg")
    assert str(caught.value).startswith("x.ulg: sensor_combined: no IMU data")


def test_path_bytes_and_file_object_give_the_same_log(real_logs_dir):
    path = real_logs_dir / VTOL
    content = path.read_bytes()
    from_path = load_flight_log(path)
    from_bytes = load_flight_log(content, name="upload.ulg")
    with open(path, "rb") as handle:
        from_handle = load_flight_log(handle)
    assert from_path.meta.source == VTOL and from_handle.meta.source == VTOL
    assert from_bytes.meta.source == "upload.ulg"
    for other in (from_bytes, from_handle):
        assert other.meta.sha256 == from_path.meta.sha256
        assert set(other.streams) == set(from_path.streams)
        for stream, frame in from_path.streams.items():
            assert other[stream].equals(frame), stream


@pytest.mark.parametrize(("content", "message"), [
    (b"", "flight.ulg: the file is empty"),
    (b"unix_time_s,i1_mA\n0.0,1.0\n" * 20,
     "flight.ulg: not a flight log solarnav reads: expected one of the formats: PX4 ULog"),
    (np.random.default_rng(5).integers(0, 256, 50_000, dtype=np.uint8).tobytes(),
     "flight.ulg: not a flight log solarnav reads"),
])
def test_not_a_ulog(content, message):
    with pytest.raises(InputError) as caught:
        load_flight_log(content, name="flight.ulg")
    assert str(caught.value).startswith(message)


def test_ulog_header_followed_by_random_bytes(real_logs_dir):
    header = (real_logs_dir / VTOL).read_bytes()[:16]
    noise = np.random.default_rng(11).integers(0, 256, 100_000, dtype=np.uint8).tobytes()
    with pytest.raises(InputError, match=r"^noise\.ulg: sensor_combined: no IMU data"):
        load_flight_log(header + noise, name="noise.ulg")


def test_unreadable_path(tmp_path):
    with pytest.raises(InputError, match=r"missing\.ulg: cannot read the file"):
        load_flight_log(tmp_path / "missing.ulg")


def test_size_limit(real_logs_dir):
    path = real_logs_dir / VTOL
    message = f"{VTOL}: file is 921631 bytes, over the limit of 100000 bytes"
    with pytest.raises(FileTooLargeError, match=re.escape(message)):
        load_flight_log(path, max_bytes=100_000)
    with pytest.raises(FileTooLargeError, match=r"upload\.ulg: file is over the limit of 100000 bytes"):
        load_flight_log(io.BytesIO(path.read_bytes()), max_bytes=100_000, name="upload.ulg")
    assert load_flight_log(path, max_bytes=path.stat().st_size).has("imu")


def test_truncated_file_loads_what_is_readable(real_logs_dir, tmp_path):
    """A copy cut in the middle of a message: the complete part is read, the cut is reported."""
    content = (real_logs_dir / SITL_FLIGHT).read_bytes()
    path = tmp_path / "cut.ulg"
    path.write_bytes(content[:len(content) // 2 + 7])
    full = load_flight_log(real_logs_dir / SITL_FLIGHT)
    log = load_flight_log(path)
    assert log.meta.warnings[0] == (f"the file is truncated: its last message is cut off at byte "
                                    f"{len(content) // 2 + 7}; the complete messages before it were read")
    assert 0.3 * full.meta.duration_s < log.meta.duration_s < 0.7 * full.meta.duration_s
    n = len(log["imu"])
    assert log["imu"].equals(full["imu"].iloc[:n])
    assert not any(w.startswith("the file is truncated") for w in full.meta.warnings)


def test_truncated_before_any_imu_sample_is_refused(real_logs_dir, tmp_path):
    content = (real_logs_dir / SITL_FLIGHT).read_bytes()
    path = tmp_path / "stub.ulg"
    path.write_bytes(content[:5000])  # inside the definitions section
    with pytest.raises(InputError, match=r"^stub\.ulg: sensor_combined: no IMU data: .*; the file is truncated: "
                                         "its last message is cut off at byte 5000"):
        load_flight_log(path)
    path.write_bytes(content[:20])  # inside the first message
    with pytest.raises(InputError, match=r"^stub\.ulg: sensor_combined: no IMU data: .*; the file is corrupt"):
        load_flight_log(path)


def test_damaged_files_give_a_log_or_an_input_error(real_logs_dir):
    """Truncated or overwritten files: never a crash other than InputError; corruption is reported."""
    original = (real_logs_dir / SITL_FLIGHT).read_bytes()
    rng = np.random.default_rng(7)
    n_corrupt_reported = 0
    for trial in range(24):
        damaged = bytearray(original)
        if trial % 2:
            damaged = damaged[: int(rng.integers(100, len(damaged)))]
        else:
            start = int(rng.integers(2000, len(damaged) - 4000))
            damaged[start:start + 3000] = rng.integers(0, 256, 3000, dtype=np.uint8).tobytes()
        try:
            log = load_flight_log(bytes(damaged), name="damaged.ulg")
        except InputError as exc:
            assert str(exc).startswith("damaged.ulg: ")
            continue
        assert np.all(np.diff(log["imu"].index.to_numpy()) > 0)
        n_corrupt_reported += any("corrupt" in w for w in log.meta.warnings)
    assert n_corrupt_reported > 0  # overwritten blocks are detected by pyulog and reported
