"""ingest.ulog: PX4 ULog -> canonical FlightLog, on the five public PX4 logs (PX4 1.6 .. 1.15) and on copies of
them with injected faults."""

from __future__ import annotations

import hashlib
import io

import numpy as np
import pytest
from pyulog import ULog

from ingest.errors import FileTooLargeError, InputError
from ingest.flightlog import OPTIONAL_COLUMNS, STREAM_COLUMNS
from ingest.frames import euler_to_quat
from ingest.px4_topics import ALL_TOPICS
from ingest.ulog import firmware_version, flightlog_from_ulog, read_ulog

REAL_LOGS = ("sample.ulg", "sample_appended_multiple.ulg", "sample_log_small.ulg",
             "sample_logging_tagged_and_default_params.ulg", "sample_px4_events.ulg")
SITL_GROUND = "sample_logging_tagged_and_default_params.ulg"  # SITL, on the ground, with ground truth
SITL_FLIGHT = "sample_px4_events.ulg"  # SITL, PX4 1.15, float64 GPS lat/lon

STANDARD_GRAVITY_M_S2 = 9.80665


@pytest.fixture(scope="module")
def logs(real_logs_dir):
    """Every real log read once."""
    return {name: read_ulog(real_logs_dir / name) for name in REAL_LOGS}


def parse(real_logs_dir, name: str) -> ULog:
    """A fresh pyulog parse (tests mutate it)."""
    return ULog(str(real_logs_dir / name), message_name_filter_list=list(ALL_TOPICS))


def dataset(ulog: ULog, topic: str):
    return next(d for d in ulog.data_list if d.name == topic and d.multi_id == 0)


@pytest.mark.parametrize("name", REAL_LOGS)
def test_streams_follow_the_contract(logs, name):
    log = logs[name]
    assert log.has("imu")
    assert set(log.meta.streams) == set(log.streams)
    for stream, frame in log.streams.items():
        required = STREAM_COLUMNS[stream]
        allowed = required + OPTIONAL_COLUMNS.get(stream, ())
        assert list(frame.columns[:len(required)]) == list(required), stream
        assert set(frame.columns) <= set(allowed), stream
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


def test_sitl_at_rest_has_no_rotation_and_level_gravity(logs):
    imu = logs[SITL_GROUND]["imu"].iloc[:200]
    gyro = imu[["gyro_x_rad_s", "gyro_y_rad_s", "gyro_z_rad_s"]].to_numpy()
    accel = imu[["accel_x_m_s2", "accel_y_m_s2", "accel_z_m_s2"]].to_numpy()
    np.testing.assert_allclose(gyro.mean(axis=0), 0.0, atol=0.005)  # SITL gyro noise/bias << 0.005 rad/s
    np.testing.assert_allclose(accel.mean(axis=0), [0.0, 0.0, -STANDARD_GRAVITY_M_S2], atol=0.15)


@pytest.mark.parametrize("name", ["sample.ulg", SITL_FLIGHT])  # gyro_integral_dt: float32 s vs uint32 us
def test_imu_dt_matches_sample_spacing(logs, name):
    imu = logs[name]["imu"]
    assert imu["dt_s"].median() == pytest.approx(np.median(np.diff(imu.index.to_numpy())), abs=2e-5)


def test_embedded_magnetometer_collapses_repeated_rows(logs):
    """sample.ulg (PX4 ~1.6) logs the magnetometer inside the 250 Hz sensor_combined: each sample repeats on
    2-3 rows; collapsed on its own sample time it runs at ~100 Hz."""
    log = logs["sample.ulg"]
    assert log.meta.streams["mag"].topic == "sensor_combined"
    assert 80.0 < log.meta.streams["mag"].rate_hz < 120.0
    field_gauss = np.linalg.norm(log["mag"][["mag_x_gauss", "mag_y_gauss", "mag_z_gauss"]].to_numpy(), axis=1)
    assert 0.25 < np.median(field_gauss) < 0.65  # Earth's field strength


