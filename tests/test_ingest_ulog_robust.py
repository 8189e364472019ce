"""ingest.ulog_reader / ingest.ulog_guard on hostile ULog files built here byte by byte (docs/robustness.md,
'ULog reader guard' and 'Time base checks'): each gives a FlightLog with a warning naming the damaged part, or
an InputError, and finishes (every test runs under a generous alarm, not a speed test)."""

from __future__ import annotations

import contextlib
import io
import signal
import struct

import numpy as np
import pytest
from pyulog import ULog

from ingest.errors import InputError
from ingest.log_formats import load_flight_log
from ingest.ulog_guard import PYULOG_HOOKS
from ingest.ulog_reader import flightlog_from_ulog

#: Any test here taking longer than this [s] hangs (a clean parse of these files takes milliseconds).
DEADLINE_S = 20
IMU_RATE_HZ = 250.0
N_IMU = 400
START_US = 1_000_000
IMU_FORMAT = "uint64_t timestamp;float[3] gyro_rad;float[3] accelerometer_m_s2"
BARO_FORMAT = "uint64_t timestamp;uint64_t timestamp_sample;float baro_alt_meter;float baro_pressure_pa"
IMU_ID, BARO_ID = 0, 1


class _Hang(Exception):
    pass


@pytest.fixture(autouse=True)
def deadline():
    """Fail a test that runs longer than DEADLINE_S (SIGALRM; pyulog is pure Python, so it interrupts)."""
    def expire(signum, frame):
        raise _Hang(f"no result within {DEADLINE_S} s")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.alarm(DEADLINE_S)
    yield
    signal.alarm(0)
    signal.signal(signal.SIGALRM, previous)


# ---------------------------------------------------------------------------------------------------------------
# ULog bytes: 16-byte header, then messages of a 3-byte header (uint16 payload size, uint8 type) and the payload


def header(start_us: int = 0) -> bytes:
    return ULog.HEADER_BYTES + b"\x01" + struct.pack("<Q", start_us)


def message(kind: str, payload: bytes) -> bytes:
    return struct.pack("<HB", len(payload), ord(kind)) + payload


def fmt(name: str, fields: str) -> bytes:
    return message("F", f"{name}:{fields};".encode())


def keyed(kind: str, type_and_key: str, value: bytes) -> bytes:
    """An 'I' (info) or 'P' (parameter) message."""
    key = type_and_key.encode()
    return message(kind, bytes([len(key)]) + key + value)


def subscribe(msg_id: int, topic: str, multi_id: int = 0) -> bytes:
    return message("A", bytes([multi_id]) + struct.pack("<H", msg_id) + topic.encode())


def data(msg_id: int, payload: bytes) -> bytes:
    return message("D", struct.pack("<H", msg_id) + payload)


def imu_times_us(n: int = N_IMU) -> np.ndarray:
    return START_US + np.round(np.arange(n) * 1e6 / IMU_RATE_HZ).astype(np.int64)


def imu_sample(time_us: int) -> bytes:
    return struct.pack("<Q6f", int(time_us) % 2**64, 0.01, -0.02, 0.03, 0.1, -0.2, -9.8)


def baro_sample(time_us: int, sample_us: int | None = None) -> bytes:
    return struct.pack("<QQff", time_us, time_us - 500 if sample_us is None else sample_us, 250.0, 98_000.0)


def ulog_file(*, formats: bytes = b"", params: bytes = b"", imu_format: str = IMU_FORMAT,
              imu_us: np.ndarray | None = None, extra_subscriptions: bytes = b"", extra_data: bytes = b"",
              baro_us: np.ndarray | None = None, baro_sample_us: dict[int, int] | None = None) -> bytes:
    """A small log: sensor_combined at 250 Hz (and vehicle_air_data at 25 Hz when ``baro_us`` is given)."""
    imu_us = imu_times_us() if imu_us is None else imu_us
    definitions = (fmt("sensor_combined", imu_format) + fmt("vehicle_air_data", BARO_FORMAT) + formats
                   + keyed("I", "char[10] sys_name", b"PX4 autopi") + keyed("P", "float SENS_BARO_QNH",
                                                                              struct.pack("<f", 1013.25))
                   + keyed("P", "int32_t MAV_TYPE", struct.pack("<i", 2)) + params)
    body = subscribe(IMU_ID, "sensor_combined") + extra_subscriptions
    if baro_us is not None:
        body += subscribe(BARO_ID, "vehicle_air_data")
    baro = iter(() if baro_us is None else baro_us)
    next_baro = next(baro, None)
    for i, t in enumerate(imu_us):
        body += data(IMU_ID, imu_sample(t))
        if next_baro is not None and i % 10 == 0:
            body += data(BARO_ID, baro_sample(next_baro, (baro_sample_us or {}).get(int(next_baro))))
            next_baro = next(baro, None)
    return header(START_US) + definitions + body + extra_data


