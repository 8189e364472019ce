"""ingest.sun_log: sun-device CSV -> the ``sun`` stream on the log clock; device JSON; attaching to a log."""

from __future__ import annotations

import io
import json

import numpy as np
import pandas as pd
import pytest

from ingest.errors import InputError
from ingest.flightlog import STREAM_COLUMNS
from ingest.log_formats import load_flight_log
from ingest.sun_device import SunDevice
from ingest.sun_log import attach_sun, load_sun_device, load_sun_log, with_sun

MA_COLUMNS = [f"i{cell}_mA" for cell in range(1, 8)]
A_COLUMNS = [f"i{cell}_A" for cell in range(1, 8)]
GPS_LOG = "sample_log_small.ulg"  # has GPS UTC time (2021-04-21)
BENCH_LOG = "sample.ulg"  # no GPS


def csv_text(time_column: str, times, currents, columns=MA_COLUMNS) -> str:
    rows = [",".join([time_column, *columns])]
    for t, row in zip(times, currents, strict=True):
        rows.append(",".join([str(t), *(repr(float(c)) for c in row)]))
    return "\n".join(rows) + "\n"


@pytest.fixture(scope="module")
def flight(real_logs_dir):
    return load_flight_log(real_logs_dir / GPS_LOG)


@pytest.fixture(scope="module")
def bench(real_logs_dir):
    return load_flight_log(real_logs_dir / BENCH_LOG)


def test_milliampere_currents_in_cell_order_on_the_log_clock(tmp_path):
    rng = np.random.default_rng(3)
    currents_ma = rng.uniform(0.0, 250.0, size=(5, 7))
    unix_s = 1_700_000_000.0 + np.array([0.0, 0.1, 0.2, 0.3, 0.4])
    path = tmp_path / "sun.csv"
    path.write_text(csv_text("unix_time_s", [f"{t:.3f}" for t in unix_s], currents_ma))
    sun = load_sun_log(path, time_offset_s=1_699_999_000.0)
    assert list(sun.columns) == list(STREAM_COLUMNS["sun"])
    assert sun.index.name == "time_s"
    np.testing.assert_allclose(sun.index.to_numpy(), unix_s - 1_699_999_000.0, atol=1e-6)
    np.testing.assert_allclose(sun.to_numpy(), currents_ma / 1000.0, rtol=1e-15)


def test_ampere_columns_extra_columns_and_column_order():
    text = ("note,i7_A,i6_A,i5_A,i4_A,i3_A,i2_A,i1_A,unix_time_s\n"
            "x,0.7,0.6,0.5,0.4,0.3,0.2,0.1,100.0\ny,0.7,0.6,0.5,0.4,0.3,0.2,0.1,100.5\n")
    sun = load_sun_log(text.encode(), time_offset_s=0.0)
    np.testing.assert_allclose(sun.iloc[0].to_numpy(), np.arange(1, 8) * 0.1)
    np.testing.assert_allclose(sun.index.to_numpy(), [100.0, 100.5])


def test_spreadsheet_byte_order_mark_and_spaces():
    text = "\ufeffunix_time_s, " + ", ".join(MA_COLUMNS) + "\n5.0, " + ", ".join(["2"] * 7) + "\n"
    sun = load_sun_log(text.encode(), time_offset_s=0.0)
    assert sun.index.tolist() == [5.0] and sun["i1_a"].iloc[0] == pytest.approx(2e-3)


def test_iso_times_with_and_without_zone():
    text = csv_text("time_utc", ["2024-03-18T12:00:00Z", "2024-03-18T14:00:00.250+02:00", "2024-03-18T12:00:00.5"],
                    np.full((3, 7), 10.0))
    sun = load_sun_log(io.StringIO(text), time_offset_s=0.0)
    noon_s = pd.Timestamp("2024-03-18T12:00:00Z").timestamp()
    np.testing.assert_allclose(sun.index.to_numpy() - noon_s, [0.0, 0.25, 0.5], atol=1e-6)