def test_missing_sensors_are_absent_and_reported(logs):
    log = logs["sample.ulg"]  # bench log: no GPS, baro fields present but never valid
    assert not log.has("gps") and "gps" not in log.streams
    assert not log.has("baro")
    assert any(w.startswith("no baro stream") and "sensor_combined: no valid samples" in w
               for w in log.meta.warnings)
    assert any(w.startswith("no gps stream") for w in log.meta.warnings)
    # a multicopter without a pitot is normal: no airspeed warning
    assert not any("airspeed" in w for w in log.meta.warnings)


@pytest.mark.parametrize("name", [SITL_GROUND, SITL_FLIGHT, "sample_log_small.ulg"])
def test_baro_pressure_is_pascal(logs, name):
    """PX4's baro_alt_meter is the ISA altitude of the static pressure for QNH = SENS_BARO_QNH [hPa]."""
    log = logs[name]
    baro = log["baro"]
    qnh_pa = 100.0 * log.meta.parameters.get("SENS_BARO_QNH", 1013.25)
    isa_alt_m = 44330.77 * (1.0 - (baro["pressure_pa"].to_numpy() / qnh_pa) ** 0.190263)
    np.testing.assert_allclose(isa_alt_m, baro["alt_m"].to_numpy(), atol=0.5)


def test_gps_int_degrees_match_ground_truth(logs):
    """PX4 1.13 logs lat/lon as int32 1e-7 deg and alt in mm; the simulator's truth is float64 degrees."""
    log = logs[SITL_GROUND]
    gps = log["gps"]
    truth = log["truth_global_position"]
    at = np.searchsorted(truth.index, gps.index[-1])
    assert gps["lat_deg"].iloc[-1] == pytest.approx(truth["lat_deg"].iloc[at - 1], abs=2e-5)  # ~2 m
    assert gps["lon_deg"].iloc[-1] == pytest.approx(truth["lon_deg"].iloc[at - 1], abs=3e-5)
    assert 400.0 < gps["alt_m"].iloc[-1] < 600.0  # PX4 SITL home (Zurich) is at 488 m MSL


def test_gps_float_degrees_match_onboard_position(logs):
    """PX4 1.15 (ver_data_format 2) logs float64 latitude_deg / longitude_deg / altitude_msl_m."""
    log = logs[SITL_FLIGHT]
    assert log.meta.ver_data_format == 2
    gps, onboard = log["gps"], log["onboard_global_position"]
    at = np.searchsorted(gps.index, onboard.index[-1])
    assert gps["lat_deg"].iloc[at] == pytest.approx(onboard["lat_deg"].iloc[-1], abs=2e-5)
    assert gps["lon_deg"].iloc[at] == pytest.approx(onboard["lon_deg"].iloc[-1], abs=3e-5)
    assert gps["alt_m"].iloc[at] == pytest.approx(onboard["alt_m"].iloc[-1], abs=3.0)


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


def test_wind_variance_names_of_both_px4_generations(logs):
    for name in ("sample_appended_multiple.ulg", "sample_log_small.ulg"):  # covariance_* (1.6), variance_* (1.11)
        assert {"wind_n_var_m2_s2", "wind_e_var_m2_s2"} <= set(logs[name]["onboard_wind"].columns), name


@pytest.mark.parametrize(("name", "expected"), [
    ("sample_appended_multiple.ulg", "v1.6.0 dev (f54a6c29)"),  # ver_sw_release 0x01060000
    (SITL_FLIGHT, "v1.15.0 dev (cb09dde6)"),  # 0x010F0000
    ("sample.ulg", "fd483321"),  # no ver_sw_release: git hash only
])
def test_firmware_version(logs, name, expected):
    assert logs[name].meta.px4_version == expected


def test_firmware_release_tag(real_logs_dir):
    ulog = parse(real_logs_dir, SITL_FLIGHT)
    ulog.msg_info_dict["ver_sw_release"] = 0x010E02FF  # v1.14.2, type 0xFF = release
    assert firmware_version(ulog) == "v1.14.2"


