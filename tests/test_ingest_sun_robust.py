"""Robustness of the sun-device readers: every bad CSV or device JSON is an InputError (or a documented warning),
never another exception and never silent NaN output. Regression cases for each failure class found by mutation
fuzzing, plus a small seeded mutation loop of our own."""

from __future__ import annotations

import json
import random

import numpy as np
import pytest

from app.cli import EXIT_BAD_INPUT, main
from ingest.errors import FileTooLargeError, InputError
from ingest.flightlog import STREAM_COLUMNS, FlightLog, LogMetadata
from ingest.sun_device import SunDevice
from ingest.sun_log import (
    MAX_CURRENT_A,
    MAX_DEVICE_JSON_BYTES,
    MAX_UNIX_TIME_S,
    MIN_CURRENT_A,
    attach_sun,
    load_sun_device,
    load_sun_log,
    with_sun,
)
from tests.conftest import SAMPLE_LOGS_DIR

MA_COLUMNS = [f"i{cell}_mA" for cell in range(1, 8)]
HEADER = "unix_time_s," + ",".join(MA_COLUMNS)
START_UNIX_S = 1_700_000_000.0


def row(time_s: float, currents_ma=(62.8878, 8.7744, 11.1396, 69.4177, 105.3826, 82.4814, 9.4803)) -> str:
    return f"{time_s:.3f}," + ",".join(f"{c:.4f}" for c in currents_ma)


def csv(*rows: str, header: str = HEADER, end: str = "\n") -> bytes:
    return ("\n".join([header, *rows]) + end).encode()


GOOD = csv(*(row(START_UNIX_S + 0.1 * k) for k in range(5)))


def load(content: bytes, **kwargs):
    return load_sun_log(content, time_offset_s=START_UNIX_S, name="sun.csv", **kwargs)


def refused(content: bytes, **kwargs) -> InputError:
    with pytest.raises(InputError) as caught:
        load(content, **kwargs)
    assert caught.value.source == "sun.csv"
    return caught.value


def device_refused(content: bytes | str) -> InputError:
    with pytest.raises(InputError) as caught:
        load_sun_device(content.encode() if isinstance(content, str) else content, name="dev.json")
    assert caught.value.source == "dev.json"
    return caught.value


def synthetic_flight() -> FlightLog:
    """A log with nothing but its time span (0 .. 10 s) and GPS UTC offset: enough for :func:`attach_sun`."""
    return FlightLog(streams={}, meta=LogMetadata(source="flight.ulg", start_time_s=0.0, end_time_s=10.0,
                                                  utc_offset_s=START_UNIX_S))


# --- sun CSV: truncation ------------------------------------------------------------------------------------------

def test_csv_cut_inside_its_last_number_drops_the_last_line_with_a_warning():
    """``9.4803`` cut to ``9``: the last line has no line break, so it is dropped and the drop reported."""
    content = GOOD[:-len("803\n")]
    assert content.endswith(b",9.4")
    sun = load(content)
    assert len(sun) == 4 and sun["i7_a"].iloc[-1] == pytest.approx(9.4803e-3)
    assert sun.attrs["warnings"] == ["sun.csv: line 6, the last, does not end with a line break and may be cut "
                                     "off (the file looks truncated); it was dropped"]
    assert load(GOOD).attrs["warnings"] == []


def test_truncation_warning_reaches_the_flight_log_warnings():
    log = with_sun(synthetic_flight(), GOOD[:-2], name="sun.csv")
    assert len(log["sun"]) == 4
    assert any("line 6, the last, does not end with a line break" in w for w in log.meta.warnings)
    assert attach_sun(synthetic_flight(), load(GOOD)).meta.warnings == []


def test_csv_whose_only_sample_is_cut_off():
    error = refused(csv(row(START_UNIX_S), end="")[:-3])
    assert str(error).startswith("sun.csv: no complete sample: line 2, the last, does not end with a line break")


