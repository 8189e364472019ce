"""``solarnav info`` through ``app.cli.main`` (argv in, exit code and output out)."""

from __future__ import annotations

import json

import pytest

from app.cli import EXIT_BAD_INPUT, main

MA_COLUMNS = [f"i{cell}_mA" for cell in range(1, 8)]


def write_sun_csv(path, unix_times_s) -> None:
    lines = ["unix_time_s," + ",".join(MA_COLUMNS)]
    lines += [f"{t:.3f}," + ",".join(["120.0"] * 7) for t in unix_times_s]
    path.write_text("\n".join(lines) + "\n")


def test_text_summary(real_logs_dir, capsys):
    assert main(["info", str(real_logs_dir / "sample_log_small.ulg")]) == 0
    out = capsys.readouterr().out
    assert out.startswith("sample_log_small.ulg  sha256 68d1020f688109f0")
    assert "firmware  v1.11.2 dev (8583f1da) on CUBEPILOT_CUBEORANGE, ULog data format 1" in out
    assert "MAV_TYPE 22 (fixed-wing)" in out
    assert "(6.50 s)" in out  # sensor data, not the 1174 s header
    assert "2021-04-21" in out  # UTC date from the log's GPS time
    rows = {line.split()[0]: line.split() for line in out.splitlines() if line.startswith(("imu ", "gps "))}
    assert rows["imu"][1:4] == ["sensor_combined", "1298", "204.6"]
    assert rows["gps"][1:4] == ["vehicle_gps_position", "32", "5.0"]
    assert "  - 1 logger dropouts, 30 ms of data lost in total (longest 30 ms at 20.328 s)" in out


def test_json_summary(real_logs_dir, capsys):
    assert main(["info", str(real_logs_dir / "sample.ulg"), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)  # strict JSON: NaN would not parse back as a number
    assert info["duration_s"] == pytest.approx(68.88, abs=0.01)
    assert info["vehicle_type"] == 2
    assert info["utc_offset_s"] is None and info["utc_start"] is None
    assert "parameters" not in info
    assert set(info["streams"]) == {"imu", "mag", "onboard_attitude", "onboard_local_position"}
    assert info["streams"]["imu"]["topic"] == "sensor_combined" and info["streams"]["imu"]["n"] == 17070
    assert info["streams"]["imu"]["rate_hz"] == pytest.approx(250.0, rel=1e-3)  # 4 ms sensor_combined
    assert any(w.startswith("no GPS: ") for w in info["warnings"])


def test_sun_and_device_options(real_logs_dir, tmp_path, capsys):
    start_s = 1710773351.0  # inside sample_px4_events.ulg (SITL: its log clock is unix time, UTC offset 0)
    sun_csv = tmp_path / "sun.csv"
    write_sun_csv(sun_csv, [start_s + 0.05 * k for k in range(40)])
    device = tmp_path / "device.json"
    device.write_text('{"tilt_deg": 35}')
    argv = ["info", str(real_logs_dir / "sample_px4_events.ulg"), "--sun", str(sun_csv), "--device", str(device)]
    assert main([*argv, "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["streams"]["sun"] == {"topic": "sun.csv", "rate_hz": pytest.approx(20.0, rel=1e-3), "n": 40,
                                      "gaps": []}
    assert info["sun_device"]["tilt_deg"] == 35.0
    assert main(argv) == 0
    assert "sun device  faces tilted 35 deg" in capsys.readouterr().out


def test_sun_time_offset_for_a_log_without_gps(real_logs_dir, tmp_path, capsys):
    sun_csv = tmp_path / "sun.csv"
    write_sun_csv(sun_csv, [1_000_120.0 + 0.1 * k for k in range(20)])  # log time 120 s .. 121.9 s
    argv = ["info", str(real_logs_dir / "sample.ulg"), "--sun", str(sun_csv), "--json"]
    assert main(argv) == EXIT_BAD_INPUT
    assert "sample.ulg has no GPS UTC time" in capsys.readouterr().err
    assert main([*argv, "--sun-time-offset-s", "1000000"]) == 0
    assert json.loads(capsys.readouterr().out)["streams"]["sun"]["n"] == 20


@pytest.mark.parametrize(("make_argv", "message"), [
    (lambda logs, tmp: ["info", str(tmp / "notes.ulg")],
     "solarnav: error: notes.ulg: not a flight log solarnav reads: expected one of the formats: PX4 ULog (starts "
     "with the bytes 55 4c 6f 67 01 12 35); ArduPilot DataFlash (starts with the bytes a3 95)"),
    (lambda logs, tmp: ["info", str(tmp / "absent.ulg")],
     "solarnav: error: {tmp}/absent.ulg: cannot read the file (No such file or directory)"),
    (lambda logs, tmp: ["info", str(logs / "sample_px4_events.ulg"), "--sun", str(tmp / "notes.ulg")],
     "solarnav: error: notes.ulg: no time column: expected unix_time_s or time_utc"),
    (lambda logs, tmp: ["info", str(logs / "sample_px4_events.ulg"), "--device", str(tmp / "notes.ulg")],
     "solarnav: error: --device and --sun-time-offset-s describe the sun-device log: give --sun too"),
])
def test_bad_input_is_one_line_and_exit_code_2(real_logs_dir, tmp_path, capsys, make_argv, message):
    (tmp_path / "notes.ulg").write_text("hello\nworld\n")
    assert main(make_argv(real_logs_dir, tmp_path)) == EXIT_BAD_INPUT
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err.count("\n") == 1 and "Traceback" not in captured.err
    assert captured.err.startswith(message.format(tmp=tmp_path))


def test_bad_arguments_return_2(capsys):
    assert main(["info"]) == EXIT_BAD_INPUT
    assert "the following arguments are required: LOG.ulg" in capsys.readouterr().err
    assert main(["--help"]) == 0
    assert "info" in capsys.readouterr().out
