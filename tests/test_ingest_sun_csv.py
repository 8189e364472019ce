"""ingest.sun_csv: sun-device CSV -> the ``sun`` stream on the log clock."""

from __future__ import annotations

import io

import numpy as np
import pytest

from ingest.errors import InputError
from ingest.flightlog import STREAM_COLUMNS
from ingest.sun_csv import CURRENT_COLUMNS_MA, read_sun_csv, with_sun
from ingest.ulog import read_ulog

HEADER_CURRENTS = ",".join(CURRENT_COLUMNS_MA)


def csv_text(time_column: str, times, currents_ma) -> str:
    rows = [f"{time_column},{HEADER_CURRENTS}"]
    for t, row in zip(times, currents_ma, strict=True):
        rows.append(f"{float(t)!r}," + ",".join(repr(float(c)) for c in row))
    return "\n".join(rows) + "\n"


@pytest.fixture(scope="module")
def flight(real_logs_dir):
    """A log with GPS UTC time (SITL, PX4 1.15)."""
    return read_ulog(real_logs_dir / "sample_px4_events.ulg")


@pytest.fixture(scope="module")
def bench(real_logs_dir):
    """A log without GPS (no UTC)."""
    return read_ulog(real_logs_dir / "sample.ulg")


def test_currents_are_amperes_in_cell_order(tmp_path):
    rng = np.random.default_rng(3)
    currents_ma = rng.uniform(0.0, 250.0, size=(5, 7))
    path = tmp_path / "sun.csv"
    path.write_text(csv_text("time_s", [1.0, 1.1, 1.2, 1.3, 1.4], currents_ma))
    sun = read_sun_csv(path)
    assert list(sun.columns) == list(STREAM_COLUMNS["sun"])
    assert sun.index.name == "time_s"
    np.testing.assert_allclose(sun.index.to_numpy(), [1.0, 1.1, 1.2, 1.3, 1.4])
    np.testing.assert_allclose(sun.to_numpy(), currents_ma / 1000.0, rtol=1e-15)


def test_extra_columns_and_column_order_do_not_matter():
    text = "note,i7_mA,i6_mA,i5_mA,i4_mA,i3_mA,i2_mA,i1_mA,time_s\nx,7,6,5,4,3,2,1,10.0\ny,7,6,5,4,3,2,1,10.5\n"
    sun = read_sun_csv(text.encode())
    np.testing.assert_allclose(sun.iloc[0].to_numpy(), np.arange(1, 8) * 1e-3)


def test_utc_times_map_onto_the_log_clock(flight):
    offset_s = flight.meta.utc_offset_s
    log_times_s = flight.meta.start_time_s + np.array([2.0, 2.2, 2.4])
    text = csv_text("time_utc_s", list(log_times_s + offset_s), np.full((3, 7), 100.0))
    sun = read_sun_csv(io.StringIO(text), utc_offset_s=offset_s)
    np.testing.assert_allclose(sun.index.to_numpy(), log_times_s, atol=1e-6)


def test_utc_times_need_a_log_with_utc(bench):
    text = csv_text("time_utc_s", [1.6e9, 1.6e9 + 0.1], np.ones((2, 7)))
    with pytest.raises(InputError, match="no GPS UTC time") as caught:
        with_sun(bench, text.encode(), name="sun.csv")
    assert str(caught.value).startswith("sun.csv: time_utc_s: ")


def test_with_sun_adds_the_stream_without_touching_the_log(flight):
    times = flight.meta.start_time_s + np.arange(0.0, 5.0, 0.1)
    sun_log = with_sun(flight, csv_text("time_s", list(times), np.full((len(times), 7), 50.0)).encode(),
                       name="sun.csv")
    assert "sun" not in flight.streams and "sun" not in flight.meta.streams
    assert sun_log.has("sun") and len(sun_log["sun"]) == len(times)
    assert sun_log.meta.streams["sun"].topic == "sun.csv"
    assert sun_log.meta.streams["sun"].rate_hz == pytest.approx(10.0, rel=1e-6)
    assert sun_log["imu"] is flight["imu"]
    assert sun_log.meta.warnings == flight.meta.warnings  # fully inside the IMU span


def test_partly_outside_the_flight_is_a_warning(flight):
    times = flight.meta.end_time_s + np.array([-0.2, -0.1, 0.5, 1.0])
    sun_log = with_sun(flight, csv_text("time_s", list(times), np.ones((4, 7))).encode(), name="sun.csv")
    assert "sun.csv: 2 of 4 sun-device samples lie outside the IMU time span" in sun_log.meta.warnings


def test_wholly_outside_the_flight_is_an_error(flight):
    text = csv_text("time_s", [1.0, 2.0], np.ones((2, 7)))  # boot-relative seconds; this log's clock is ~1.7e9 s
    with pytest.raises(InputError, match="no sample inside the flight log's time span"):
        with_sun(flight, text.encode(), name="sun.csv")


@pytest.mark.parametrize(("text", "field", "message"), [
    (f"t,{HEADER_CURRENTS}\n0,1,2,3,4,5,6,7\n", None, "no time column: expected time_s or time_utc_s"),
    ("time_s,i1_mA,i2_mA,i3_mA,i4_mA,i5_mA,i6_mA\n0,1,2,3,4,5,6\n", None, r"missing current column\(s\) i7_mA"),
    (f"time_s,{HEADER_CURRENTS}\n", None, "header but no samples"),
    (f"time_s,{HEADER_CURRENTS}\n0,1,2,3,4,5,6,7\n0.1,1,2,abc,4,5,6,7\n", "i3_mA", "line 3: .*got 'abc'"),
    (f"time_s,{HEADER_CURRENTS}\n0,1,2,3,4,5,6,7\n0.1,1,2,3,4,,6,7\n", "i5_mA", "line 3: .*an empty cell"),
    (f"time_s,{HEADER_CURRENTS}\n0,1,2,3,4,5,6,7\n0.2,1,2,3,4,5,6,7\n0.1,1,2,3,4,5,6,7\n", "time_s",
     "line 4 is not after"),
    (f"time_s,{HEADER_CURRENTS}\n0,1,2,3,4,5,6,7\n0,1,2,3,4,5,6,7\n", "time_s", "line 3 is not after"),
    ("", None, "cannot read the CSV"),
])
def test_bad_files_name_the_problem(text, field, message):
    with pytest.raises(InputError, match=message) as caught:
        read_sun_csv(text.encode(), name="sun.csv")
    assert caught.value.source == "sun.csv"
    assert caught.value.field == field


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match="cannot read the CSV"):
        read_sun_csv(tmp_path / "nope.csv")
