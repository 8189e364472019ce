"""ArduPilot DataFlash reader: the two real ArduPlane 4.0.8 logs against pymavlink's DFReader (every field read,
float32 tolerance), the stream mapping, vehicle types and instances on small written logs, and bad input."""

from __future__ import annotations

import io
import time

import numpy as np
import pytest
from pymavlink import DFReader

from app.cli import EXIT_BAD_INPUT, main
from ingest import dataflash_format as df
from ingest.dataflash_reader import flightlog_from_dataflash
from ingest.errors import InputError
from ingest.flightlog import FlightLog
from ingest.frames import quat_to_euler
from ingest.log_formats import load_flight_log
from ingest.quality import assess_input_quality
from sim.dataflash_writer import Message, dataflash_bytes

STATIC, WALK = "arduplane_4.0.8_ground_static.bin", "arduplane_4.0.8_ground_walk.bin"
#: Message types the reader decodes on these logs.
READ_TYPES = ("IMU", "MAG", "BARO", "GPS", "GPA", "ARSP", "XKF1", "XKF2", "POS", "PARM", "MSG")
#: Relative tolerance of float32 rounding.
F32 = 2e-7


@pytest.fixture(scope="module")
def walk_path(real_logs_dir):
    return real_logs_dir / WALK


@pytest.fixture(scope="module")
def walk(walk_path):
    return load_flight_log(walk_path)


@pytest.fixture(scope="module")
def dfreader_walk(walk_path):
    """DFReader's messages of :data:`READ_TYPES`, by type, as lists of dicts."""
    reader = DFReader.DFReader_binary(str(walk_path), zero_time_base=False)
    messages = {name: [] for name in READ_TYPES}
    while (message := reader.recv_match(type=list(READ_TYPES))) is not None:
        messages[message.get_type()].append(message.to_dict())
    return messages


def test_real_logs_streams_and_rates(real_logs_dir):
    expected_hz = {"imu": 50.0, "mag": 10.0, "baro": 10.0, "gps": 5.0, "onboard_attitude": 25.0,
                   "onboard_local_position": 25.0, "onboard_global_position": 25.0, "onboard_wind": 25.0}
    for name in (STATIC, WALK):
        log = load_flight_log(real_logs_dir / name)
        assert set(log.meta.streams) == set(expected_hz), name
        for stream, rate_hz in expected_hz.items():
            assert log.meta.streams[stream].rate_hz == pytest.approx(rate_hz, rel=0.01), (name, stream)
        assert log.meta.streams["imu"].topic == "IMU[0]"  # IMU2 exists: instance 0 is said
        assert log.meta.streams["onboard_attitude"].topic == "XKF1"
        assert not log.has("airspeed")
        assert any(w.startswith("no airspeed sensor: ARSP: every Airspeed and DiffPress is zero")
                   for w in log.meta.warnings)
        assert log.meta.vehicle_type == 1 and log.meta.is_fixed_wing
        assert log.meta.px4_version == "ArduPlane V4.0.8 (ac9a4b9a)" and log.meta.hardware == "PH4-mini"
        assert log.utc(log.meta.start_time_s)[0].strftime("%Y-%m-%d") == "2021-09-15"
        assert log.meta.parameters["AHRS_EKF_TYPE"] == 3.0
        # ArduPlane's default 50 Hz IMU logging is accepted (flagged as coarse), not refused
        assert [(f.kind, f.severity) for f in assess_input_quality(log)] == [("imu_rate", "flag")]


def test_every_read_field_equals_dfreader(walk_path, dfreader_walk):
    """The numpy decoding of every field of the read message types equals DFReader's value."""
    data = np.frombuffer(walk_path.read_bytes(), dtype=np.uint8)
    index = df.walk_records(data)
    formats = {fmt.name: fmt for fmt in df.read_formats(data, index)[0].values()}
    for name in READ_TYPES:
        fmt = formats[name]
        records = df.decode(data, index, fmt)
        expected = dfreader_walk[name]
        assert len(records) == len(expected), name
        for column, code in zip(fmt.columns, fmt.format, strict=True):
            theirs = [message[column] for message in expected]
            if code in "nNZ":
                assert df.text_column(records, column) == theirs, (name, column)
            else:
                np.testing.assert_allclose(df.scaled(records, fmt, column), np.array(theirs, dtype=float),
                                           rtol=F32, atol=0, err_msg=f"{name}.{column}")


