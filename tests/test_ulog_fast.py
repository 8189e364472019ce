"""ingest.ulog_fast: the numpy/numba data section equals pyulog's parse (the guarded pyulog path it falls back to)
on every real log, for the reader's topics and for every topic, and on hand-built files with the damage pyulog
only skips; where pyulog's recovery decides the outcome it falls back (docs/robustness.md, 'Fast data section').
"""

from __future__ import annotations

import struct
from collections import Counter

import fuzz_mutations as fm
import numpy as np
import pandas as pd
import pytest
from pyulog import ULog
from test_ingest_ulog_robust import IMU_FORMAT, data, fmt, header, imu_sample, keyed, message, subscribe, ulog_file

from ingest.errors import InputError
from ingest.log_formats import load_flight_log
from ingest.px4_topics import ALL_TOPICS
from ingest.ulog_fast import read_ulog
from ingest.ulog_guard import parse_ulog
from ingest.ulog_reader import flightlog_from_ulog

#: What a parse yields besides the topic data (pyulog's attributes).
PARSED = ("_dropouts", "_logged_messages", "_logged_messages_tagged", "_changed_parameters", "_msg_info_dict",
          "_msg_info_dict_types", "_msg_info_multiple_dict", "_initial_parameters", "_default_parameters",
          "_file_corrupt", "_start_timestamp", "_last_timestamp", "_sync_seq_cnt", "_filtered_message_ids",
          "_appended_offsets")
#: Mutated logs compared (the fuzz suite's operators and CI seeds; cases of their own seed range).
DIFFERENTIAL_CASES = 120
DIFFERENTIAL_FIRST_SEED = 500_000


def assert_same_parse(content: bytes, topics) -> ULog | InputError:
    """``read_ulog`` gives what the guarded pyulog parse gives (data of every topic, field for field, and the
    rest; or the same error); returns the fast result."""
    try:
        reference, warnings = parse_ulog(content, "x.ulg", topics)
    except InputError as error:
        with pytest.raises(InputError) as raised:
            read_ulog(content, "x.ulg", topics)
        assert str(raised.value) == str(error)
        return raised.value
    fast, fast_warnings = read_ulog(content, "x.ulg", topics)
    assert fast_warnings == warnings
    assert [(d.name, d.multi_id, d.msg_id) for d in fast.data_list] == [(d.name, d.multi_id, d.msg_id)
                                                                       for d in reference.data_list]
    for mine, theirs in zip(fast.data_list, reference.data_list, strict=True):
        assert [f.field_name for f in mine.field_data] == [f.field_name for f in theirs.field_data]
        assert mine == theirs, mine.name  # pyulog's equality: fields, dtypes and values (NaN equal to NaN)
        assert all(mine.data[k].dtype == theirs.data[k].dtype for k in theirs.data)
    for attribute in PARSED:  # (a NaN parameter value is equal by its repr)
        mine, theirs = getattr(fast, attribute), getattr(reference, attribute)
        assert mine == theirs or repr(mine) == repr(theirs), attribute
    return fast


def _every_topic(content: bytes) -> list[str]:
    definitions, _ = parse_ulog(content, "x.ulg", ())
    return sorted(definitions.message_formats)


@pytest.mark.parametrize("name", ["sample.ulg", "sample_appended_multiple.ulg", "sample_log_small.ulg",
                                  "sample_logging_tagged_and_default_params.ulg", "sample_px4_events.ulg",
                                  "px4_1.14_octo_flight_61.ulg", "px4_1.14_octo_flight_123.ulg",
                                  "px4_1.9_quad_mission.ulg", "px4_1.17_quad_flight_corrupt.ulg"])
def test_real_logs_parse_as_pyulog_parses_them_for_the_readers_topics_and_for_every_topic(real_logs_dir, name):
    content = (real_logs_dir / name).read_bytes()
    fast = assert_same_parse(content, ALL_TOPICS)
    assert_same_parse(content, _every_topic(content))  # nested types, padding, arrays of every PX4 message
    if name == "px4_1.17_quad_flight_corrupt.ulg":  # garbage pyulog steps through byte by byte
        assert fast.data_reader.startswith("pyulog (message of unknown type")
    else:
        assert fast.data_reader == "numpy" and fast.data_list
    if name == "sample_appended_multiple.ulg":
        assert fast.has_data_appended and len(fast._appended_offsets) == 3
    if name == "sample.ulg":
        assert len(fast.dropouts) == 4 and all(d.timestamp > fast.start_timestamp for d in fast.dropouts)
    if name == "sample_logging_tagged_and_default_params.ulg":
        assert fast.logged_messages_tagged and fast._default_parameters