def test_crlf_and_cr_line_ends_are_complete_files():
    for end in ("\r\n", "\r"):
        content = (end.join([HEADER, row(START_UNIX_S), row(START_UNIX_S + 0.1)]) + end).encode()
        sun = load(content)
        assert len(sun) == 2 and sun.attrs["warnings"] == []


# --- sun CSV: header and columns ----------------------------------------------------------------------------------

@pytest.mark.parametrize("duplicated", ["i3_mA", "unix_time_s"])
def test_duplicated_column_name_is_refused(duplicated):
    header = HEADER + "," + duplicated
    error = refused(csv(row(START_UNIX_S) + ",5", header=header))
    assert error.field == duplicated
    assert "the column is named 2 times" in str(error)


def test_duplicated_column_with_surrounding_space():
    error = refused(csv(row(START_UNIX_S) + ",5", header=HEADER + ", i1_mA "))
    assert error.field == "i1_mA"


def test_duplicated_ignored_columns_are_harmless():
    """Spreadsheet exports end rows with a comma: two unnamed columns are not ours to refuse."""
    sun = load(csv(row(START_UNIX_S) + ",,", header=HEADER + ",,"))
    assert len(sun) == 1


@pytest.mark.parametrize(("content", "message"), [
    (b"\xff\xfeu\x00n\x00", "sun.csv: not UTF-8 text"),
    (HEADER.encode() + b"\n1700000000.0,1,2,3,4,5,6,\xe97\n",
     "sun.csv: not UTF-8 text (byte b'\\xe9' on line 2, at byte offset 79)"),
    (b"", "sun.csv: the file is empty"),
    (b"\n\n\n", "sun.csv: the file has no header line"),
    (b"   \n", "sun.csv: the file has no header line"),
    (HEADER.encode() + b"\n\n", "sun.csv: the CSV has a header but no samples"),
    (csv(row(START_UNIX_S) + ",1"), "sun.csv: cannot read the CSV (Error tokenizing data. C error: Expected 8 "
                                    "fields in line 2, saw 9)"),
    (csv('"' + row(START_UNIX_S)), "sun.csv: cannot read the CSV"),
    (csv("1700000000.0,1,2,3"), "sun.csv: i4_mA: line 2: expected a finite number, got an empty cell"),
    (csv("1700000000.0,1,2,3,4,5\x00,6,7"), "sun.csv: i5_mA: line 2: expected a finite number"),
])
def test_unreadable_csv(content, message):
    assert str(refused(content)).startswith(message)


def test_byte_order_mark_and_blank_lines_keep_line_numbers():
    content = b"\xef\xbb\xbf\n" + csv(row(START_UNIX_S), "", row(START_UNIX_S + 0.1), "1700000000.2,1,x,3,4,5,6,7")
    assert str(refused(content)).startswith("sun.csv: i2_mA: line 6: expected a finite number, got 'x'")
    assert len(load(content[:-len("1700000000.2,1,x,3,4,5,6,7\n")])) == 2


# --- sun CSV: values ----------------------------------------------------------------------------------------------

@pytest.mark.parametrize("cell", ["inf", "-inf", "Infinity", "1e400", "nan", "NaN", "0x10", "5 mA", "1,5"])
def test_non_finite_or_non_numeric_current(cell):
    content = csv(row(START_UNIX_S), f"{START_UNIX_S + 0.1},1,2,3,4,{cell},6,7")
    assert refused(content).field in {"i5_mA", "i6_mA", None}  # "1,5" adds a field: a parse error


@pytest.mark.parametrize(("time_cell", "expected"), [
    ("-1.0", "expected a UTC time between 1970 and 2100"),
    ("nan", "expected a finite number"),
    ("inf", "expected a finite number"),
    ("1e400", "expected a finite number"),
    (f"{START_UNIX_S + 1e12:.1f}", "expected a UTC time between 1970 and 2100"),
    (f"{MAX_UNIX_TIME_S:.1f}", "expected a UTC time between 1970 and 2100"),
    ("", "expected a finite number, got an empty cell"),
])
def test_implausible_unix_time(time_cell, expected):
    error = refused(csv(row(START_UNIX_S), time_cell + ",1,2,3,4,5,6,7"))
    assert error.field == "unix_time_s" and f"line 3: {expected}" in str(error)


