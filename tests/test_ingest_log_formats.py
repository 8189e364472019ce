"""ingest.log_formats: the reader is chosen by the file's content, a file of no format is one InputError naming
each format, and another format is one more entry of FORMATS."""

from __future__ import annotations

import pytest

from ingest import log_formats
from ingest.dataflash_reader import is_dataflash
from ingest.errors import InputError
from ingest.log_formats import FORMATS, LogFormat, load_flight_log
from ingest.ulog_reader import flightlog_from_ulog_content, is_ulog

ULOG, DATAFLASH = "sample_log_small.ulg", "arduplane_4.0.8_ground_static.bin"


def test_each_real_log_is_recognised_by_exactly_one_format(real_logs_dir):
    expected = {".ulg": "PX4 ULog", ".bin": "ArduPilot DataFlash"}
    for path in sorted(real_logs_dir.glob("*.*[gn]")):
        content = path.read_bytes()
        assert [f.name for f in FORMATS if f.recognises(content)] == [expected[path.suffix]], path.name


def test_a_ulog_named_like_a_dataflash_log_is_read_as_a_ulog(real_logs_dir):
    by_path = load_flight_log(real_logs_dir / ULOG)
    renamed = load_flight_log((real_logs_dir / ULOG).read_bytes(), name="flight.bin")
    assert renamed.meta.source == "flight.bin" and renamed.meta.sha256 == by_path.meta.sha256
    assert renamed.meta.streams == by_path.meta.streams


@pytest.mark.parametrize("content", [b"unix_time_s,i1_mA\n0.0,1.0\n", b"ULog\x01\x12", b"\xa3", b"\x95\xa3" * 40])
def test_content_of_no_format_is_one_input_error_naming_each_format(content):
    assert not is_ulog(content) and not is_dataflash(content)
    with pytest.raises(InputError) as caught:
        load_flight_log(content, name="notes.ulg")
    assert str(caught.value) == ("notes.ulg: not a flight log solarnav reads: expected one of the formats: PX4 "
                                 "ULog (starts with the bytes 55 4c 6f 67 01 12 35); ArduPilot DataFlash (starts "
                                 "with the bytes a3 95)")
    assert caught.value.source == "notes.ulg"


def test_the_ulog_reader_refuses_a_dataflash_log_by_itself(real_logs_dir):
    with pytest.raises(InputError, match=r"^static\.bin: not a PX4 ULog file"):
        flightlog_from_ulog_content((real_logs_dir / DATAFLASH).read_bytes()[:4096], source="static.bin")


def test_another_format_is_one_more_entry(monkeypatch):
    read = []
    csv_format = LogFormat("CSV log", "starts with the text 'time_s,'", lambda content: content.startswith(b"time_s,"),
                           lambda content, source: read.append((content, source)) or "the CSV reader's log")
    monkeypatch.setattr(log_formats, "FORMATS", (*FORMATS, csv_format))
    assert load_flight_log(b"time_s,ax\n0.0,1.0\n", name="log.csv") == "the CSV reader's log"
    assert read == [(b"time_s,ax\n0.0,1.0\n", "log.csv")]
    with pytest.raises(InputError, match=r"; CSV log \(starts with the text 'time_s,'\)$"):
        load_flight_log(b"hello", name="notes.txt")