def test_metadata(logs, real_logs_dir):
    log = logs["sample_log_small.ulg"]
    assert log.meta.vehicle_type == 22 and log.meta.is_fixed_wing  # standard VTOL
    assert log.meta.hardware == "CUBEPILOT_CUBEORANGE"
    assert log.meta.sha256 == hashlib.sha256((real_logs_dir / "sample_log_small.ulg").read_bytes()).hexdigest()
    assert log.meta.duration_s < 10.0  # the header spans 1174 s, the sensor data ~6.5 s
    assert log.meta.parameters["MAV_TYPE"] == 22.0
    assert any("logger dropouts" in w for w in log.meta.warnings)


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
    warnings = " | ".join(log.meta.warnings)
    assert "sensor_combined: dropped 1 rows with a zero or negative timestamp" in warnings
    assert "sensor_combined: dropped 1 rows repeating an earlier timestamp" in warnings
    assert "sensor_combined: 1 rows were out of time order" in warnings
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
    assert any("3 rows with non-finite gyro/accel" in w for w in log.meta.warnings)


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


def test_fixed_wing_without_airspeed_is_reported(real_logs_dir):
    ulog = parse(real_logs_dir, SITL_FLIGHT)
    ulog.initial_parameters["MAV_TYPE"] = 1  # fixed wing
    log = flightlog_from_ulog(ulog, source="x.ulg")
    assert "no airspeed stream (airspeed: not in the log)" in log.meta.warnings


def test_log_without_imu_is_refused(real_logs_dir):
    ulog = parse(real_logs_dir, SITL_FLIGHT)
    ulog.data_list[:] = [d for d in ulog.data_list if d.name != "sensor_combined"]
    with pytest.raises(InputError, match="sensor_combined") as caught:
        flightlog_from_ulog(ulog, source="x.ulg")
    assert str(caught.value).startswith("x.ulg: sensor_combined: no IMU data")


def test_path_bytes_and_file_object_give_the_same_log(real_logs_dir):
    path = real_logs_dir / "sample_log_small.ulg"
    content = path.read_bytes()
    from_path = read_ulog(path)
    from_bytes = read_ulog(content, name="upload.ulg")
    with open(path, "rb") as handle:
        from_handle = read_ulog(handle)
    assert from_bytes.meta.source == "upload.ulg" and from_handle.meta.source == "sample_log_small.ulg"
    for other in (from_bytes, from_handle):
        assert other.meta.sha256 == from_path.meta.sha256
        assert set(other.streams) == set(from_path.streams)
        for stream, frame in from_path.streams.items():
            assert other[stream].equals(frame), stream


@pytest.mark.parametrize(("content", "message"), [
    (b"", "not a readable PX4 ULog file"),
    (b"time_s,i1_mA\n0.0,1.0\n" * 20, "not a readable PX4 ULog file"),
])
def test_not_a_ulog(content, message):
    with pytest.raises(InputError, match=message) as caught:
        read_ulog(content, name="flight.ulg")
    assert str(caught.value).startswith("flight.ulg: ")


def test_unreadable_path(tmp_path):
    with pytest.raises(InputError, match="cannot read the file"):
        read_ulog(tmp_path / "missing.ulg")


def test_size_limit(real_logs_dir):
    path = real_logs_dir / "sample_log_small.ulg"
    with pytest.raises(FileTooLargeError, match="limit"):
        read_ulog(path, max_bytes=100_000)
    with pytest.raises(FileTooLargeError, match="limit"):
        read_ulog(io.BytesIO(path.read_bytes()), max_bytes=100_000)
    assert read_ulog(path, max_bytes=path.stat().st_size).has("imu")


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
            log = read_ulog(bytes(damaged), name="damaged.ulg")
        except InputError as exc:
            assert str(exc).startswith("damaged.ulg: ")
            continue
        assert np.all(np.diff(log["imu"].index.to_numpy()) > 0)
        n_corrupt_reported += any("corrupt" in w for w in log.meta.warnings)
    assert n_corrupt_reported > 0  # overwritten blocks are detected by pyulog and reported