def load(content: bytes):
    return load_flight_log(content, name="hostile.ulg")


def warnings_of(content: bytes) -> str:
    return "\n".join(load(content).meta.warnings)


def baro_times_us(n: int = N_IMU // 10) -> np.ndarray:
    return imu_times_us()[::10][:n] + 100


# ---------------------------------------------------------------------------------------------------------------


def test_the_clean_builder_log_loads_without_damage_warnings():
    log = load(ulog_file(baro_us=baro_times_us()))
    assert len(log.streams["imu"]) == N_IMU and len(log.streams["baro"]) == N_IMU // 10
    assert log.meta.vehicle_type == 2 and log.meta.parameters["SENS_BARO_QNH"] == pytest.approx(1013.25)
    assert not [w for w in log.meta.warnings if "dropped" in w or "corrupt" in w or "unusable" in w]


def test_pyulog_private_hooks_the_guard_overrides_still_exist():
    empty = ULog(None)  # instance attributes are set before any parsing
    assert [hook for hook in PYULOG_HOOKS if not hasattr(empty, hook)] == []


@pytest.mark.parametrize("param", [
    keyed("P", "char[3] SYS_BAD", b"abc"),      # text value
    keyed("P", "uint7_t SYS_BAD", b"\x01\x02"),  # unknown type: pyulog hands over the raw bytes
    keyed("P", "float SYS_BAD", struct.pack("<f", float("nan"))),
])
def test_a_parameter_that_is_not_a_finite_number_is_dropped_with_a_warning(param):
    log = load(ulog_file(params=param + keyed("P", "int32_t SYS_GOOD", struct.pack("<i", 7))))
    assert "SYS_BAD" not in log.meta.parameters and log.meta.parameters["SYS_GOOD"] == 7.0
    assert any("SYS_BAD" in w and "not a finite number" in w for w in log.meta.warnings)


def test_a_non_numeric_mav_type_leaves_the_vehicle_type_unknown_with_a_warning():
    content = ulog_file(params=keyed("P", "char[4] MAV_TYPE", b"quad"))  # the later value wins in pyulog
    log = load(content)
    assert log.meta.vehicle_type is None
    assert any("MAV_TYPE is not a number" in w for w in log.meta.warnings)


def test_info_fields_of_the_wrong_type_are_ignored_with_a_warning():
    params = (keyed("I", "float ver_sw_release", struct.pack("<f", 1.5))
              + keyed("I", "int32_t ver_hw", struct.pack("<i", 3)))
    log = load(ulog_file(params=params))
    assert log.meta.hardware is None and log.meta.px4_version is None
    assert any("ver_sw_release" in w for w in log.meta.warnings) and any("ver_hw" in w for w in log.meta.warnings)


def test_an_implausible_qnh_falls_back_to_the_standard_atmosphere():
    log = load(ulog_file(params=keyed("P", "float SENS_BARO_QNH", struct.pack("<f", 1e30)),
                         baro_us=baro_times_us()))
    assert any("SENS_BARO_QNH" in w and "implausible" in w for w in log.meta.warnings)
    assert np.isfinite(log.streams["baro"]["alt_m"]).all()


# --- formats ----------------------------------------------------------------------------------------------------


def test_a_topic_whose_format_lost_its_timestamp_is_dropped_and_the_rest_of_the_file_read():
    no_timestamp = "uint64_t time;uint64_t timestamp_sample;float baro_alt_meter;float baro_pressure_pa"
    content = ulog_file(baro_us=baro_times_us()).replace(
        fmt("vehicle_air_data", BARO_FORMAT), fmt("vehicle_air_data", no_timestamp))
    log = load(content)
    assert len(log.streams["imu"]) == N_IMU  # pyulog alone stops at the first baro sample
    assert "baro" not in log.streams
    assert any("vehicle_air_data: topic dropped" in w and "no uint64_t timestamp" in w for w in log.meta.warnings)


def test_flightlog_from_ulog_skips_a_parsed_topic_without_timestamp():
    ulog = ULog(io.BytesIO(ulog_file(baro_us=baro_times_us())), message_name_filter_list=None)
    baro = next(d for d in ulog.data_list if d.name == "vehicle_air_data")
    del baro.data["timestamp"]
    log = flightlog_from_ulog(ulog, source="x.ulg")
    assert "baro" not in log.streams and len(log.streams["imu"]) == N_IMU
    assert any("vehicle_air_data: no timestamp field" in w for w in log.meta.warnings)


@pytest.mark.parametrize("formats, baro_fields, reason", [
    (b"", BARO_FORMAT + ";vehicle_air_data loop", "contains itself"),
    (fmt("ping", "pong p") + fmt("pong", "ping q"), BARO_FORMAT + ";ping a", "contains itself"),
    (b"".join(fmt(f"n{i}", f"n{i + 1} x") for i in range(3000)) + fmt("n3000", "uint8_t y"),
     BARO_FORMAT + ";n0 deep", "nested deeper"),
    (fmt("a", "uint8_t[65535] x") + fmt("b", "a[65535] y"), BARO_FORMAT + ";b[65535] z", "bytes per sample"),
    (fmt("e", "") + fmt("f", "e[65535] x") + fmt("g", "f[65535] y"), BARO_FORMAT + ";g[65535] z",
     "fields and nested elements"),
    (b"", BARO_FORMAT + ";undefined_t u", "is not defined"),
    (b"", BARO_FORMAT + ";float baro_alt_meter", "defined twice"),
])
def test_an_unusable_format_costs_only_its_topic(formats, baro_fields, reason):
    """Self-reference, mutual recursion, 3000-level chains, arrays multiplying out to 2.8e14 fields or
    elements: pyulog recurses, hangs or crashes on each; the guard drops the topic."""
    content = ulog_file(formats=formats, baro_us=baro_times_us()).replace(
        fmt("vehicle_air_data", BARO_FORMAT), fmt("vehicle_air_data", baro_fields))
    log = load(content)
    assert len(log.streams["imu"]) == N_IMU and "baro" not in log.streams
    assert any(w.startswith("vehicle_air_data: topic dropped") and reason in w for w in log.meta.warnings)


def test_a_self_referential_imu_format_is_an_input_error_naming_it():
    content = ulog_file(imu_format=IMU_FORMAT + ";sensor_combined again")
    with pytest.raises(InputError, match=r"^hostile\.ulg: sensor_combined: no IMU data.*contains itself"):
        load(content)


def test_a_damaged_format_of_a_topic_the_reader_does_not_use_costs_nothing():
    content = ulog_file(formats=fmt("unused_topic", "uint64_t timestamp;unused_topic x"),
                        extra_subscriptions=subscribe(7, "unused_topic"))
    log = load(content)
    assert len(log.streams["imu"]) == N_IMU and not any("unused_topic" in w for w in log.meta.warnings)


def test_subscriptions_beyond_the_total_field_budget_are_dropped():
    big = "uint64_t timestamp;float baro_alt_meter;uint8_t[60000] pad"
    content = ulog_file(formats=fmt("vehicle_magnetometer", big) + fmt("sensor_baro", big)
                        + fmt("airspeed", big),
                        extra_subscriptions=subscribe(5, "vehicle_magnetometer") + subscribe(6, "sensor_baro")
                        + subscribe(8, "airspeed"))
    warnings = warnings_of(content)
    assert "airspeed: topic dropped, its format definition is unusable (more than 131072" in warnings


# --- message walk -----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("content", [
    header() + b"\xff\xff\x00",  # pyulog's recovery seeks back to 0 and repeats forever
    header() + bytes.fromhex("d3e8fa"),
    header() + fmt("sensor_combined", IMU_FORMAT) * 50 + b"\xff\xff\x00",
    header() + fmt("sensor_combined", IMU_FORMAT) + b"\x10\x27\x00" + b"\xab" * 9000,
], ids=["19_bytes", "19_bytes_unknown_type", "after_formats", "short_payload"])
def test_a_corrupt_header_at_the_end_of_the_definitions_is_an_input_error_not_a_hang(content):
    with pytest.raises(InputError, match=r"^hostile\.ulg: not a readable PX4 ULog file: the ULog parser cannot get "
                                         r"past damaged messages \(it goes in circles"):
        load(content)