def test_time_jump_backwards_and_repeat():
    assert "line 4: time goes backwards" in str(refused(csv(row(START_UNIX_S), row(START_UNIX_S + 1e6),
                                                            row(START_UNIX_S + 0.2))))
    assert "line 3: time goes backwards or repeats" in str(refused(csv(row(START_UNIX_S), row(START_UNIX_S))))


@pytest.mark.parametrize(("time_cell", "expected"), [
    ("0000-01-01", "expected a UTC time between 1970 and 2100"),  # once an OutOfBoundsDatetime traceback
    ("1960-01-01T00:00:00Z", "expected a UTC time between 1970 and 2100"),
    ("-2024-01-01", "expected an ISO-8601 time"),
    ("now", "expected an ISO-8601 time"),  # pandas would read the time of reading
    ("today", "expected an ISO-8601 time"),
    ("9999-12-31T23:59:59Z", "expected a UTC time between 1970 and 2100"),
])
def test_implausible_iso_time(time_cell, expected):
    header = "time_utc," + ",".join(MA_COLUMNS)
    error = refused(csv("2024-03-18T12:00:00Z,1,2,3,4,5,6,7", f"{time_cell},1,2,3,4,5,6,7", header=header))
    assert error.field == "time_utc" and f"line 3: {expected}" in str(error)


@pytest.mark.parametrize("offset_s", [float("nan"), float("inf"), -float("inf")])
def test_non_finite_time_offset(offset_s):
    with pytest.raises(InputError, match=r"^sun\.csv: time offset: .* must be a finite number"):
        load_sun_log(GOOD, time_offset_s=offset_s, name="sun.csv")


def test_size_limit(tmp_path):
    path = tmp_path / "sun.csv"
    path.write_bytes(GOOD)
    for source in (GOOD, path):
        with pytest.raises(FileTooLargeError, match="over the limit of 100 bytes"):
            load_sun_log(source, time_offset_s=START_UNIX_S, max_bytes=100)
    assert len(load_sun_log(path, time_offset_s=START_UNIX_S, max_bytes=None)) == 5
    with pytest.raises(FileTooLargeError):
        with_sun(synthetic_flight(), GOOD, max_bytes=100)


# --- device JSON --------------------------------------------------------------------------------------------------

@pytest.mark.parametrize(("text", "field", "message"), [
    ('{"tilt_deg": NaN}', "tilt_deg", "expected finite numbers, got nan"),
    ('{"tilt_deg": Infinity}', "tilt_deg", "expected finite numbers"),
    ('{"tilt_deg": 1e400}', "tilt_deg", "expected finite numbers"),
    ('{"azimuths_deg": [0, 60, NaN, 180, 240, 300]}', "azimuths_deg", "expected finite numbers, got nan"),
    ('{"azimuths_deg": [0, 60, 120, 180, 240, -Infinity]}', "azimuths_deg", "expected finite numbers, got -inf"),
    ('{"mount_rpy_deg": [0, NaN, 0]}', "mount_rpy_deg", "expected finite numbers"),
    ('{"mount_rpy_deg": [0, 0, ' + "9" * 400 + "]}", "mount_rpy_deg", "expected finite numbers"),  # OverflowError
    ('{"tilt_deg": ' + "1" * 400 + "}", "tilt_deg", "expected finite numbers"),
    ('{"tilt_deg": 30, "tilt_deg": 40}', "tilt_deg", "the key appears more than once"),
    ('{"tilt_deg": [30]}', "tilt_deg", "expected a number, got [30]"),
    ('{"azimuths_deg": [0, 60, [120], 180, 240, 300]}', "azimuths_deg", "expected a list of numbers"),
    ('{"azimuths_deg": [0, 60, true, 180, 240, 300]}', "azimuths_deg", "expected a list of numbers"),
    ('{"azimuths_deg": "0,60,120,180,240,300"}', "azimuths_deg", "expected a list of numbers"),
])
def test_bad_device_value_names_the_key(text, field, message):
    error = device_refused(text)
    assert error.field == field and message in str(error)