@pytest.mark.parametrize("name", ["sample.ulg", "sample_appended_multiple.ulg", "px4_1.14_octo_flight_61.ulg",
                                  "px4_1.17_quad_flight_corrupt.ulg"])
def test_the_flight_log_equals_the_one_from_pyulogs_parse(real_logs_dir, name):
    content = (real_logs_dir / name).read_bytes()
    log = load_flight_log(content, name=name)
    reference, notes = parse_ulog(content, name, ALL_TOPICS)
    expected = flightlog_from_ulog(reference, source=name, sha256=log.meta.sha256, notes=notes)
    assert log.meta == expected.meta
    assert log.streams.keys() == expected.streams.keys()
    for stream, frame in expected.streams.items():
        pd.testing.assert_frame_equal(log.streams[stream], frame, check_exact=True)


# ---------------------------------------------------------------------------------------------------------------
# Hand-built files: damage pyulog only skips is skipped alike (numpy path); pyulog's recovery is left to pyulog

BARO = "vehicle_air_data"
NESTED = (fmt("inner", "float x;uint8_t flag;uint8_t[3] _padding0")
          + fmt("nested_topic", "uint64_t timestamp;inner[2] parts;uint8_t count;uint8_t[7] _padding0"))
NESTED_SAMPLE_BYTES = 8 + 2 * 8 + 1  # trailing padding stripped, as PX4 logs it


def nested_sample(time_us: int, count: int) -> bytes:
    return struct.pack("<QfB3xfB3xB", time_us, 1.5, 1, -2.5, 0, count)


def with_body(body: bytes, definitions: bytes = b"") -> bytes:
    """A log with the IMU format (plus ``definitions``) whose data section is ``body``."""
    return header(1_000_000) + fmt("sensor_combined", IMU_FORMAT) + NESTED + definitions + body


def imu(time_us: int) -> bytes:
    return data(0, imu_sample(time_us))


@pytest.mark.parametrize("body", [
    pytest.param(subscribe(0, "sensor_combined") + b"".join(imu(2_000_000 + 4000 * i) for i in range(50)), id="clean"),
    pytest.param(subscribe(0, "sensor_combined") + imu(2_000_000) + data(9, b"\x00" * 12) + imu(2_004_000),
                 id="unknown-msg-id"),
    pytest.param(subscribe(0, "sensor_combined") + imu(2_000_000) + data(0, imu_sample(2_004_000)[:-3])
                 + data(0, imu_sample(2_008_000) + b"\x00") + message("D", b"\x00") + imu(2_012_000),
                 id="wrong-sizes-and-a-short-message"),
    pytest.param(imu(1_500_000) + subscribe(0, "sensor_combined") + imu(2_000_000), id="data-before-its-subscription"),
    pytest.param(subscribe(0, "sensor_combined") + imu(2_000_000) + subscribe(0, "sensor_combined", multi_id=1)
                 + imu(2_004_000), id="msg-id-subscribed-again"),
    pytest.param(subscribe(3, "not_read") + data(3, b"\x01" * 9) + subscribe(3, "sensor_combined") + imu(2_000_000),
                 id="filtered-then-subscribed"),
    pytest.param(subscribe(0, "sensor_combined") + imu(2_000_000) + message("O", struct.pack("<H", 40))
                 + keyed("P", "float SOME_PARAM", struct.pack("<f", 2.0)) + imu(3_000_000) + imu(2_500_000)
                 + message("O", struct.pack("<H", 7)) + message("L", b"\x06" + struct.pack("<Q", 9) + b"hello")
                 + message("C", b"\x06\x02\x00" + struct.pack("<Q", 9) + b"tagged") + message("O", b"\x01"),
                 id="dropouts-parameters-strings"),
    pytest.param(subscribe(0, "sensor_combined") + imu(2_000_000) + message("R", b"\x00\x00")
                 + message("S", ULog.SYNC_BYTES) + message("F", b"late:uint64_t timestamp;") + imu(2_004_000),
                 id="unknown-and-sync-messages"),
    pytest.param(subscribe(0, "sensor_combined") + subscribe(1, "nested_topic")
                 + b"".join(imu(2_000_000 + 4000 * i) + data(1, nested_sample(2_000_000 + 4000 * i, i))
                            for i in range(5)), id="nested-types-and-padding"),
    pytest.param(subscribe(0, "sensor_combined") + imu(2_000_000) + imu(2_004_000)[:-5], id="truncated"),
    pytest.param(subscribe(0, "sensor_combined") + imu(2_000_000) + b"\x02", id="header-cut"),
    pytest.param(subscribe(0, "sensor_combined") + message("A", b"\x00"), id="short-subscription"),
])
def test_damage_pyulog_skips_is_skipped_alike_on_the_numpy_path(body):
    fast = assert_same_parse(with_body(body), ["sensor_combined", "nested_topic", BARO])
    assert fast.data_reader == "numpy"