def _column(messages, field):
    return np.array([m[field] for m in messages], dtype=float)


def test_streams_equal_dfreader_values(walk, dfreader_walk):
    """Canonical columns against DFReader's values with the documented conversions."""
    d = dfreader_walk
    imu = walk["imu"]
    assert np.array_equal(imu.index.to_numpy(), _column(d["IMU"], "TimeUS") * 1e-6)  # TimeUS [us] x 1e-6
    for axis in "xyz":
        np.testing.assert_allclose(imu[f"gyro_{axis}_rad_s"], _column(d["IMU"], f"Gyr{axis.upper()}"), rtol=F32)
        np.testing.assert_allclose(imu[f"accel_{axis}_m_s2"], _column(d["IMU"], f"Acc{axis.upper()}"), rtol=F32)
        np.testing.assert_allclose(walk["mag"][f"mag_{axis}_gauss"], _column(d["MAG"], f"Mag{axis.upper()}") / 1e3)
    np.testing.assert_allclose(walk["baro"]["pressure_pa"], _column(d["BARO"], "Press"), rtol=F32)
    np.testing.assert_allclose(walk["baro"]["temp_c"], _column(d["BARO"], "Temp"), rtol=F32)
    gps = walk["gps"]
    for column, field in (("lat_deg", "Lat"), ("lon_deg", "Lng"), ("alt_m", "Alt"), ("vd_m_s", "VZ")):
        np.testing.assert_allclose(gps[column], _column(d["GPS"], field), rtol=F32, err_msg=column)
    for column, field in (("eph_m", "HAcc"), ("epv_m", "VAcc"), ("speed_accuracy_m_s", "SAcc")):
        np.testing.assert_allclose(gps[column], _column(d["GPA"], field), rtol=F32, err_msg=column)
    course = np.radians(_column(d["GPS"], "GCrs"))
    np.testing.assert_allclose(gps["vn_m_s"], _column(d["GPS"], "Spd") * np.cos(course), rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(gps["ve_m_s"], _column(d["GPS"], "Spd") * np.sin(course), rtol=1e-6, atol=1e-9)
    # UTC: GPS week 2175 (2021-09-12) plus milliseconds, 18 leap seconds; NaN before the receiver knows the week
    week = _column(d["GPS"], "GWk")
    assert week[0] == 0 and (week[1:] == 2175).all()
    np.testing.assert_allclose(gps["time_utc_s"], np.where(week > 0, 315964800 + 604800 * week
                                                           + _column(d["GPS"], "GMS") / 1e3 - 18, np.nan),
                               rtol=0, atol=1e-6)
    att = walk["onboard_attitude"]
    trim_deg = np.degrees([walk.meta.parameters["AHRS_TRIM_X"], walk.meta.parameters["AHRS_TRIM_Y"]])
    np.testing.assert_allclose(att["roll_deg"] - trim_deg[0], _column(d["XKF1"], "Roll"), atol=1e-9)
    np.testing.assert_allclose(att["pitch_deg"] - trim_deg[1], _column(d["XKF1"], "Pitch"), atol=1e-9)
    yaw = _column(d["XKF1"], "Yaw")
    np.testing.assert_allclose(att["yaw_deg"], (yaw + 180) % 360 - 180, atol=1e-9)
    roll, pitch, _ = quat_to_euler(att[["qw", "qx", "qy", "qz"]].to_numpy())
    np.testing.assert_allclose(np.degrees(roll), att["roll_deg"], atol=1e-9)
    np.testing.assert_allclose(np.degrees(pitch), att["pitch_deg"], atol=1e-9)
    local = walk["onboard_local_position"]
    for column, field in (("x_m", "PN"), ("y_m", "PE"), ("z_m", "PD"), ("vx_m_s", "VN"), ("vz_m_s", "VD")):
        np.testing.assert_allclose(local[column], _column(d["XKF1"], field), rtol=F32, err_msg=column)
    np.testing.assert_allclose(walk["onboard_wind"]["wind_n_m_s"], _column(d["XKF2"], "VWN"), atol=1e-12)
    np.testing.assert_allclose(walk["onboard_global_position"]["lat_deg"], _column(d["POS"], "Lat"), rtol=F32)
    first = {}
    for message in d["PARM"]:
        first.setdefault(message["Name"], message["Value"])
    assert walk.meta.parameters == pytest.approx(first, rel=F32)


def test_ingest_within_1_5x_of_dfreader_indexing(walk_path):
    """The whole FlightLog in at most 1.5x the time DFReader needs just to open and index the file."""
    content = walk_path.read_bytes()
    flightlog_from_dataflash(content, source=WALK)  # numba's cache warm

    runs = {"ours": lambda: flightlog_from_dataflash(content, source=WALK),
            "dfreader": lambda: DFReader.DFReader_binary(str(walk_path), zero_time_base=False)}
    best = dict.fromkeys(runs, np.inf)
    for _ in range(5):  # alternating rounds: a load change hits both
        for name, run in runs.items():
            start = time.perf_counter()
            run()
            best[name] = min(best[name], time.perf_counter() - start)
    ours_s, dfreader_s = best["ours"], best["dfreader"]
    assert ours_s <= 1.5 * dfreader_s + 0.05, (ours_s, dfreader_s)  # + 50 ms: load jitter of a shared CI box


def test_chosen_by_content_not_name(walk_path, walk):
    content = walk_path.read_bytes()
    for source in (content, io.BytesIO(content)):
        log = load_flight_log(source, name="renamed.ulg")
        assert log.meta.source == "renamed.ulg" and log.meta.sha256 == walk.meta.sha256
        assert log.meta.streams == walk.meta.streams


# --- small written logs -----------------------------------------------------------------------------------


def _imu(time_s, instance=None) -> Message:
    n = len(time_s)
    values = (np.zeros(n), np.zeros(n), np.full(n, 0.01), np.zeros(n), np.zeros(n), np.full(n, -9.81))
    columns = ("TimeUS", "GyrX", "GyrY", "GyrZ", "AccX", "AccY", "AccZ")
    if instance is None:
        return Message("IMU", "Qffffff", columns, time_s, values)
    return Message("IMU", "QBffffff", (columns[0], "I", *columns[1:]), time_s, (instance, *values))


def _log(messages, *, texts=("ArduPlane V4.5.0 (abcdef12)",), parameters=None) -> bytes:
    return dataflash_bytes(messages, parameters=parameters or {}, texts=texts, start_time_s=1.0)


TIME_S = 1.0 + np.arange(400) / 100.0


@pytest.mark.parametrize(("firmware", "parameters", "mav_type"), [
    ("ArduPlane V4.5.0", {}, 1), ("ArduPlane V4.5.0", {"Q_ENABLE": 1.0}, 20),
    ("ArduPlane V4.5.0", {"Q_ENABLE": 1.0, "Q_TILT_ENABLE": 1.0}, 21), ("ArduCopter V4.3.0", {}, 2),
    ("ArduCopter V4.3.0", {"FRAME_CLASS": 2.0}, 13), ("ArduCopter V4.3.0", {"FRAME_CLASS": 6.0}, 4),
    ("ArduRover V4.2.0", {}, 10), ("APM:Plane V3.4.0", {}, 1)])
def test_vehicle_type_from_firmware_and_frame(firmware, parameters, mav_type):
    log = flightlog_from_dataflash(_log([_imu(TIME_S)], texts=(firmware,), parameters=parameters), source="v.bin")
    assert log.meta.vehicle_type == mav_type and log.meta.px4_version == firmware


def test_no_firmware_string_leaves_vehicle_unknown():
    log = flightlog_from_dataflash(_log([_imu(TIME_S)], texts=()), source="v.bin")
    assert log.meta.vehicle_type is None
    assert any("vehicle type unknown" in w for w in log.meta.warnings)


def test_instance_field_picks_instance_0():
    """ArduPilot >= 4.2 logs every IMU in one message with the instance field I; rows of instance 1 interleave."""
    time_s = np.repeat(TIME_S, 2)
    instance = np.tile([1, 0], len(TIME_S))
    log = flightlog_from_dataflash(_log([_imu(time_s, instance)]), source="i.bin")
    assert log.meta.streams["imu"].topic == "IMU[0]"
    np.testing.assert_allclose(log["imu"].index.to_numpy(), TIME_S, rtol=0, atol=1e-9)


def test_ekf_core_field_and_older_ekf2():
    """XKF1 with the core field C (4.1 on): core 0; without EKF3, EKF2's NKF1/NKF2."""
    n = len(TIME_S)
    core = np.tile([0, 1], n // 2)
    xkf1 = Message("XKF1", "QBccCffffff", ("TimeUS", "C", "Roll", "Pitch", "Yaw", "VN", "VE", "VD", "PN", "PE", "PD"),
                   TIME_S, (core, 10.0 * core + 1.0, np.full(n, 2.0), np.full(n, 350.0), *(np.zeros(n),) * 6))
    log = flightlog_from_dataflash(_log([_imu(TIME_S), xkf1]), source="c.bin")
    assert log.meta.streams["onboard_attitude"].topic == "XKF1[0]"
    assert np.allclose(log["onboard_attitude"]["roll_deg"], 1.0) and np.allclose(log["onboard_attitude"]["yaw_deg"],
                                                                                -10.0)
    nkf2 = Message("NKF2", "Qcc", ("TimeUS", "VWN", "VWE"), TIME_S, (np.full(n, 3.0), np.full(n, -4.0)))
    nkf1 = Message("NKF1", "Qccc", ("TimeUS", "Roll", "Pitch", "Yaw"), TIME_S, (np.zeros(n),) * 3)
    log = flightlog_from_dataflash(_log([_imu(TIME_S), nkf1, nkf2]), source="n.bin")
    assert log.meta.streams["onboard_wind"].topic == "NKF2"
    assert np.allclose(log["onboard_wind"][["wind_n_m_s", "wind_e_m_s"]], [3.0, -4.0])
    assert log.meta.streams["onboard_attitude"].topic == "NKF1"


def test_imu_too_slow_for_strapdown_is_refused():
    log = flightlog_from_dataflash(_log([_imu(1.0 + np.arange(100) / 25.0)]), source="slow.bin")
    refused = [f for f in assess_input_quality(log) if f.severity == "refuse"]
    assert [f.kind for f in refused] == ["imu_rate"]
    assert "imu (IMU) logged at 25.0 Hz, below the 50 Hz" in refused[0].message


def test_time_cleaning_reported():
    time_s = TIME_S.copy()
    time_s[20] = time_s[19]
    time_s[30] = 0.0
    time_s[50] = 1e7  # a corrupt TimeUS, 116 days away
    content = bytearray(_log([_imu(time_s)]))
    index = df.walk_records(np.frombuffer(bytes(content), dtype=np.uint8))
    a, b = index.offsets[index.type_ids == index.type_ids[-1]][[40, 41]]  # swap two IMU records in the file
    content[a:b + (b - a)] = content[b:b + (b - a)] + content[a:b]
    log = flightlog_from_dataflash(bytes(content), source="t.bin")
    assert np.all(np.diff(log["imu"].index.to_numpy()) > 0) and len(log["imu"]) == len(TIME_S) - 3
    assert log.meta.duration_s < 5.0
    text = " | ".join(log.meta.warnings)
    assert "out of time order" in text and "repeating an earlier TimeUS" in text and "TimeUS 0" in text
    assert "dropped 1 rows timed more than 3600 s away from the rest (corrupt TimeUS)" in text


# --- bad input ------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def small_log():
    return _log([_imu(TIME_S)])


def test_truncated_file_gives_the_complete_records(small_log):
    cut = small_log[:len(small_log) - 10]
    log = flightlog_from_dataflash(cut, source="cut.bin")
    assert len(log["imu"]) == len(TIME_S) - 1
    assert any(w.startswith("the file is truncated: its last record is cut off") for w in log.meta.warnings)


def test_garbage_and_unknown_format_ids_are_skipped(small_log):
    record = df.record_dtype("Qffffff", ("TimeUS", "GyrX", "GyrY", "GyrZ", "AccX", "AccY", "AccZ")).itemsize
    first, second = len(small_log) - 200 * record, len(small_log) - 100 * record  # record boundaries
    unknown = bytes((df.HEAD_1, df.HEAD_2, 250)) + bytes(40)  # a type id no FMT defines
    damaged = small_log[:first] + b"\xff" * 100 + small_log[first:second] + unknown + small_log[second:]
    log = flightlog_from_dataflash(damaged, source="g.bin")
    assert len(log["imu"]) == len(TIME_S)
    assert any("skipped 143 bytes in 2 stretches" in w for w in log.meta.warnings)


def test_fmt_lies(small_log):
    """An FMT whose length disagrees with its format, or with an unknown format code, rejects its type."""
    fmt_at = small_log.index(b"IMU\0") - 5  # type, length, then the name
    for offset, value, reason in ((4, 30, "record length 30 bytes, but its format 'Qffffff' needs 35"),
                                  (9, ord("X"), "unknown format codes 'X'")):
        lying = bytearray(small_log)
        lying[fmt_at + offset] = value
        with pytest.raises(InputError, match="no IMU data") as caught:
            flightlog_from_dataflash(bytes(lying), source="lie.bin")
        assert reason in str(caught.value)


@pytest.mark.parametrize(("content", "message"), [
    (b"\xa3\x95" + bytes(range(256)) * 4, "no valid FMT records"),
    (b"\xa3\x95", "no valid FMT records"),
    (b"ULog\x01\x12\x35" + bytes(64), None),  # a broken ULog: the ULog reader's error
])
def test_unreadable_content_is_an_input_error(content, message):
    with pytest.raises(InputError, match=message):
        load_flight_log(content, name="bad.bin")


def test_not_dataflash_is_refused_by_the_reader():
    with pytest.raises(InputError, match="not an ArduPilot DataFlash log"):
        flightlog_from_dataflash(b"ULog\x01\x12\x35", source="x.bin")


def test_header_without_imu_is_an_input_error(small_log):
    only_formats = small_log[:small_log.index(b"IMU\0") + 200]
    with pytest.raises(InputError, match="no IMU data"):
        flightlog_from_dataflash(only_formats, source="f.bin")


def test_seeded_mutations_give_a_log_or_an_input_error(real_logs_dir):
    """Bit flips, overwrites with garbage, cuts, duplicated stretches and FMT format codes swapped for other
    codes of a real log's first 256 KiB: every case reads (with warnings) or raises InputError, each within two
    seconds (on a loaded machine)."""
    seed = (real_logs_dir / STATIC).read_bytes()[:256 * 1024]
    rng = np.random.default_rng(17)
    outcomes = {"log": 0, "error": 0}
    fmt_offsets = df.walk_records(np.frombuffer(seed, dtype=np.uint8))
    fmt_offsets = fmt_offsets.offsets[fmt_offsets.type_ids == df.FMT_TYPE]
    for case in range(50):
        data = bytearray(seed)
        kind = case % 5
        at = int(rng.integers(0, len(data) - 1024))
        if kind == 0:
            for position in rng.integers(0, len(data), 50):
                data[position] ^= 1 << int(rng.integers(0, 8))
        elif kind == 1:
            data[at:at + 512] = rng.integers(0, 256, 512, dtype=np.uint8).tobytes()
        elif kind == 2:
            data = data[:at]
        elif kind == 3:
            for offset in rng.choice(fmt_offsets, 10):
                data[offset + 9 + int(rng.integers(0, 16))] = ord(rng.choice(list(df.FORMAT_CODES)))
        else:
            data[at:at] = data[at:at + int(rng.integers(1, 1000))]
        start = time.perf_counter()
        try:
            result = load_flight_log(bytes(data), name=f"mutant{case}.bin")
        except InputError:
            outcomes["error"] += 1
        else:
            assert isinstance(result, FlightLog) and len(result["imu"]) >= 2
            outcomes["log"] += 1
        assert time.perf_counter() - start < 2.0, case  # a clean 256 KiB read takes ~20 ms
    assert outcomes["log"] > 0


def test_cli_bad_bin_writes_nothing(tmp_path, small_log):
    bad = tmp_path / "bad.bin"
    bad.write_bytes(small_log[:small_log.index(b"IMU\0") + 200])
    out, parm = tmp_path / "calib.json", tmp_path / "out.parm"
    assert main(["calibrate", str(bad), "-o", str(out), "--ardupilot-parm", str(parm)]) == EXIT_BAD_INPUT
    assert not out.exists() and not parm.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["bad.bin"]