@pytest.mark.parametrize(("text", "message"), [
    ("[" * 100_000 + "]" * 100_000, "not valid JSON (nested too deeply"),  # once a RecursionError
    ('{"tilt_deg": ' + "[" * 100_000 + "]" * 100_000 + "}", "not valid JSON (nested too deeply"),
    ('{"tilt_deg": ' + "1" * 5000 + "}", "not valid JSON (Exceeds the limit"),  # once a bare ValueError
    ("[1, 2]", "expected a JSON object with the keys tilt_deg, azimuths_deg, mount_rpy_deg, got a JSON array"),
    ('"tilt_deg"', "expected a JSON object with the keys tilt_deg, azimuths_deg, mount_rpy_deg, got a JSON string"),
    ("45", "expected a JSON object with the keys tilt_deg, azimuths_deg, mount_rpy_deg, got a JSON number"),
    ("null", "expected a JSON object with the keys tilt_deg, azimuths_deg, mount_rpy_deg, got a JSON null"),
    ("true", "expected a JSON object with the keys tilt_deg, azimuths_deg, mount_rpy_deg, got a JSON boolean"),
    ("", "the file is empty"),
    ("   ", "not valid JSON"),
    ('{"tilt_deg": 45', "not valid JSON"),
    ('{"azimuths_deg": [0, 60, 120, 180, 240]}', "azimuths_deg must list 6 side-cell azimuths, got 5"),
    ('{"azimuths_deg": [0, 60, 120, 180, 240, 300, 360]}', "azimuths_deg must list 6 side-cell azimuths, got 7"),
    ('{"mount_rpy_deg": [0, 0]}', "mount_rpy_deg must have 3 angles, got 2"),
    ('{"tilt_deg": 0}', "tilt_deg must be in (0, 90) deg"),
    ('{"tilt_deg": 90}', "tilt_deg must be in (0, 90) deg"),
    ('{"azimuths_deg": [0, 60, 1e300, 180, 240, 300]}', "azimuths_deg must be finite angles within +-360 deg"),
    ('{"mount_rpy_deg": [0, -400, 0]}', "mount_rpy_deg must be finite angles within +-360 deg"),
    ('{"azimuths_deg": [10, 10, 10, 10, 10, 10]}', "the cell normals do not span 3-D space"),
    ('{"azimuths_deg": [0, 180, 0, 180, 360, -180]}', "the cell normals do not span 3-D space"),
])
def test_bad_device_json(text, message):
    assert str(device_refused(text)).startswith(f"dev.json: {message}")


def test_device_json_encodings_and_size():
    text = json.dumps({"tilt_deg": 30})
    assert load_sun_device(b"\xef\xbb\xbf" + text.encode()).tilt_deg == 30.0  # byte order mark
    assert load_sun_device(text.encode("utf-16")).tilt_deg == 30.0  # json detects UTF-16/32 itself
    assert "not UTF-8 text" in str(device_refused(b'{"tilt_deg": 30, "\xff": 1}'))
    with pytest.raises(FileTooLargeError):
        load_sun_device(b" " * (MAX_DEVICE_JSON_BYTES + 1) + b"{}")


def test_sun_device_refuses_non_finite_geometry_in_code():
    with pytest.raises(ValueError, match="azimuths_deg must be finite angles"):
        SunDevice(azimuths_deg=(0.0, 60.0, float("nan"), 180.0, 240.0, 300.0))
    with pytest.raises(ValueError, match="tilt_deg must be in"):
        SunDevice(tilt_deg=float("nan"))
    with pytest.raises(ValueError, match="mount_rpy_deg must be finite angles"):
        SunDevice(mount_rpy_deg=(0.0, float("inf"), 0.0))