def test_the_nested_topic_has_pyulogs_flattened_fields_and_values():
    body = subscribe(1, "nested_topic") + data(1, nested_sample(2_000_000, 7))
    (nested,) = assert_same_parse(with_body(body), ["nested_topic"]).data_list
    assert [f.field_name for f in nested.field_data] == ["timestamp", "parts[0].x", "parts[0].flag",
                                                         "parts[0]._padding0[0]", "parts[0]._padding0[1]",
                                                         "parts[0]._padding0[2]", "parts[1].x", "parts[1].flag",
                                                         "parts[1]._padding0[0]", "parts[1]._padding0[1]",
                                                         "parts[1]._padding0[2]", "count"]
    assert nested.data["parts[1].x"][0] == np.float32(-2.5) and nested.data["count"][0] == 7


@pytest.mark.parametrize("garbage", [
    pytest.param(b"\x05\x00\x00abcde", id="type-0"),
    pytest.param(b"\x00\x00z", id="size-0"),
    pytest.param(struct.pack("<HB", 20_000, ord("z")) + b"\x00" * 20_000, id="huge-size"),
    pytest.param(message("z", b"ab" + ULog.SYNC_BYTES + b"cd"), id="sync-bytes-in-unknown-message"),
])
def test_damage_pyulog_recovers_from_is_parsed_by_pyulog(garbage):
    body = (subscribe(0, "sensor_combined") + imu(2_000_000) + garbage + message("S", ULog.SYNC_BYTES)
            + imu(2_004_000))
    fast = assert_same_parse(with_body(body), ["sensor_combined"])
    assert fast.data_reader.startswith("pyulog (message of unknown type")


def _appended(first: bytes, appended: bytes, offset_shift: int = 0) -> bytes:
    """A log whose flag bits announce ``appended`` as appended data after ``first``."""
    def definitions(offset: int) -> bytes:  # flag bits (incompat bit 0: data appended at offset) and the format
        return message("B", bytes(8) + b"\x01" + bytes(7) + struct.pack("<3Q", offset, 0, 0)) + fmt(
            "sensor_combined", IMU_FORMAT)

    offset = len(header()) + len(definitions(0)) + len(first) + offset_shift
    return header(1_000_000) + definitions(offset) + first + appended


@pytest.mark.parametrize("shift", [0, -7, 10_000_000])
def test_appended_data_is_read_in_pyulogs_passes(shift):
    first = subscribe(0, "sensor_combined") + b"".join(imu(2_000_000 + 4000 * i) for i in range(5))
    appended = subscribe(0, "sensor_combined", multi_id=1) + imu(9_000_000)
    fast = assert_same_parse(_appended(first, appended, shift), ["sensor_combined"])
    assert fast.data_reader == "numpy" and fast.has_data_appended


def test_the_builder_logs_of_the_robustness_tests_parse_alike():
    content = ulog_file(baro_us=np.arange(1_000_100, 2_000_000, 40_000))
    assert_same_parse(content, ALL_TOPICS)


def test_mutated_logs_parse_as_pyulog_parses_them_on_both_paths():
    seeds = fm.ci_seeds("ulog")
    paths = Counter()
    for case_seed in range(DIFFERENTIAL_FIRST_SEED, DIFFERENTIAL_FIRST_SEED + DIFFERENTIAL_CASES):
        case = fm.make_case("ulog", seeds, case_seed)
        fast = assert_same_parse(case.data, ALL_TOPICS)
        paths["error" if isinstance(fast, InputError) else fast.data_reader.split(" ")[0]] += 1
    assert paths["numpy"] > DIFFERENTIAL_CASES / 2 and paths["pyulog"] > 0, paths