def test_gps_utc_offset_of_the_flight_log(flight):
    """UTC unix time -> log time through the log's GPS-derived offset; an explicit offset wins."""
    log_times_s = flight.meta.start_time_s + np.array([1.0, 1.5, 2.0])
    unix_s = log_times_s + flight.meta.utc_offset_s
    text = csv_text("unix_time_s", [f"{t:.6f}" for t in unix_s], np.full((3, 7), 100.0))
    np.testing.assert_allclose(load_sun_log(text.encode(), flight_log=flight).index.to_numpy(), log_times_s,
                               atol=2e-6)
    shifted = load_sun_log(text.encode(), flight_log=flight, time_offset_s=flight.meta.utc_offset_s + 3.0)
    np.testing.assert_allclose(shifted.index.to_numpy(), log_times_s - 3.0, atol=2e-6)


def test_no_way_to_the_log_clock(bench):
    text = csv_text("unix_time_s", [1.0, 2.0], np.ones((2, 7))).encode()
    with pytest.raises(InputError, match=r"^sun\.csv: cannot put the sun-device times on the log clock: the "
                                         r"flight log sample\.ulg has no GPS UTC time; give the time offset"):
        load_sun_log(text, flight_log=bench, name="sun.csv")
    with pytest.raises(InputError, match=r"^sun\.csv: cannot put .*: no flight log was given"):
        load_sun_log(text, name="sun.csv")


HEADER = "unix_time_s," + ",".join(MA_COLUMNS)
GOOD_ROW = "1.0," + ",".join(["5"] * 7)


@pytest.mark.parametrize(("text", "message"), [
    ("", "sun.csv: the file is empty"),
    (HEADER + "\n", "sun.csv: the CSV has a header but no samples"),
    ("t," + ",".join(MA_COLUMNS) + "\n" + GOOD_ROW + "\n",
     "sun.csv: no time column: expected unix_time_s or time_utc (found t, i1_mA"),
    ("unix_time_s," + ",".join(MA_COLUMNS[:5]) + "\n1.0,1,2,3,4,5\n",
     "sun.csv: missing current column(s) i6_mA, i7_mA [mA]"),
    ("unix_time_s," + ",".join(MA_COLUMNS[:6]) + ",i7_A\n" + GOOD_ROW + "\n",
     "sun.csv: current columns mix mA and A"),
    (HEADER + "\n" + GOOD_ROW + "\n2.0,1,2,x,4,5,6,7\n",
     "sun.csv: i3_mA: line 3: expected a finite number, got 'x'"),
    (HEADER + "\n" + GOOD_ROW + "\n2.0,1,2,3,4,5,,7\n", "sun.csv: i6_mA: line 3: expected a finite number, "
                                                       "got an empty cell"),
    (HEADER + "\n" + GOOD_ROW + "\n2.0,1,2,3,4,5,nan,7\n", "sun.csv: i6_mA: line 3: expected a finite number"),
    (HEADER + "\n" + GOOD_ROW + "\n2.0,1,2,3,-1.5,5,6,7\n",
     "sun.csv: i4_mA: line 3: expected a current between -1 mA (noise around zero) and 10 A, got '-1.5'"),
    (HEADER + "\n" + GOOD_ROW + "\n2.0,1,2,3,4,5,6,12000\n",
     "sun.csv: i7_mA: line 3: expected a current between -1 mA (noise around zero) and 10 A, got '12000'"),
    (HEADER + "\n" + GOOD_ROW + "\n2.0," + ",".join(["5"] * 7) + "\n1.5," + ",".join(["5"] * 7) + "\n",
     "sun.csv: unix_time_s: line 4: time goes backwards or repeats"),
    (HEADER + "\n" + GOOD_ROW + "\n" + GOOD_ROW + "\n", "sun.csv: unix_time_s: line 3: time goes backwards"),
    ("time_utc," + ",".join(MA_COLUMNS) + "\n2024-03-18T12:00:00Z," + ",".join(["5"] * 7)
     + "\nyesterday," + ",".join(["5"] * 7) + "\n",
     "sun.csv: time_utc: line 3: expected an ISO-8601 time such as 2024-03-18T14:49:11.250Z, got 'yesterday'"),
])
def test_bad_csv(text, message):
    with pytest.raises(InputError) as caught:
        load_sun_log(text.encode(), time_offset_s=0.0, name="sun.csv")
    assert str(caught.value).startswith(message)


def test_noise_below_zero_is_accepted():
    text = HEADER + "\n" + GOOD_ROW + "\n2.0,1,2,3,-0.9,5,6,7\n"
    assert load_sun_log(text.encode(), time_offset_s=0.0)["i4_a"].iloc[1] == pytest.approx(-0.9e-3)