def test_cli_sun_refuses_a_nan_device_in_one_line(tmp_path, capsys):
    """Once exit 0 with every sun vector NaN."""
    device = tmp_path / "dev.json"
    device.write_text('{"tilt_deg": 45, "azimuths_deg": [0, 60, 120, 180, 240, NaN]}')
    out = tmp_path / "out.csv"
    code = main(["sun", str(SAMPLE_LOGS_DIR / "failed_cell.ulg"), "--sun", str(SAMPLE_LOGS_DIR / "failed_cell_sun.csv"),
                 "--device", str(device), "-o", str(out)])
    assert code == EXIT_BAD_INPUT and not out.exists()
    err = capsys.readouterr().err.strip()
    assert err.startswith("solarnav: error: dev.json: azimuths_deg: expected finite numbers") and "\n" not in err


# --- seeded mutation loop -----------------------------------------------------------------------------------------

TOKENS = [b"nan", b"inf", b"-inf", b"1e400", b"-1", b",", b"\n", b"\r", b'"', b"\xff", b"\x00", b"\xef\xbb\xbf", b"",
          b"9" * 30, b"[", b"]", b"{", b"}", b"NaN", b"Infinity", b"-", b" ", b"i1_mA", b"unix_time_s", b"1e12"]


def mutate(content: bytes, rng: random.Random) -> bytes:
    """One to three random edits: truncate, replace/insert a token, duplicate or drop a line, flip a byte."""
    data = bytearray(content)
    for _ in range(rng.randint(1, 3)):
        kind = rng.randrange(6)
        at = rng.randrange(len(data) + 1)
        if kind == 0:
            data = data[:at]
        elif kind == 1:
            data[at:at + rng.randint(0, 6)] = rng.choice(TOKENS)
        elif kind == 2:
            data[at:at] = rng.choice(TOKENS)
        elif kind in (3, 4):
            lines = bytes(data).split(b"\n")
            k = rng.randrange(len(lines))
            lines[k:k + 1] = [lines[k], lines[k]] if kind == 3 else []
            data = bytearray(b"\n".join(lines))
        elif data:
            data[min(at, len(data) - 1)] ^= 1 << rng.randrange(8)
    return bytes(data)


def check_sun_frame(sun) -> None:
    assert list(sun.columns) == list(STREAM_COLUMNS["sun"]) and len(sun) > 0
    values = sun.to_numpy()
    assert np.isfinite(values).all() and np.isfinite(sun.index.to_numpy()).all()
    assert ((values >= MIN_CURRENT_A) & (values <= MAX_CURRENT_A)).all()
    assert (np.diff(sun.index.to_numpy()) > 0).all()


@pytest.mark.parametrize("seed", range(3))
def test_mutated_sun_csv_is_read_or_refused(seed):
    rng = random.Random(seed)
    iso = ("time_utc," + ",".join(MA_COLUMNS) + "\n" + "".join(
        f"2024-03-18T12:00:{k:02d}.250Z,{row(0.0).split(',', 1)[1]}\n" for k in range(4))).encode()
    for _ in range(40):
        content = mutate(rng.choice([GOOD, iso]), rng)
        try:
            sun = load_sun_log(content, time_offset_s=START_UNIX_S, name="m.csv")
        except InputError as error:
            assert str(error).startswith("m.csv: ") and "\n" not in error.detail.strip()
            continue
        check_sun_frame(sun)
        if not content.endswith((b"\n", b"\r")):
            assert sun.attrs["warnings"], content


DEVICE = json.dumps({"tilt_deg": 45.0, "azimuths_deg": [0.0, 60.0, 120.0, 180.0, 240.0, 300.0],
                     "mount_rpy_deg": [0.0, 0.0, 90.0]}).encode()


@pytest.mark.parametrize("seed", range(3))
def test_mutated_device_json_is_read_or_refused(seed):
    rng = random.Random(100 + seed)
    for _ in range(40):
        content = mutate(DEVICE, rng)
        try:
            device = load_sun_device(content, name="m.json")
        except InputError as error:
            assert str(error).startswith("m.json: ")
            continue
        normals = device.normals_body
        assert normals.shape == (7, 3) and np.isfinite(normals).all()
        np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-12)