def test_flag_bits_that_are_not_the_first_message_are_corruption_not_an_incompatible_file():
    flag_bits = message("B", bytes(8) + b"\x02" + bytes(7) + bytes(24))  # unknown incompatible bit set
    content = ulog_file(params=flag_bits)
    log = load(content)
    assert len(log.streams["imu"]) == N_IMU
    assert any("corrupt in places" in w for w in log.meta.warnings)
    with pytest.raises(InputError, match="incompatible flag"):  # as the first message it means what it says
        load(header(START_US) + flag_bits + content[16:])


def test_a_long_run_of_ff_bytes_is_refused_quickly_not_stepped_through_for_minutes():
    """Each 0xff byte reads as a corrupt 64 KiB message: pyulog steps one byte and re-reads 64 KiB each time."""
    clean = ulog_file()
    at = clean.index(subscribe(IMU_ID, "sensor_combined"))
    with pytest.raises(InputError, match=r"cannot get past damaged messages \(its recovery re-reads too much"):
        load(clean[:at] + b"\xff" * 300_000 + clean[at:])


@pytest.mark.parametrize("short", [
    keyed("I", "int32_t x", b"\x01\x02"),  # value 2 bytes short
    message("D", b"\x00"),                  # no room for the msg_id
    message("L", b"6\x00"),                 # logging message without its timestamp
    message("O", b"\x01"),                  # dropout with 1 of 2 bytes
], ids=["info", "data", "logging", "dropout"])
def test_a_short_message_is_skipped_as_corruption_not_taken_for_the_end_of_the_file(short):
    times = imu_times_us()
    body = b"".join(data(IMU_ID, imu_sample(t)) for t in times[N_IMU // 2:])
    content = ulog_file(imu_us=times[:N_IMU // 2], extra_data=short + body)
    log = load(content)
    assert len(log.streams["imu"]) == N_IMU  # plain pyulog keeps only the first half
    assert any("corrupt in places" in w for w in log.meta.warnings)


def test_seeded_byte_mutations_give_a_flightlog_or_an_input_error():
    clean = ulog_file(baro_us=baro_times_us())
    rng = np.random.default_rng(13)
    for _ in range(60):
        content = bytearray(clean)
        kind = rng.integers(3)
        if kind == 0:  # a few random bytes
            for at in rng.integers(16, len(content), rng.integers(1, 9)):
                content[at] = rng.integers(256)
        elif kind == 1:  # 0xff run
            at = int(rng.integers(16, len(content) - 3))
            content[at:at + 3] = b"\xff\xff\x00"
        else:  # cut
            content = content[:int(rng.integers(16, len(content)))]
        with contextlib.suppress(InputError):
            load(bytes(content))


# --- time base --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("row, value", [(N_IMU // 2, 10**16), (N_IMU - 1, 10**13), (3, 2**63 - 1)])
def test_an_isolated_corrupt_imu_timestamp_is_dropped_with_a_warning(row, value):
    times = imu_times_us()
    times[row] = value
    log = load(ulog_file(imu_us=times))
    assert len(log.streams["imu"]) == N_IMU - 1
    assert log.meta.duration_s < 2.0  # not 1e10 s
    assert any(w.startswith("sensor_combined: dropped 1 rows whose timestamps jump") for w in log.meta.warnings)


def test_a_time_base_that_jumps_for_a_minority_of_rows_keeps_the_majority():
    times = imu_times_us()
    times[300:] += 10**13
    log = load(ulog_file(imu_us=times))
    assert len(log.streams["imu"]) == 300 and log.meta.duration_s < 2.0
    assert any("sensor_combined: dropped 100 rows" in w for w in log.meta.warnings)


def test_a_hopeless_imu_time_base_is_an_input_error():
    times = np.random.default_rng(4).integers(START_US, 10**16, N_IMU)
    with pytest.raises(InputError, match=r"^hostile\.ulg: sensor_combined: no IMU data.*no consistent time base"):
        load(ulog_file(imu_us=times))


def test_a_logger_pause_is_not_taken_for_corruption():
    times = imu_times_us()
    times[200:] += 100_000_000  # 100 s pause
    log = load(ulog_file(imu_us=times))
    assert len(log.streams["imu"]) == N_IMU and log.meta.duration_s > 100
    assert not any("jump" in w for w in log.meta.warnings)


@pytest.mark.parametrize("shifted", [slice(20, None), slice(None)])
def test_rows_of_another_stream_far_outside_the_imu_span_are_dropped(shifted):
    """Not isolated (half or all of the topic), but the IMU says when the log was."""
    baro = baro_times_us()
    baro[shifted] += 10**13
    log = load(ulog_file(baro_us=baro))
    n_shifted = len(baro[shifted])
    assert len(log.streams.get("baro", ())) == len(baro) - n_shifted
    assert any(f"vehicle_air_data: dropped {n_shifted} rows timed more than 3600 s outside the IMU" in w
               for w in log.meta.warnings)


def test_a_corrupt_sample_time_becomes_nan_with_a_warning():
    baro = baro_times_us()
    log = load(ulog_file(baro_us=baro, baro_sample_us={int(baro[5]): 10**15}))
    sample_time_s = log.streams["baro"]["sample_time_s"].to_numpy()
    assert np.isnan(sample_time_s[5]) and np.isfinite(np.delete(sample_time_s, 5)).all()
    assert any("vehicle_air_data: 1 timestamp_sample values" in w for w in log.meta.warnings)


def test_replay_refuses_an_absurd_number_of_output_epochs():
    """Defence behind ingest: a log whose few IMU samples (too few to judge) span 1e9 s."""
    from estimators.inputs.build import build_replay_inputs

    times = imu_times_us(12)
    times[-1] = START_US + 10**15
    log = load(ulog_file(imu_us=times))
    assert log.meta.duration_s > 1e8
    with pytest.raises(InputError, match=r"^hostile\.ulg: imu: the IMU time axis spans .* implausible"):
        build_replay_inputs(log)