def test_unreadable_path(tmp_path):
    with pytest.raises(InputError, match=r"nope\.csv: cannot read the file"):
        load_sun_log(tmp_path / "nope.csv", time_offset_s=0.0)


def sun_frame(time_s, current_a=0.05) -> pd.DataFrame:
    return pd.DataFrame({column: np.full(len(time_s), current_a) for column in STREAM_COLUMNS["sun"]},
                        index=pd.Index(np.asarray(time_s, dtype=float), name="time_s"))


def test_attach_sun_returns_a_new_log(flight):
    times = flight.meta.start_time_s + np.arange(0.0, 2.0, 0.05)
    device = SunDevice(tilt_deg=30.0)
    with_sun_log = attach_sun(flight, sun_frame(times), device=device, source="sun.csv")
    assert with_sun_log["sun"].equals(sun_frame(times))
    info = with_sun_log.meta.streams["sun"]
    assert (info.topic, info.n_samples) == ("sun.csv", 40)
    assert info.rate_hz == pytest.approx(20.0, rel=1e-6)
    assert with_sun_log.meta.sun_device == device
    assert "sun" not in flight.streams and "sun" not in flight.meta.streams  # the original is untouched
    assert flight.meta.sun_device is None
    assert with_sun_log["imu"] is flight["imu"]


def test_attach_sun_reports_samples_outside_the_flight(flight):
    times = flight.meta.end_time_s + np.array([-0.2, -0.1, 0.5, 1.0])
    log = attach_sun(flight, sun_frame(times), source="sun.csv")
    assert "sun.csv: 2 of 4 sun-device samples lie outside the IMU time span" in log.meta.warnings
    assert log.meta.sun_device == SunDevice()
    with pytest.raises(InputError, match=r"^sun\.csv: no sample inside the flight log's time span"):
        attach_sun(flight, sun_frame(flight.meta.end_time_s + np.array([5.0, 6.0])), source="sun.csv")


def test_with_sun_reads_and_attaches(flight, tmp_path):
    log_times_s = flight.meta.start_time_s + np.arange(0.5, 3.0, 0.1)
    path = tmp_path / "cells.csv"
    path.write_text(csv_text("unix_time_s", [f"{t:.6f}" for t in log_times_s + flight.meta.utc_offset_s],
                             np.full((len(log_times_s), 7), 80.0)))
    log = with_sun(flight, path, device=SunDevice(tilt_deg=40.0))
    assert log.meta.streams["sun"].topic == "cells.csv"
    np.testing.assert_allclose(log["sun"].index.to_numpy(), log_times_s, atol=2e-6)
    np.testing.assert_allclose(log["sun"].to_numpy(), 0.08)
    assert log.meta.sun_device.tilt_deg == 40.0


def test_device_json(tmp_path):
    path = tmp_path / "device.json"
    path.write_text(json.dumps({"tilt_deg": 30, "azimuths_deg": [10, 70, 130, 190, 250, 310],
                                "mount_rpy_deg": [0, 0, 90]}))
    assert load_sun_device(path) == SunDevice(30.0, (10.0, 70.0, 130.0, 190.0, 250.0, 310.0), (0.0, 0.0, 90.0))
    assert load_sun_device(b"{}") == SunDevice()


@pytest.mark.parametrize(("text", "message"), [
    ('{"tilt_deg": 30, "mount": [0, 0, 0]}',
     "dev.json: unknown key(s) mount; expected tilt_deg, azimuths_deg, mount_rpy_deg"),
    ('{"azimuths_deg": [0, 60, 120]}', "dev.json: azimuths_deg must list 6 side-cell azimuths, got 3"),
    ('{"tilt_deg": 95}', "dev.json: tilt_deg must be in (0, 90) deg, got 95.0"),
    ('{"tilt_deg": "steep"}', "dev.json: tilt_deg: expected a number, got 'steep'"),
    ('{"mount_rpy_deg": 5}', "dev.json: mount_rpy_deg: expected a list of numbers, got 5"),
    ("[1, 2]", "dev.json: expected a JSON object with the keys tilt_deg, azimuths_deg, mount_rpy_deg"),
    ("{tilt: 3", "dev.json: not valid JSON"),
])
def test_bad_device_json(text, message):
    with pytest.raises(InputError) as caught:
        load_sun_device(text.encode(), name="dev.json")
    assert str(caught.value).startswith(message)
